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
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from .balance_report import read_report
from .graph import StageGraph, stage_graph
from .placement import Placement, default_placement, save_placement
from .plan import ExchangePlan, exchange_plan
from .schedule import Costs, Schedule, fit_latency, simulate

MARGIN = 0.05
"""A candidate placement is recommended when its predicted period is at least this much
shorter than the current one (the model's error on this machine is a few per cent)."""

INTERVALS = 160
"""Intervals the model plays for each placement :func:`analyse` judges."""

def _percent(x: float) -> str:
    """A business as text; a report may not hold one."""
    return f"{x * 100:.0f} %" if math.isfinite(x) else "not measured"


def placement_of(report: dict[str, Any]) -> Placement:
    pl = report.get("placement") or {}
    return Placement(tuple(tuple(g) for g in pl.get("axes", [])),
                     frozenset(pl.get("central_blocks", [])))


def replies_mode(plan: ExchangePlan, costs: Costs, depth: int, asked: str) -> str:
    """What ``--replies auto`` would pick (runtime/central/warmup.py): ``each`` when the
    central's work between two rounds exceeds a round trip."""
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


def calibrate(report: dict[str, Any], *, source: str = "report", steps: int = 40
              ) -> tuple[StageGraph, Costs, dict[str, Any]]:
    """The model calibrated on a run: costs, and the latency that gives its mean period
    (in realtime, its median traversal: the clock pads the period), fitted in ``steps``
    halvings.

    The run's report as written, read here by :func:`read_report`."""
    report = read_report(report, source=source)
    graph = stage_graph(report["law"], report["model"], observer=report["observer"],
                        model_state=report["model_state"])
    plan = exchange_plan(graph, placement_of(report))
    costs = model_costs(report, plan)
    depth = int(report.get("pipeline") or 1)
    measured = report.get("period_mean_s")
    if not measured or not math.isfinite(measured):
        measured = (report.get("period_s") or {}).get("p50") or math.nan
    latency = 0.0
    mode = (report.get("replies") or {}).get("mode") or "fused"
    paced = report["run"]["clock"] == "realtime"
    # the realtime clock pads each period: an interval's own time is its traversal, which
    # the model gives alone at depth 1
    own = ((report.get("traversal_s") or {}).get("p50") or measured) if paced else measured
    if plan.round_trips and math.isfinite(own):
        latency = fit_latency(plan, costs, own, depth=1 if paced else depth, replies=mode,
                              figure="traversal_s" if paced else "period_mean_s", steps=steps)
    costs = costs.with_latency(latency)
    return graph, costs, {"measured_period_s": measured, "interval_s": own, "depth": depth,
                          "paced": paced}


def predict(graph: StageGraph, placement: Placement, costs: Costs, *, depth: int,
            replies: str = "auto") -> tuple[Schedule, str]:
    """The model's schedule for ``placement`` at ``depth``; returns it and the replies mode."""
    plan = exchange_plan(graph, placement)
    mode = replies_mode(plan, costs, depth, replies)
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
        # a whole round's blocks at once: the round's exchange comes back with its first
        for r in exchange_plan(graph, Placement(placement.axes)).rounds:
            back = {b.name for b in r.blocks} & placement.central_blocks
            if len(back) > 1:
                out.append((why + f"give round {r.index}'s blocks ({', '.join(sorted(back))}) "
                            "back to the peripherals",
                            Placement(placement.axes, placement.central_blocks - back)))
    return out


def central_arithmetic(graph: StageGraph, placement: Placement,
                       block_s: Mapping[str, float], own_s: float) -> float:
    """The central's share of ``own_s`` (a period, or in realtime a traversal) spent in
    its blocks: the thesis's "busy" that :func:`candidates` reads."""
    n = placement.peripherals
    spent = sum(v for k, v in block_s.items() if n == 0 or not graph.block(k).per_axis
                or k in placement.central_blocks)
    return spent / own_s if own_s and math.isfinite(own_s) else math.nan


def _latency_is(cal: dict[str, Any], *, plan_ahead: bool) -> str:
    """What the fitted latency was fitted to (:func:`calibrate`)."""
    if not cal["paced"]:
        return "fitted to the run's mean period"
    return ("fitted to the run's median traversal, one interval alone (the realtime clock "
            "pads the period)" + ("; the rounds run ahead of the sample are not in it, so "
                                  "the latency is at most the true one" if plan_ahead and
                                  cal["depth"] == 2 else ""))


def analyse(report: Any, *, source: str = "report") -> dict[str, Any]:
    """Balance analysis of one run's report; returns the analysis and a placement.

    The report is read by :func:`read_report` first (a :class:`ReportError` names what is
    wrong with it)."""
    graph, costs, cal = calibrate(report, source=source)
    report = read_report(report, source=source)
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
    ranked: list[dict[str, Any]] = []
    # the period, or in realtime the traversal (the work's own)
    arithmetic = central_arithmetic(graph, placement, block, cal["interval_s"])
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
        "run": report["run"] | {"replies": asked},
        "block_cost_s": dict(block), "t_s_s": t_s, "t_p_s": t_p, "business": business,
        "central_arithmetic_share": arithmetic,
        "model_costs_s": {"send": costs.send_s, "reply": costs.reply_s,
                          "step": costs.step_s, "start": costs.start_s,
                          "finish": costs.finish_s, "latency": costs.latency_s,
                          "latency_is": _latency_is(cal, plan_ahead=bool(
                              exchange_plan(graph, placement).ahead_rounds))},
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
    # the model plays free-running intervals; a realtime run's period is its clock's
    before = analysis["current"][f"depth{depth}"]["period_s"] \
        if analysis["run"]["clock"] == "realtime" else analysis["measured"]["period_s"]
    if rerun["run"]["clock"] == "realtime":
        raise ValueError("the re-run is a realtime run, whose period is its clock's: re-run "
                         "with --clock freerun, as the command balance prints, to measure "
                         "the period it predicts")
    _same_run(analysis, rerun)
    return {"depth": depth, "predicted_period_s": predicted, "measured_period_s": measured,
            "before_is": "the model's, free-running" if analysis["run"]["clock"] == "realtime"
            else "measured",
            "error": measured / predicted - 1.0 if predicted else math.nan,
            "before_period_s": before, "gain": 1.0 - measured / before if before else math.nan,
            "gantt_ms": rerun.get("gantt_ms") or []}


def _same_run(analysis: dict[str, Any], rerun: dict[str, Any]) -> None:
    """A re-run is the run analysed with the placement written, as the command balance
    prints makes it: the same law, graph, depth, cost model and task, and its clock (a
    realtime run's re-run is free-running). Raises ValueError naming the first field that
    differs."""
    want, got = analysis["run"], rerun["run"]
    clock = "freerun" if want["clock"] == "realtime" else want["clock"]
    pairs = [(k, analysis[k], rerun[k]) for k in ("law", "model", "observer", "model_state",
                                                   "pipeline")]
    pairs += [(k, want[k], got[k]) for k in ("cost_model", "cost_scale", "task")
              if want[k] is not None and got[k] is not None]
    for field, a, b in [("clock", clock, got["clock"]), *pairs]:
        if a != b:
            raise ValueError(f"the re-run's {field} is {b!r} where the command balance "
                             f"prints runs {a!r}: re-run with that command")


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
    rounds: list[dict[str, Any]] = []
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
