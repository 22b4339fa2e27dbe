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

A lost peripheral comes back (rejoins) by answering again. ``ctrlunit start`` starts a
peripheral whose process exited anew (at most :data:`RESTARTS` times a run); one started
by hand (``ctrlunit peripheral --index K --unit U --connect ...``) asks for the run's
configuration first. Either gets the placement with ``go`` (:class:`~.orders.Orders`)
and answers the requests it sees. Its replies are dropped, without being counted against
it, until :data:`REJOIN_PARTS` in a row have come for current intervals; from the next
interval on (whose first request is not out yet) its rounds are its own again, and the
central, which never waited for it, computes its part only of the intervals begun
before.

A peripheral lost to silence is not asked any more, and the others stand by with it
(:meth:`TakeOver.take`). If a reply of its own comes after all (it was slow, not frozen:
it read the requests sent before its loss), it is alive and reading, so the requests go
out again (at most :data:`RESUMES` times a run) and every peripheral taken over comes
back as above. Until then each must answer within the silence limit: one that does not
stops the requests again, for the rest of the run.
"""

from __future__ import annotations

import time
from collections import Counter
from collections.abc import Callable, Collection
from typing import Any

import msgpack

from ..config import EXIT_PERIPHERAL
from .fault import Fault
from .intervals import Intervals
from .late import LateData
from .outgoing import Outgoing
from .records import InFlight
from .silence import SilenceWatch

REJOIN_PARTS = 50
"""Replies in a row, each on time, that bring a lost peripheral back: it has shown that
it keeps up. On time: in realtime before its round's data would have been late (the
late-data time, its share of the deadline), so that the intervals that wait for it again
are not made late; in the other clocks, for an interval at most :data:`CURRENT_BEHIND`
behind the newest begun."""
CURRENT_BEHIND = 4
DUE_KEPT = 64
"""Rounds whose late-data time is kept for judging a lost peripheral's replies."""
RESUMES = 3
"""How often in one run the requests go out again after a peripheral's silence, once a
reply of its own shows it alive (:meth:`TakeOver.sift`)."""
RESTARTS = 3
"""How often the launcher (``ctrlunit start``) starts a peripheral whose process exited
anew in one run: a role that keeps failing costs the machine no more starts."""


class TakeOver:
    """The central's rule for a lost peripheral.

    Parameters
    ----------
    enabled : ``--peripheral-loss takeover``.
    late : the late-data part, which computes a round for given peripherals.
    silence : the silence watch, told to watch a lost peripheral no more.
    intervals : the intervals' part.
    outgoing : what the central sends (its requests stop once every peripheral is taken
        over).
    on_message : the recording's hook, or None.
    """

    def __init__(self, *, enabled: bool, late: LateData, silence: SilenceWatch,
                 intervals: Intervals, outgoing: Outgoing,
                 on_message: Callable[..., None] | None = None) -> None:
        self.enabled = enabled
        self.late = late
        self.silence = silence
        self.intervals = intervals
        self.outgoing = outgoing
        self.on_message = on_message
        self.lost: dict[int, dict[str, Any]] = {}
        """Lost peripheral (0-based) -> its record: ``peripheral`` (1-based),
        ``from_cycle`` (the first interval it did not serve), ``at_interval`` (intervals
        done) and ``why`` (the fault's message); once it is back, ``back_from_cycle``."""
        self.history: list[dict[str, Any]] = []
        """Every loss's record, in the order they came (the report's ``degraded``)."""
        self.back: dict[int, int] = {}
        """Peripheral back -> the first interval it serves again: the central still
        computes its part of the intervals begun before."""
        self.due: dict[tuple[int, int], int] = {}
        """(cycle, round) -> when its data is late (realtime), for the rounds computed
        here for a lost peripheral: its replies are judged on time against it."""
        self.settling: set[int] = set()
        """Peripherals back while intervals begun before their return are in flight."""
        self.in_a_row: dict[int, int] = {}
        self.restarts: Counter[int] = Counter()
        """Peripheral -> how often the launcher started it anew."""
        self.starting: set[int] = set()
        """Peripherals started anew that have not answered yet (then :meth:`sift` gives
        them the unit's scheduling policy)."""
        """Lost peripheral -> its current replies in a row (:data:`REJOIN_PARTS`)."""
        self.resumes = 0
        """How often the requests went out again after a silence (:data:`RESUMES`)."""
        self.silent: int | None = None
        """The peripheral whose silence stopped the requests, until a reply of its own."""
        self.quiet: set[int] = set()
        """Peripherals lost to that silence: the silent one and those that stood by (one
        whose process exited comes back as a restarted one does, not on probation)."""
        self.on_probation: dict[int, int] = {}
        """While the requests go out again: each peripheral taken over -> when it last
        answered (or the requests resumed)."""
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
        restart = self.silence.supervision.restart
        if fault.lost == "exited" and restart is not None and self.restarts[k] < RESTARTS:
            self.restarts[k] += 1
            self.lost[k]["started_again"] = self.restarts[k]
            self.starting.add(k)
            restart(fault.process)  # it comes back once it answers (:meth:`sift`)
        if fault.lost == "silent":
            if self.on_probation or self.resumes >= RESUMES:  # the requests stop for good
                self._for_good(k, "silent again after the requests went out again"
                               if self.on_probation else f"they went out again {RESUMES} "
                               "times already")
            self.silent = k if self.resumes < RESUMES else None
            self.quiet = {k}
            for j in range(self.intervals.settings.peripherals):
                if j not in self.lost:
                    self.quiet.add(j)
                    self._lose(j, f"stands by: peripheral {k + 1} fell silent, and a silent "
                               "process may have stopped reading the requests they share",
                               intervals, done=done, next_cycle=next_cycle)
            self.outgoing.requests_on = False
        self.cover(intervals)
        return True

    def _lose(self, k: int, why: str, intervals: Collection[InFlight], *, done: int,
              next_cycle: int) -> None:
        """Note peripheral ``k`` lost (``why``), watch it no more, record it."""
        waiting = [f.cycle for f in intervals if k in f.waiting]
        self.lost[k] = {"peripheral": k + 1, "from_cycle": min(waiting, default=next_cycle),
                        "at_interval": done, "why": why}
        self.history.append(self.lost[k])
        self.in_a_row[k] = 0
        self.silence.forget(k)
        self._record(self.lost[k], next_cycle)

    def _record(self, record: dict[str, Any], cycle: int) -> None:
        if self.on_message is not None:
            self.on_message("degraded", f"{self.late.faults_key}/degraded", cycle, 0,
                            msgpack.packb(record), time.monotonic_ns())

    def covers(self, k: int, cycle: int) -> bool:
        """Whether the central computes peripheral ``k``'s part of interval ``cycle``."""
        return k in self.lost or cycle < self.back.get(k, -1)

    def may_rejoin(self, role: str) -> bool:
        """Whether ``role`` (``peripheral-K``) is lost and could come back: requests still
        go out (:meth:`take`)."""
        k = int(role.rsplit("-", 1)[1]) - 1 if role.startswith("peripheral-") else -1
        return k in self.lost and self.outgoing.requests_on

    def sift(self, k: int, parts: list[dict[str, Any]], *, next_cycle: int, done: int,
             rx: int = 0) -> list[dict[str, Any]]:
        """The parts of peripheral ``k``'s reply the central is to take: those of
        intervals it does not compute for ``k`` (:meth:`covers`). The others are dropped,
        not counted against it; while ``k`` is lost each counts towards its coming back,
        which starts at ``next_cycle`` (the next interval to begin), where it came on
        time (:data:`REJOIN_PARTS`; ``rx``: when it came)."""
        if not self.history:
            return parts
        kept = [p for p in parts if not self.covers(k, p["cycle"])]
        if len(kept) == len(parts):
            return parts
        self.dropped_replies += len(parts) - len(kept)
        if k in self.lost:
            self.lost[k]["replies_while_lost"] = self.lost[k].get("replies_while_lost", 0) \
                + len(parts)
            self._alive(k, rx or time.monotonic_ns(), done=done)
            promote = self.silence.supervision.promote
            if k in self.starting and promote is not None:
                self.starting.discard(k)  # set up: it answers
                promote(f"peripheral-{k + 1}")
            for p in parts:
                late_ns = self.due.get((p["cycle"], p["stage"]), 0)
                current = (rx <= late_ns if late_ns
                           else p["cycle"] >= next_cycle - CURRENT_BEHIND)
                self.in_a_row[k] = self.in_a_row[k] + 1 if current else 0
            if self.in_a_row[k] >= REJOIN_PARTS:
                record = self.lost.pop(k)
                record["back_from_cycle"] = self.back[k] = next_cycle
                self.settling.add(k)
                record["back_at_interval"] = done
                self.silence.watch_again(k, time.monotonic_ns())
                self._record(record, next_cycle)
        return kept

    def _alive(self, k: int, now: int, *, done: int) -> None:
        """Lost peripheral ``k`` answered at ``now``: on probation, noted; the one whose
        silence stopped the requests, proved alive and reading: they go out again (and
        the recording says so)."""
        if k in self.on_probation:
            self.on_probation[k] = now
        if k != self.silent or self.outgoing.requests_on:
            return
        self.silent = None
        self.resumes += 1
        self.outgoing.requests_on = True
        self.on_probation = dict.fromkeys(self.quiet & self.lost.keys(), now)
        self.lost[k]["requests_again_at_interval"] = done
        self._record(self.lost[k], self.intervals.next_cycle)

    def _for_good(self, k: int, why: str) -> None:
        """The requests stop for the rest of the run (``why``, on peripheral ``k``'s
        record, and in the recording)."""
        self.outgoing.requests_on = False
        self.resumes = RESUMES
        self.on_probation.clear()
        self.silent = None
        record = self.lost.get(k) or {"peripheral": k + 1}
        record["requests_stopped_again"] = why
        self._record(record, self.intervals.next_cycle)

    def probation(self, now: int) -> None:
        """While the requests go out again (the silence watch's turn, once the inbox is
        read): a peripheral taken over that has not answered within the silence limit,
        the central's own stalls and the plant's shared silence allowed as the silence
        rule allows them (:meth:`~.silence.SilenceWatch.fault_at`), may have stopped
        reading them (its socket would fill until the central's put waited:
        :meth:`take`), so they stop for the rest of the run, and those back since stand
        by again."""
        if not self.on_probation:
            return
        for j in [j for j in self.on_probation if j not in self.lost]:
            del self.on_probation[j]
        limit = self.silence.limit_ns(self.intervals.done)
        unheard = sorted(j for j, heard in self.on_probation.items()
                         if now > self.silence.fault_at(heard, now, limit))
        if not unheard:
            return
        why = f"no answer for {limit / 1e6:.1f} ms after the requests went out again"
        self._for_good(unheard[0], why)
        iv = self.intervals
        for j in range(iv.settings.peripherals):
            if j not in self.lost:
                self._lose(j, f"stands by: peripheral {unheard[0] + 1} gave {why}",
                           iv.inflight.values(), done=iv.done, next_cycle=iv.next_cycle)
        self.cover(iv.inflight.values())

    @property
    def covering(self) -> bool:
        """Whether the central computes a peripheral's part of some interval."""
        return bool(self.lost or self.settling)

    def check_children(self) -> None:
        """The silence watch's look at the role processes before the run (the warm-up,
        the placement): a peripheral whose process exited is taken over there too."""
        try:
            self.silence.check_children()
        except Fault as fault:
            if not self.take(fault, (), done=self.intervals.done,
                             next_cycle=self.intervals.next_cycle):
                raise

    def cover(self, intervals: Collection[InFlight]) -> bool:
        """Compute here the lost peripherals' part of every round that waits for one;
        returns whether an interval went on (its round complete: what it made ready is to
        be sent). Raises :class:`~.fault.Fault` where a round needs values only a lost
        peripheral held (a round run on values it kept from an earlier round)."""
        went_on = False
        for k in [k for k in self.settling if all(f.cycle >= self.back[k] for f in intervals)]:
            self.settling.discard(k)
        for f in list(intervals):
            gone = sorted(k for k in f.waiting if self.covers(k, f.cycle))
            if not gone or f.round is None:
                continue
            if self.lost.keys() & set(gone):  # when its data would be late (:meth:`sift`)
                self.due[(f.cycle, f.round.index)] = f.late_ns
                if len(self.due) > DUE_KEPT:
                    del self.due[min(self.due)]
            if not self.late.compute(f, gone, late=False):
                k = gone[0]
                raise Fault(f"peripheral {k + 1} was lost and round {f.round.index} of cycle "
                            f"{f.cycle} needs values only it held: "
                            f"{self.lost[k]['why']}", process=f"peripheral-{k + 1}",
                            code=EXIT_PERIPHERAL)
            went_on = went_on or not f.waiting
        return went_on

    def report(self) -> list[dict[str, Any]]:
        """The report's ``degraded``: each loss, in the order they came."""
        return [dict(r) for r in self.history]


__all__ = ["CURRENT_BEHIND", "REJOIN_PARTS", "RESTARTS", "RESUMES", "TakeOver"]
