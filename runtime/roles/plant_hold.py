"""What the plant's drives apply while no command comes: the trend of the last commands.

A realtime plant whose command is not there at its tick applies the command the central
extrapolated for that period (``next``, sent with the command before); past that one
period it used to keep the last command it applied. A command is noisy from one interval
to the next (the feedback acts on encoder counts: a few tenths of a newton metre at 1 ms),
so one of them held for tens of milliseconds drives the arms off: a central that did not
run for 50 ms cost the slow pick & place 6.5-9.4 mm of tracking, where the robot had
followed within 0.1 mm, and one such stall faulted the take-over test (the observer lost
the robot at 26 mm).

:class:`CommandHold` keeps the commands applied over the last :data:`HOLD_WINDOW_S` and
gives, for a period without one, the least-squares line through them evaluated at that
period, at most :data:`HOLD_AHEAD_S` past the newest: the trend filters the noise and follows
a torque that is changing, and stops growing where a line no longer says anything.
Offline, the simulated Delta at 1 ms with bursts of late commands (bench/missed.py),
worst tracking over six phases of the task (docs/measurements/2026-11-29-command-hold.md):

| task, burst (commands x periods late) | last command kept | mean of last 16 | this rule |
|---|---|---|---|
| pick & place (80 m/s^2), 4 by 2 | 0.122 mm | 0.219 mm | 0.127 mm |
| pick & place, 16 by 16 | 3.80 mm | 8.78 mm | 3.86 mm |
| slow pick & place (2 m/s^2), 16 by 16 | 0.767 mm | 0.091 mm | 0.133 mm |
| slow pick & place, 64 by 64 | 9.46 mm | 1.17 mm | 1.05 mm |

(64 periods without a command cost the fast pick & place hundreds of millimetres
whatever is held: no drive rides that out.)
"""

from __future__ import annotations

from collections import deque
from typing import Final

HOLD_WINDOW_S: Final = 0.016
"""The time back over which the held command's line is fitted (16 commands at 1 ms, at
least three)."""

HOLD_AHEAD_S: Final = 0.004
"""The time past the newest command up to which the line is followed (4 periods at 1 ms,
at least one); then it is held."""


class CommandHold:
    """The last commands applied, and the command to hold in a period without one, at
    sampling period ``period_s``."""

    __slots__ = ("ahead", "recent")

    def __init__(self, period_s: float) -> None:
        if not period_s > 0:
            raise ValueError(f"period_s must be > 0 s, got {period_s!r}")
        self.recent: deque[tuple[int, list[float]]] = deque(
            maxlen=max(3, round(HOLD_WINDOW_S / period_s)))
        self.ahead = max(1, round(HOLD_AHEAD_S / period_s))

    def note(self, cycle: int, tau: list[float]) -> None:
        """Command ``tau`` of ``cycle`` was applied (cycles increasing)."""
        self.recent.append((cycle, tau))

    def held(self, cycle: int) -> list[float] | None:
        """The command for period ``cycle``, which has none of its own: the least-squares
        line through the commands noted, at ``min(cycle, newest + ahead)``; their mean
        while fewer than three are noted; None before any."""
        recent = self.recent
        n = len(recent)
        if n == 0:
            return None
        if n < 3:
            return [sum(c[1][i] for c in recent) / n for i in range(3)]
        xs = [c[0] for c in recent]
        mx = sum(xs) / n
        sxx = sum((x - mx) ** 2 for x in xs)
        at = min(cycle, xs[-1] + self.ahead) - mx
        out = []
        for i in range(3):
            ys = [c[1][i] for c in recent]
            my = sum(ys) / n
            slope = sum((x - mx) * (y - my) for x, y in zip(xs, ys, strict=True)) / sxx
            out.append(my + slope * at)
        return out


__all__ = ["HOLD_AHEAD_S", "HOLD_WINDOW_S", "CommandHold"]
