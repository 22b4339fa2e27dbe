"""The peripheral role: runs the per-axis blocks of its axes on request.

Each request carries one or more parts (at pipeline depth 2, the second round of interval
k and the first of k+1 in one message); a part names its cycle, its round (``stage``) and
holds exactly the values the round's blocks need. The reply has one part per request
part: the values the central needs and the compute span ``(t0, t1)`` on the host's
monotonic clock. Values from earlier rounds of the same cycle stay here (a few cycles at
most).

When the request asks for a reply per round (``each``), each reply leaves the moment its
part is computed, before the next part's computation starts: that is what lets the
central go on with interval k while this peripheral computes interval k+1's round, the
overlap of the two-stage pipeline (§ IV.7.2, Fig. 24; docs/architecture.md).

:class:`Peripheral` is the role without its transport (bytes in, bytes out, one reply
at a time), so that what it does with any payload can be checked without Zenoh;
:func:`serve` is its loop on a :class:`..transport.node.Node`. A payload that fails validation in
any way is counted under a reason and dropped: no payload ends the role.
"""

from __future__ import annotations

import queue
import sys
import time
from collections import Counter
from collections.abc import Callable, Iterator
from contextlib import nullcontext
from typing import Any

from ...topology.pipeline import reply_order
from ..compute.engine import Engine
from ..compute.setup import Setup
from ..config import EXIT_LINK, EXIT_OK, ConfigError
from ..host import sched
from ..transport.codec import BadMessage, check_vals, decode, encode, is_warmup, parts_of
from ..transport.node import WARM_RSS_AT, Node, control_order, cpu_used, rss_kb, say_bye
from .rolelog import role_log, role_log_end

MAX_KEPT_CYCLES = 8
ALL_AXES = (0, 1, 2)


class Peripheral:
    """The per-axis work of peripheral ``index`` (0-based) for unit ``unit``.

    Parameters
    ----------
    engine : the engine built from the same plan as the central's.
    index : 0-based peripheral index; its axes are ``engine.plan.placement.axes[index]``.
    unit : the unit id every message must carry.
    trace : also return every intermediate value (recording, ``replay --verify``).
    rejected : the counter that rejections are added to (the node's, so that the role's
        report has them all); a fresh one by default.
    place : ``place(central_blocks) -> Engine``, the engine of the same run with those
        blocks on the central (raises :class:`..config.ConfigError` on anything but a list
        of the law's per-axis block names); None: ``place`` orders are refused.
    live : the run balances itself (``--balance live``): a ``place`` order is taken once
        the run has begun too (:meth:`on_place`).
    clock : the monotonic clock (ns) that stamps each part's compute span.
    """

    def __init__(self, engine: Engine, index: int, unit: str, *, trace: bool = False,
                 rejected: Counter[str] | None = None,
                 place: Callable[[Any], Engine] | None = None, live: bool = False,
                 clock: Callable[[], int] = time.monotonic_ns) -> None:
        self.unit = unit
        self.clock = clock
        self.place = place
        self.live = live
        self.index = index
        self.trace = trace
        self.rejected: Counter[str] = rejected if rejected is not None else Counter()
        self.served = 0
        self.busy_ns = 0
        self.rss_warm = -1
        self.from_cycle = 0
        """The first interval of the plan in use (a live re-placement's)."""
        self.use(engine)

    def use(self, engine: Engine) -> None:
        """Answer from now on by ``engine``'s plan (a central's ``place`` order, before the
        run starts); the values kept for cycles of the old plan are dropped."""
        self.engine = engine
        self.axes = engine.plan.placement.axes[self.index]
        self._rounds = {r.index: r for r in engine.plan.rounds}
        self._trace_names = {r.index: [o for b in r.blocks for o in b.outputs
                                       if o not in r.recv] for r in engine.plan.rounds}
        self._ctxs: dict[int, dict] = {}

    def on_place(self, order: dict[str, Any], role: str, *, started: bool) -> bytes | None:
        """A central's ``place`` order (``central_blocks``: the blocks it now runs): switch
        to that plan and return the acknowledgement to publish (``placed``, with the
        blocks); None, the order counted as rejected, when it cannot be taken. Once the
        run has ``started``, only a live re-placement is taken, in a run that balances
        itself (``live``): one that names the first
        interval of the new plan (``from_cycle``, none begun, the central having drained
        its pipeline: runtime/central/rebalance.py), after which a request part of an
        earlier interval is refused (``unknown_cycle``); any other is ``bad_stage``.
        Names that are not the law's per-axis blocks change nothing (``bad_value``).
        Never raises."""
        live = order.get("from_cycle")
        if self.place is None or (started and (not self.live or type(live) is not int
                                               or live < 0)):
            self.rejected["bad_stage"] += 1
            return None
        try:
            engine = self.place(order.get("central_blocks"))
        except ConfigError:
            self.rejected["bad_value"] += 1
            return None
        since = live if started and type(live) is int else 0
        if (since, engine.plan.placement) != (self.from_cycle, self.engine.plan.placement):
            self.use(engine)  # an order given again is acknowledged again, nothing dropped
            self.from_cycle = since
        return encode(self.unit, 0, "placed", role=role,
                      central_blocks=sorted(engine.plan.placement.central_blocks))

    def _parts(self, data: bytes) -> tuple[list[tuple[int, Any, dict]], bool]:
        """Decode and validate a whole request: ``([(cycle, round, vals)], each)``.

        Raises
        ------
        BadMessage
            On anything the request may not hold; nothing of it is used then.
        """
        msg = decode(data, self.unit)
        each = msg.get("each", False)
        if type(each) is not bool:
            raise BadMessage("bad_value", "each must be true or false")
        parts = []
        for part in parts_of(msg):
            rnd = self._rounds.get(part["stage"])
            if rnd is None:
                raise BadMessage("bad_stage")
            parts.append((part["cycle"], rnd, check_vals(part.get("vals"), rnd.send, 3)))
        return parts, each

    def on_request(self, data: bytes) -> Iterator[bytes]:
        """Answer one request: yield the reply payloads to publish, in order (none when
        the request was rejected). Never raises for anything in ``data``.

        With ``each``, a part's reply is yielded as soon as that part is computed and the
        next part is computed only when the caller asks for the next reply: publish each
        payload before taking the next one (``for p in role.on_request(data):
        publish(p)``), so that the central can use it while this role computes on.
        Otherwise the one reply holding every part is yielded once all are computed.
        """
        try:
            parts, each = self._parts(data)
        except BadMessage as exc:
            self.rejected[exc.reason] += 1
            return
        except Exception as exc:  # a validation gap must not end the role: count it
            self.rejected[f"invalid:{type(exc).__name__}"] += 1
            return
        # first rounds first when each is answered at once (docs/architecture.md)
        parts = [parts[i] for i in reply_order([p[1].index for p in parts], each=each)]
        out: list[dict[str, Any]] = []
        engine = self.engine
        for cycle, rnd, vals in parts:
            t0 = self.clock()
            ctx = self._ctxs.get(cycle)  # the central's warm-up intervals are kept alike
            if ctx is None:
                if cycle < self.from_cycle or (rnd.index != 0
                                               and engine.plan.round_trips > 1):
                    # a later round of a cycle this peripheral never saw (restart, loss):
                    # the values of earlier rounds are missing
                    self.rejected["unknown_cycle"] += 1
                    continue
                ctx = {n: [None, None, None] for n in engine.axis_names}
                self._ctxs[cycle] = ctx
                if len(self._ctxs) > MAX_KEPT_CYCLES:
                    del self._ctxs[min(self._ctxs)]
            Engine.merge(ctx, vals, ALL_AXES)
            try:
                # the central's warm-up occupies no modelled time (CostModel.waived)
                with engine.cost.waived() if is_warmup(cycle) else nullcontext():
                    engine.run_round(rnd, ctx, self.axes)
            except Exception as exc:
                self.rejected[f"kernel_error:{type(exc).__name__}"] += 1
                continue
            part: dict[str, Any] = {"cycle": cycle, "stage": rnd.index,
                                    "vals": Engine.reply_vals(rnd, ctx, self.axes)}
            if self.trace:  # recording: every intermediate value too, for replay --verify
                part["trace"] = {n: [ctx[n][i] for i in self.axes]
                                 for n in self._trace_names[rnd.index]}
            t1 = self.clock()
            part["span"] = [t0, t1]
            out.append(part)
            self.busy_ns += t1 - t0
            self.served += 1
            if self.served == 2 * WARM_RSS_AT:
                self.rss_warm = rss_kb()
            if rnd.index == engine.plan.round_trips - 1:
                self._ctxs.pop(cycle, None)
            if each:  # this part's reply leaves now, before the next part is computed
                yield encode(self.unit, cycle, rnd.index, parts=out)
                out = []
        if out:
            yield encode(self.unit, out[0]["cycle"], out[0]["stage"], parts=out)


def declare(node: Node, index: int) -> Any:
    """Declare the request subscriber and the reply publisher (before the handshake, so
    that nothing the central sends after ``go`` can be missed)."""
    node.route(node.keys.request, "request")
    return node.publisher(node.keys.reply(index + 1))


def serve(node: Node, engine: Engine, index: int, reply: Any, *, watchdog: float,
          trace: bool = False, place: Callable[[Any], Engine] | None = None,
          live: bool = False) -> dict[str, Any]:
    """Answer requests until stopped; returns counters.

    Parameters
    ----------
    node : this role's node (after the handshake).
    engine : the engine built from the same plan as the central's.
    index : 0-based peripheral index.
    reply : the publisher from :func:`declare`.
    watchdog : seconds of silence from the central after which the role exits.
    place, live : as :class:`Peripheral`'s; a ``place`` order it takes is acknowledged on
        the hello key (:meth:`Peripheral.on_place`).
    """
    role = Peripheral(engine, index, node.unit, trace=trace, rejected=node.rejected,
                      place=place, live=live)
    said = node.publisher(node.keys.hello(node.role))
    t_start = time.monotonic_ns()

    def result(exit_reason: str) -> dict[str, Any]:
        return {"exit": exit_reason, "served": role.served, "busy_ns": role.busy_ns,
                "wall_ns": time.monotonic_ns() - t_start, "rejected": dict(node.rejected),
                "rss_kb": {"warm": role.rss_warm, "end": rss_kb()}, "cpu_s": cpu_used(node)}

    while True:
        try:
            ev = node.events.get(timeout=0.2)
        except queue.Empty:
            if (time.monotonic_ns() - node.last_heard_ns) / 1e9 > watchdog:
                return result("watchdog")
            continue
        if ev.kind == "control":
            order = control_order(node, ev)
            if order is None:
                continue
            if order["stage"] == "stop":
                return result("stop")
            if order["stage"] == "place":
                ack = role.on_place(order, node.role, started=node.cpu_start_s is not None)
                if ack is not None:
                    said.put(ack)
            continue
        if ev.kind != "request":
            continue
        for payload in role.on_request(ev.data):  # each reply out as soon as it is made
            node.last_heard_ns = ev.rx_ns  # a request that passed validation: central alive
            reply.put(payload)


def run_peripheral(setup: Setup, index: int, conf: Any) -> int:
    name = f"peripheral-{index}"
    with Node(conf, setup.rc.transport.unit, name) as node:
        role_log(name, f"connected to unit {setup.rc.transport.unit}; waiting for the go")
        try:
            reply = declare(node, index - 1)
            go = node.wait_for_go(timeout=setup.rc.transport.startup_timeout)
            role_log(name, "go" + (f": central blocks {go['central_blocks']}"
                                   if go.get("central_blocks") is not None else ""))
            # started again during a run (.takeover): the placement it runs comes with go
            blocks = go.get("central_blocks")
            engine = (setup.engine() if blocks is None
                      else setup.with_central_blocks(blocks).engine())
            res = serve(node, engine, index - 1, reply,
                        watchdog=max(5.0, 3 * setup.rc.transport.timeout), trace=setup.rc.run.trace,
                        place=lambda blocks: setup.with_central_blocks(blocks).engine(),
                        live=setup.rc.schedule.balance == "live")
        except (TimeoutError, ConfigError) as exc:  # no go, or a go naming no placement
            print(f"ctrlunit peripheral {index}: {exc}", file=sys.stderr)
            return EXIT_LINK
        res["sched"] = sched.policy_name()
        say_bye(node, res)
        role_log_end(name, res)
        return EXIT_OK if res["exit"] == "stop" else EXIT_LINK
