"""The central role: the pipeline scheduler of § IV.7.2 (Fig. 24) and its loop.

Up to ``depth`` intervals are in flight; the rules that decide when an interval starts,
when its sample-free steps run ahead, when a ready round waits to be fused with the next
interval's first round, and when an interval finishes are the pure functions of
:mod:`ctrlunit.topology.pipeline`, shared with the schedule model that ``ctrlunit
balance`` calibrates (docs/architecture.md explains them, with a diagram). Every wait
is bounded: a missing reply or sample is a detected fault, never a hang.

:class:`Central` runs the loop and routes what it receives to the parts it holds, each
given what it needs at construction (docs/architecture.md, the central's parts).

Clocks: in ``lockstep`` and ``realtime`` interval k starts from plant sample k
(``realtime`` skips to the newest sample when the unit falls behind, and counts the
skipped ones); in ``freerun`` there is no plant, and each interval starts as soon as a
slot is free from a synthetic sample (the reference's inverse kinematics, quantised).
"""

from __future__ import annotations

import queue
import time
from collections import OrderedDict
from collections.abc import Callable
from typing import Any

from ..compute.controller import Controller
from ..compute.engine import Engine
from ..config import RunConfig
from ..config.handed import config_message
from ..transport.node import Event, Node, rss_kb
from .excuse import UNSUPERVISED, Supervision
from .fault import Fault
from .flood import FloodWatch
from .inbox import Inbox
from .intake import Intake
from .intervals import Intervals
from .late import LateData
from .meters import Meters
from .orders import Orders
from .outgoing import Outgoing
from .overload import Overload
from .rate import RateChange
from .rebalance import LiveBalance
from .records import CycleLog, InFlight
from .replies import Replies
from .settings import LoopSettings
from .silence import SilenceWatch
from .snapshot import History, Progress, RunSnapshot, progress_of, snapshot_of
from .state_check import hold_torques
from .takeover import TakeOver
from .warmup import WarmUp


class Central:
    """The central process of a unit.

    Parameters
    ----------
    node : the central's Zenoh node.
    rc : run configuration.
    engine : engine built from the run's plan (placement included).
    controller : sources and observer state.
    cycles : number of intervals to run.
    on_cycle : ``on_cycle(progress, ctx)`` after each interval (recording, progress,
        views: :class:`~.snapshot.Progress`).
    on_message : ``on_message(direction, key, cycle, stage, payload, t_ns)`` for every
        exchange (recording).
    supervision : what this central can learn of the role processes it started.
    trial : the admission's trial (:mod:`..admission`): intervals from the plant's trial
        samples (flagged ``probe``, numbered from ``controller.first_cycle``) at the
        reference's own synthetic position, commands sent flagged ``probe`` (dropped).
    reply_each : peripherals answer each part of a fused request at once (a trial takes
        the run's choice; otherwise :meth:`WarmUp.choose_replies` makes it).
    """

    def __init__(self, node: Node, rc: RunConfig, engine: Engine, controller: Controller,
                 cycles: int, *, on_cycle: Callable[[Progress, dict], None] | None = None,
                 on_message: Callable[[str, str, int, Any, bytes, int], None] | None = None,
                 supervision: Supervision = UNSUPERVISED, trial: bool = False,
                 reply_each: bool = False) -> None:
        sch = rc.schedule
        n = engine.plan.placement.peripherals
        self.node = node
        self.rc = rc
        self.settings = LoopSettings.of(rc, peripherals=n, cycles=cycles,
                                        first_cycle=controller.first_cycle, trial=trial)
        self.on_cycle = on_cycle
        self.on_message = on_message
        keys = node.keys
        self.log = CycleLog()
        self.meters = Meters(n, keep_cycle_spans=on_cycle is not None)
        self.intake = Intake(node, trial=trial)
        self.silence = SilenceWatch.of(rc, peripherals=n, stride=lambda: self.ctl.stride,
                                       supervision=supervision, hint=self.overload_hint)
        self.late = LateData(engine, late=sch.late, late_policy=sch.late_policy,
                             faults_key=f"{keys.root}/faults", pending=node.events.pending,
                             advance=lambda f: self.intervals.advance(f),
                             span=self.meters.span, on_message=on_message)
        self.overload = Overload(enabled=not trial and rc.halves_on_overload, period_s=sch.period,
                                 change_rate=lambda stride, why: self.rate(stride, why))
        self.outgoing = Outgoing(node, self.settings, meters=self.meters, reply_each=reply_each,
                                 on_message=on_message)
        self.intervals = Intervals(
            node, self.settings, engine, controller, outgoing=self.outgoing, intake=self.intake,
            silence=self.silence, overload=self.overload, expect_late=self.late.expect_late,
            meters=self.meters, log=self.log, hint=self.overload_hint,
            on_cycle=None if on_cycle is None else (
                lambda k, ctx: on_cycle(progress_of(self, k, self._history), ctx)),
            on_message=on_message)
        self.takeover = TakeOver(enabled=sch.peripheral_loss == "takeover", late=self.late,
                                 silence=self.silence, intervals=self.intervals,
                                 outgoing=self.outgoing, on_message=on_message)
        self._history = History(self.log, self.takeover.report)
        self.replies = Replies(intervals=self.intervals, intake=self.intake,
                               takeover=self.takeover, late=self.late, silence=self.silence,
                               meters=self.meters, keys=keys, on_message=on_message)
        self.inbox = Inbox(node, self.settings, intervals=self.intervals, replies=self.replies,
                           intake=self.intake, flood=FloodWatch.of(node, rc.transport),
                           silence=self.silence, log=self.log, meters=self.meters,
                           on_hello=lambda ev: self.orders.on_hello(ev), on_message=on_message)
        self.orders = Orders(node, peripherals=n, plant=self.settings.plant,
                             startup_timeout_s=rc.transport.startup_timeout,
                             check_children=self.takeover.check_children, config=config_message(rc),
                             take_sample=self.inbox.sample, may_join=self.takeover.may_rejoin)
        self.warmup = WarmUp(node, engine, controller,
                             publish=self.outgoing.publish_request, depth=sch.pipeline,
                             asked=sch.replies, startup_timeout_s=rc.transport.startup_timeout,
                             check_children=self.takeover.check_children, other=self.handle,
                             lost=lambda: self.takeover.lost)
        self.balance = LiveBalance(rc, intervals=self.intervals, orders=self.orders,
                                   warmup=self.warmup, outgoing=self.outgoing, use=self.use,
                                   lost=self.takeover.lost, on_message=on_message)
        self.rate = RateChange(ctl=lambda: self.ctl, where=lambda: (self.next_cycle, self.done),
                               intake=self.intake, orders=self.orders,
                               plant_key=keys.control("plant"), on_message=on_message)

    def use(self, engine: Engine, controller: Controller) -> None:
        """Run ``engine``'s plan with ``controller`` (when the placement changes before
        the run: :meth:`place`); the warm-up's round trips, which were of the old plan,
        are dropped."""
        for part in (self.intervals, self.warmup):
            part.use(engine, controller)
        self.late.use(engine)

    @property
    def engine(self) -> Engine:
        return self.intervals.engine

    @property
    def ctl(self) -> Controller:
        """The controller: the interval's sources and the observer's state."""
        return self.intervals.ctl

    @property
    def cycles(self) -> int:
        """The cycle number after the run's last."""
        return self.settings.end

    @property
    def done(self) -> int:
        """Intervals finished."""
        return self.intervals.done

    @property
    def next_cycle(self) -> int:
        """The cycle of the next interval to start."""
        return self.intervals.next_cycle

    @property
    def inflight(self) -> OrderedDict[int, InFlight]:
        """The intervals in flight, by cycle."""
        return self.intervals.inflight

    def snapshot(self) -> RunSnapshot:
        """The run as the report reads it, now (:class:`~.snapshot.RunSnapshot`)."""
        return snapshot_of(self)

    def handshake(self) -> None:
        """Wait for every role's hello and hand out the run (:meth:`Orders.handshake`)."""
        self.orders.handshake()

    def warm_up(self) -> None:
        """Round trips before measuring (:meth:`WarmUp.run`), once live balance's judge
        is ready (:meth:`LiveBalance.prepare`)."""
        self.balance.prepare()
        self.warmup.run()

    def choose_placement(self) -> dict[str, Any]:
        """``--placement auto``'s choice from the warm-up (:meth:`WarmUp.choose_placement`)."""
        return self.warmup.choose_placement()

    def say(self, stage: str, **fields: Any) -> None:
        """Tell every role ``stage`` (:meth:`Orders.say`)."""
        self.orders.say(stage, **fields)

    def zenoh_identity(self) -> dict[str, Any]:
        """This node's Zenoh id and its peers' (:meth:`Orders.zenoh_identity`)."""
        return self.orders.zenoh_identity()

    @property
    def params(self) -> Any:
        """The robot's parameters the run's plan computes with."""
        return self.engine.cfg.params

    def choose_replies(self) -> dict[str, Any]:
        """Decide how peripherals answer fused requests (:meth:`WarmUp.choose_replies`)
        and follow the decision; returns it (for the report)."""
        info = self.warmup.choose_replies()
        self.outgoing.reply_each = info["mode"] == "each"
        return info

    def place(self, rc: RunConfig, engine: Engine, controller: Controller) -> None:
        """Switch to ``engine``'s placement before the run (``--placement auto``'s choice at
        warm-up) without starting again: each peripheral not taken over rebuilds its plan
        and says ``placed`` (else :class:`~.fault.Fault`); warm up again before measuring."""
        self.orders.place(sorted(engine.plan.placement.central_blocks),
                          skip={f"peripheral-{k + 1}" for k in self.takeover.lost})
        self.rc = rc
        self.use(engine, controller)

    def hold_torques(self) -> list[float]:
        """Gravity-holding torques at the last estimate (the safe stop's first stage)."""
        return hold_torques(self.engine.cfg.params, self.ctl.est[0])

    def stop(self, *, reason: str = "done", wait: float = 1.0) -> None:
        """Tell every role to stop (the plant runs its safe stop, holding
        :meth:`hold_torques`) and collect their reports for up to ``wait`` seconds."""
        self.orders.stop(reason=reason, hold=self.hold_torques(), wait=wait)

    def overload_hint(self) -> str:
        """For a fault's message: in realtime, when most deadlines were missed, that the
        machine, not a process, is the likely cause."""
        return self.intervals.pace.overload_hint(
            misses=self.meters.plant_misses, skipped=self.meters.skipped,
            periods=self.next_cycle)

    # -- the loop ---------------------------------------------------------------------

    def run(self) -> None:
        """Run ``cycles`` intervals. Raises :class:`~.fault.Fault` on a detected fault."""
        m = self.meters
        m.t_start_ns = time.monotonic_ns()
        cpu0 = time.process_time()
        try:
            self._loop()
        finally:  # a fault too: where the CPU went, and when, are part of its diagnosis
            m.cpu_s = time.process_time() - cpu0
            m.t_end_ns = time.monotonic_ns()
            self.balance.close()
        m.rss_end = rss_kb()

    def _loop(self) -> None:
        """The event loop of :meth:`run`: each turn starts what may start, sends what is
        ready, waits for one event until something is due, handles it, checks."""
        end = self.settings.end
        iv = self.intervals
        while iv.done < end and not (iv.next_cycle >= end and not iv.inflight):
            limit_ns = self.limit_ns()
            self.balance.turn(self.done)  # a live re-placement at a drained boundary
            self.start_ready()
            now = time.monotonic_ns()
            hold_until = self.send_ready(now)
            if self.takeover.covering and self.takeover.cover(self.inflight.values()):
                continue  # an interval went on: send what it made ready
            if self.prime():
                continue  # the primed interval may have its slot and sample already
            wait_until = self.next_check(now, limit_ns, hold_until)
            t0 = time.monotonic_ns()
            try:
                ev = self.node.events.get(timeout=max(0.0, (wait_until - now) / 1e9))
            except queue.Empty:
                ev = None
            t1 = time.monotonic_ns()
            self.meters.wait_ns += t1 - t0
            self.silence.woke(wait_until, t1, slept_from=t0)
            if ev is not None:
                self.handle(ev)
            self.check_late(time.monotonic_ns())
            self.check_silence(limit_ns)

    def start_ready(self) -> None:
        """Start every interval whose slot and sample have come (:meth:`Intervals.start_ready`)."""
        self.intervals.start_ready()

    def send_ready(self, now: int) -> int:
        """Send the rounds ready at ``now`` as one request; when a lone round is held for
        the next interval's first, until when (ns), else 0 (:meth:`Intervals.flush`)."""
        return self.intervals.flush(now)

    def prime(self) -> bool:
        """Depth 2: run the next interval's sample-free steps early; whether it did
        (:meth:`Intervals.prime`)."""
        return self.intervals.prime()

    def limit_ns(self) -> int:
        """How long a reply or a sample may be missing now before it is a fault
        (:meth:`SilenceWatch.limit_ns`)."""
        return self.silence.limit_ns(self.done)

    def next_check(self, now: int, limit_ns: int, hold_until: int) -> int:
        """When the loop must look at the clock again, however quiet the inbox: a held
        round's release, a round's deadline, its late-data time where its policy acts on
        it, and in realtime the moment a silent peripheral or plant would become a
        fault."""
        wake = self.silence.wake_at(now, limit_ns, self.inflight.values())
        if hold_until:
            wake = min(wake, hold_until)
        late = self.late.wake_at(self.inflight.values())
        return wake if late is None else min(wake, late)

    def check_late(self, now: int) -> None:
        """Apply the late-data policy of each round late at ``now`` (realtime)."""
        self.late.check(now, self.inflight.values())

    def check_silence(self, limit_ns: int) -> None:
        """Raise the fault of a silent peripheral or plant, unless messages are still
        waiting in the inbox (the central may have been the slow one: a reply it has not
        read yet is not silence). Those are read first, and the silence is looked at only
        once none waits: looking costs a late central most (an excuse reads ``/proc``,
        0.25-0.3 ms a process on the reference machine, and the fault's message again).
        A role process that exited is a fault at once. A lost peripheral is taken over
        where ``--peripheral-loss`` says so (:class:`~.takeover.TakeOver`)."""
        try:
            if not self.node.events.pending():  # else the check runs after each event
                plant_awaited = self.intervals.samples.awaited(self.next_cycle) \
                    if self.next_cycle < self.settings.end else None
                self.silence.check(time.monotonic_ns(), limit_ns, self.inflight.values(),
                                   done=self.done, plant_awaited=plant_awaited,
                                   newest_sample=self.intake.newest_sample,
                                   started_ns=self.meters.t_start_ns)
                self.takeover.probation(time.monotonic_ns())
            self.silence.check_children()
        except Fault as fault:
            if not self.takeover.take(fault, self.inflight.values(), done=self.done,
                                      next_cycle=self.next_cycle):
                raise

    # -- messages in ------------------------------------------------------------------

    def handle(self, ev: Event) -> None:
        """Take one event of the inbox (:meth:`Inbox.handle`)."""
        self.inbox.handle(ev)


__all__ = ["Central"]
