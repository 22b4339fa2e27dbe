"""The central's warm-up: throw-away intervals over the real path before measuring, the
round trip they show, and the choice of reply mode made from it (``--replies auto``).

:class:`CentralWarmUp` is a part of :class:`~.central.Central` (a mixin).
"""

from __future__ import annotations

import math
import queue
import statistics
import time
from typing import Any

from ..kernels.kinematics import inverse_kinematics
from ..topology.balance import auto_central_blocks
from ..topology.pipeline import (
    reply_mode,
)
from ..topology.plan import Round
from .blocks import ObserverDiverged
from .central_guard import Fault
from .codec import (
    BadMessage,
    check_span,
    check_vals,
    encode,
    parts_of,
)
from .config import EXIT_PERIPHERAL
from .engine import Engine


class CentralWarmUp:
    """Warm-up and reply-mode choice of :class:`~.central.Central`."""

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

    def drain_trial(self, *, seconds: float) -> None:
        """After an admission trial that stopped early: for ``seconds``, drop the trial's
        stragglers (replies, samples) so that the run does not count them as rejected."""
        deadline = time.monotonic() + seconds
        while (left := deadline - time.monotonic()) > 0:
            try:
                ev = self.node.events.get(timeout=left)
            except queue.Empty:
                break
            if ev.kind == "hello":
                self._handle(ev)

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
        deadline = time.monotonic() + self.rc.transport.startup_timeout
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
            if ev.kind == "reply":
                msg = self.node.decode(ev.data)
                if msg is None or msg["cycle"] != cycle or ev.index not in waiting:
                    continue
                try:
                    part = parts_of(msg)[0]
                    if part["stage"] != rnd.index:
                        continue
                    axes = self.plan.placement.axes[ev.index]
                    Engine.merge(ctx, check_vals(part.get("vals"), rnd.recv, len(axes)), axes)
                    span = check_span(part.get("span"))
                except BadMessage:
                    continue
                waiting.discard(ev.index)
                # the exchange alone: less the slowest peripheral's compute span
                compute_s = max(compute_s, (span[1] - span[0]) / 1e9)
                if not waiting and sends == 1 and rnd.index == 0:
                    self.warm_rtt_s.append(time.perf_counter() - t_sent - compute_s)
            elif ev.kind == "sample":
                self._on_sample(ev.data, ev.rx_ns)
            elif ev.kind == "hello":
                self._handle(ev)

    def choose_replies(self) -> dict[str, Any]:
        """Decide how peripherals answer fused requests (``--replies``); the rule and its
        figures are in docs/architecture.md. Returns what was decided and from which
        figures (for the report)."""
        asked = self.rc.schedule.replies
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

    def central_between_rounds_s(self) -> float:
        """The central's work from the end of one round to the send of the next interval's
        first round: every central step except those after the last round and, at depth
        2, the sample-free ones run ahead (:meth:`_prime`)."""
        names = self.plan.middle_blocks(ahead=self.depth > 1)
        costs = self.block_costs_s()
        return sum(costs[b] for b in names if b in costs)

    def block_costs_s(self, *, repeat: int = 20) -> dict[str, float]:
        """Each block's time on the central for one interval (all the axes it runs on):
        T-800 costs from the cost model; native costs measured here once, medians over
        ``repeat`` throw-away intervals run whole in this process (the reply rule and the
        placement rule both read them)."""
        if self.block_costs is not None:
            return self.block_costs
        graph = self.plan.graph
        if self.engine.cost.name == "t800":
            self.block_costs = {b.name: b.t800_s(self.engine.cost.scale) for b in graph.blocks}
            return self.block_costs
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
        self.block_costs = {b: statistics.median(v) / 1e9 for b, v in acc.items()}
        return self.block_costs

    def choose_placement(self) -> dict[str, Any]:
        """``--placement auto``: which rounds the central runs itself
        (:func:`~ctrlunit.topology.balance.auto_central_blocks`), from the warm-up's round
        trip and the blocks' costs here. Returns the choice and its figures (for the
        report); ``central_blocks`` is the placement to run."""
        rtt = statistics.median(self.warm_rtt_s) if self.warm_rtt_s else math.inf
        blocks, rounds = auto_central_blocks(self.plan, self.block_costs_s(), rtt)
        moved = [r for r in rounds if r["moved"]]
        why = ("; ".join(f"round {r['round']} ({', '.join(r['blocks'])}) costs the central "
                         f"{r['arithmetic_s'] * 1e6:.0f} us against a {rtt * 1e6:.0f} us round "
                         "trip: on the central" for r in moved)
               or "every round but the last costs more on the central than its round trip "
               "(or there is only one): the peripherals keep their blocks")
        return {"asked": "auto", "central_blocks": sorted(blocks), "round_trip_s": rtt,
                "rounds": rounds, "why": why}
