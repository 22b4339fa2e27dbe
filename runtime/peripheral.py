"""The peripheral role: runs the per-axis blocks of its axes on request.

Each request carries the cycle, the round (``stage``) and exactly the values the round's
blocks need; the reply carries the values the central needs and the compute span
``(t0, t1)`` on the host's monotonic clock. Values from earlier rounds of the same cycle
stay here (a few cycles at most). Bad or foreign requests are counted and dropped.
"""

from __future__ import annotations

import queue
import time
from typing import Any

from .codec import BadMessage, check_vals, encode
from .engine import Engine, _plain
from .node import WARM_RSS_AT, Node, is_stop, rss_kb

MAX_KEPT_CYCLES = 8
WARMUP_BASE = 1 << 40  # cycles from here on are the central's warm-up
ALL_AXES = (0, 1, 2)


def declare(node: Node, index: int) -> Any:
    """Declare the request subscriber and the reply publisher (before the handshake, so
    that nothing the central sends after ``go`` can be missed)."""
    node.route(node.keys.request, "request")
    return node.publisher(node.keys.reply(index + 1))


def serve(node: Node, engine: Engine, index: int, reply: Any, *, watchdog: float,
          trace: bool = False) -> dict[str, Any]:
    """Answer requests until stopped; returns counters.

    Parameters
    ----------
    node : this role's node (after the handshake).
    engine : the engine built from the same plan as the central's.
    index : 0-based peripheral index.
    reply : the publisher from :func:`declare`.
    watchdog : seconds of silence from the central after which the role exits.
    """
    axes = engine.plan.placement.axes[index]
    rounds = {r.index: r for r in engine.plan.rounds}
    trace_names = {r.index: [o for b in r.blocks for o in b.outputs if o not in r.recv]
                   for r in engine.plan.rounds}
    ctxs: dict[int, dict] = {}
    served = 0
    rss_warm = -1
    busy_ns = 0
    t_start = time.monotonic_ns()
    while True:
        try:
            ev = node.events.get(timeout=0.2)
        except queue.Empty:
            if (time.monotonic_ns() - node.last_heard_ns) / 1e9 > watchdog:
                return {"exit": "watchdog", "served": served, "busy_ns": busy_ns,
                        "rejected": dict(node.rejected)}
            continue
        if ev[0] == "control":
            if is_stop(node, ev):
                break
            continue
        if ev[0] != "request":
            continue
        msg = node.decode(ev[2])
        if msg is None:
            continue
        node.last_heard_ns = ev[3]
        rnd = rounds.get(msg["stage"]) if isinstance(msg["stage"], int) else None
        if rnd is None:
            node.reject("bad_stage")
            continue
        t0 = time.monotonic_ns()
        try:
            vals = check_vals(msg.get("vals"), rnd.send, 3)
        except BadMessage as exc:
            node.reject(exc.reason)
            continue
        cycle = msg["cycle"]
        ctx = ctxs.get(cycle)
        if cycle >= WARMUP_BASE:  # a throw-away warm-up interval: keep nothing
            ctx = {n: [None, None, None] for n in engine.axis_names}
        elif ctx is None:
            if rnd.index != 0 and engine.plan.round_trips > 1:
                # a later round of a cycle this peripheral never saw (restart, loss): the
                # values of earlier rounds are missing
                node.reject("unknown_cycle")
                continue
            ctx = {n: [None, None, None] for n in engine.axis_names}
            ctxs[cycle] = ctx
            if len(ctxs) > MAX_KEPT_CYCLES:
                del ctxs[min(ctxs)]
        Engine.merge(ctx, vals, ALL_AXES)
        try:
            engine.run_round(rnd, ctx, axes)
        except Exception as exc:
            node.reject(f"kernel_error:{type(exc).__name__}")
            continue
        out = Engine.reply_vals(rnd, ctx, axes)
        extra = {}
        if trace:  # recording: every intermediate value too, for replay --verify
            extra["trace"] = {n: [_plain(ctx[n][i]) for i in axes] for n in trace_names[rnd.index]}
        t1 = time.monotonic_ns()
        reply.put(encode(node.unit, cycle, rnd.index, vals=out, span=[t0, t1], **extra))
        busy_ns += t1 - t0
        served += 1
        if served == 2 * WARM_RSS_AT:
            rss_warm = rss_kb()
        if rnd.index == engine.plan.round_trips - 1:
            ctxs.pop(cycle, None)
    return {"exit": "stop", "served": served, "busy_ns": busy_ns,
            "wall_ns": time.monotonic_ns() - t_start, "rejected": dict(node.rejected),
            "rss_kb": {"warm": rss_warm, "end": rss_kb()}}
