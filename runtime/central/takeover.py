"""Take-over: a lost peripheral costs no motion (``--peripheral-loss takeover``).

A peripheral is lost when its process exits or it stays silent past the silence rule
(:mod:`.silence`: the faults it raises with ``lost``). Its work is redundant: the central
already computes a late peripheral's round itself with the kernels the peripheral would
have run, bit for bit its reply's values (:meth:`.late.LateData.compute`). From the loss
on, the central runs the lost peripheral's axes of every round itself as soon as the
round's request is out, while the others compute theirs; the rounds that were waiting for
it when it was lost are computed at once. The commands are those of an undisturbed run.

Each computed round is recorded as the late ones are (``faults/computed``), so that
``replay --verify`` re-executes a run with a take-over; the loss itself is recorded on
``faults/degraded`` and listed in the report's ``degraded`` (docs/faults-and-errors.md).

A lost peripheral stays lost for the rest of the run: a reply it still sends is dropped
without being counted against it.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Collection
from typing import Any

import msgpack

from ..config import EXIT_PERIPHERAL
from .fault import Fault
from .intervals import Intervals
from .late import LateData
from .records import InFlight
from .silence import SilenceWatch


class TakeOver:
    """The central's rule for a lost peripheral.

    Parameters
    ----------
    enabled : ``--peripheral-loss takeover``.
    late : the late-data part, which computes a round for given peripherals.
    silence : the silence watch, told to watch a lost peripheral no more.
    intervals : the intervals' part (its requests stop once every peripheral is taken over).
    on_message : the recording's hook, or None.
    """

    def __init__(self, *, enabled: bool, late: LateData, silence: SilenceWatch,
                 intervals: Intervals, on_message: Callable[..., None] | None = None) -> None:
        self.enabled = enabled
        self.late = late
        self.silence = silence
        self.intervals = intervals
        self.on_message = on_message
        self.lost: dict[int, dict[str, Any]] = {}
        """Lost peripheral (0-based) -> its record: ``peripheral`` (1-based),
        ``from_cycle`` (the first interval it did not serve), ``at_interval`` (intervals
        done) and ``why`` (the fault's message)."""
        self.dropped_replies = 0
        """Replies of lost peripherals that came anyway (dropped, not counted against
        them)."""

    def take(self, fault: Fault, intervals: Collection[InFlight], *, done: int,
             next_cycle: int) -> bool:
        """Take over the peripheral ``fault`` names, if it is a loss and the policy is
        ``takeover``: from now on its rounds are computed here, those waiting for it at
        once (:meth:`cover`). A peripheral lost to silence may be alive and not reading:
        every request would then fill its socket until the central's put waited for it
        (Zenoh's low-latency transport writes in the caller), and it reads the same
        request key as the others; so the others are taken over too and no request is
        sent any more (they stand by). Returns False where the fault stands (another
        kind, or the policy ``fault``)."""
        if not (self.enabled and fault.lost and fault.process.startswith("peripheral-")):
            return False
        k = int(fault.process.rsplit("-", 1)[1]) - 1
        if k in self.lost:
            return True
        self._lose(k, str(fault), intervals, done=done, next_cycle=next_cycle)
        if fault.lost == "silent":
            for j in range(self.intervals.settings.peripherals):
                if j not in self.lost:
                    self._lose(j, f"stands by: peripheral {k + 1} fell silent, and a silent "
                               "process may have stopped reading the requests they share",
                               intervals, done=done, next_cycle=next_cycle)
            self.intervals.requests_on = False
        self.cover(intervals)
        return True

    def _lose(self, k: int, why: str, intervals: Collection[InFlight], *, done: int,
              next_cycle: int) -> None:
        """Note peripheral ``k`` lost (``why``), watch it no more, record it."""
        waiting = [f.cycle for f in intervals if k in f.waiting]
        self.lost[k] = {"peripheral": k + 1, "from_cycle": min(waiting, default=next_cycle),
                        "at_interval": done, "why": why}
        self.silence.forget(k)
        if self.on_message is not None:
            self.on_message("degraded", f"{self.late.faults_key}/degraded", next_cycle, 0,
                            msgpack.packb(self.lost[k]), time.monotonic_ns())

    def cover(self, intervals: Collection[InFlight]) -> bool:
        """Compute here the lost peripherals' part of every round that waits for one;
        returns whether an interval went on (its round complete: what it made ready is to
        be sent). Raises :class:`~.fault.Fault` where a round needs values only a lost
        peripheral held (a round run on values it kept from an earlier round)."""
        went_on = False
        for f in list(intervals):
            gone = sorted(f.waiting & self.lost.keys())
            if not gone or f.round is None:
                continue
            if not self.late.compute(f, gone, late=False):
                k = gone[0]
                raise Fault(f"peripheral {k + 1} was lost and round {f.round.index} of cycle "
                            f"{f.cycle} needs values only it held: "
                            f"{self.lost[k]['why']}", process=f"peripheral-{k + 1}",
                            code=EXIT_PERIPHERAL)
            went_on = went_on or not f.waiting
        return went_on

    def ignores(self, k: int) -> bool:
        """Whether a reply of peripheral ``k`` is to be dropped (it was taken over)."""
        if k in self.lost:
            self.dropped_replies += 1
            return True
        return False

    def report(self) -> list[dict[str, Any]]:
        """The report's ``degraded``: each loss, in the order they came."""
        return list(self.lost.values())


__all__ = ["TakeOver"]
