"""The central's records: one interval in flight through the pipeline, and the log of
every finished interval."""

from __future__ import annotations

import hashlib
import math
import struct
from collections.abc import Generator
from dataclasses import dataclass, field
from typing import Any

from ...topology.plan import Round
from ..compute.timing import BoundedSeries, ErrorSeries, IntervalTimes


@dataclass
class InFlight:
    """One interval between its sample and its command: its steps (a generator that yields
    each round to exchange), values, and where it stands in the pipeline."""

    cycle: int
    gen: Generator[Round, None, Any]
    ctx: dict
    sample_ns: int
    start_ns: int
    round: Round | None = None
    waiting: set[int] = field(default_factory=set)
    deadline_ns: int = 0
    handed_off: bool = False
    started: bool = False
    late_ns: int = 0  # realtime: when this round's data is late (its share of the deadline)
    finishing: bool = False  # every exchange done; its last central steps are pending
    dropped: set[int] = field(default_factory=set)  # peripherals whose replies were held
    work_ns: int = 0  # the longest work one peripheral reported for one of its rounds
    awaiting_sample: bool = False
    """Started ahead of its sample (depth 2, a plan whose rounds run ahead): its sample-free
    steps and rounds run now, the rest once its sample comes (``sample_ns`` is 0 until
    then)."""
    gated: bool = False  # its steps are done up to the sample: resume once it is here

    # -- its phase: these methods are the only writers (tests/test_central_seen.py) -----

    def stepped(self) -> None:
        """Its steps' generator has been started (it is resumed from now on)."""
        self.started = True

    def handed(self) -> None:
        """Its estimate is final: the next interval may use it (Fig. 24's hand-off)."""
        self.handed_off = True

    def at_round(self, rnd: Round) -> None:
        """Its steps reached ``rnd``, the next round to exchange."""
        self.round = rnd

    def gate(self) -> None:
        """Run ahead of its sample, its sample-free steps and rounds are done: it waits
        for its sample."""
        self.gated, self.round = True, None

    def sampled(self, sample_ns: int, start_ns: int) -> bool:
        """Its sample came at ``sample_ns``; returns whether it was gated (its rounds run
        ahead are back: it goes on from the sample's steps), and is no longer."""
        self.sample_ns, self.start_ns = sample_ns, start_ns
        self.awaiting_sample = False
        gated, self.gated = self.gated, False
        return gated

    def sent(self, peripherals: int, *, deadline_ns: int, late_ns: int) -> None:
        """Its round went out: it waits for every peripheral, a silence past
        ``deadline_ns`` is a fault, its data is late past ``late_ns`` (0: never)."""
        self.waiting = set(range(peripherals))
        self.deadline_ns = deadline_ns
        self.late_ns = late_ns

    def late_at(self, late_ns: int) -> None:
        """Its round's data is late past ``late_ns`` (0: not judged late any more)."""
        self.late_ns = late_ns

    def answered(self, k: int, work_ns: int = 0) -> bool:
        """Peripheral ``k``'s part of its round came (after ``work_ns`` of work); returns
        whether the round is complete."""
        self.work_ns = max(self.work_ns, work_ns)
        self.waiting.discard(k)
        return not self.waiting

    def stood_in(self, k: int, *, late: bool) -> None:
        """The central supplied peripheral ``k``'s part (held or computed values); ``late``:
        its reply, when it comes, is a late one."""
        if late:
            self.dropped.add(k)
        self.waiting.discard(k)

    def finish_after_request(self) -> None:
        """Its last round is complete; its last steps run once the next request is out."""
        self.finishing = True


LATE_KEPT = 4096
"""How many late intervals' work :class:`CycleLog` keeps (bounded memory)."""


@dataclass
class CycleLog:
    """Per-cycle measurements in bounded memory (a long run does not grow): the intervals'
    command times and traversals and the tracking errors, exact for the newest ones and
    summarised before (:mod:`..compute.timing`); the commands only as a running digest and peak.
    """

    times: IntervalTimes = field(default_factory=IntervalTimes)
    errors: ErrorSeries = field(default_factory=ErrorSeries)
    digest: Any = field(default_factory=hashlib.sha256)
    torque_max: float = 0.0
    true_p: dict[int, tuple[float, float, float]] = field(default_factory=dict)  # recent only
    work_ns: BoundedSeries = field(default_factory=lambda: BoundedSeries("i"))
    """Each interval's longest work of one peripheral in one round (ns), in realtime with
    peripherals only: the newest intervals, the reference of :attr:`late_work_ns`."""
    late: int = 0
    """Intervals whose command left after its deadline (realtime; ``depth`` periods after
    the sample)."""
    late_work_ns: list[int] = field(default_factory=list)
    """Their work as in :attr:`work_ns`, the first :data:`LATE_KEPT` of them."""

    def sampled(self, cycle: int, p: tuple[float, float, float],
                ref: Any | None) -> None:
        """Note the plant's true position ``p`` at sample ``cycle`` and, for the run's
        samples (``ref``, the reference there; None for one past the run's end), the
        tracking error."""
        true_p = self.true_p
        true_p[cycle] = p
        if len(true_p) > 64:  # the oldest goes, even the one just taken (samples ahead)
            del true_p[min(true_p)]
        if ref is not None:
            self.errors.append(math.dist(p, ref))

    def record(self, f: InFlight, cmd: Any, now: int, *, deadline_ns: int) -> bool:
        """Log interval ``f``, whose command ``cmd`` left at ``now``: its times, where
        ``deadline_ns`` is set (realtime with peripherals) its work and whether it was
        late, the command into the digest and the peak. Returns whether it was late."""
        self.times.append(now, now - f.sample_ns)
        late = False
        if deadline_ns:  # only realtime reports where late intervals went
            self.work_ns.append(f.work_ns)
            if now - f.sample_ns > deadline_ns:
                late = True
                self.late += 1
                if len(self.late_work_ns) < LATE_KEPT:
                    self.late_work_ns.append(f.work_ns)
        self.digest.update(struct.pack("<3d", *cmd))
        self.torque_max = max(self.torque_max, abs(cmd[0]), abs(cmd[1]), abs(cmd[2]))
        return late

    @property
    def cmd_ns(self) -> BoundedSeries:
        """When each interval's command left (ns)."""
        return self.times.cmd_ns

    @property
    def traversal_ns(self) -> BoundedSeries:
        """Each interval's traversal, sample to command (ns)."""
        return self.times.traversal_ns

    @property
    def sample_ns(self) -> list[int]:
        """Sample times of the kept intervals, from command times and traversals."""
        return self.times.sample_ns


__all__ = ["LATE_KEPT", "CycleLog", "InFlight"]
