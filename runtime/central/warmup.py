"""The central's warm-up: throw-away intervals over the real path before measuring, the
round trip they show, and the choices made from it: how peripherals answer fused
requests (``--replies auto``) and which rounds the central runs itself (``--placement
auto``); docs/architecture.md gives both rules and their figures."""

from __future__ import annotations

import math
import queue
import statistics
import time
from collections.abc import Callable, Collection
from typing import Any

from ...kernels.kinematics import inverse_kinematics
from ...topology.balance import auto_central_blocks
from ...topology.pipeline import reply_mode
from ...topology.plan import Round
from ..compute.blocks import ObserverDiverged
from ..compute.controller import Controller
from ..compute.engine import Engine
from ..config import EXIT_PERIPHERAL
from ..transport.codec import WARMUP_BASE, BadMessage, check_span, check_vals, encode, parts_of
from ..transport.node import Event, Node
from .fault import Fault

RESEND_S = 0.2
"""A warm-up request unanswered this long is sent again (the first may race the routes)."""


class WarmUp:
    """The warm-up of one central.

    Parameters
    ----------
    node : the central's node; ``publish`` puts a request on its request key.
    engine, controller : the run's plan and estimate (:meth:`use` when they change).
    depth, asked : the pipeline depth and ``--replies``.
    startup_timeout_s : how long a peripheral may take to answer a warm-up round.
    check_children : raises the fault of a role process that has exited (or takes the
        peripheral over: .takeover).
    other : takes the events that are not the warm-up's replies (samples, hellos).
    lost : the peripherals taken over, whose blocks the warm-up runs here.
    """

    def __init__(self, node: Node, engine: Engine, controller: Controller, *,
                 publish: Callable[[bytes], None], depth: int, asked: str,
                 startup_timeout_s: float, check_children: Callable[[], None],
                 other: Callable[[Event], None],
                 lost: Callable[[], Collection[int]] = frozenset) -> None:
        self.node = node
        self.publish = publish
        self.depth = depth
        self.asked = asked
        self.startup_timeout_s = startup_timeout_s
        self.check_children = check_children
        self.other = other
        self.lost = lost
        self.block_costs: dict[str, float] | None = None
        """Each block's time on the central (measured once)."""
        self.reply_each = False
        """Peripherals answer each part of a fused request as soon as it is computed."""
        self.replies_info: dict[str, Any] = {"mode": "fused"}
        self.use(engine, controller)

    def use(self, engine: Engine, controller: Controller) -> None:
        """Warm up ``engine``'s plan from ``controller``'s estimate; the round trips kept,
        which were of the old plan, are dropped."""
        self.engine = engine
        self.ctl = controller
        self.warm_rtt_s: list[float] = []
        """Each warm-up round trip less the peripherals' compute (s)."""

    def run(self, intervals: int = 30) -> None:
        """Exercise the request/reply path before measuring (Zenoh routes, every round's
        code path on every process) with whole throw-away intervals; the replies are
        checked, merged and discarded. Each round trip less the peripherals' compute is
        kept (:attr:`warm_rtt_s`). The intervals occupy no modelled time
        (:meth:`CostModel.waived`): they are not the run's work."""
        plan = self.engine.plan
        if plan.placement.peripherals == 0 or not plan.rounds:
            return
        with self.engine.cost.waived():  # the peripherals waive theirs alike
            for i in range(intervals):
                ctx = self.throwaway_ctx()
                gen = self.engine.cycle(ctx)
                cycle = WARMUP_BASE + i
                try:
                    rnd = next(gen)
                    while True:
                        self._round(cycle, rnd, ctx)
                        rnd = gen.send(None)
                except (StopIteration, ObserverDiverged):
                    continue

    def throwaway_ctx(self) -> dict:
        """A context at the current estimate, measured there exactly (warm-up, timing)."""
        est = self.ctl.est
        ctx = self.engine.new_ctx(0.0, est, [0.0] * 3, [0.0] * 3)
        ctx["qmeas_i"] = [float(q) for q in inverse_kinematics(self.engine.cfg.params, est[0])]
        return ctx

    def _round(self, cycle: int, rnd: Round, ctx: dict) -> None:
        payload = encode(self.node.unit, cycle, rnd.index, parts=[
            {"cycle": cycle, "stage": rnd.index,
             "vals": Engine.request_vals(rnd, ctx, (0, 1, 2))}])
        axes_of = self.engine.plan.placement.axes
        waiting = set(range(self.engine.plan.placement.peripherals))
        self._run_lost(rnd, ctx, waiting)
        deadline = time.monotonic() + self.startup_timeout_s
        resend = 0.0
        sends = 0
        compute_s = 0.0
        t_sent = time.perf_counter()
        while waiting:
            if time.monotonic() >= resend:  # the first requests may race the routes
                t_sent = time.perf_counter()
                self.publish(payload)
                sends += 1
                resend = time.monotonic() + RESEND_S
            left = deadline - time.monotonic()
            if left <= 0:
                k = min(waiting)
                raise Fault(f"peripheral {k + 1} did not answer during warm-up",
                            process=f"peripheral-{k + 1}", code=EXIT_PERIPHERAL)
            try:
                ev = self.node.events.get(timeout=min(left, 0.1))
            except queue.Empty:
                self.check_children()
                self._run_lost(rnd, ctx, waiting)
                continue
            if ev.kind != "reply":
                self.other(ev)
                continue
            msg = self.node.decode(ev.data)
            if msg is None or msg["cycle"] != cycle or ev.index not in waiting:
                continue
            try:
                part = parts_of(msg)[0]
                if part["stage"] != rnd.index:
                    continue
                axes = axes_of[ev.index]
                Engine.merge(ctx, check_vals(part.get("vals"), rnd.recv, len(axes)), axes)
                span = check_span(part.get("span"))
            except BadMessage:
                continue
            waiting.discard(ev.index)
            # the exchange alone: less the slowest peripheral's compute span
            compute_s = max(compute_s, (span[1] - span[0]) / 1e9)
            if not waiting and sends == 1 and rnd.index == 0:
                self.warm_rtt_s.append(time.perf_counter() - t_sent - compute_s)

    def _run_lost(self, rnd: Round, ctx: dict, waiting: set[int]) -> None:
        """Run here the blocks of the peripherals in ``waiting`` that were lost."""
        for k in sorted(waiting & set(self.lost())):
            self.engine.run_round(rnd, ctx, self.engine.plan.placement.axes[k])
            waiting.discard(k)

    def choose_replies(self) -> dict[str, Any]:
        """Decide how peripherals answer fused requests (``--replies``). Returns what was
        decided and from which figures (for the report)."""
        peripherals = self.engine.plan.placement.peripherals
        info: dict[str, Any] = {"asked": self.asked}
        rtt = between = math.nan
        if self.asked == "auto" and self.depth >= 2 and peripherals:
            rtt = statistics.median(self.warm_rtt_s) if self.warm_rtt_s else math.inf
            between = self.central_between_rounds_s()  # round trip: the exchange alone
            info.update(round_trip_s=rtt, central_between_rounds_s=between)
        mode, why = reply_mode(self.asked, depth=self.depth, peripherals=peripherals,
                               between_s=between, round_trip_s=rtt)
        if why != "asked":
            info["why"] = why
        info["mode"] = mode
        self.reply_each = mode == "each"
        self.replies_info = info
        return info

    def central_between_rounds_s(self) -> float:
        """The central's work from the end of one round to the send of the next interval's
        first round: every central step except those after the last round and, at depth
        2, the sample-free ones run ahead."""
        names = self.engine.plan.middle_blocks(ahead=self.depth > 1)
        costs = self.block_costs_s()
        return sum(costs[b] for b in names if b in costs)

    def block_costs_s(self, *, repeat: int = 20) -> dict[str, float]:
        """Each block's time on the central for one interval (all the axes it runs on):
        T-800 costs from the cost model; native costs measured here once, medians over
        ``repeat`` throw-away intervals run whole in this process (the reply rule and the
        placement rule both read them)."""
        if self.block_costs is not None:
            return self.block_costs
        graph = self.engine.plan.graph
        if self.engine.cost.name == "t800":
            self.block_costs = {b.name: b.t800_s(self.engine.cost.scale) for b in graph.blocks}
            return self.block_costs
        acc: dict[str, list[int]] = {}
        old = self.engine.span
        self.engine.span = lambda name, t0, t1: acc.setdefault(name, []).append(t1 - t0)
        try:
            for _ in range(repeat):
                self.engine.run_local(self.throwaway_ctx())
        except ObserverDiverged:
            pass
        finally:
            self.engine.span = old
        self.block_costs = {b: statistics.median(v) / 1e9 for b, v in acc.items()}
        return self.block_costs

    def choose_placement(self) -> dict[str, Any]:
        """``--placement auto``: which rounds the central runs itself
        (:func:`~ctrlunit.topology.balance.auto_central_blocks`), from the warm-up's round
        trip and the blocks' costs here. Returns the choice and its figures (for the
        report); ``central_blocks`` is the placement to run."""
        rtt = statistics.median(self.warm_rtt_s) if self.warm_rtt_s else math.inf
        blocks, rounds = auto_central_blocks(self.engine.plan, self.block_costs_s(), rtt)
        moved = [r for r in rounds if r["moved"]]
        why = ("; ".join(f"round {r['round']} ({', '.join(r['blocks'])}) costs the central "
                         f"{r['arithmetic_s'] * 1e6:.0f} us against a {rtt * 1e6:.0f} us round "
                         "trip: on the central" for r in moved)
               or "every round but the last costs more on the central than its round trip "
               "(or there is only one): the peripherals keep their blocks")
        return {"asked": "auto", "central_blocks": sorted(blocks), "round_trip_s": rtt,
                "rounds": rounds, "why": why}


__all__ = ["WARMUP_BASE", "WarmUp"]
