"""Late data (realtime): a round whose replies are not all in by its share of the
deadline follows its late-data policy (docs/faults-and-errors.md): ``wait`` for them,
``hold`` the last values of the missing peripherals' axes, ``compute`` the missing axes
on the central with the kernels the peripherals would have run, or ``fault``.

:class:`LateData` keeps the values it may hold (the last accepted per axis) and which
rounds' replies will come late; the scheduler asks it after every event
(:meth:`LateData.check`) and gets back, through ``advance``, each interval whose round it
completed.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Collection
from typing import Any

import msgpack

from ...topology.plan import ExchangePlan as Plan
from ..compute.blocks import ObserverDiverged
from ..compute.engine import Engine
from ..config import EXIT_OBSERVER, EXIT_PERIPHERAL, LATE_POLICIES
from .fault import Fault
from .records import InFlight

HELD_KEPT = 1024
"""How many (cycle, round, peripheral) whose replies will come late are remembered (the
oldest are forgotten: their replies then count as unexpected, not late)."""


def late_policies(plan: Plan, late: dict[str, str], default: str) -> dict[int, str]:
    """Policy per round: the strictest of its blocks' (fault > hold > compute > wait),
    from ``late`` (per block) or ``default``; every round has at least one block."""
    order = {p: k for k, p in enumerate(LATE_POLICIES)}
    return {r.index: max((late.get(b.name, default) for b in r.blocks),
                         key=order.__getitem__) for r in plan.rounds}


class LateData:
    """The late-data policies of one central.

    Parameters
    ----------
    engine : the engine of the run's plan (:meth:`use` when it changes).
    late, late_policy : the policy per block and the default (``rc.schedule``).
    faults_key : where held and computed rounds are recorded (``<root>/faults``).
    pending : whether events wait in the central's inbox.
    advance : go on with an interval whose round is now complete.
    span : note the central's own compute (process, cycle, t0, t1).
    on_message : the recording's hook, or None.
    """

    def __init__(self, engine: Engine, *, late: dict[str, str],
                 late_policy: str, faults_key: str, pending: Callable[[], bool],
                 advance: Callable[[InFlight], None],
                 span: Callable[[str, int, int, int], None],
                 on_message: Callable[..., None] | None = None) -> None:
        self.late = late
        self.default = late_policy
        self.faults_key = faults_key
        self.pending = pending
        self.advance = advance
        self.span = span
        self.on_message = on_message
        self.last_vals: dict[str, list[Any]] = {}
        """The last accepted value of each received name, per axis."""
        self.held: set[tuple[int, int, int]] = set()
        """(cycle, round, peripheral) whose values were held or computed, or whose
        interval was dropped: their replies, when they come, are late."""
        self.late_per_axis = [0, 0, 0]
        self.computed = 0
        """Late peripherals' rounds the central ran itself (``compute``)."""
        self.taken_over = 0
        """Rounds of lost peripherals the central ran itself (.takeover)."""
        self.use(engine)

    def use(self, engine: Engine) -> None:
        """Follow ``engine``'s plan (its rounds' policies)."""
        self.engine = engine
        self.policy = late_policies(engine.plan, self.late, self.default)

    # -- what the intake tells it --------------------------------------------------------

    def remember(self, vals: dict[str, Any], axes: tuple[int, ...]) -> None:
        """Keep ``vals`` (a reply's, for ``axes``) as the last accepted values."""
        Engine.merge(self.last_vals, vals, axes)

    def expect_late(self, cycle: int, stage: int, peripheral: int) -> None:
        """A reply of ``peripheral`` to ``cycle``'s round ``stage`` will come late."""
        self.held.add((cycle, stage, peripheral))
        if len(self.held) > HELD_KEPT:
            self.held.discard(min(self.held))

    def came_late(self, cycle: int, stage: int, peripheral: int) -> bool:
        """Whether a reply to ``cycle``'s round ``stage`` was expected late (and now no
        longer is)."""
        key = (cycle, stage, peripheral)
        if key not in self.held:
            return False
        self.held.discard(key)
        return True

    # -- what the scheduler asks -----------------------------------------------------------

    def wake_at(self, intervals: Collection[InFlight]) -> int | None:
        """The earliest late-data time of a waiting round whose policy acts on it
        (``hold``, ``compute`` or ``fault``: under ``wait`` lateness changes nothing, and
        a wake-up for it would cost the central a wake-up of its inbox's thread)."""
        times = [f.late_ns for f in intervals if f.waiting and f.late_ns
                 and f.round is not None and self.policy[f.round.index] != "wait"]
        return min(times) if times else None

    def check(self, now: int, intervals: Collection[InFlight]) -> None:
        """Apply each waiting round's policy once its late-data time has passed (only
        the realtime clock sets one: runtime/central/pace.py)."""
        for f in list(intervals):
            if not f.waiting or f.round is None or not f.late_ns or now < f.late_ns:
                continue
            policy = self.policy[f.round.index]
            if policy == "wait":
                f.late_at(0)
                continue
            if policy == "compute":
                if self.pending():
                    continue  # a reply may be among them: read first, look again after
                if not self._compute(f):
                    f.late_at(0)  # it needs values the peripherals kept: wait
                continue
            if policy == "fault":
                late = [b.name for b in f.round.blocks]
                k = min(f.waiting)
                raise Fault(f"late data: peripheral {k + 1} missed the deadline of round "
                            f"{f.round.index} ({', '.join(late)}) of cycle {f.cycle}",
                            process=f"peripheral-{k + 1}", code=EXIT_PERIPHERAL)
            if self._hold(f, now):
                self.advance(f)
            else:
                f.late_at(0)  # nothing to hold yet: wait

    def _hold(self, f: InFlight, now: int) -> bool:
        """``hold``: the last values of the missing peripherals' axes into ``f``; False,
        and nothing done, while a missing peripheral never answered this round (its
        slots are None)."""
        rnd = f.round
        assert rnd is not None
        axes_of = self.engine.plan.placement.axes
        if not all(self.last_vals.get(name, (None,) * 3)[a] is not None
                   for name in rnd.recv for p in f.waiting for a in axes_of[p]):
            return False
        for p in sorted(f.waiting):
            axes = axes_of[p]
            held = {name: [self.last_vals[name][a] for a in axes] for name in rnd.recv}
            Engine.merge(f.ctx, held, axes)
            for a in axes:
                self.late_per_axis[a] += 1
            f.stood_in(p, late=True)
            self.held.add((f.cycle, rnd.index, p))
            if self.on_message is not None:  # the recording, so that replay holds too
                self.on_message("held", f"{self.faults_key}/held", f.cycle, rnd.index,
                                msgpack.packb({"cycle": f.cycle, "stage": rnd.index,
                                               "peripheral": p, "vals": held},
                                              use_single_float=False), now)
            if len(self.held) > HELD_KEPT:
                self.held.discard(min(self.held))
        return True

    def _compute(self, f: InFlight) -> bool:
        """``compute``: run the round of ``f`` for the axes of the peripherals that have
        not answered, here, with the kernels they would have run on the values they were
        sent (bit for bit their reply's values), and go on with the interval. Their
        replies, when they come, are counted as late; their silence is still watched.
        False, and nothing done, where the round needs values only the peripherals
        hold."""
        return self.compute(f, sorted(f.waiting))

    def compute(self, f: InFlight, peripherals: list[int], *, late: bool = True) -> bool:
        """Run the round of ``f`` here for the axes of ``peripherals`` (of those it waits
        for), as they would have (:meth:`_compute`), record each as computed (the
        recording's ``faults/computed``: replay computes it too), and go on with the
        interval once it waits for no one. ``late``: their replies will come late
        (``--late-policy compute``); else they were taken over (.takeover) and are not
        counted as late. False, and nothing done, where the round needs values only the
        peripherals hold."""
        rnd = f.round
        assert rnd is not None
        axes_of = self.engine.plan.placement.axes
        axes = [a for p in peripherals for a in axes_of[p]]
        if not Engine.can_run(rnd, f.ctx, axes):
            return False
        t0 = time.monotonic_ns()
        try:
            self.engine.run_round(rnd, f.ctx, axes)
        except ObserverDiverged as exc:  # as in the central's own steps (.intervals)
            raise Fault(f"cycle {f.cycle}: {exc}", process="central",
                        code=EXIT_OBSERVER) from None
        for p in peripherals:
            paxes = axes_of[p]
            Engine.merge(self.last_vals, Engine.reply_vals(rnd, f.ctx, paxes), paxes)
            if late:
                for a in paxes:
                    self.late_per_axis[a] += 1
                self.held.add((f.cycle, rnd.index, p))
                self.computed += 1
            else:
                self.taken_over += 1
            f.stood_in(p, late=late)
            if self.on_message is not None:  # the recording: replay knows the reply is missing
                self.on_message("computed", f"{self.faults_key}/computed", f.cycle,
                                rnd.index, msgpack.packb({"cycle": f.cycle, "stage": rnd.index,
                                                          "peripheral": p}), t0)
        while len(self.held) > HELD_KEPT:  # bounded: the oldest rounds' late replies forgotten
            self.held.discard(min(self.held))
        self.span("central", f.cycle, t0, time.monotonic_ns())
        if not f.waiting:
            self.advance(f)
        return True


__all__ = ["HELD_KEPT", "LateData", "late_policies"]
