"""``ctrlunit balance``: where the time goes and how to rebalance (§ IV.7.2).

From a run's report (``--report`` JSON) or a recording, with the measured per-block costs:

* ``t_s`` (Eq. IV.24): every block on one processor;
* ``t_p`` (Eq. IV.25): the central's blocks plus the per-axis blocks divided over n;
* a predicted depth-2 period: the larger of the central's time per interval and a
  peripheral's time per interval plus its rounds' transport, each from the block costs and
  the measured round trip (the thesis's argument: at depth 2 the central and the
  peripherals work on different intervals, so the slower side sets the period);
* recommendations: when the central is under 50 % busy, move the lightest per-axis block
  of the last round to the central (it then needs no exchange of its own); when the central
  is the bottleneck, give the peripherals more (move central-placed blocks back) or group
  two peripherals' work; the resulting placement is written for ``--placement``.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ..topology.graph import stage_graph
from ..topology.placement import Placement, default_placement, save_placement
from ..topology.plan import ExchangePlan, exchange_plan


@dataclass
class Prediction:
    central_s: float
    peripheral_s: float
    transport_s: float
    period_depth2_s: float
    traversal_depth1_s: float
    round_trips: int


def predict(plan: ExchangePlan, block_cost_s: dict[str, float], round_trip_s: float,
            central_overhead_s: float = 0.0) -> Prediction:
    """Predicted times for ``plan`` from per-block costs (each block's cost for all three
    axes, as measured by the single-processor run)."""
    n = plan.placement.peripherals
    axes_max = max((len(g) for g in plan.placement.axes), default=3)
    central = central_overhead_s
    periph = 0.0
    for b in plan.graph.blocks:
        c = block_cost_s.get(b.name, 0.0)
        remote = b.per_axis and n > 0 and b.name not in plan.placement.central_blocks
        if remote:
            periph += c * axes_max / 3.0
        else:
            central += c
    rt = plan.round_trips
    transport = rt * round_trip_s
    period2 = max(central, periph + transport, (central + periph + transport) / 2.0)
    trav1 = central + periph + transport
    return Prediction(central, periph, transport, period2, trav1, rt)


def analyse(report: dict[str, Any], *, round_trip_s: float | None = None) -> dict[str, Any]:
    """Balance analysis of one run's report; returns the analysis and a placement."""
    law, model = report.get("law", "resolved-acceleration"), report.get("model", "complete")
    graph = stage_graph(law, model)
    pl = report.get("placement") or {}
    placement = Placement(tuple(tuple(g) for g in pl.get("axes", [])),
                          frozenset(pl.get("central_blocks", [])))
    plan = exchange_plan(graph, placement)
    costs = {k: float(v) for k, v in (report.get("block_cost_s") or {}).items()}
    t_s = sum(costs.values())
    n = placement.peripherals
    central_s = sum(v for k, v in costs.items() if not graph.block(k).per_axis)
    axis_s = t_s - central_s
    t_p = central_s + axis_s / max(n, 1)
    measured_period = (report.get("period_s") or {}).get("p50") or math.nan
    measured_trav = (report.get("traversal_s") or {}).get("p50") or math.nan
    business = report.get("business") or {}
    # the central's per-interval cost beyond its blocks (codec, Zenoh), from its business
    c_busy = business.get("central", math.nan) * measured_period
    base = predict(plan, costs, 0.0)
    overhead = max(0.0, c_busy - base.central_s) if math.isfinite(c_busy) else 0.0
    if round_trip_s is None:
        # what each round costs beyond the arithmetic and the central's own overhead, from
        # the measured depth-1 traversal (at depth 2 the traversal includes queueing)
        with_overhead = predict(plan, costs, 0.0, overhead)
        if plan.round_trips and math.isfinite(measured_trav) and report.get("pipeline") == 1:
            round_trip_s = max(0.0, (measured_trav - with_overhead.traversal_depth1_s) /
                               plan.round_trips)
        else:
            round_trip_s = 250e-6
    current = predict(plan, costs, round_trip_s, overhead)
    # recommendations
    recs: list[str] = []
    new = placement
    central_busy = business.get("central", math.nan)
    depth = report.get("pipeline") or 1

    def score(p: Prediction) -> float:
        return p.period_depth2_s if depth == 2 else p.traversal_depth1_s

    if n > 0 and math.isfinite(central_busy) and central_busy < 0.5:
        # every single per-axis block that could move to the central, judged by the
        # predicted time of the plan it gives (a move that splits a round costs a round trip)
        best, best_score = None, score(current)
        for b in (b for r in plan.rounds for b in r.blocks):
            cand = Placement(placement.axes, placement.central_blocks | {b.name})
            p = predict(exchange_plan(graph, cand), costs, round_trip_s, overhead)
            if score(p) < best_score - 1e-9:
                best, best_score = (b, cand), score(p)
        if best is not None:
            b, new = best
            recs.append(f"the central is {central_busy * 100:.0f} % busy (< 50 %): move the "
                        f"block '{b.name}' ({costs.get(b.name, 0) * 1e6:.1f} us for 3 axes) "
                        f"to the central (predicted {best_score * 1e6:.0f} us against "
                        f"{score(current) * 1e6:.0f} us)")
        else:
            recs.append(f"the central is {central_busy * 100:.0f} % busy (< 50 %), but no "
                        "single block moved to it shortens the predicted period (each move "
                        "would add a round trip or load the central more)")
    elif n > 1 and math.isfinite(central_busy) and central_busy >= 0.9:
        if placement.central_blocks:
            new = Placement(placement.axes, frozenset())
            recs.append("the central is the bottleneck: run every per-axis block on the "
                        "peripherals again")
        else:
            new = default_placement(n - 1)
            recs.append(f"the central is the bottleneck ({central_busy * 100:.0f} % busy): "
                        f"group two peripherals' work (n = {n - 1})")
    if new == placement:
        recs.append("the load is balanced as far as these rules go: keep the placement")
    new_plan = exchange_plan(graph, new)
    predicted = predict(new_plan, costs, round_trip_s, overhead)
    return {
        "law": law, "model": model, "peripherals": n, "pipeline": report.get("pipeline"),
        "block_cost_s": costs, "t_s_s": t_s, "t_p_s": t_p, "business": business,
        "round_trip_s": round_trip_s, "central_overhead_s": overhead,
        "current": current.__dict__, "measured": {"period_s": measured_period,
                                                   "traversal_s": measured_trav},
        "recommendations": recs, "placement": new.to_dict(),
        "predicted": predicted.__dict__,
    }


def write_placement(analysis: dict[str, Any], path: str | Path) -> None:
    pl = analysis["placement"]
    save_placement(Placement(tuple(tuple(g) for g in pl["axes"]),
                             frozenset(pl["central_blocks"])), path)


def load_report(path: str | Path) -> dict[str, Any]:
    """A run's report from ``--report`` JSON or from a recording."""
    path = Path(path)
    if path.suffix == ".mcap":
        from ..runtime.recording import read, report_from_recording

        return report_from_recording(read(path))
    return json.loads(path.read_text())
