"""The peripheral role: runs the per-axis blocks of its axes on request.

Each request carries one or more parts (at pipeline depth 2, the second round of interval
k and the first of k+1 in one message); a part names its cycle, its round (``stage``) and
holds exactly the values the round's blocks need. The reply has one part per request
part: the values the central needs and the compute span ``(t0, t1)`` on the host's
monotonic clock. Values from earlier rounds of the same cycle
stay here (a few cycles at most). Bad or foreign requests are counted and dropped.
"""

from __future__ import annotations

import queue
import time
from typing import Any

from .codec import BadMessage, check_vals, encode, parts_of
from .engine import Engine
from .node import WARM_RSS_AT, Node, cpu_used, is_stop, rss_kb

MAX_KEPT_CYCLES = 8
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
        try:
            each = msg.get("each", False)
            if type(each) is not bool:
                raise BadMessage("bad_value", "each must be true or false")
            parts = []
            for part in parts_of(msg):
                rnd = rounds.get(part["stage"])
                if rnd is None:
                    raise BadMessage("bad_stage")
                parts.append((part["cycle"], rnd, check_vals(part.get("vals"), rnd.send, 3)))
        except BadMessage as exc:
            node.reject(exc.reason)
            continue
        if each:  # first rounds first, each answered at once (see central.py)
            parts.sort(key=lambda x: x[1].index)
        out = []
        for cycle, rnd, vals in parts:
            t0 = time.monotonic_ns()
            ctx = ctxs.get(cycle)  # the central's warm-up intervals are kept alike
            if ctx is None:
                if rnd.index != 0 and engine.plan.round_trips > 1:
                    # a later round of a cycle this peripheral never saw (restart, loss):
                    # the values of earlier rounds are missing
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
            part = {"cycle": cycle, "stage": rnd.index,
                    "vals": Engine.reply_vals(rnd, ctx, axes)}
            if trace:  # recording: every intermediate value too, for replay --verify
                part["trace"] = {n: [ctx[n][i] for i in axes]
                                 for n in trace_names[rnd.index]}
            t1 = time.monotonic_ns()
            part["span"] = [t0, t1]
            out.append(part)
            busy_ns += t1 - t0
            served += 1
            if served == 2 * WARM_RSS_AT:
                rss_warm = rss_kb()
            if rnd.index == engine.plan.round_trips - 1:
                ctxs.pop(cycle, None)
            if each:
                reply.put(encode(node.unit, cycle, rnd.index, parts=out))
                out = []
        if out:
            reply.put(encode(node.unit, out[0]["cycle"], out[0]["stage"], parts=out))
    return {"exit": "stop", "served": served, "busy_ns": busy_ns,
            "wall_ns": time.monotonic_ns() - t_start, "rejected": dict(node.rejected),
            "rss_kb": {"warm": rss_warm, "end": rss_kb()}, "cpu_s": cpu_used(node)}
