"""The predicted schedule of a unit: a discrete-event model of the central's scheduler.

Given an exchange plan (stage graph + placement), per-block costs and the costs of a
message, :func:`simulate` plays ``freerun`` intervals through the same rules as
:class:`~ctrlunit.runtime.central.Central`: up to ``depth`` intervals in flight, the next
interval started once the newest has handed off its estimate, its sample-free steps run
ahead at depth 2, ready rounds fused into one request, a lone second half held for the
next first round, replies fused or one per part (first rounds first), and the central
finishing an interval after the next request is out. The central is one server that
handles replies in the order they arrive; each peripheral runs its requests in order.
Rounds that need no sample (``ExchangePlan.ahead_rounds``) leave ahead of their interval
only where its sample has yet to come (lockstep, realtime); in freerun the next interval
starts as soon as the newest hands off, before the central would run it ahead, so such a
round is its interval's first, as here.

It predicts the period, the traversal, each process's business and a Gantt chart, for a
placement that has never run: what ``ctrlunit balance`` needs to rank placements
(§ IV.7.2) and to be checked against a re-run.
"""

from __future__ import annotations

import heapq
import math
from collections.abc import Mapping
from dataclasses import dataclass, field, replace

from .pipeline import (
    finishes_after_next_request,
    handoff_step,
    holds_lone_round,
    may_prime,
    may_start,
    reply_order,
)
from .plan import ExchangePlan


@dataclass(frozen=True)
class Costs:
    """What the model charges, in seconds.

    Attributes
    ----------
    block_s : each block's time for all three axes (a per-axis block on a peripheral owning
        ``m`` axes takes ``m / 3`` of it).
    send_s : the central's time to send a request (encode, put).
    reply_s : the central's time per reply message (decode, check, merge).
    step_s : the central's time per run of consecutive central steps, beyond its blocks
        (generator, bookkeeping, its share of the event loop).
    start_s, finish_s : the central's time per interval to start it (sample, context) and
        to finish it (checks, command, logs, progress).
    latency_s : one way, from a put to the receiver working on it (transport, wake-up, the
        peripheral's decode and encode).
    """

    block_s: Mapping[str, float]
    send_s: float = 0.0
    reply_s: float = 0.0
    step_s: float = 0.0
    latency_s: float = 0.0
    start_s: float = 0.0
    finish_s: float = 0.0

    def with_latency(self, latency_s: float) -> Costs:
        return replace(self, latency_s=latency_s)


@dataclass
class Schedule:
    """A simulated run: spans ``(process, cycle, t0_s, t1_s)``, command and sample times."""

    spans: list[tuple[str, int, float, float]]
    cmd_s: list[float]
    sample_s: list[float]
    exchanges: int
    intervals: int

    def _steady(self) -> tuple[list[float], list[float]]:
        skip = max(2, len(self.cmd_s) // 5)
        return self.cmd_s[skip:], self.sample_s[skip:]

    @property
    def period_mean_s(self) -> float:
        """Mean time between commands after the first fifth (the start-up)."""
        cmd, _ = self._steady()
        return (cmd[-1] - cmd[0]) / (len(cmd) - 1) if len(cmd) > 1 else math.nan

    @property
    def traversal_s(self) -> float:
        """Median time from an interval's sample to its command (steady state)."""
        cmd, smp = self._steady()
        tr = sorted(c - s for c, s in zip(cmd, smp))
        return tr[len(tr) // 2] if tr else math.nan

    @property
    def exchanges_per_interval(self) -> float:
        return self.exchanges / max(1, self.intervals)

    def business(self) -> dict[str, float]:
        """Busy share of each process over the steady state."""
        cmd, _ = self._steady()
        if len(cmd) < 2:
            return {}
        t0, t1 = cmd[0], cmd[-1]
        out: dict[str, float] = {}
        for proc, _c, a, b in self.spans:
            lo, hi = max(a, t0), min(b, t1)
            if hi > lo:
                out[proc] = out.get(proc, 0.0) + (hi - lo)
        return {k: v / (t1 - t0) for k, v in sorted(out.items())}

    def window(self, *, intervals: int = 4) -> list[tuple[str, int, float, float]]:
        """Spans of a few steady-state intervals, in ms from the first (Gantt charts)."""
        mid = self.intervals // 2
        sel = [s for s in self.spans if mid <= s[1] < mid + intervals]
        if not sel:
            return []
        t0 = min(s[2] for s in sel)
        return [(p, c, (a - t0) * 1e3, (b - t0) * 1e3) for p, c, a, b in sel]


@dataclass
class _Interval:
    cycle: int
    sample_s: float
    seg: int = 0  # next segment of central steps to run
    round: int = -1  # round in flight (-1: none)
    waiting: set[int] = field(default_factory=set)
    handed: bool = False
    finishing: bool = False


class _Model:
    def __init__(self, plan: ExchangePlan, costs: Costs, depth: int, each: bool,
                 intervals: int) -> None:
        self.costs = costs
        self.depth = depth
        self.each = each
        self.total = intervals
        self.n = plan.placement.peripherals
        self.rounds = plan.round_trips
        # central segments: the steps before round 0, between rounds, after the last
        seg_cost = [0.0] * (self.rounds + 1)
        seg, hand_seg = 0, 0
        hand = handoff_step(plan)
        self.prefix_s = 0.0
        for k, st in enumerate(plan.steps):
            if st.round is not None:
                seg += 1
                continue
            assert st.block is not None
            c = costs.block_s.get(st.block.name, 0.0)
            seg_cost[seg] += c
            if k < plan.presample_steps:
                self.prefix_s += c
            if k == hand:
                hand_seg = seg
        self.seg_cost = seg_cost
        self.hand_seg = hand_seg if hand >= 0 else self.rounds
        axes = plan.placement.axes
        self.round_cost = [[sum(costs.block_s.get(b.name, 0.0) for b in r.blocks) * len(g) / 3
                            for g in axes] for r in plan.rounds]
        self.t = 0.0
        self.events: list[tuple[float, int, int, list[tuple[int, int]]]] = []
        self.seq = 0
        self.free_at = [0.0] * self.n
        self.inflight: dict[int, _Interval] = {}
        self.outbox: list[_Interval] = []
        self.primed = -1
        self.next = 0
        self.done = 0
        self.exchanges = 0
        self.spans: list[tuple[str, int, float, float]] = []
        self.cmd: list[float] = []
        self.smp: list[float] = []

    # -- the central ---------------------------------------------------------------

    def busy(self, cycle: int, cost: float) -> None:
        self.spans.append(("central", cycle, self.t, self.t + cost))
        self.t += cost

    def newest_handed(self) -> bool | None:
        return list(self.inflight.values())[-1].handed if self.inflight else None

    def may_start(self) -> bool:
        live = sum(1 for f in self.inflight.values() if not f.finishing)
        return may_start(depth=self.depth, live=live, next_cycle=self.next, cycles=self.total,
                         newest_handed_off=self.newest_handed())

    def start_ready(self) -> None:
        while self.may_start():
            k = self.next
            self.next += 1
            f = _Interval(k, self.t)
            self.inflight[k] = f
            skip = self.prefix_s if self.primed == k else 0.0
            self.primed = -1
            self.t += self.costs.start_s
            self.advance(f, skip)

    def prime(self) -> bool:
        if not may_prime(depth=self.depth, primed=self.primed >= 0, next_cycle=self.next,
                         cycles=self.total, newest_handed_off=self.newest_handed()):
            return False
        self.primed = self.next
        self.busy(self.next, self.prefix_s + self.costs.step_s)
        return True

    def advance(self, f: _Interval, skip: float = 0.0) -> None:
        self.busy(f.cycle, self.seg_cost[f.seg] - skip + self.costs.step_s)
        if f.seg >= self.hand_seg:
            f.handed = True
        if f.seg == self.rounds:
            self.cmd.append(self.t)
            self.smp.append(f.sample_s)
            del self.inflight[f.cycle]
            self.done += 1
            self.t += self.costs.finish_s
            return
        f.round = f.seg
        f.seg += 1
        self.outbox.append(f)

    def flush(self) -> None:
        if not self.outbox:
            return
        f = self.outbox[0]
        if holds_lone_round(depth=self.depth, ready=len(self.outbox), handed_off=f.handed,
                            cycle=f.cycle, next_cycle=self.next, cycles=self.total):
            return  # held for the next interval's first round
        self.t += self.costs.send_s
        self.exchanges += 1
        parts = [(f.cycle, f.round) for f in self.outbox]
        for f in self.outbox:
            f.waiting = set(range(self.n))
        self.outbox.clear()
        each = self.each and len(parts) > 1
        arrive = self.t + self.costs.latency_s
        for p in range(self.n):
            start = max(arrive, self.free_at[p])
            order = [parts[i] for i in reply_order([r for _, r in parts], each=each)]
            done_parts = []
            for cycle, r in order:
                end = start + self.round_cost[r][p]
                self.spans.append((f"peripheral_{p + 1}", cycle, start, end))
                start = end
                done_parts.append((cycle, r))
                if each:
                    self.post(end + self.costs.latency_s, p, done_parts)
                    done_parts = []
            if done_parts:
                self.post(start + self.costs.latency_s, p, done_parts)
            self.free_at[p] = start

    def post(self, t: float, p: int, parts: list[tuple[int, int]]) -> None:
        heapq.heappush(self.events, (t, self.seq, p, parts))
        self.seq += 1

    def on_reply(self, p: int, parts: list[tuple[int, int]]) -> None:
        self.t += self.costs.reply_s
        complete = []
        for cycle, _r in parts:
            f = self.inflight[cycle]
            f.waiting.discard(p)
            if not f.waiting:
                complete.append(f)
        last = self.rounds - 1
        finishing = [f for f in complete if finishes_after_next_request(
            depth=self.depth, round_index=f.round, last_round=last)]
        for f in complete:
            if f not in finishing:
                f.round = -1
                self.advance(f)
        if finishing:
            for f in finishing:
                f.finishing = True
            self.start_ready()
            self.flush()
            for f in finishing:
                f.round = -1
                self.advance(f)

    def tail(self) -> None:
        self.start_ready()
        self.flush()
        if self.prime():
            self.start_ready()
            self.flush()

    def run(self) -> None:
        self.tail()
        while self.done < self.total:
            if not self.events:
                raise RuntimeError(f"schedule model stalled at interval {self.done}")
            t, _s, p, parts = heapq.heappop(self.events)
            self.t = max(self.t, t)
            self.on_reply(p, parts)
            self.tail()


def simulate(plan: ExchangePlan, costs: Costs, *, depth: int = 1, replies: str = "fused",
             intervals: int = 200) -> Schedule:
    """Play ``intervals`` freerun intervals of ``plan`` through the central's rules.

    Parameters
    ----------
    plan : the exchange plan (its placement says who runs what).
    costs : block and message costs.
    depth : pipeline depth, 1 or 2.
    replies : ``fused`` or ``each`` (see ``--replies``).
    intervals : how many intervals to play (the first fifth is start-up).
    """
    if depth not in (1, 2):
        raise ValueError(f"depth must be 1 or 2, got {depth}")
    if replies not in ("fused", "each"):
        raise ValueError(f"replies must be fused or each, got {replies!r}")
    if intervals < 10:
        raise ValueError(f"intervals must be at least 10, got {intervals}")
    m = _Model(plan, costs, depth, replies == "each", intervals)
    m.run()
    return Schedule(m.spans, m.cmd, m.smp, m.exchanges, intervals)


def fit_latency(plan: ExchangePlan, costs: Costs, period_s: float, *, depth: int,
                replies: str = "fused", intervals: int = 120,
                figure: str = "period_mean_s", steps: int = 40) -> float:
    """The one-way latency with which the model's period equals a measured one (bisection
    in ``steps`` halvings; the period does not decrease as the latency grows). 0 when the
    model is already slower at no latency. ``figure`` ``"traversal_s"``: its traversal
    instead (one interval's own time, where a realtime clock pads the period)."""
    def period(lat: float) -> float:
        return getattr(simulate(plan, costs.with_latency(lat), depth=depth, replies=replies,
                                intervals=intervals), figure)

    lo, hi = 0.0, max(1e-3, period_s)
    if period(lo) >= period_s:
        return 0.0
    for _ in range(60):
        if period(hi) >= period_s:
            break
        hi *= 2.0
    for _ in range(steps):
        mid = 0.5 * (lo + hi)
        if period(mid) < period_s:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)
