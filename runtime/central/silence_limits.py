"""How long a silence may last, by clock: the part :class:`~.silence.SilenceWatch` is given
once, when the run's clock is known (docs/faults-and-errors.md, the silence rule).

:class:`Timeout` (lockstep and freerun): time is the processes' own, so a silence is a
fault after ``--timeout`` whatever the machine does, and a peripheral is watched only
while a round waits for it. :class:`Paced` (realtime): ``--fault-periods`` periods at the
current control rate, lengthened by the central's own stalls, by a silence the plant
shared and while the machine, not the process, is slow (:class:`~.excuse.Excuses`); every
process that has spoken is watched between its rounds too (a frozen one is named within
its limit). Both answer the same questions; the watch asks them without knowing the clock.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Sequence

from . import silence_rule
from .excuse import Excuses

STARTUP_INTERVALS = 20
STARTUP_LIMIT_S = 0.020
"""Realtime: until :data:`STARTUP_INTERVALS` intervals are done the silence limit is at
least this (first samples, first real values through every process)."""

Gaps = deque[tuple[int, int]]
"""Spans ``(from, to)`` in which something did not happen (:mod:`.silence_rule`)."""


class Timeout:
    """Lockstep and freerun: the limit is ``timeout_s``, and nothing lengthens it."""

    def __init__(self, timeout_s: float) -> None:
        self.timeout_ns = int(timeout_s * 1e9)

    def limit_ns(self, done: int) -> int:
        """The limit after ``done`` intervals: the time-out, always."""
        return self.timeout_ns

    def asked(self, now: int) -> None:
        """A request went out at ``now``: nothing to note."""

    def own_stall(self, since: int, now: int) -> int:
        """The central's own stalls are not the machine's doing here: none counts."""
        return 0

    def fault_at(self, since: int, now: int, limit_ns: int) -> int:
        """A silence since ``since`` is a fault ``limit_ns`` later."""
        return since + limit_ns

    def excused(self, role: str, since: int, now: int, limit_ns: int, *, answered: int,
                limit_end: Callable[[], int]) -> bool:
        """No silence is excused."""
        return False

    def watched(self, heard: Sequence[int]) -> list[int]:
        """Of processes last heard at ``heard`` (0: never), those whose silence is watched
        between their rounds: none (a silence counts only while a round waits)."""
        return []


class Paced:
    """Realtime: the silence rule's three steps (docs/faults-and-errors.md).

    Parameters
    ----------
    period_s : the sampling period.
    fault_periods : the limit in periods (at the current control rate).
    stride : the control-rate divisor now: samples come every ``stride()`` periods.
    own_gaps, plant_gaps : the central's own stalls and the plant's silences, as the watch
        records them (shared, not copied).
    last_sample : when the newest sample came (0: none yet).
    excuse : the excuses of silences past their limit.
    """

    def __init__(self, *, period_s: float, fault_periods: float, stride: Callable[[], int],
                 own_gaps: Gaps, plant_gaps: Gaps, last_sample: Callable[[], int],
                 excuse: Excuses) -> None:
        self.period_s = period_s
        self.period_ns = int(period_s * 1e9)
        self.fault_periods = fault_periods
        self.stride = stride
        self.own_gaps = own_gaps
        self.plant_gaps = plant_gaps
        self.last_sample = last_sample
        self.excuse = excuse

    def limit_ns(self, done: int) -> int:
        """``fault_periods`` periods at the current rate (samples come every ``stride``
        periods); during the first :data:`STARTUP_INTERVALS` intervals at least
        :data:`STARTUP_LIMIT_S` (first samples, first real values through every
        process)."""
        limit = self.fault_periods * self.period_s * self.stride()
        if done < STARTUP_INTERVALS:
            limit = max(limit, STARTUP_LIMIT_S)
        return int(limit * 1e9)

    def asked(self, now: int) -> None:
        """A request went out at ``now``: note the machine's CPU pressure
        (:meth:`Excuses.mark`)."""
        self.excuse.mark(now)

    def own_stall(self, since: int, now: int) -> int:
        """How much of ``[since, now]`` the central itself did not run: no silence can be
        judged while the judge is stopped; a process that failed in that time is named
        within the limit after the central runs again."""
        return silence_rule.overlap(self.own_gaps, since, now)

    def fault_at(self, since: int, now: int, limit_ns: int) -> int:
        """When a peripheral silent since ``since`` becomes a fault: ``since + limit_ns``,
        later by the part of the silence in which the central itself did not run, and once
        that has passed, by the part the plant's samples shared, up to one more limit
        (:func:`~.silence_rule.fault_at`). A silence the whole unit shares is a stall of
        the machine, not a failed process; a frozen process is still named while the
        plant goes on talking."""
        own = self.own_stall(since, now)
        return silence_rule.fault_at(since, now, limit_ns, own_ns=own, shared=lambda: (
            silence_rule.plant_shared(
                self.plant_gaps, self.last_sample(), since, now,
                every_ns=self.period_ns * self.stride(),  # how often the plant samples
                own_ns=own, limit_ns=limit_ns)))

    def excused(self, role: str, since: int, now: int, limit_ns: int, *, answered: int,
                limit_end: Callable[[], int]) -> bool:
        """Whether the silence of ``role`` past its limit is excused now
        (:meth:`Excuses.ask`)."""
        return self.excuse.ask(role, since, now, limit_ns, answered=answered,
                               limit_end=limit_end)

    def watched(self, heard: Sequence[int]) -> list[int]:
        """Of processes last heard at ``heard`` (0: never), those whose silence is watched
        between their rounds too: each that has spoken (liveness)."""
        return [k for k, at in enumerate(heard) if at]


__all__ = ["STARTUP_INTERVALS", "STARTUP_LIMIT_S", "Paced", "Timeout"]
