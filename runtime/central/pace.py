"""When a round's data is late and how long a lone round may wait: the run's clock,
chosen once (docs/architecture.md, late data and the lone round's hold).

Under the ``realtime`` clock the command of sample k is due ``depth`` periods after it
(the deadline); round i of r has its data late at its share of that deadline, ``(i + 1)
/ r`` (runtime/central/late.py applies each round's policy then), and a round run ahead
of its sample is late as soon as the sample is here. A lone round held for the next
interval's first round waits until the next sample is due, one period on, and a quarter
period more (a late or lost sample).

Under ``lockstep`` and ``freerun`` time is the processes' own: no data is late, and the
lone round waits for the next sample as long as a silence may last (the plant's silence
is a fault after ``--timeout``).
"""

from __future__ import annotations

import time
from typing import Protocol

from .records import InFlight
from .settings import LoopSettings


class Pace(Protocol):
    """The deadlines of one clock."""

    def round_late_at(self, f: InFlight, index: int, round_trips: int) -> int:
        """When the data of round ``index`` (of ``round_trips``) of ``f``, just sent, is
        late (``time.monotonic_ns``); ``f.late_ns`` as it is (0: never) where the clock
        sets no such time."""

    def sample_late_at(self, f: InFlight, t_ns: int) -> int:
        """When the rounds ``f`` ran ahead of its sample, which came at ``t_ns``, are
        late; ``f.late_ns`` as it is where the clock sets no such time."""

    def hold_until(self, f: InFlight, limit_ns: int) -> int:
        """Until when the lone round of ``f`` waits for the next interval's first round;
        ``limit_ns`` is the silence limit now."""

    def overload_hint(self, *, misses: int, skipped: int, periods: int) -> str:
        """For a fault's message: when most deadlines were missed (more than 5 and a tenth
        of ``periods``), that the machine, not a process, is the likely cause; "" where
        the clock sets no deadline."""


class Realtime:
    """The realtime clock's deadlines (module notes)."""

    def __init__(self, settings: LoopSettings) -> None:
        self.depth, self.period_ns = settings.depth, settings.period_ns
        self.peripherals = settings.peripherals

    def round_late_at(self, f: InFlight, index: int, round_trips: int) -> int:
        if not round_trips or f.awaiting_sample:
            return f.late_ns
        share = (index + 1) / round_trips
        return f.sample_ns + int(self.depth * self.period_ns * share)

    def sample_late_at(self, f: InFlight, t_ns: int) -> int:
        return t_ns

    def hold_until(self, f: InFlight, limit_ns: int) -> int:
        return f.sample_ns + self.period_ns + self.period_ns // 4

    def overload_hint(self, *, misses: int, skipped: int, periods: int) -> str:
        periods = max(1, periods)
        if misses + skipped <= max(5, periods // 10):
            return ""
        return (f"; {misses} commands missed their deadline and {skipped} "
                f"samples were skipped in {periods} periods: this machine does not sustain "
                f"a {self.period_ns / 1e6:g} ms period with {self.peripherals} peripheral(s) "
                "(try a longer --period or --fault-periods, or --clock lockstep)")


class Virtual:
    """Lockstep and freerun: no data is late (module notes)."""

    def round_late_at(self, f: InFlight, index: int, round_trips: int) -> int:
        return f.late_ns

    def sample_late_at(self, f: InFlight, t_ns: int) -> int:
        return f.late_ns

    def hold_until(self, f: InFlight, limit_ns: int) -> int:
        return time.monotonic_ns() + limit_ns

    def overload_hint(self, *, misses: int, skipped: int, periods: int) -> str:
        return ""


def pace_of(settings: LoopSettings) -> Pace:
    """The deadlines of ``settings.clock``."""
    return Realtime(settings) if settings.clock == "realtime" else Virtual()


__all__ = ["Pace", "Realtime", "Virtual", "pace_of"]
