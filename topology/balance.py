"""``ctrlunit balance``: where the time goes and how to rebalance (§ IV.7.2).

From a run's report (``--report`` JSON; a recording gives the same report without the
central's message costs):

* ``t_s`` (Eq. IV.24): every block on one processor; ``t_p`` (Eq. IV.25): the central's
  blocks plus the per-axis blocks divided over n; the business of each process;
* the schedule model (:mod:`ctrlunit.topology.schedule`) calibrated on the run: block costs
  from its single-processor measurement, the central's costs per request, per reply and
  per run of steps as measured by the central, and the one-way message latency fitted so
  that the model gives the run's own mean period. It predicts the period at depth 1 and 2
  of any placement, with its Gantt chart;
* recommendations by the thesis's rules, each candidate judged by its predicted period at
  the run's depth: when the central is under 50 % busy, move per-axis work to it (one
  block, or a whole round, which then needs no exchange); when the central is busy and
  the peripherals are under-used, group two peripherals' work (n - 1) or give moved
  blocks back. The best candidate is recommended when it is predicted at least
  :data:`MARGIN` faster; its placement is written for ``ctrlunit start --placement``;
* :func:`compare`: a re-run with that placement against the prediction;
* :func:`auto_central_blocks`: the rule ``ctrlunit start --placement auto`` applies at
  warm-up, from that run's own figures (no report, no model): a round whose arithmetic
  costs the central less than the round trip it needs runs on the central.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

from .graph import LAWS, MODEL_STATES, OBSERVERS, StageGraph, stage_graph
from .placement import Placement, default_placement, placement_from_mapping, save_placement
from .plan import ExchangePlan, exchange_plan
from .schedule import Costs, Schedule, fit_latency, simulate

MARGIN = 0.05
"""A candidate placement is recommended when its predicted period is at least this much
shorter than the current one (the model's error on this machine is a few per cent)."""

INTERVALS = 160

MAX_COST_S = 10.0
"""The largest per-interval cost or period a report may hold (s): far above any run of the
unit, small enough that sums and ratios of them stay finite."""


class ReportError(ValueError):
    """A report balance cannot read; the message names the field, its value and what is
    allowed."""


def _bad(source: str, field: str, value: Any, allowed: str) -> ReportError:
    shown = repr(value)
    if len(shown) > 60:
        shown = shown[:57] + "..."
    return ReportError(f"{source}: {field} = {shown}; allowed: {allowed}")


def _percent(x: float) -> str:
    """A business as text; a report may not hold one."""
    return f"{x * 100:.0f} %" if math.isfinite(x) else "not measured"


def _key(field: str, key: str) -> str:
    """``field.key``, or ``field['key']`` when the key is not a plain name."""
    return f"{field}.{key}" if key.isidentifier() and key.isascii() else f"{field}[{key!r}]"


_JSON_TYPES = {dict: "an object", list: "a list", str: "a string", bool: "a boolean",
               int: "a number", float: "a number", type(None): "null"}


def _is_number(x: Any) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool)


def _seconds(source: str, field: str, x: Any, *, optional: bool = True,
             positive: bool = False) -> float | None:
    """A duration in seconds: a finite number in [0, MAX_COST_S] ((0, ...] if positive)."""
    if x is None and optional:
        return None
    lo = "(0" if positive else "[0"
    allowed = f"a number of seconds in {lo}, {MAX_COST_S:g}]" + (" or null" if optional else "")
    if not _is_number(x) or not math.isfinite(x) or not 0 <= x <= MAX_COST_S \
            or (positive and x == 0):
        raise _bad(source, field, x, allowed)
    return float(x)


def _mapping(source: str, field: str, x: Any) -> dict[str, Any]:
    if x is None:
        return {}
    if not isinstance(x, dict):
        raise _bad(source, field, x, "an object or null")
    return x


def _choice(source: str, field: str, x: Any, allowed: tuple[str, ...], default: str) -> str:
    if x is None:
        return default
    if x not in allowed:
        raise _bad(source, field, x, ", ".join(allowed))
    return x


def read_report(doc: Any, *, source: str = "report") -> dict[str, Any]:
    """The fields balance reads from a run's report, each checked for type and range.

    Parameters
    ----------
    doc : a run's report as decoded from ``--report`` JSON, or rebuilt from a recording.
    source : the file's name, for the messages.

    Returns
    -------
    A report holding only the fields :func:`analyse` and :func:`compare` use, with
    defaults filled in (law resolved-acceleration, model complete, depth 1, replies auto).

    Raises
    ------
    ReportError
        Naming the field, its value and what is allowed, for anything else: a document
        that is not an object, a law, model or depth the unit has not, a placement that is
        not one, block costs of blocks the law has not or that are not durations, figures
        of the wrong type, negative, non-finite or beyond :data:`MAX_COST_S`.
    """
    if not isinstance(doc, dict):
        got = _JSON_TYPES.get(type(doc), type(doc).__name__)
        raise ReportError(f"{source}: a run's report must be a JSON object, got {got} (write "
                          "one with ctrlunit start --report)")
    law = _choice(source, "law", doc.get("law"), LAWS, "resolved-acceleration")
    model = _choice(source, "model", doc.get("model"), ("complete", "simplified"), "complete")
    blocks_raw = _mapping(source, "block_cost_s", doc.get("block_cost_s"))
    # reports written before the observer was recorded: its second iteration's blocks say it
    observer = _choice(source, "observer", doc.get("observer"), OBSERVERS,
                       "previous" if "ik_obs1" in blocks_raw else "predict")
    # reports written before the model state was recorded evaluated it at the sample
    model_state = _choice(source, "model_state", doc.get("model_state"), MODEL_STATES,
                          "acting" if "ahead" in blocks_raw else
                          "foreseen" if "foresee" in blocks_raw else "sample")
    graph = stage_graph(law, model, observer=observer, model_state=model_state)
    names = [b.name for b in graph.blocks]
    if not blocks_raw:
        raise _bad(source, "block_cost_s", doc.get("block_cost_s"),
                   "the measured cost of each block (a report of ctrlunit start --report, "
                   "or a recording)")
    block: dict[str, float] = {}
    for k, v in blocks_raw.items():
        if k not in names:
            raise _bad(source, "a key of block_cost_s", k,
                       f"the blocks of {law}/{model}/{observer}/model at {model_state}: "
                       f"{', '.join(names)}")
        block[k] = _seconds(source, _key("block_cost_s", k), v, optional=False)  # type: ignore
    depth = doc.get("pipeline")
    if depth is None:
        depth = 1
    if depth not in (1, 2) or isinstance(depth, bool):
        raise _bad(source, "pipeline", depth, "1 or 2")
    per_axis = {b.name for b in graph.blocks if b.per_axis}
    pl = doc.get("placement")
    if pl is None:
        n = doc.get("peripherals", 0)
        pl = {"peripherals": n if n is not None else 0}
    try:
        placement = placement_from_mapping(pl, block_names=per_axis,
                                           source=f"{source}: placement")
    except ValueError as exc:
        raise ReportError(str(exc)) from None
    replies = _mapping(source, "replies", doc.get("replies"))
    cc = _mapping(source, "central_costs_s", doc.get("central_costs_s"))
    costs = {k: _seconds(source, f"central_costs_s.{k}", cc.get(k))
             for k in ("send", "reply", "start", "finish", "busy_per_interval")}
    per_interval: dict[str, float | None] = {}
    for k in ("replies_per_interval",):
        v = cc.get(k)
        if v is not None and (not _is_number(v) or not math.isfinite(v) or not 0 <= v <= 100):
            raise _bad(source, f"central_costs_s.{k}", v, "a number in [0, 100] or null")
        per_interval[k] = v
    exchanges = doc.get("exchanges_per_interval")
    if exchanges is not None and (not _is_number(exchanges) or not math.isfinite(exchanges)
                                  or not 0 <= exchanges <= 100):
        raise _bad(source, "exchanges_per_interval", exchanges, "a number in [0, 100] or null")

    def quantiles(field: str) -> dict[str, float | None]:
        q = _mapping(source, field, doc.get(field))
        return {k: _seconds(source, f"{field}.{k}", q.get(k), positive=True)
                for k in ("p50", "p99", "max") if k in q}

    business: dict[str, float] = {}
    for k, v in _mapping(source, "business", doc.get("business")).items():
        if not _is_number(v) or not math.isfinite(v) or not 0 <= v <= 10:
            raise _bad(source, _key("business", k), v, "a fraction of the run's time in [0, 10]")
        business[k] = float(v)
    cpu = {k: _seconds(source, _key("cpu_per_interval_s", k), v)
           for k, v in _mapping(source, "cpu_per_interval_s", doc.get("cpu_per_interval_s"))
           .items()}
    cores = doc.get("cpu_cores")
    if cores is not None and (not isinstance(cores, int) or isinstance(cores, bool)
                              or not 1 <= cores <= 4096):
        raise _bad(source, "cpu_cores", cores, "an integer in [1, 4096] or null")
    gantt = doc.get("gantt_ms")
    if gantt is None:
        gantt = []
    if not isinstance(gantt, (list, tuple)) or not all(
            isinstance(g, (list, tuple)) and len(g) == 4 and isinstance(g[0], str)
            and isinstance(g[1], int) and not isinstance(g[1], bool)
            and all(_is_number(t) and math.isfinite(t) and 0 <= t <= 1e9 for t in g[2:])
            for g in gantt):
        raise _bad(source, "gantt_ms", gantt,
                   "a list of [process, cycle, start ms, end ms] with finite times in [0, 1e9]")
    return {
        "law": law, "model": model, "observer": observer, "model_state": model_state,
        "pipeline": depth,
        "placement": placement.to_dict(), "block_cost_s": block,
        "replies": {"asked": _choice(source, "replies.asked", replies.get("asked"),
                                     ("auto", "each", "fused"), "auto"),
                    "mode": _choice(source, "replies.mode", replies.get("mode"),
                                    ("each", "fused"), "fused")},
        "central_costs_s": costs | per_interval, "exchanges_per_interval": exchanges,
        "period_mean_s": _seconds(source, "period_mean_s", doc.get("period_mean_s"),
                                  positive=True),
        "period_s": quantiles("period_s"), "traversal_s": quantiles("traversal_s"),
        "business": business, "cpu_per_interval_s": cpu, "cpu_cores": cores,
        "cpu_bound_period_s": _seconds(source, "cpu_bound_period_s",
                                       doc.get("cpu_bound_period_s")),
        "gantt_ms": gantt,
    }


def placement_of(report: dict[str, Any]) -> Placement:
    pl = report.get("placement") or {}
    return Placement(tuple(tuple(g) for g in pl.get("axes", [])),
                     frozenset(pl.get("central_blocks", [])))


def _replies_mode(plan: ExchangePlan, costs: Costs, depth: int, asked: str) -> str:
    """What ``--replies auto`` would pick (central.py): ``each`` when the central's work
    between two rounds exceeds a round trip."""
    if depth < 2 or plan.placement.peripherals == 0:
        return "fused"
    if asked in ("fused", "each"):
        return asked
    between = sum(costs.block_s.get(b, 0.0) for b in plan.middle_blocks(ahead=True))
    rtt = costs.send_s + costs.reply_s + 2 * costs.latency_s
    return "each" if between > rtt else "fused"


def asked_replies(report: dict[str, Any]) -> str:
    return ((report.get("replies") or {}).get("asked")) or "auto"


def model_costs(report: dict[str, Any], plan: ExchangePlan) -> Costs:
    """The model's costs from a report, the latency not yet fitted."""
    block = {k: float(v) for k, v in (report.get("block_cost_s") or {}).items()}
    cc = report.get("central_costs_s") or {}
    send, reply = float(cc.get("send") or 0.0), float(cc.get("reply") or 0.0)
    start, finish = float(cc.get("start") or 0.0), float(cc.get("finish") or 0.0)
    busy = float(cc.get("busy_per_interval") or 0.0)
    step = 0.0
    if busy > 0:  # the rest of the central's busy time, per run of steps
        central_blocks = sum(block.get(st.block.name, 0.0) for st in plan.steps
                             if st.block is not None)
        exchanges = report.get("exchanges_per_interval") or 0.0
        replies = float(cc.get("replies_per_interval") or 0.0)
        runs = plan.round_trips + 1 + (1 if report.get("pipeline") == 2 else 0)
        step = max(0.0, busy - central_blocks - exchanges * send - replies * reply - start
                   - finish) / runs
    return Costs(block, send, reply, step, 0.0, start, finish)


def calibrate(report: dict[str, Any]) -> tuple[StageGraph, Costs, dict[str, Any]]:
    """The model calibrated on a run: costs, and the latency that gives its mean period.

    The report is read by :func:`read_report` (idempotent on its own output)."""
    report = read_report(report)
    graph = stage_graph(report["law"], report["model"], observer=report["observer"],
                        model_state=report["model_state"])
    plan = exchange_plan(graph, placement_of(report))
    costs = model_costs(report, plan)
    depth = int(report.get("pipeline") or 1)
    measured = report.get("period_mean_s")
    if not measured or not math.isfinite(measured):
        measured = (report.get("period_s") or {}).get("p50") or math.nan
    latency = 0.0
    if plan.round_trips and math.isfinite(measured):
        mode = (report.get("replies") or {}).get("mode") or "fused"
        latency = fit_latency(plan, costs, measured, depth=depth, replies=mode)
    costs = costs.with_latency(latency)
    return graph, costs, {"measured_period_s": measured, "depth": depth}


def predict(graph: StageGraph, placement: Placement, costs: Costs, *, depth: int,
            replies: str = "auto") -> tuple[Schedule, str]:
    """The model's schedule for ``placement`` at ``depth``; returns it and the replies mode."""
    plan = exchange_plan(graph, placement)
    mode = _replies_mode(plan, costs, depth, replies)
    return simulate(plan, costs, depth=depth, replies=mode, intervals=INTERVALS), mode


def candidates(graph: StageGraph, placement: Placement, business: dict[str, float],
               arithmetic: float) -> list[tuple[str, Placement]]:
    """Placements the thesis's rules (§ IV.7.2) suggest from this one, with the rule.

    ``arithmetic`` is the central's share of the period spent in its blocks: the thesis's
    "busy" (a Transputer's links moved data alongside its CPU; here messages cost the
    central's CPU too, which ``business`` includes and the model charges separately)."""
    n = placement.peripherals
    central = business.get("central", math.nan)
    periph = max((v for k, v in business.items() if k.startswith("peripheral")),
                 default=math.nan)
    out: list[tuple[str, Placement]] = []
    if n == 0 or not math.isfinite(central):
        return out
    plan = exchange_plan(graph, placement)
    if arithmetic < 0.5:
        why = (f"the central computes {arithmetic * 100:.0f} % of the time (< 50 %; "
               f"{central * 100:.0f} % busy with its messages): ")
        for r in plan.rounds:
            names = [b.name for b in r.blocks]
            if len(plan.rounds) == 1:  # the last round: peripherals left with nothing to do
                out.append((why + f"move the last round ({', '.join(names)}) to the central: "
                            "one processor (n = 0) runs the interval with no exchange; the "
                            "star does not pay on this machine",
                            default_placement(0)))
            elif len(names) > 1:
                out.append((why + f"move round {r.index} ({', '.join(names)}) to the central "
                            "(no exchange for it)",
                            Placement(placement.axes, placement.central_blocks | set(names))))
            for b in names:
                out.append((why + f"move the block '{b}' to the central",
                            Placement(placement.axes, placement.central_blocks | {b})))
    if central >= 0.5 and (not math.isfinite(periph) or central > periph):
        why = (f"the central is {central * 100:.0f} % busy and the peripherals "
               f"{_percent(periph)}: ")
        if n > 1:
            grouped = default_placement(n - 1)
            out.append((why + f"group two peripherals' work (n = {n - 1})",
                        Placement(grouped.axes, placement.central_blocks)))
        for b in sorted(placement.central_blocks):
            out.append((why + f"give the block '{b}' back to the peripherals",
                        Placement(placement.axes, placement.central_blocks - {b})))
    return out


def analyse(report: Any, *, source: str = "report") -> dict[str, Any]:
    """Balance analysis of one run's report; returns the analysis and a placement.

    The report is read by :func:`read_report` first (a :class:`ReportError` names what is
    wrong with it)."""
    report = read_report(report, source=source)
    graph, costs, cal = calibrate(report)
    placement = placement_of(report)
    depth = cal["depth"]
    asked = asked_replies(report)
    block = costs.block_s
    t_s = sum(block.values())
    central_s = sum(v for k, v in block.items() if not graph.block(k).per_axis)
    n = placement.peripherals
    t_p = central_s + (t_s - central_s) / max(n, 1)
    business = report.get("business") or {}
    current = {d: predict(graph, placement, costs, depth=d, replies=asked)[0] for d in (1, 2)}
    now = current[depth]
    ranked = []
    central_blocks = sum(v for k, v in block.items() if n == 0 or not graph.block(k).per_axis
                         or k in placement.central_blocks)
    measured = cal["measured_period_s"]
    arithmetic = central_blocks / measured if measured and math.isfinite(measured) else math.nan
    for why, cand in candidates(graph, placement, business, arithmetic):
        sched, mode = predict(graph, cand, costs, depth=depth, replies=asked)
        ranked.append({"why": why, "placement": cand.to_dict(), "replies": mode,
                       "period_s": sched.period_mean_s})
    ranked.sort(key=lambda c: c["period_s"])
    recs: list[str] = []
    new = placement
    if ranked and ranked[0]["period_s"] < (1.0 - MARGIN) * now.period_mean_s:
        best = ranked[0]
        new = placement_of(best)
        recs.append(f"{best['why']}: predicted period {best['period_s'] * 1e6:.0f} us "
                    f"against {now.period_mean_s * 1e6:.0f} us now (depth {depth})")
    elif ranked:
        recs.append(f"no placement the rules suggest is predicted {MARGIN * 100:.0f} % faster "
                    f"(best: {ranked[0]['why']}, {ranked[0]['period_s'] * 1e6:.0f} us "
                    f"against {now.period_mean_s * 1e6:.0f} us): keep the placement")
    elif n == 0:
        recs.append("one processor (n = 0): nothing to place; keep the placement")
    else:
        recs.append("the rules suggest no move (central busy "
                    f"{_percent(business.get('central', math.nan))}): keep the placement")
    after = current if new == placement else {
        d: predict(graph, new, costs, depth=d, replies=asked)[0] for d in (1, 2)}

    def figures(s: Schedule) -> dict[str, Any]:
        return {"period_s": s.period_mean_s, "traversal_s": s.traversal_s,
                "exchanges_per_interval": s.exchanges_per_interval,
                "business": s.business()}

    return {
        "law": graph.law, "model": graph.model, "observer": graph.observer,
        "model_state": graph.model_state, "peripherals": n, "pipeline": depth,
        "block_cost_s": dict(block), "t_s_s": t_s, "t_p_s": t_p, "business": business,
        "central_arithmetic_share": arithmetic,
        "model_costs_s": {"send": costs.send_s, "reply": costs.reply_s,
                          "step": costs.step_s, "start": costs.start_s,
                          "finish": costs.finish_s, "latency": costs.latency_s,
                          "latency_is": "fitted to the run's mean period"},
        "cpu": {"per_interval_s": report.get("cpu_per_interval_s") or {},
                "cores": report.get("cpu_cores"),
                "bound_period_s": report.get("cpu_bound_period_s")},
        "measured": {"period_s": cal["measured_period_s"],
                     "traversal_s": (report.get("traversal_s") or {}).get("p50"),
                     "gantt_ms": report.get("gantt_ms") or []},
        "current": {f"depth{d}": figures(s) for d, s in current.items()}
        | {"gantt_ms": now.window()},
        "candidates": ranked,
        "recommendations": recs,
        "placement": new.to_dict(),
        "predicted": {f"depth{d}": figures(s) for d, s in after.items()}
        | {"gantt_ms": after[depth].window(), "period_s": after[depth].period_mean_s},
    }


def compare(analysis: dict[str, Any], rerun: Any, *, source: str = "re-run") \
        -> dict[str, Any]:
    """A re-run with the written placement against the analysis's prediction."""
    rerun = read_report(rerun, source=source)
    pl = rerun["placement"]
    if (pl.get("axes") != analysis["placement"]["axes"]
            or sorted(pl.get("central_blocks", [])) != sorted(
                analysis["placement"]["central_blocks"])):
        raise ValueError(f"the re-run's placement {pl} is not the one balance wrote "
                         f"{analysis['placement']}")
    depth = int(rerun.get("pipeline") or 1)
    predicted = analysis["predicted"][f"depth{depth}"]["period_s"]
    measured = rerun.get("period_mean_s") or math.nan
    before = analysis["measured"]["period_s"]
    return {"depth": depth, "predicted_period_s": predicted, "measured_period_s": measured,
            "error": measured / predicted - 1.0 if predicted else math.nan,
            "before_period_s": before, "gain": 1.0 - measured / before if before else math.nan,
            "gantt_ms": rerun.get("gantt_ms") or []}


def write_placement(analysis: dict[str, Any], path: str | Path) -> None:
    save_placement(placement_of(analysis), path)


def auto_central_blocks(plan: ExchangePlan, block_s: dict[str, float], round_trip_s: float
                        ) -> tuple[frozenset[str], list[dict[str, Any]]]:
    """``--placement auto``: the per-axis blocks the central should run itself (§ IV.7.2:
    a block goes where it costs least).

    Every round but the last moves to the central when its blocks, run there for all
    three axes, cost less than the round trip that carries them; the last round stays
    (moving it too would leave the peripherals nothing: the one-processor unit, n = 0,
    which is what ``--peripherals 0`` asks for). Where the plan has rounds that need no
    sample (:attr:`~ctrlunit.topology.plan.ExchangePlan.ahead_rounds`, model state
    ``foreseen``), those stay, since at depth 2 they run before the sample, off the path
    from sample to command, and every round that needs the sample is judged as above.
    Balance's candidates include the same move, judged by the calibrated model of a whole
    run; this rule needs only what the warm-up measured.

    Parameters
    ----------
    plan : the plan of the placement the unit started with.
    block_s : seconds of each block for all the axes it runs on (one interval); a block
        without a figure counts as infinitely costly (it stays).
    round_trip_s : one round trip less the peripherals' compute (the warm-up's median).

    Returns
    -------
    The placement's central blocks with the moved rounds' blocks added, and per round
    ``{"round", "blocks", "arithmetic_s", "round_trip_s", "moved"}``.
    """
    moved: set[str] = set(plan.placement.central_blocks)
    rounds = []
    if plan.placement.peripherals == 0:
        return frozenset(moved), rounds
    ahead = plan.ahead_rounds
    for rnd in plan.rounds[ahead:] if ahead else plan.rounds[:-1]:
        names = [b.name for b in rnd.blocks]
        cost = sum(block_s.get(b, math.inf) for b in names)
        move = cost < round_trip_s
        if move:
            moved.update(names)
        rounds.append({"round": rnd.index, "blocks": names, "arithmetic_s": cost,
                       "round_trip_s": round_trip_s, "moved": move})
    return frozenset(moved), rounds
