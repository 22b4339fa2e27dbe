"""The central role: the pipeline scheduler (§ IV.7.2, Fig. 24), timing and faults.

Scheduling
----------
Up to ``depth`` intervals are in flight. Interval k+1 may start when (a) its sample is
here, (b) fewer than ``depth`` intervals are in flight and (c) interval k has passed its
hand-off point (the observer's estimate is final), so that at depth 2 the central works on
one interval while the peripherals work on the other. Every message carries its cycle and
round; a reply for anything else is counted and dropped. Every wait is bounded: a missing
reply or sample is a detected fault, never a hang.

Fused exchanges: rounds that are ready at the same moment go out as the parts of one
request (and come back as the parts of one reply per peripheral). At depth 2 the second
round of interval k and the first round of k+1 are ready together (Fig. 24: the
peripherals work on both halves at once), so an interval costs one exchange instead of
two, with the same arithmetic. The second half of k therefore waits for the first round of
k+1: in ``realtime`` for sample k+1 (at most a quarter period past its expected time), in
``lockstep`` and ``freerun`` for k+1's slot. Sent alone, it would queue on the peripherals
ahead of the next first round, which is on the observer's chain from one interval to the
next.

Running ahead: at depth 2 the next interval's leading steps that need no sample (the plan's
``presample_steps``: the reference and the observer's prediction) run as soon as the
newest interval has handed off its estimate (:meth:`Central._prime`). When the slot frees
and the sample is here, the first round goes out at once instead of after them: the
peripherals are not left idle while the central computes what it could have computed
while they worked (Fig. 24's processors are never idle for want of ready work).

Replies to a fused request: one per peripheral with every part (``fused``), or one per part
as soon as it is computed, first rounds first (``each``): then the central works on the
middle of interval k+1 while the peripherals work on the second round of k. ``auto``
(:meth:`Central.choose_replies`) takes ``each`` when the central's work between two
rounds exceeds the round trip measured at warm-up: the overlap then gains more than the
extra reply costs.

Clocks
------
``lockstep`` and ``realtime``: interval k starts from plant sample k (``realtime`` skips
to the newest sample when the unit falls behind, and counts the skipped ones).
``freerun``: no plant; each interval starts as soon as a slot is free, from a synthetic
sample (the reference's inverse kinematics, quantised): it measures the shortest period
the unit itself sustains.
"""

from __future__ import annotations

import hashlib
import math
import queue
import statistics
import struct
import time
from array import array
from collections import OrderedDict
from collections.abc import Callable, Generator
from dataclasses import dataclass, field
from typing import Any

from ..kernels.kinematics import ik_axis, inverse_kinematics
from ..kernels.workspace import check_point
from ..topology.pipeline import (
    finishes_after_next_request,
    handoff_step,
    holds_lone_round,
    may_prime,
    may_start,
    reply_mode,
)
from ..topology.plan import Round
from .blocks import ObserverDiverged
from .codec import (
    BadMessage,
    check_span,
    check_vals,
    check_vector,
    encode,
    parts_of,
    short_text,
)
from .config import EXIT_LINK, EXIT_OBSERVER, EXIT_OK, EXIT_PERIPHERAL, EXIT_PLANT, RunConfig
from .controller import Controller
from .engine import CostModel, Engine
from .node import WARM_RSS_AT, Node, rss_kb


class Fault(RuntimeError):
    """A detected fault: ``process`` names the failed process, ``code`` the exit code."""

    def __init__(self, message: str, *, process: str, code: int) -> None:
        super().__init__(message)
        self.process = process
        self.code = code


@dataclass
class InFlight:
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


@dataclass
class CycleLog:
    """Per-cycle measurements, compact so that long runs stay small: two integers per
    interval, one float per plant sample; the commands only as a running digest and peak.
    """

    cmd_ns: array = field(default_factory=lambda: array("q"))
    traversal_ns: array = field(default_factory=lambda: array("i"))  # saturates at 2.1 s
    errors: array = field(default_factory=lambda: array("d"))
    digest: Any = field(default_factory=hashlib.sha256)
    torque_max: float = 0.0
    true_p: dict[int, tuple[float, float, float]] = field(default_factory=dict)  # recent only

    @property
    def sample_ns(self) -> list[int]:
        """Sample times, from command times and traversals."""
        return [c - t for c, t in zip(self.cmd_ns, self.traversal_ns)]


class Central:
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
    ) -> None:
        self.node = node
        self.rc = rc
        self.engine = engine
        self.ctl = controller
        self.cycles = cycles
        self.on_cycle = on_cycle
        self.on_message = on_message
        self.plan = engine.plan
        self.n = self.plan.placement.peripherals
        self.depth = rc.pipeline
        self.hand = handoff_step(self.plan)
        self.round_step = {}
        for k, s in enumerate(self.plan.steps):
            if s.round is not None:
                self.round_step[s.round.index] = k
        keys = node.keys
        self.pub_req = node.publisher(keys.request) if self.n else None
        self.pub_cmd = node.publisher(keys.command)
        self.pub_ctl = [node.publisher(keys.control(r)) for r in ("peripheral", "plant")]
        for k in range(self.n):
            node.route(keys.reply(k + 1), "reply", k)
        node.route(keys.hello, "hello")
        if rc.clock != "freerun":
            node.route(keys.sample, "sample")
        self.log = CycleLog()
        self.inflight: OrderedDict[int, InFlight] = OrderedDict()
        self.samples: dict[int, tuple[list[int], int]] = {}
        self.next_cycle = 0
        self.done = 0
        self.skipped = 0
        self.late_replies = 0
        self.plant_misses = 0
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
        self.t1_inputs: list[tuple] = []
        self.newest_sample = -1
        self.peers_seen: set[str] = set()
        self.rss_warm = -1
        self.rss_end = -1
        self.rss_series: list[tuple[int, int]] = []
        self.last_vals: dict[str, list[Any]] = {}
        self.late_per_axis = [0, 0, 0]
        self.held: set[tuple[int, int, int]] = set()
        self.last_reply_ns = [0] * self.n
        self.late_policy = self._late_policies()
        self.cycle_spans: dict[int, list[tuple[str, int, int]]] = {}
        self.child_check: Callable[[], tuple[str, int] | None] | None = None
        self._next_child_check = 0.0
        self.outbox: list[InFlight] = []  # intervals whose next round waits to be sent
        self.primed: tuple[int, dict] | None = None  # next interval, sample-free steps run
        self.exchanges = 0  # requests sent (each may carry several rounds)
        self.send_ns = 0  # time spent sending requests (encode, put)
        self.reply_ns = 0  # time spent on replies (decode, check, merge), not what follows
        self.reply_msgs = 0
        self.admit_ns = 0  # starting intervals (sample, context), not their steps
        self.finish_ns = 0  # finishing them (checks, command, logs, progress)
        self.period_ns = int(rc.period * 1e9)
        self.last_round = self.plan.rounds[-1].index if self.plan.rounds else -1
        self.reply_each = False
        self.replies_info: dict[str, Any] = {"mode": "fused"}
        self.warm_rtt_s: list[float] = []

    # -- start-up ---------------------------------------------------------------------

    def expected_roles(self) -> set[str]:
        roles = {f"peripheral-{k + 1}" for k in range(self.n)}
        if self.rc.clock != "freerun":
            roles.add("plant")
        return roles

    def handshake(self) -> None:
        """Wait for every role's hello, then say go."""
        expected = self.expected_roles()
        seen: set[str] = set()
        deadline = time.monotonic() + self.rc.startup_timeout
        while seen != expected:
            left = deadline - time.monotonic()
            if left <= 0:
                missing = ", ".join(sorted(expected - seen))
                raise Fault(f"no hello from {missing} within {self.rc.startup_timeout} s",
                            process=missing, code=EXIT_LINK)
            self._check_children()
            try:
                ev = self.node.events.get(timeout=min(left, 0.1))
            except queue.Empty:
                continue
            if ev[0] == "hello":
                msg = self.node.decode(ev[2])
                if msg is not None and msg.get("role") in expected:
                    seen.add(msg["role"])
            elif ev[0] == "sample":
                pass  # the plant's first sample may only follow go
        self.say("go")

    def say(self, stage: str, **extra: Any) -> None:
        """Publish a control order (go, start, stop) to every other role."""
        payload = encode(self.node.unit, 0, stage, **extra)
        for pub in self.pub_ctl:
            pub.put(payload)

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
            wait_until = now + timeout_ns
            if hold_until:
                wait_until = min(wait_until, hold_until)
            for f in self.inflight.values():
                if f.waiting:
                    wait_until = min(wait_until, f.deadline_ns)
                    if f.late_ns:
                        wait_until = min(wait_until, f.late_ns)
                    if self.rc.clock == "realtime":  # liveness: wake when it would fail
                        for k in f.waiting:
                            if self.last_reply_ns[k]:
                                wait_until = min(wait_until, self.last_reply_ns[k] + timeout_ns)
            if self.rc.clock == "realtime" and self.last_sample_ns:
                wait_until = min(wait_until, self.last_sample_ns + timeout_ns)
            t0 = time.monotonic_ns()
            try:
                ev = self.node.events.get(timeout=max(0.0, (wait_until - now) / 1e9))
            except queue.Empty:
                ev = None
            self.wait_ns += time.monotonic_ns() - t0
            if ev is not None:
                self._handle(ev)
            self._check_late(time.monotonic_ns())
            self._check_deadlines(timeout_ns)
            self._check_children()

    def _timeout_ns(self) -> int:
        """How long a reply or a sample may be missing before it is a fault: the
        ``--timeout`` in lockstep and freerun; in realtime ``--fault-periods`` periods
        (default 3; during the first 20 intervals at least 20 ms). A reply later than its
        deadline but within that is lateness (a miss at the plant, or the late-data
        policy); silence for that long is a failed process or link."""
        if self.rc.clock == "realtime":
            limit = self.rc.fault_periods * self.rc.period
            if self.done < self.STARTUP_INTERVALS:  # first real intervals: start-up
                limit = max(limit, self.STARTUP_LIMIT_S)
            return int(limit * 1e9)
        return int(self.rc.timeout * 1e9)

    STARTUP_INTERVALS = 20
    STARTUP_LIMIT_S = 0.020
    """Realtime: until this many intervals are done the silence limit is at least
    ``STARTUP_LIMIT_S`` (first samples, first real values through every process)."""

    WARMUP_BASE = 1 << 40

    def warm_up(self, intervals: int = 30) -> None:
        """Exercise the request/reply path before measuring (Zenoh routes, every round's
        code path on every process) with whole throw-away intervals; the replies are
        checked, merged and discarded. Each round trip less the peripherals' compute is
        kept (:attr:`warm_rtt_s`)."""
        if self.n == 0 or not self.plan.rounds:
            return
        for i in range(intervals):
            ctx = self._throwaway_ctx()
            gen = self.engine.cycle(ctx)
            cycle = self.WARMUP_BASE + i
            try:
                rnd = next(gen)
                while True:
                    self._warm_round(cycle, rnd, ctx)
                    rnd = gen.send(None)
            except (StopIteration, ObserverDiverged):
                continue

    def _throwaway_ctx(self) -> dict:
        """A context at the current estimate, measured there exactly (warm-up, timing)."""
        est = self.ctl.est
        ctx = self.engine.new_ctx(0.0, est, [0.0] * 3, [0.0] * 3)
        ctx["qmeas_i"] = [float(q) for q in inverse_kinematics(self.engine.cfg.params, est[0])]
        return ctx

    def _warm_round(self, cycle: int, rnd: Round, ctx: dict) -> None:
        payload = encode(self.node.unit, cycle, rnd.index, parts=[
            {"cycle": cycle, "stage": rnd.index,
             "vals": Engine.request_vals(rnd, ctx, (0, 1, 2))}])
        waiting = set(range(self.n))
        deadline = time.monotonic() + self.rc.startup_timeout
        resend = 0.0
        sends = 0
        compute_s = 0.0
        t_sent = time.perf_counter()
        while waiting:
            if time.monotonic() >= resend:  # the first requests may race the routes
                t_sent = time.perf_counter()
                self.pub_req.put(payload)
                sends += 1
                resend = time.monotonic() + 0.2
            left = deadline - time.monotonic()
            if left <= 0:
                k = min(waiting)
                raise Fault(f"peripheral {k + 1} did not answer during warm-up",
                            process=f"peripheral-{k + 1}", code=EXIT_PERIPHERAL)
            try:
                ev = self.node.events.get(timeout=min(left, 0.1))
            except queue.Empty:
                self._check_children()
                continue
            if ev[0] == "reply":
                msg = self.node.decode(ev[2])
                if msg is None or msg["cycle"] != cycle or ev[1] not in waiting:
                    continue
                try:
                    part = parts_of(msg)[0]
                    if part["stage"] != rnd.index:
                        continue
                    axes = self.plan.placement.axes[ev[1]]
                    Engine.merge(ctx, check_vals(part.get("vals"), rnd.recv, len(axes)), axes)
                    span = check_span(part.get("span"))
                except BadMessage:
                    continue
                waiting.discard(ev[1])
                # the exchange alone: less the slowest peripheral's compute span
                compute_s = max(compute_s, (span[1] - span[0]) / 1e9)
                if not waiting and sends == 1 and rnd.index == 0:
                    self.warm_rtt_s.append(time.perf_counter() - t_sent - compute_s)
            elif ev[0] == "sample":
                self._on_sample(ev[2], ev[3])
            elif ev[0] == "hello":
                self._handle(ev)

    def choose_replies(self) -> dict[str, Any]:
        """Decide how peripherals answer fused requests (``--replies``); see the module
        notes. Returns what was decided and from which figures (for the report)."""
        asked = self.rc.replies
        info: dict[str, Any] = {"asked": asked}
        rtt = between = math.nan
        if asked == "auto" and self.depth >= 2 and self.n:
            rtt = statistics.median(self.warm_rtt_s) if self.warm_rtt_s else math.inf
            between = self.central_between_rounds_s()  # round trip: the exchange alone
            info.update(round_trip_s=rtt, central_between_rounds_s=between)
        mode, why = reply_mode(asked, depth=self.depth, peripherals=self.n,
                               between_s=between, round_trip_s=rtt)
        if why != "asked":
            info["why"] = why
        info["mode"] = mode
        self.reply_each = mode == "each"
        self.replies_info = info
        return info

    def central_between_rounds_s(self, *, repeat: int = 20) -> float:
        """The central's work from the end of one round to the send of the next interval's
        first round: every central step except those after the last round and, at depth
        2, the sample-free ones run ahead (:meth:`_prime`). T-800 costs from the cost
        model; native costs measured here on throw-away intervals."""
        names = self.plan.middle_blocks(ahead=self.depth > 1)
        if self.engine.cost.name == "t800":
            graph = self.plan.graph
            return sum(graph.block(b).t800_s(self.engine.cost.scale) for b in names)
        acc: dict[str, list[int]] = {}
        old = self.engine.span
        self.engine.span = lambda name, t0, t1: acc.setdefault(name, []).append(t1 - t0)
        try:
            for _ in range(repeat):
                self.engine.run_local(self._throwaway_ctx())
        except ObserverDiverged:
            pass
        finally:
            self.engine.span = old
        return sum(statistics.median(acc[b]) for b in names if b in acc) / 1e9

    def _check_deadlines(self, timeout_ns: int) -> None:
        """Raise the fault of a silent peripheral or plant, unless messages are still
        waiting in the inbox (the central may have been the slow one: a reply it has not
        read yet is not silence)."""
        try:
            self._find_silence(timeout_ns)
        except Fault:
            if self.node.events.pending():
                return  # read them first; the check runs again after each event
            raise

    def _find_silence(self, timeout_ns: int) -> None:
        now = time.monotonic_ns()
        if self.rc.clock == "realtime" and self.done:
            for k, t in enumerate(self.last_reply_ns):  # alive, even when its data is held
                if t and now - t > timeout_ns and any(k in f.dropped or k in f.waiting
                                                      for f in self.inflight.values()):
                    raise Fault(f"peripheral {k + 1} has not answered for "
                                f"{(now - t) / 1e6:.1f} ms (limit {timeout_ns / 1e6:.1f} ms)"
                                f"{self._overload_hint()}",
                                process=f"peripheral-{k + 1}",
                                code=EXIT_PERIPHERAL)
        for f in self.inflight.values():
            if f.waiting and now > f.deadline_ns:
                k = min(f.waiting)
                silent = (now - f.deadline_ns + timeout_ns) / 1e6
                raise Fault(
                    f"peripheral {k + 1} did not answer round {f.round.index if f.round else '?'}"
                    f" of cycle {f.cycle}: silent for {silent:.1f} ms (limit "
                    f"{timeout_ns / 1e6:.1f} ms){self._overload_hint()}",
                    process=f"peripheral-{k + 1}", code=EXIT_PERIPHERAL)
        if (self.rc.clock != "freerun" and not self.samples and self.next_cycle < self.cycles
                and not any(f.waiting for f in self.inflight.values())):
            last = self.last_sample_ns or self.t_start_ns
            if now - last > timeout_ns:
                raise Fault(f"no sample from the plant for {(now - last) / 1e6:.1f} ms "
                            f"(cycle {self.next_cycle} awaited, newest seen "
                            f"{self.newest_sample}){self._overload_hint()}", process="plant",
                            code=EXIT_PLANT)

    def _check_children(self) -> None:
        """Fault at once when a role process this central started has died."""
        if self.child_check is None:
            return
        now = time.monotonic()
        if now < self._next_child_check:
            return
        self._next_child_check = now + 0.05
        dead = self.child_check()
        if dead is not None:
            name, rc = dead
            code = EXIT_PLANT if name == "plant" else EXIT_PERIPHERAL
            raise Fault(f"{name} exited (status {rc})", process=name, code=code)

    # -- late data (realtime) -------------------------------------------------------------

    def _late_policies(self) -> dict[int, str]:
        """Policy per round: the strictest of its blocks' (fault > hold > wait)."""
        order = {"wait": 0, "hold": 1, "fault": 2}
        out = {}
        for r in self.plan.rounds:
            pols = [self.rc.late.get(b.name, self.rc.late_policy) for b in r.blocks]
            out[r.index] = max(pols, key=lambda p: order[p]) if pols else "wait"
        return out

    def _check_late(self, now: int) -> None:
        if self.rc.clock != "realtime":
            return
        for f in list(self.inflight.values()):
            if not f.waiting or f.round is None or not f.late_ns or now < f.late_ns:
                continue
            policy = self.late_policy[f.round.index]
            if policy == "wait":
                f.late_ns = 0
                continue
            k = min(f.waiting)
            late = [b.name for b in f.round.blocks]
            if policy == "fault":
                raise Fault(f"late data: peripheral {k + 1} missed the deadline of round "
                            f"{f.round.index} ({', '.join(late)}) of cycle {f.cycle}",
                            process=f"peripheral-{k + 1}", code=EXIT_PERIPHERAL)
            # hold: the last values of the missing peripherals' axes
            if not all(name in self.last_vals for name in f.round.recv):
                f.late_ns = 0  # nothing to hold yet: wait
                continue
            for p in sorted(f.waiting):
                axes = self.plan.placement.axes[p]
                held = {name: [self.last_vals[name][a] for a in axes] for name in f.round.recv}
                Engine.merge(f.ctx, held, axes)
                for a in axes:
                    self.late_per_axis[a] += 1
                f.dropped.add(p)
                self.held.add((f.cycle, f.round.index, p))
                if len(self.held) > 1024:
                    self.held.discard(min(self.held))
            f.waiting.clear()
            self._advance(f)

    # -- events -----------------------------------------------------------------------

    def _handle(self, ev: tuple[str, int, bytes, int]) -> None:
        kind, index, data, rx = ev
        if kind == "reply":
            self._on_reply(index, data, rx)
        elif kind == "sample":
            self._on_sample(data, rx)
        elif kind == "hello":
            msg = self.node.decode(data)
            if msg is None:
                return
            if msg.get("stage") == "hello":
                self.say("go")  # a role that missed go asks again
            elif msg.get("stage") == "bye" and msg.get("role") in self.expected_roles():
                report = msg.get("report")
                if type(report) is not dict:
                    self.node.reject("bad_value")
                    return
                self.role_reports[msg["role"]] = role_report(report)
        else:
            self.node.reject("unexpected_key")

    def _on_sample(self, data: bytes, rx: int) -> None:
        msg = self.node.decode(data)
        if msg is None:
            return
        if msg["stage"] != "sample":
            self.node.reject("bad_stage")
            return
        try:
            counts = msg.get("counts")
            if not isinstance(counts, list) or len(counts) != 3 or not all(
                isinstance(c, int) and not isinstance(c, bool) and abs(c) < 10**9
                for c in counts
            ):
                raise BadMessage("bad_value", "counts")
            t_ns = msg.get("t_ns")
            if isinstance(t_ns, bool) or not isinstance(t_ns, int):
                raise BadMessage("bad_value", "t_ns")
            p = check_vector(msg.get("p"), 3, "p")
            span = check_span(msg.get("span"))
        except BadMessage as exc:
            self.node.reject(exc.reason)
            return
        cycle = msg["cycle"]
        if cycle < self.next_cycle or cycle >= self.cycles + self.depth + 1:
            self.node.reject("stale_cycle" if cycle < self.next_cycle else "future_cycle")
            return
        self.last_sample_ns = rx
        self.newest_sample = max(self.newest_sample, cycle)
        self.samples[cycle] = (counts, t_ns)
        if len(self.samples) > 64:  # realtime and far behind: keep the newest
            del self.samples[min(self.samples)]
        true_p = self.log.true_p
        true_p[cycle] = (p[0], p[1], p[2])
        if len(true_p) > 64:
            del true_p[min(true_p)]
        ref = self.engine.cfg.task.sample(cycle * self.rc.period)[0]  # type: ignore[union-attr]
        self.log.errors.append(math.dist(true_p[cycle], ref))
        self.plant_busy_ns += span[1] - span[0]
        misses = msg.get("misses")
        if isinstance(misses, int) and not isinstance(misses, bool):
            self.plant_misses = misses
        self._span("plant", cycle, span[0], span[1])
        if self.on_message is not None:
            self.on_message("in", self.node.keys.sample, cycle, "sample", data, rx)

    def _on_reply(self, k: int, data: bytes, rx: int) -> None:
        t_in = time.perf_counter_ns()
        msg = self.node.decode(data)
        if msg is None:
            return
        try:
            parts = parts_of(msg)
        except BadMessage as exc:
            self.node.reject(exc.reason)
            return
        axes = self.plan.placement.axes[k]
        complete = []
        accepted = False
        for part in parts:
            f = self.inflight.get(part["cycle"])
            if (f is None or f.round is None or part["stage"] != f.round.index
                    or k not in f.waiting):
                key = (part["cycle"], part["stage"], k)
                if key in self.held:  # its values were replaced by the last ones (hold)
                    self.held.discard(key)
                    self.last_reply_ns[k] = rx
                    self.node.reject("late_reply")
                else:
                    self.node.reject("unexpected_reply")
                continue
            try:
                vals = check_vals(part.get("vals"), f.round.recv, len(axes))
                if "trace" in part and not isinstance(part["trace"], dict):
                    raise BadMessage("bad_value", "trace")
                span = check_span(part.get("span"))
            except BadMessage as exc:
                self.node.reject(exc.reason)
                continue
            accepted = True
            Engine.merge(f.ctx, vals, axes)
            for name, v in vals.items():
                slot = self.last_vals.setdefault(name, [None, None, None])
                for j, a in enumerate(axes):
                    slot[a] = v[j]
            self.periph_busy_ns[k] += span[1] - span[0]
            self._span(f"peripheral_{k + 1}", f.cycle, span[0], span[1])
            f.waiting.discard(k)
            if not f.waiting:
                complete.append(f)
        if not accepted:
            return
        self.reply_ns += time.perf_counter_ns() - t_in
        self.reply_msgs += 1
        self.last_reply_ns[k] = rx
        if self.on_message is not None:
            self.on_message("in", self.node.keys.reply(k + 1), msg["cycle"], msg["stage"],
                            data, rx)
        # depth 2: intervals with more rounds first; those whose last round this was
        # finish after the next request is out (their last central blocks, command,
        # recording and progress overlap the peripherals' work)
        finishing = [f for f in complete if f.round is not None
                     and finishes_after_next_request(depth=self.depth,
                                                     round_index=f.round.index,
                                                     last_round=self.last_round)]
        for f in complete:
            if f not in finishing:
                self._advance(f)
        if finishing:
            for f in finishing:
                f.finishing = True
            self._start_ready()
            self._flush(time.monotonic_ns())
            for f in finishing:
                self._advance(f)

    # -- intervals --------------------------------------------------------------------

    def _newest_handed_off(self) -> bool | None:
        if not self.inflight:
            return None
        return next(reversed(self.inflight.values())).handed_off

    def _may_start(self) -> bool:
        live = sum(1 for f in self.inflight.values() if not f.finishing)
        return may_start(depth=self.depth, live=live, next_cycle=self.next_cycle,
                         cycles=self.cycles, newest_handed_off=self._newest_handed_off())

    def _start_ready(self) -> None:
        while self._may_start():
            t_in = time.perf_counter_ns()
            k = self.next_cycle
            if self.rc.clock == "freerun":
                counts, t_ns = self._synthetic_sample(k), time.monotonic_ns()
                if self.on_message is not None:
                    self.on_message("in", self.node.keys.sample, k, "sample", encode(
                        self.node.unit, k, "sample", counts=counts, t_ns=t_ns, synthetic=True),
                        t_ns)
            else:
                if self.rc.clock == "realtime" and self.samples and max(self.samples) > k:
                    # behind the plant's clock: start from the newest sample, never queue
                    newest = max(self.samples)
                    self.skipped += sum(1 for c in self.samples if c < newest) + (
                        newest - k - len(self.samples) + 1)
                    self.samples = {newest: self.samples[newest]}
                    self.next_cycle = k = newest
                if k not in self.samples:
                    return
                counts, t_ns = self.samples.pop(k)
            self.next_cycle = k + 1
            t0 = time.monotonic_ns()
            primed, self.primed = self.primed, None
            if primed is not None and primed[0] == k:  # its sample-free steps are done
                ctx = primed[1]
                self.ctl.measure(ctx, k, counts)
                gen = self.engine.cycle(ctx, skip_prefix=True)
            else:
                ctx = self.ctl.sources(k, counts)
                gen = self.engine.cycle(ctx)
            if len(self.t1_inputs) < self.rc.t1_cycles:
                self.t1_inputs.append((ctx["t"], ctx["est"], list(ctx["qmeas_i"]),
                                       list(ctx["qdmeas_i"])))
            f = InFlight(k, gen, ctx, t_ns, t0)
            self.inflight[k] = f
            self.admit_ns += time.perf_counter_ns() - t_in
            self._advance(f)

    def _prime(self) -> bool:
        """Depth 2: run the next interval's sample-free leading steps (the plan's
        ``presample_steps``: for resolved acceleration the reference and the observer's
        prediction) as soon as the newest interval has handed off its estimate, before
        the next interval has a slot or its sample. They would otherwise sit between one
        interval's last reply and the next request, with the peripherals idle. Same
        arithmetic: the estimate they use is final at the hand-off. Returns whether it
        ran them."""
        if not may_prime(depth=self.depth, primed=self.primed is not None,
                         next_cycle=self.next_cycle, cycles=self.cycles,
                         newest_handed_off=self._newest_handed_off()):
            return False
        k = self.next_cycle
        t0 = time.monotonic_ns()
        ctx = self.ctl.context(k)
        try:
            self.engine.prefix(ctx)
        except ObserverDiverged as exc:
            raise Fault(f"cycle {k}: {exc}", process="central", code=EXIT_OBSERVER) from None
        self.primed = (k, ctx)
        self._span("central", k, t0, time.monotonic_ns())
        return True

    def _synthetic_sample(self, k: int) -> list[int]:
        p = self.engine.cfg.task.sample(k * self.rc.period)[0]  # type: ignore[union-attr]
        params = self.engine.cfg.params
        x, y, z = float(p[0]), float(p[1]), float(p[2])
        return [round(ik_axis(params, i, x, y, z).q / params.increment) for i in range(3)]

    def _advance(self, f: InFlight) -> None:
        """Run the interval's central steps up to its next round (or its end)."""
        f.start_ns = time.monotonic_ns()  # the central's span starts here, not at a send
        try:
            rnd = f.gen.send(None) if f.started else next(f.gen)
        except StopIteration:
            rnd = None
        except ObserverDiverged as exc:
            raise Fault(f"cycle {f.cycle}: {exc}", process="central",
                        code=EXIT_OBSERVER) from None
        f.started = True
        if not f.handed_off and (rnd is None or self.round_step[rnd.index] > self.hand):
            self.ctl.handoff(f.ctx)
            f.handed_off = True
        if rnd is None:
            self._finish(f)
            return
        f.round = rnd
        self.outbox.append(f)
        self._span("central", f.cycle, f.start_ns, time.monotonic_ns())

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
            if self.rc.clock == "realtime" and self.plan.round_trips:
                share = (rnd.index + 1) / self.plan.round_trips
                f.late_ns = f.sample_ns + int(self.depth * self.period_ns * share)
            parts.append({"cycle": f.cycle, "stage": rnd.index,
                          "vals": Engine.request_vals(rnd, f.ctx, (0, 1, 2))})
        self.outbox.clear()
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
                                next_cycle=self.next_cycle, cycles=self.cycles):
            return 0
        if self.rc.clock == "realtime":
            return f.sample_ns + self.period_ns + self.period_ns // 4
        return time.monotonic_ns() + self._timeout_ns()

    def _check_state(self, f: InFlight) -> None:
        """The observed state must track the reference and stay in the usable workspace
        (Eq. V.33, checked every 10th interval); otherwise stop safely with a reason."""
        p, pc = f.ctx.get("p"), f.ctx.get("pc")
        if p is None or pc is None:
            return
        err = math.dist(p, pc)
        why = None
        if err > self.rc.max_error:
            why = (f"tracking error {err * 1e3:.1f} mm exceeds --max-error "
                   f"{self.rc.max_error * 1e3:.1f} mm")
        elif f.cycle % 10 == 0:
            chk = check_point(self.engine.cfg.params, p)
            if not chk.ok:
                why = f"the robot left the usable workspace: {chk.reason}"
        if why is None:
            return
        raise Fault(f"cycle {f.cycle}: {why}{self._overload_hint()}", process="central",
                    code=EXIT_OBSERVER)

    def _overload_hint(self) -> str:
        """In realtime, when most deadlines were missed: say that the machine, not a
        process, is the likely cause."""
        periods = max(1, self.next_cycle)
        late = self.plant_misses + self.skipped
        if self.rc.clock != "realtime" or late <= max(5, periods // 10):
            return ""
        return (f"; {self.plant_misses} commands missed their deadline and {self.skipped} "
                f"samples were skipped in {periods} periods: this machine does not sustain "
                f"a {self.rc.period * 1e3:g} ms period with {self.n} peripheral(s) (try a "
                "longer --period or --fault-periods, or --clock lockstep)")

    def _finish(self, f: InFlight) -> None:
        t_in = time.perf_counter_ns()
        self._check_state(f)  # here, after the next request is out: off the critical path
        cmd = f.ctx["cmd"]
        payload = encode(self.node.unit, f.cycle, "command", tau=[float(x) for x in cmd])
        self.pub_cmd.put(payload)
        now = time.monotonic_ns()
        self._span("central", f.cycle, f.start_ns, now)
        if self.on_message is not None:
            self.on_message("out", self.node.keys.command, f.cycle, "command", payload, now)
        del self.inflight[f.cycle]
        log = self.log
        log.cmd_ns.append(now)
        log.traversal_ns.append(min(now - f.sample_ns, 2**31 - 1))
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

    # -- end --------------------------------------------------------------------------

    def hold_torques(self) -> list[float]:
        """Gravity-holding torques at the last estimated position (the first stage of the
        safe stop); zeros if that position is not usable."""
        from ..kernels.dynamics import gravity_torques

        p = self.ctl.est[0]
        try:
            if check_point(self.engine.cfg.params, p).ok:
                return [float(x) for x in gravity_torques(self.engine.cfg.params, p)]
        except (ValueError, ZeroDivisionError):
            pass
        return [0.0, 0.0, 0.0]

    def zenoh_identity(self) -> dict[str, Any]:
        """This central's Zenoh id and the ids of the peers it is connected to."""
        info = self.node.session.info
        self.peers_seen.update(str(z) for z in info.peers_zid())
        return {"zid": str(info.zid()), "peers": sorted(self.peers_seen)}

    def stop(self, *, reason: str = "done", wait: float = 1.0) -> None:
        """Tell every role to stop (the plant runs its safe stop) and collect their
        reports for up to ``wait`` seconds."""
        expected = self.expected_roles()
        deadline = time.monotonic() + wait
        hold = self.hold_torques()
        # a fault's message is long; whole, it made the order undecodable (the roles then
        # ran on, and the plant made no safe stop, until the launcher ended them)
        reason = short_text(reason)
        self.say("stop", reason=reason, hold=hold)
        next_say = time.monotonic() + 0.1
        while set(self.role_reports) < expected and time.monotonic() < deadline:
            try:
                ev = self.node.events.get(timeout=0.05)
            except queue.Empty:
                ev = None
            if ev is not None and ev[0] == "hello":
                self._handle(ev)
            if time.monotonic() > next_say:
                self.say("stop", reason=reason, hold=hold)
                next_say = time.monotonic() + 0.1


ROLE_REPORT_FIELDS: dict[str, tuple[type, ...]] = {
    "exit": (str,), "sched": (str,), "served": (int,), "samples": (int,), "misses": (int,),
    "busy_ns": (int,), "wall_ns": (int,), "cpu_s": (int, float), "rejected": (dict,),
    "rss_kb": (dict,), "safe_stop": (dict,),
}
"""What a role's ``bye`` report may hold, by field; anything else is left out."""


def role_report(report: dict[str, Any]) -> dict[str, Any]:
    """The fields of a role's final report that have the type the report reader expects
    (:data:`ROLE_REPORT_FIELDS`; ``rejected`` keeps only counts by text reason), so that
    a malformed or forged ``bye`` cannot break the run's report."""
    out: dict[str, Any] = {}
    for name, types in ROLE_REPORT_FIELDS.items():
        v = report.get(name)
        if isinstance(v, bool) or not isinstance(v, types):
            continue
        if name == "rejected":
            v = {k: n for k, n in v.items() if isinstance(k, str) and type(n) is int}
        out[name] = v
    return out


def measure_t1(engine_factory: Callable[[], Engine], inputs: list[tuple], *, repeat: int = 1
               ) -> tuple[float, dict[str, float]]:
    """``t_1``: the same intervals computed by one process with no exchange.

    Parameters
    ----------
    engine_factory : builds an n = 0 engine (same law, model, cost model).
    inputs : ``(t, est, qmeas, qdmeas)`` of recorded intervals.

    Returns
    -------
    (median seconds per interval, mean seconds per block)
    """
    block_ns: dict[str, list[int]] = {}

    def span(name: str, t0: int, t1: int) -> None:
        block_ns.setdefault(name, []).append(t1 - t0)

    eng = engine_factory()
    eng.span = span
    times = []
    for _ in range(repeat):
        for t, est, q, qd in inputs:
            ctx = eng.new_ctx(t, est, q, qd)
            t0 = time.perf_counter_ns()
            try:
                eng.run_local(ctx)
            except ObserverDiverged:
                continue
            times.append(time.perf_counter_ns() - t0)
    if not times:
        return math.nan, {}
    per_block = {k: statistics.fmean(v) / 1e9 for k, v in block_ns.items()}
    return statistics.median(times) / 1e9, per_block


__all__ = ["EXIT_OK", "Central", "CostModel", "Fault", "measure_t1"]
