"""The central role: the pipeline scheduler of § IV.7.2 (Fig. 24) and its loop.

Up to ``depth`` intervals are in flight; the rules that decide when an interval starts,
when its sample-free steps run ahead, when a ready round waits to be fused with the next
interval's first round, and when an interval finishes are the pure functions of
:mod:`ctrlunit.topology.pipeline`, shared with the schedule model that ``ctrlunit
balance`` calibrates (docs/architecture.md explains them, with a diagram). Every wait
is bounded: a missing reply or sample is a detected fault, never a hang.

The central is one class in parts, each in its own module: this loop and its intervals;
:mod:`.central_intake` (every received message, checked); :mod:`.central_guard` (faults,
deadlines, late data, the robot's state); :mod:`.central_warmup` (throw-away intervals
and the reply mode); :mod:`.central_lifecycle` (handshake, orders, stop).

Clocks: in ``lockstep`` and ``realtime`` interval k starts from plant sample k
(``realtime`` skips to the newest sample when the unit falls behind, and counts the
skipped ones); in ``freerun`` there is no plant, and each interval starts as soon as a
slot is free from a synthetic sample (the reference's inverse kinematics, quantised).
"""

from __future__ import annotations

import math
import queue
import struct
import time
from collections import OrderedDict, deque
from collections.abc import Callable
from typing import Any

from ..kernels.kinematics import ik_axis
from ..topology.graph import EST2
from ..topology.pipeline import (
    handoff_step,
    hold_rule,
    holds_lone_round,
    may_prime,
    may_start,
)
from ..topology.plan import Round
from .blocks import ObserverDiverged
from .central_guard import CentralGuard, Excuse, Fault
from .central_intake import CentralIntake
from .central_lifecycle import CentralLifecycle
from .central_state import LATE_KEPT, CycleLog, InFlight
from .central_warmup import CentralWarmUp
from .codec import (
    encode,
)
from .config import EXIT_OBSERVER, RunConfig
from .controller import Controller
from .engine import AWAIT_SAMPLE, Engine
from .node import WARM_RSS_AT, Node, rss_kb
from .supervise import MachineLoad, ThreadTimes

OVERLOAD_WINDOW = 100
"""The intervals over which :meth:`Central._check_overload` counts late ones."""

OVERLOAD_LATE = 10
"""Late intervals (command after its deadline, or started behind, skipping samples) within
:data:`OVERLOAD_WINDOW` that make a realtime run with ``--overload halve`` halve its
control rate."""

OVERLOAD_SETTLE = 20
"""Real intervals before late ones count towards a halving: the first ones after the
warm-up meet the start of the motion and the peripherals' first real rounds."""

OVERLOAD_LEAD = 3
"""Periods between the newest sample and the first one of a new rate: the plant hears
the order before that tick."""

OVERLOAD_CALM_S = 2.0
"""Time at the halved rate without a late interval after which the run goes back to the
full rate (1000 intervals at 1 ms); doubled after each return."""

OVERLOAD_RETURNS = 3
"""Returns to the full rate per run; after the last one a halving stays."""

OVERLOAD_PROBE_S = 0.5
"""After a return to the full rate, the time during which it is on trial: there
:data:`OVERLOAD_PROBE_LATE` late intervals within :data:`OVERLOAD_WINDOW` halve the rate
again. A return into a host still slow then costs about that many late intervals instead
of the :data:`OVERLOAD_LATE` of a first halving (nothing tells beforehand whether the full
rate will hold again: the return is its own trial)."""

OVERLOAD_PROBE_LATE = 3
"""Late intervals within :data:`OVERLOAD_WINDOW` that end a return on trial
(:data:`OVERLOAD_PROBE_S`)."""


def t1_input(ctx: dict) -> tuple:
    """What ``t_1`` recomputes an interval from (runtime/engine.py, :func:`measure_t1`):
    its sources ``t, est, qmeas, qdmeas`` and, where the graph has it, ``est2``."""
    base = (ctx["t"], ctx["est"], list(ctx["qmeas_i"]), list(ctx["qdmeas_i"]))
    return (*base, ctx[EST2]) if EST2 in ctx else base


def extrapolated_command(tau: list[float], prev: list[float]) -> list[float]:
    """The command expected one period after ``tau``, from the one before it (``prev``):
    ``2 tau - prev``, the torques carried on at their last change. Sent with ``tau`` as
    ``next`` for the plant to apply if the next command is late (``--missed-command``)."""
    return [2.0 * a - b for a, b in zip(tau, prev, strict=True)]


class Central(CentralLifecycle, CentralIntake, CentralGuard, CentralWarmUp):
    """The central process of a unit.

    Parameters
    ----------
    node : the central's Zenoh node.
    rc : run configuration.
    engine : engine built from the run's plan (placement included).
    controller : sources and observer state.
    cycles : number of intervals to run.
    on_cycle : optional ``on_cycle(central, cycle, ctx)`` after each interval (recording,
        progress).
    on_message : optional ``on_message(direction, key, cycle, stage, payload, t_ns)`` for
        every exchange (recording).
    trial : the admission's trial (:mod:`.admission`): intervals from the plant's trial
        samples (flagged ``probe``, numbered from ``controller.first_cycle``) at the
        reference's own synthetic position, commands computed but never sent.
    """

    def __init__(
        self,
        node: Node,
        rc: RunConfig,
        engine: Engine,
        controller: Controller,
        cycles: int,
        *,
        on_cycle: Callable[[Central, int, dict], None] | None = None,
        on_message: Callable[[str, str, int, Any, bytes, int], None] | None = None,
        trial: bool = False,
    ) -> None:
        self.node = node
        self.trial = trial
        self.rc = rc
        self.cycles = cycles
        self.on_cycle = on_cycle
        self.on_message = on_message
        self.n = engine.plan.placement.peripherals
        self.depth = rc.schedule.pipeline
        self.hold = hold_rule(rc.schedule.hold_rounds, clock=rc.schedule.clock)
        self.use(engine, controller)
        keys = node.keys
        self.pub_req = node.publisher(keys.request) if self.n else None
        self.pub_cmd = node.publisher(keys.command)
        self.pub_ctl = [node.publisher(keys.control(r)) for r in ("peripheral", "plant")]
        for k in range(self.n):
            node.route(keys.reply(k + 1), "reply", k)
        node.route(keys.hello, "hello")
        if rc.schedule.clock != "freerun":
            node.route(keys.sample, "sample")
        self.log = CycleLog()
        self.inflight: OrderedDict[int, InFlight] = OrderedDict()
        self.samples: dict[int, tuple[list[int], int]] = {}
        self.next_cycle = controller.first_cycle
        self.cycles += controller.first_cycle  # the end of the cycle numbers
        self.done = 0
        self.skipped = 0
        self.skip_marks: list[tuple[int, int]] = []
        """In a trial: where samples were skipped, as (traversals logged before, samples
        skipped), so that the admission can tell one stall from a steady lag."""
        self.late_replies = 0
        self.plant_misses = 0
        self._last_cmd: tuple[int, list[float]] | None = None  # (cycle, tau) last sent
        self.plant_busy_ns = 0
        self.periph_busy_ns = [0] * self.n
        self.wait_ns = 0
        self.t_start_ns = 0
        self.t_end_ns = 0
        self.cpu_s: float | None = None  # CPU of this process (all threads) during run()
        self.role_reports: dict[str, dict] = {}
        self.spans: list[tuple[str, int, int, int]] = []  # (process, cycle, t0, t1), bounded
        self.max_spans = 4_000  # the first few hundred intervals: Gantt charts
        self.last_sample_ns = 0
        # the plant's silences over two periods (from, to), the newest: see _fault_at
        self.plant_gaps: deque[tuple[int, int]] = deque(maxlen=8)
        # the central's own stalls (from, to): it woke more than a period after it meant to
        self.own_gaps: deque[tuple[int, int]] = deque(maxlen=8)
        self.t1_inputs: list[tuple] = []
        self.newest_sample = -1
        self.peers_seen: set[str] = set()
        self.rss_warm = -1
        self.rss_end = -1
        self.rss_series: list[tuple[int, int]] = []
        self.last_vals: dict[str, list[Any]] = {}
        self.late_per_axis = [0, 0, 0]
        self.computed = 0  # late peripherals' rounds the central ran itself (compute)
        self.held: set[tuple[int, int, int]] = set()
        self.last_reply_ns = [0] * self.n
        self.asked_ns = [0] * self.n  # the first request sent to each after its last reply
        self.cycle_spans: dict[int, list[tuple[str, int, int]]] = {}
        self.child_check: Callable[[], tuple[str, int] | None] | None = None
        # what a role's process is doing (supervise.process_state), for the roles this
        # central started; None: unknown (roles started by hand, on other hosts)
        self.role_state: Callable[[str], str] | None = None
        # the scheduler accounting of a role's threads (supervise.thread_times), where
        # this central can read it: renews an excuse while the machine starves a role
        self.role_times: Callable[[str], ThreadTimes] | None = None
        # how short of CPUs the machine is (supervise.machine_load), read with role_state
        self.machine_load: Callable[[], MachineLoad] | None = None
        self.excused: dict[str, Excuse] = {}  # role -> the excuse of its silence
        self.excuses = 0  # silences past their limit excused (central_guard._excuse)
        self._next_child_check = 0.0
        self.outbox: list[InFlight] = []  # intervals whose next round waits to be sent
        self.primed: list[tuple[int, dict]] = []  # next intervals, sample-free steps run
        self.exchanges = 0  # requests sent (each may carry several rounds)
        self.send_ns = 0  # time spent sending requests (encode, put)
        self.reply_ns = 0  # time spent on replies (decode, check, merge), not what follows
        self.reply_msgs = 0
        self.admit_ns = 0  # starting intervals (sample, context), not their steps
        self.finish_ns = 0  # finishing them (checks, command, logs, progress)
        self.period_ns = int(rc.schedule.period * 1e9)
        self.realtime_deadline_ns = self.depth * self.period_ns \
            if rc.schedule.clock == "realtime" and self.n else 0
        """Realtime with peripherals: an interval whose command leaves later than this after
        its sample is late (its work goes to :attr:`CycleLog.late_work_ns`); 0 otherwise."""
        self.rate_changes: list[dict[str, Any]] = []
        """Each change of the control rate (``--overload``): stride, first cycle, when
        and why."""
        self.halve_on_overload = not trial and rc.halves_on_overload
        self._late_marks: deque[int] = deque()  # self.done at each late interval (full rate)
        self._calm_since = 0  # halved: self.done at the halving or the latest late interval
        self._calm_needed = 0  # halved: intervals without a late one before going back
        self._trial_until = 0  # full rate after a return: self.done up to which it is on trial
        self.reply_each = False
        self.replies_info: dict[str, Any] = {"mode": "fused"}
        self.block_costs: dict[str, float] | None = None  # measured once (warm-up)

    def use(self, engine: Engine, controller: Controller) -> None:
        """Run ``engine``'s plan with ``controller`` (at construction, and when the
        placement changes before the run: :meth:`place`); the warm-up's round trips,
        which were of the old plan, are dropped."""
        self.engine = engine
        self.ctl = controller
        self.plan = engine.plan
        self.hand = handoff_step(self.plan)
        self.round_step = {s.round.index: k for k, s in enumerate(self.plan.steps)
                           if s.round is not None}
        self.last_round = self.plan.rounds[-1].index if self.plan.rounds else -1
        # rounds that need no sample (sent ahead of it at depth 2); derived once: the
        # plan's property walks the graph (about 10 us), and the loop asks per interval
        self.ahead_rounds = self.plan.ahead_rounds if self.n else 0
        self.late_policy = self._late_policies()
        self.warm_rtt_s: list[float] = []

    # -- the loop ---------------------------------------------------------------------

    def run(self) -> None:
        """Run ``cycles`` intervals. Raises :class:`Fault` on a detected fault."""
        self.zenoh_identity()  # note the peers connected now (others may leave before the end)
        self.t_start_ns = time.monotonic_ns()
        cpu0 = time.process_time()
        try:
            self._loop()
        finally:  # a fault too: where the CPU went is part of its diagnosis
            self.cpu_s = time.process_time() - cpu0
        self.t_end_ns = time.monotonic_ns()
        self.rss_end = rss_kb()

    def _loop(self) -> None:
        """The event loop of :meth:`run`."""
        while self.done < self.cycles and not (self.next_cycle >= self.cycles
                                               and not self.inflight):
            timeout_ns = self._timeout_ns()
            self._start_ready()
            now = time.monotonic_ns()
            hold_until = self._flush(now)
            if self._prime():
                continue  # the primed interval may have its slot and sample already
            wait_until = self._next_check(now, timeout_ns, hold_until)
            t0 = time.monotonic_ns()
            try:
                ev = self.node.events.get(timeout=max(0.0, (wait_until - now) / 1e9))
            except queue.Empty:
                ev = None
            t1 = time.monotonic_ns()
            self.wait_ns += t1 - t0
            self._woke(wait_until, t1)
            if ev is not None:
                self._handle(ev)
            self._check_late(time.monotonic_ns())
            self._check_deadlines(timeout_ns)
            self._check_children()

    def _woke(self, meant_ns: int, now: int) -> None:
        """Note a stall of the central itself: it meant to be awake again by ``meant_ns``
        and woke more than a period later (the machine did not run it). The silence rule
        does not count that time (:meth:`CentralGuard._own_stall`)."""
        if now - meant_ns > self.period_ns:
            self.own_gaps.append((meant_ns, now))

    # -- intervals --------------------------------------------------------------------

    def _newest_handed_off(self) -> bool | None:
        """Whether the newest interval started from its sample has handed off (None: none
        in flight); an interval run ahead of its sample does not count yet."""
        for f in reversed(self.inflight.values()):
            if not f.awaiting_sample:
                return f.handed_off
        return None

    def _may_start(self) -> bool:
        live = sum(1 for f in self.inflight.values()
                   if not f.finishing and not f.awaiting_sample)
        return may_start(depth=self.depth, live=live, next_cycle=self.next_cycle,
                         cycles=self.cycles, newest_handed_off=self._newest_handed_off())

    def _start_ready(self) -> None:
        while self._may_start():
            t_in = time.perf_counter_ns()
            k = self.next_cycle
            if self.rc.schedule.clock == "freerun":
                counts, t_ns = self._synthetic_sample(k), time.monotonic_ns()
                if self.on_message is not None:
                    self.on_message("in", self.node.keys.sample, k, "sample", encode(
                        self.node.unit, k, "sample", counts=counts, t_ns=t_ns, synthetic=True),
                        t_ns)
            else:
                if self.rc.schedule.clock == "realtime" and self.samples and max(self.samples) > k:
                    # behind the plant's clock: start from the newest sample, never queue
                    newest = max(self.samples)
                    if self.ctl.stride > 1:  # the rate is halved: the grid's samples only
                        skipped = sum(1 for c in range(k, newest) if self.ctl.on_grid(c))
                    else:
                        skipped = sum(1 for c in self.samples if c < newest) + (
                            newest - k - len(self.samples) + 1)
                    self.skipped += skipped
                    self._mark_late()  # one late interval, however long the stall
                    if self.trial:
                        self.skip_marks.append((len(self.log.traversal_ns), skipped))
                    self.samples = {newest: self.samples[newest]}
                    self.next_cycle = k = newest
                if k not in self.samples:
                    return
                counts, t_ns = self.samples.pop(k)
                if self.trial:  # the robot rests; the trial follows the reference
                    counts = self._synthetic_sample(k)
            self.next_cycle = k + self.ctl.hold_of(k)
            t0 = time.monotonic_ns()
            primed = self._take_primed(k)
            ahead = self.inflight.get(k) if primed is not None else None
            if ahead is not None and ahead.awaiting_sample:  # its rounds ran ahead
                self.ctl.measure(ahead.ctx, k, counts)
                if len(self.t1_inputs) < self.rc.run.t1_cycles:
                    ctx = ahead.ctx
                    self.t1_inputs.append(t1_input(ctx))
                ahead.sample_ns, ahead.start_ns = t_ns, t0
                ahead.awaiting_sample = False
                if ahead.waiting and self.rc.schedule.clock == "realtime":
                    ahead.late_ns = t_ns  # a round run ahead is late once its sample is here
                self.admit_ns += time.perf_counter_ns() - t_in
                if ahead.gated:  # its rounds are back: on from the sample's steps
                    ahead.gated = False
                    self._advance(ahead)
                continue
            if primed is not None:  # its sample-free steps are done
                ctx = primed
                self.ctl.measure(ctx, k, counts)
                gen = self.engine.cycle(ctx, skip_prefix=True)
            else:
                ctx = self.ctl.sources(k, counts)
                gen = self.engine.cycle(ctx)
            if len(self.t1_inputs) < self.rc.run.t1_cycles:
                self.t1_inputs.append(t1_input(ctx))
            f = InFlight(k, gen, ctx, t_ns, t0)
            self.inflight[k] = f
            self.admit_ns += time.perf_counter_ns() - t_in
            self._advance(f)

    def _take_primed(self, k: int) -> dict | None:
        """The context of interval ``k`` if its sample-free steps ran (it was primed),
        else None, with the previous interval's estimate, final now (with foresight 2 it
        was not when ``k`` was primed). Intervals primed before ``k`` are dropped (their
        samples were skipped); those after it stay (foresight 2: primed with ``k``)."""
        ctx = None
        while self.primed and self.primed[0][0] <= k:
            cycle, c = self.primed.pop(0)
            if cycle == k:
                ctx = c
                ctx["est"] = self.ctl.est
                continue
            self._drop_ahead(cycle)
            if self.on_message is not None:
                self._note_discarded(cycle)
        return ctx

    def _drop_ahead(self, cycle: int) -> None:
        """Forget an interval started ahead of a sample that was skipped: its replies, if
        any come, are late ones (counted, never merged)."""
        f = self.inflight.get(cycle)
        if f is None or not f.awaiting_sample:
            return
        del self.inflight[cycle]
        if f in self.outbox:
            self.outbox.remove(f)
        elif f.round is not None:
            for k in f.waiting:
                self.held.add((cycle, f.round.index, k))

    def _prime(self) -> bool:
        """Depth 2: run the next interval's sample-free leading steps (the plan's
        ``presample_steps``: for resolved acceleration the reference and the observer's
        prediction) as soon as the newest interval has handed off its estimate, before
        the next interval has a slot or its sample. They would otherwise sit between one
        interval's last reply and the next request, with the peripherals idle. Same
        arithmetic: the estimate they use is final at the hand-off. Returns whether it
        ran them."""
        if not may_prime(depth=self.depth, primed=bool(self.primed),
                         next_cycle=self.next_cycle, cycles=self.cycles,
                         newest_handed_off=self._newest_handed_off()):
            return False
        for k in self._prime_cycles():
            t0 = time.monotonic_ns()
            ctx = self.ctl.context(k)
            if self.ahead_rounds:  # its rounds run ahead of the sample too
                f = InFlight(k, self.engine.cycle(ctx, gate=True), ctx, 0, t0,
                             awaiting_sample=True)
                self.inflight[k] = f
                self.primed.append((k, ctx))
                self._advance(f)
                continue
            try:
                self.engine.prefix(ctx)
            except ObserverDiverged as exc:
                raise Fault(f"cycle {k}: {exc}", process="central",
                            code=EXIT_OBSERVER) from None
            self.primed.append((k, ctx))
            self._span("central", k, t0, time.monotonic_ns())
        return True

    def _prime_cycles(self) -> list[int]:
        """The intervals :meth:`_prime` starts: the next one, and where the graph's
        sample-free steps read the estimate of two intervals back (foresight 2) and the
        next interval comes a period after it, that one too: its ``est2`` is final
        already, and the two intervals' rounds go in one request (one exchange per two
        intervals)."""
        k = self.next_cycle
        if (self.plan.graph.foresight > 1 and self.ctl.hold_of(k) == 1
                and k + 1 < self.cycles and self.ctl.on_grid(k + 1)):
            return [k, k + 1]
        return [k]

    def _note_discarded(self, cycle: int) -> None:
        """Tell the recording that the primed steps of ``cycle`` ran but its interval did
        not (its sample was skipped): the reference they computed stays in the task's
        cache, which a later loop of the task reads, so replay runs them too
        (runtime/replay.py, ``discarded_primes``)."""
        assert self.on_message is not None
        self.on_message("in", self.node.keys.inbox("central") + "/primed", cycle, "primed",
                        encode(self.node.unit, cycle, "primed"), time.monotonic_ns())

    def _synthetic_sample(self, k: int) -> list[int]:
        p = self.engine.cfg.task.sample(self.ctl.time_of(k))[0]  # type: ignore[union-attr]
        params = self.engine.cfg.params
        x, y, z = float(p[0]), float(p[1]), float(p[2])
        return [round(ik_axis(params, i, x, y, z).q / params.increment) for i in range(3)]

    def _advance(self, f: InFlight) -> None:
        """Run the interval's central steps up to its next round (or its end)."""
        f.start_ns = time.monotonic_ns()  # the central's span starts here, not at a send
        rnd = self._step(f)
        while rnd is AWAIT_SAMPLE:  # run ahead: its sample-free steps and rounds are done
            if f.awaiting_sample:
                f.gated, f.round = True, None
                self._span("central", f.cycle, f.start_ns, time.monotonic_ns())
                return
            rnd = self._step(f)  # the sample came while its rounds were out
        if not f.handed_off and (rnd is None or self.round_step[rnd.index] > self.hand):
            self.ctl.handoff(f.ctx)
            f.handed_off = True
        if rnd is None:
            self._finish(f)
            return
        f.round = rnd
        self.outbox.append(f)
        self._span("central", f.cycle, f.start_ns, time.monotonic_ns())

    @staticmethod
    def _step(f: InFlight) -> Round | None:
        """Run the steps of ``f`` up to its next round (None: to its end)."""
        try:
            rnd = f.gen.send(None) if f.started else next(f.gen)
        except StopIteration:
            rnd = None
        except ObserverDiverged as exc:
            raise Fault(f"cycle {f.cycle}: {exc}", process="central",
                        code=EXIT_OBSERVER) from None
        f.started = True
        return rnd

    def _flush(self, now: int) -> int:
        """Send every queued round as the parts of one request; returns, when a round is
        held back to be fused with the next interval's first round (realtime, depth 2),
        the time until which it is held, else 0."""
        if not self.outbox:
            return 0
        hold_until = self._hold_until()
        if hold_until and now < hold_until:
            return hold_until
        t_in = time.perf_counter_ns()
        timeout_ns = self._timeout_ns()
        parts = []
        for f in self.outbox:
            rnd = f.round
            assert rnd is not None
            f.waiting = set(range(self.n))
            f.deadline_ns = now + timeout_ns
            if self.rc.schedule.clock == "realtime" and self.plan.round_trips \
                    and not f.awaiting_sample:
                share = (rnd.index + 1) / self.plan.round_trips
                f.late_ns = f.sample_ns + int(self.depth * self.period_ns * share)
            parts.append({"cycle": f.cycle, "stage": rnd.index,
                          "vals": Engine.request_vals(rnd, f.ctx, (0, 1, 2))})
        self.outbox.clear()
        for k in range(self.n):
            if self.asked_ns[k] <= self.last_reply_ns[k]:
                self.asked_ns[k] = now
        extra = {"each": True} if self.reply_each and len(parts) > 1 else {}
        payload = encode(self.node.unit, parts[0]["cycle"], parts[0]["stage"], parts=parts,
                         **extra)
        self.pub_req.put(payload)
        self.exchanges += 1
        self.send_ns += time.perf_counter_ns() - t_in
        if self.on_message is not None:
            self.on_message("out", self.node.keys.request, parts[0]["cycle"],
                            parts[0]["stage"], payload, time.monotonic_ns())
        return 0

    def _hold_until(self) -> int:
        """Depth 2 with a plant: a lone round of an interval past its hand-off waits for
        the next interval's first round, so that both go in one exchange. In realtime the
        next sample is due one period after this interval's; the round waits at most a
        quarter period past that (a late or lost sample). In lockstep the next sample
        follows the command just sent; the plant's silence is a fault after
        ``--timeout``."""
        f = self.outbox[0]
        if not holds_lone_round(depth=self.depth, ready=len(self.outbox),
                                handed_off=f.handed_off, cycle=f.cycle,
                                next_cycle=self.next_cycle, cycles=self.cycles,
                                hold=self.hold):
            return 0
        if self.rc.schedule.clock == "realtime":
            return f.sample_ns + self.period_ns + self.period_ns // 4
        return time.monotonic_ns() + self._timeout_ns()

    def _next_command(self, cycle: int, tau: list[float]) -> list[float] | None:
        """Realtime at the full rate: the command this one's sample's successor is expected
        to bring, extrapolated from the last two (``2 tau_k - tau_(k-1)``), sent with this
        one so that the plant applies it if that command is late (runtime/plant_node.py,
        :meth:`PlantServer.apply`). None at the first command, across a gap or a change
        of rate, in the other clocks (no deadline) and with ``--missed-command hold``."""
        last, self._last_cmd = self._last_cmd, (cycle, tau)
        if (self.rc.schedule.clock != "realtime" or self.trial or last is None
                or self.rc.schedule.missed_command != "extrapolate"
                or last[0] != cycle - 1 or self.ctl.hold_of(cycle) != 1
                or not self.ctl.on_grid(cycle + 1)):
            return None
        return extrapolated_command(tau, last[1])

    def _finish(self, f: InFlight) -> None:
        t_in = time.perf_counter_ns()
        self._check_state(f)  # here, after the next request is out: off the critical path
        cmd = f.ctx["cmd"]
        tau = [float(x) for x in cmd]
        nxt = self._next_command(f.cycle, tau)
        payload = (encode(self.node.unit, f.cycle, "command", tau=tau) if nxt is None else
                   encode(self.node.unit, f.cycle, "command", tau=tau, next=nxt))
        if not self.trial:
            self.pub_cmd.put(payload)
        now = time.monotonic_ns()
        self._span("central", f.cycle, f.start_ns, now)
        if self.on_message is not None:
            self.on_message("out", self.node.keys.command, f.cycle, "command", payload, now)
        del self.inflight[f.cycle]
        log = self.log
        log.times.append(now, now - f.sample_ns)
        if self.realtime_deadline_ns:  # only realtime reports where late intervals went
            log.work_ns.append(f.work_ns)
            if now - f.sample_ns > self.realtime_deadline_ns:
                log.late += 1
                if len(log.late_work_ns) < LATE_KEPT:
                    log.late_work_ns.append(f.work_ns)
                self._mark_late()
        if self.halve_on_overload:
            self._check_overload()
        log.digest.update(struct.pack("<3d", *cmd))
        log.torque_max = max(log.torque_max, abs(cmd[0]), abs(cmd[1]), abs(cmd[2]))
        self.done += 1
        if self.done == WARM_RSS_AT:
            self.rss_warm = rss_kb()
        if self.done % 10_000 == 0:
            self.rss_series.append((self.done, rss_kb()))
        if self.on_cycle is not None:
            self.on_cycle(self, f.cycle, f.ctx)
            self.cycle_spans.pop(f.cycle, None)
            for c in [c for c in self.cycle_spans if c < f.cycle - 8]:
                del self.cycle_spans[c]
        self.finish_ns += time.perf_counter_ns() - t_in

    def _mark_late(self) -> None:
        """Note a late interval now (for :meth:`_check_overload`): its command left after
        its deadline, or it started behind, skipping samples (one mark for the skip, so
        that one stall of the host does not halve the rate by itself)."""
        if not self.halve_on_overload or self.done < OVERLOAD_SETTLE:
            return
        if self.ctl.stride == 1:
            self._late_marks.append(self.done)
        else:
            self._calm_since = self.done

    def _check_overload(self) -> None:
        """``--overload halve``, after each interval. At the full rate, once
        :data:`OVERLOAD_LATE` of the last :data:`OVERLOAD_WINDOW` intervals were late,
        halve it: take only every second sample, and tell the plant, which then publishes
        those samples only and holds each command two periods (a deadline still ``depth``
        periods after its sample); the plant and the deadlines keep the period. At the
        halved rate, after :data:`OVERLOAD_CALM_S` without a late interval (twice as long
        after each return), go back to every sample, at most
        :data:`OVERLOAD_RETURNS` times a run; for :data:`OVERLOAD_PROBE_S` after a return,
        :data:`OVERLOAD_PROBE_LATE` late intervals halve the rate again."""
        if self.ctl.stride == 1:
            marks = self._late_marks
            if not marks:
                return
            while marks and marks[0] <= self.done - OVERLOAD_WINDOW:
                marks.popleft()
            on_trial = self.done <= self._trial_until
            if len(marks) >= (OVERLOAD_PROBE_LATE if on_trial else OVERLOAD_LATE):
                why = {"late": len(marks), "window": OVERLOAD_WINDOW}
                if on_trial:  # intervals since the return was decided
                    why["after_return"] = self.done - self.rate_changes[-1]["at_interval"]
                self._change_rate(2, **why)
                marks.clear()
                self._calm_since = self.done
                returns = len(self.rate_changes) // 2  # changes alternate: 2, 1, 2, ...
                self._calm_needed = 0 if returns >= OVERLOAD_RETURNS else math.ceil(
                    OVERLOAD_CALM_S / (2 * self.rc.schedule.period)) << returns
            return
        if self._calm_needed and self.done - self._calm_since >= self._calm_needed:
            self._change_rate(1, calm=self._calm_needed)
            self._trial_until = self.done + OVERLOAD_LEAD + math.ceil(
                OVERLOAD_PROBE_S / self.rc.schedule.period)

    def _change_rate(self, stride: int, **why: int) -> None:
        """Change the control rate from the first sample of the current grid at least
        :data:`OVERLOAD_LEAD` periods past the newest one, and order the plant to."""
        grid = self.ctl.grid
        k = grid.next_on_grid(max(self.next_cycle, self.newest_sample + 1) + OVERLOAD_LEAD)
        grid.change(stride, k)
        change = {"stride": stride, "from_cycle": k - self.ctl.first_cycle,
                  "at_interval": self.done, **why}
        self.rate_changes.append(change)
        # the plant reads stride and start; the rest is for the recording's report
        payload = self.say("stride", plant_only=True, start=k, **change)
        if self.on_message is not None:  # the recording: replay changes where the run did
            self.on_message("out", self.node.keys.control("plant"), k, "stride", payload,
                            time.monotonic_ns())

    def _span(self, proc: str, cycle: int, t0: int, t1: int) -> None:
        if len(self.spans) < self.max_spans:
            self.spans.append((proc, cycle, t0, t1))
        if self.on_cycle is not None:
            self.cycle_spans.setdefault(cycle, []).append((proc, t0, t1))

    def costs(self) -> dict[str, float]:
        """The central's own time, for the schedule model (:mod:`ctrlunit.topology.schedule`):
        per request sent, per reply message handled, per interval to start and to finish
        it, and busy (not waiting) per interval."""
        wall = max(1, self.t_end_ns - self.t_start_ns)
        done = max(1, self.done)
        return {
            "start": self.admit_ns / done / 1e9,
            "finish": self.finish_ns / done / 1e9,
            "send": self.send_ns / max(1, self.exchanges) / 1e9,
            "reply": self.reply_ns / max(1, self.reply_msgs) / 1e9,
            "replies_per_interval": self.reply_msgs / max(1, self.done),
            "busy_per_interval": (wall - self.wait_ns) / done / 1e9,
        }

    def spans_of(self, cycle: int) -> list[tuple[str, int, int]]:
        """The spans recorded for ``cycle`` (each process's compute time)."""
        return self.cycle_spans.get(cycle, [])



__all__ = ["Central", "Fault"]
