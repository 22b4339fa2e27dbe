"""``ctrlunit replay --verify``: verify a recording bit for bit (republishing it and
exporting it: :mod:`.republish`).

``verify`` re-executes every block in one process on the recorded samples, round by round
in the recorded plan: each recorded request must equal the central's recomputed values,
each recorded reply the recomputed per-axis values, each command the recomputed command.
The first divergence names the cycle, the block that produces the value, the axis, the
expected (recorded) and the recomputed value. Within an interval the blocks are compared
in plan order before its requests, so that the first wrong value found is the one a block
made, not a later request that carried it on.

A round whose reply came too late under ``--late-policy hold`` was computed by the
central with the peripheral's last values (recorded on ``/faults/held``): verify checks
that those are the last values the recording's accepted replies gave for those axes, and
uses them, as the central did.
"""

from __future__ import annotations

from collections.abc import Callable, Collection
from dataclasses import dataclass
from typing import Any

from ..compute.stride import StrideSchedule
from .reader import Recording

Vals = dict[str, Any]


@dataclass
class Divergence:
    cycle: int
    block: str
    axis: int | None
    value: str
    expected: Any
    got: Any

    def __str__(self) -> str:
        where = f"axis {self.axis}" if self.axis is not None else "central"
        return (f"first divergence at cycle {self.cycle}, block {self.block} ({where}), value "
                f"{self.value}: recorded {self.expected!r}, recomputed {self.got!r}")


def _setup(rec: Recording) -> Any:
    from ..compute.setup import make_setup
    from .recorded_config import run_config

    return make_setup(run_config(rec))


def _index(rec: Recording, kind: str) -> dict[tuple[int, ...], dict]:
    """``kind`` "request": (cycle, stage) -> request part; "reply": (peripheral, cycle,
    stage) -> reply part (a fused exchange holds several parts)."""
    out: dict[tuple[int, ...], dict] = {}
    for topic in rec.topics:
        if topic == "/peripheral/request" and kind == "request":
            for _, m in rec.decoded(topic):
                for part in m.get("parts") or []:
                    out[(part["cycle"], part["stage"])] = part
        elif topic.startswith("/central/reply/") and kind == "reply":
            k = int(topic.split("/")[3]) - 1
            for _, m in rec.decoded(topic):
                for part in m.get("parts") or []:
                    out[(k, part["cycle"], part["stage"])] = part
    return out


def _plain(v: Any) -> Any:
    if isinstance(v, tuple | list):
        return [_plain(x) for x in v]
    return v


def cycles_in_order(rec: Recording) -> list[tuple[int, list[int]]]:
    """Started intervals in order with their encoder counts (from the commands' cycles)."""
    samples = {m["cycle"]: m["counts"] for _, m in rec.decoded("/central/sample")}
    out = []
    for _, m in rec.decoded("/plant/command"):
        k = m["cycle"]
        if k in samples:
            out.append((k, samples[k]))
    return out


def stride_changes(rec: Recording) -> list[tuple[int, int]]:
    """``(start, stride)`` of each change of the recorded run's control rate (its
    ``stride`` orders to the plant, on ``/plant/control``), in order."""
    return [(m["start"], m["stride"]) for _, m in rec.decoded("/plant/control")
            if m.get("stage") == "stride" and type(m.get("start")) is int
            and type(m.get("stride")) is int]


def discarded_primes(rec: Recording) -> list[int]:
    """Cycles whose sample-free leading steps the central ran (primed) before it skipped
    their sample (``/central/primed``), in order: their reference calls filled the task's
    cache, which later loops of the task read, so replay runs them at the same point."""
    return sorted(m["cycle"] for _, m in rec.decoded("/central/primed")
                  if type(m.get("cycle")) is int)


def placements(rec: Recording) -> list[tuple[int, list[str]]]:
    """``(from_cycle, central_blocks)`` of each live re-placement of the recorded run
    (``/central/placement``: runtime/central/rebalance.py), in order."""
    return sorted((m["from_cycle"], list(m["central_blocks"]))
                  for _, m in rec.decoded("/central/placement")
                  if type(m.get("from_cycle")) is int and isinstance(m.get("central_blocks"),
                                                                    list))


def stride_grid(rec: Recording) -> StrideSchedule:
    """The recorded run's control rate, cycle by cycle (:func:`stride_changes`)."""
    grid = StrideSchedule()
    for start, stride in stride_changes(rec):
        grid.change(stride, start)
    return grid


def _controller(rec: Recording, setup: Any, engine: Any) -> Any:
    """The run's controller, halving its rate (and going back) where the recorded run
    did."""
    ctl = setup.controller(engine)
    ctl.grid = stride_grid(rec)
    return ctl


def recorded_inputs(rec: Recording, setup: Any) -> list[tuple]:
    """``(t, est, qmeas, qdmeas)`` of the recorded intervals (for ``t_1``)."""

    engine = setup.engine(peripherals_plan=False)
    ctl = _controller(rec, setup, engine)
    out = []
    primes = discarded_primes(rec)
    for k, counts in cycles_in_order(rec):
        while primes and primes[0] < k:  # as in :func:`verify`
            engine.prefix(ctl.context(primes.pop(0)))
        ctx = ctl.sources(k, counts)
        out.append((ctx["t"], ctx["est"], list(ctx["qmeas_i"]), list(ctx["qdmeas_i"])))
        engine.run_local(ctx)
        ctl.handoff(ctx)
    return out


def verify(
    rec: Recording,
    *,
    cycles: tuple[int, int] | None = None,
    alter: tuple[str, int] | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> tuple[int, Divergence | None]:
    """Re-execute every block and compare with the recording.

    Parameters
    ----------
    cycles : only compare cycles in ``[a, b)`` (all are re-executed: the observer's state
        runs through every interval).
    alter : ``(block, cycle)``: perturb that block's first output at that cycle (to check
        that verification catches a wrong kernel).

    Returns
    -------
    (intervals compared, first divergence or None)
    """
    from ..compute.engine import Engine

    setup = _setup(rec)
    engine = setup.engine(cost="native")  # the values alone: no T-800 time emulated
    producer = {o: b.name for b in engine.plan.graph.blocks for o in b.outputs}
    ctl = _controller(rec, setup, engine)
    requests, replies = _index(rec, "request"), _index(rec, "reply")
    commands = {m["cycle"]: m["tau"] for _, m in rec.decoded("/plant/command")}
    held, computed = _late_rounds(rec)
    last: dict[str, list[Any]] = {}  # the last accepted values, by name and axis
    central_trace = _central_trace(rec)
    current: dict[str, int] = {}  # the interval being re-executed (for ``alter``)
    done = 0
    seq = cycles_in_order(rec)
    primes = discarded_primes(rec)
    moves = [(-1, sorted(engine.plan.placement.central_blocks)), *placements(rec)]
    for idx, (k, counts) in enumerate(seq):
        engine = _placed(engine, moves, k, alter, current)  # the plan the run had at k
        while primes and primes[0] < k:  # primed, then its sample skipped: as the run did
            engine.prefix(ctl.context(primes.pop(0)))
        current["cycle"] = k
        compare = cycles is None or cycles[0] <= k < cycles[1]
        ctx = ctl.sources(k, counts)
        gen = engine.cycle(ctx)
        sent: Divergence | None = None  # the first request that differs, reported after
        # the blocks: a wrong block's output reaches a later request before the blocks
        # are compared, and the block is the finding, not the request that carried it
        try:
            rnd = next(gen)
            while True:
                if compare and engine.plan.placement.peripherals and sent is None:
                    m = requests.get((k, rnd.index))
                    if m is None:
                        sent = Divergence(k, "(request)", None, "missing", None, None)
                    else:
                        sent = _diff(Engine.request_vals(rnd, ctx, (0, 1, 2)), m["vals"],
                                     (0, 1, 2), producer, k)
                engine.run_round(rnd, ctx, (0, 1, 2))
                d = _apply_held(engine.plan, rnd.index, ctx, k, held, replies, last,
                                computed)
                if d and compare:
                    return done, d
                rnd = gen.send(None)
        except StopIteration:
            pass
        # the estimate for the next interval: one after the other here, so its values at
        # the end of the interval are those the central handed off at its hand-off point
        ctl.handoff(ctx)
        if compare:
            d = _compare_blocks(engine.plan, ctx, k, central_trace(k), replies,
                                held.keys() | computed) or sent
            if d:
                return done, d
            rec_cmd = commands.get(k)
            if rec_cmd != [float(x) for x in ctx["cmd"]]:
                return done, Divergence(k, "output", None, "cmd", rec_cmd, list(ctx["cmd"]))
            done += 1
        if progress is not None and idx % 500 == 0:
            progress(idx, len(seq))
    return done, None


def _central_trace(rec: Recording) -> Callable[[int], dict | None]:
    """Interval -> the central's outputs the recording traced: None for an interval a
    recording that traces the central lacks (or holds in a form the reader skips); {}
    (nothing to compare) for any of one that does not trace it (no such channel), and
    past the last traced one of a salvaged file (its command and its trace may have been
    written in chunks on either side of the cut)."""
    traced = bool(rec.topics.get("/trace/central"))  # messages there, readable or not
    trace = {m["cycle"]: m["vals"] for _, m in rec.decoded("/trace/central")}
    last = max(trace, default=-1)
    return lambda k: trace.get(k, {} if not traced or (rec.salvaged and k > last) else None)


def _placed(engine: Any, moves: list[tuple[int, list[str]]], k: int,
            alter: tuple[str, int] | None, current: dict[str, int]) -> Any:
    """``engine``, or, where a move of ``moves`` applies at interval ``k`` (the moves made
    are taken off the list), one with its placement, perturbed as ``alter`` says."""
    if not moves or moves[0][0] > k:
        return engine
    while moves and moves[0][0] <= k:
        engine = engine.placed(moves.pop(0)[1])
    if alter is not None:
        _alter(engine, *alter, current)
    return engine


def _late_rounds(rec: Recording) -> tuple[dict[tuple[int, int, int], Vals],
                                          set[tuple[int, int, int]]]:
    """The rounds of late peripherals, by (peripheral, cycle, stage): the values the
    central held for them (``--late-policy hold``), and those it computed itself
    (``compute``: no reply to compare)."""
    held = {(m["peripheral"], m["cycle"], m["stage"]): m["vals"]
            for _, m in rec.decoded("/faults/held")}
    computed = {(m["peripheral"], m["cycle"], m["stage"])
                for _, m in rec.decoded("/faults/computed")}
    return held, computed


def _alter(engine: Any, name: str, at: int, current: dict[str, int]) -> None:
    """Make ``engine``'s block ``name`` perturb its first output at cycle ``at``
    (``current["cycle"]``: the interval being re-executed)."""
    fn, names, cost, per_axis = engine._bound[name]
    block = engine.plan.graph.block(name)

    def altered(c: dict, *args: Any) -> None:
        fn(c, *args)
        if current["cycle"] != at:
            return
        out = names[block.outputs[0]]
        if per_axis:
            i = args[0]
            c[out][i] = _nudge(c[out][i])
        else:
            c[out] = _nudge(c[out])

    engine._bound[name] = (altered, names, cost, per_axis)


def _apply_held(plan: Any, stage: int, ctx: dict, k: int, held: dict, replies: dict,
                last: dict[str, list[Any]], computed: Collection[tuple[int, int, int]] = ()
                ) -> Divergence | None:
    """After round ``stage`` of interval ``k``: where the central held a late reply, put
    the held values into ``ctx`` (as the central did) and check they are the last accepted
    ones; where it computed the round itself (``computed``), its values (here in ``ctx``)
    are the last ones, as the central keeps them; elsewhere note the accepted reply's
    values as the last ones."""
    from ..compute.engine import Engine

    out = None
    for p in range(plan.placement.peripherals):
        axes = plan.placement.axes[p]
        if (p, k, stage) in computed:
            Engine.merge(last, Engine.reply_vals(plan.rounds[stage], ctx, axes), axes)
            continue
        vals = held.get((p, k, stage))
        if vals is None:  # accepted: its values are the last ones, as the central keeps them
            Engine.merge(last, (replies.get((p, k, stage)) or {}).get("vals") or {}, axes)
            continue
        for name, v in vals.items():
            for j, a in enumerate(axes):
                want = _plain(last.get(name, [None] * 3)[a])
                if out is None and _plain(v[j]) != want:
                    out = Divergence(k, "(hold)", a, name, v[j], want)
        Engine.merge(ctx, vals, axes)
    return out


def _compare_blocks(plan: Any, ctx: dict, k: int, central: dict | None,
                    replies: dict[tuple[int, ...], dict],
                    held: Collection[tuple[int, int, int]]) -> Divergence | None:
    """Compare every block's outputs, in plan order, with what the recording holds: the
    central's trace for central blocks, the replies (values and trace) for per-axis blocks
    run on the peripherals (except the rounds the central held, which
    :func:`_apply_held` checked, or computed itself: ``held`` names both). The first
    difference names its block."""
    for step in plan.steps:
        if step.round is None:
            b = step.block
            if central is None:  # the recording traces the central, but not this interval
                return Divergence(k, "(central trace)", None, "missing", None, None)
            for name in b.outputs:
                if name in central and _plain(ctx[name]) != central[name]:
                    return Divergence(k, b.name, None, name, central[name], _plain(ctx[name]))
            continue
        rnd = step.round
        for b in rnd.blocks:
            for p in range(plan.placement.peripherals):
                axes = plan.placement.axes[p]
                if (p, k, rnd.index) in held:
                    continue
                m = replies.get((p, k, rnd.index))
                if m is None:
                    return Divergence(k, "(reply)", None, "missing", None, None)
                recorded = dict(m.get("trace") or {})
                recorded.update(m["vals"])
                for name in b.outputs:
                    if name not in recorded:  # a traced reply holds every output
                        if m.get("trace") is None:
                            continue
                        return Divergence(k, b.name, None, name, "missing", None)
                    for j, axis in enumerate(axes):
                        got = _plain(ctx[name][axis])
                        if got != recorded[name][j]:
                            return Divergence(k, b.name, axis, name, recorded[name][j], got)
    return None


def _nudge(v: Any) -> Any:
    if isinstance(v, float):
        return v + abs(v) * 1e-12 + 1e-300
    if isinstance(v, tuple | list):
        head = _nudge(v[0])
        rest = list(v[1:])
        try:
            return type(v)(head, *rest)  # named tuples
        except TypeError:
            return type(v)([head, *rest])
    return v


def _diff(got: Vals, recorded: Vals, axes: tuple[int, ...], producer: dict[str, str],
          cycle: int) -> Divergence | None:
    for name, rv in recorded.items():
        gv = _plain(got.get(name))
        if name.endswith("_i"):
            for j, axis in enumerate(axes):
                if gv is None or gv[j] != rv[j]:
                    return Divergence(cycle, producer.get(name, "?"), axis, name, rv[j],
                                      None if gv is None else gv[j])
        elif gv != rv:
            return Divergence(cycle, producer.get(name, "?"), None, name, rv, gv)
    return None
