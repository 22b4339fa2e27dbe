"""The live balance's choice (``--balance live``, runtime/central/rebalance.py): the model
and the rules of ``ctrlunit balance`` (:mod:`.balance`) on a window of a running unit."""

from __future__ import annotations

import time
from typing import Any

from .balance import (
    MARGIN,
    asked_replies,
    calibrate,
    candidates,
    central_arithmetic,
    placement_of,
    replies_mode,
)
from .balance_report import read_report
from .placement import Placement
from .plan import exchange_plan
from .schedule import simulate

LIVE_INTERVALS = 60
"""Intervals the model plays for each placement judged (:data:`.balance.INTERVALS` for the
offline analysis): a fifth is start-up, the rest is steady."""
LIVE_STEPS = 10
"""Halvings of the latency fit: to 2^-10 of its bracket (the period), far below the
model's error."""


def live_choice(report: dict[str, Any]) -> dict[str, Any] | None:
    """The live balance's re-placement (``balance = "live"``, runtime/central/rebalance.py):
    :func:`.balance.analyse`'s model and rules on a window of a running unit, given as a
    report, of which only the candidates that keep every peripheral's axes count (a running
    unit keeps its processes). A lighter play than :func:`.balance.analyse`'s
    (:data:`LIVE_INTERVALS` intervals, the latency fitted in :data:`LIVE_STEPS` halvings)
    at the run's depth only.

    Returns ``{"central_blocks", "why", "predicted_period_s", "model_period_s",
    "measured_period_s"}`` for the best candidate predicted at least :data:`MARGIN` faster
    than the model of the current placement, else None."""
    graph, costs, cal = calibrate(report, source="live balance", steps=LIVE_STEPS)
    report = read_report(report, source="live balance")
    placement = placement_of(report)
    depth, asked = cal["depth"], asked_replies(report)

    def period(p: Placement) -> float:
        plan = exchange_plan(graph, p)
        mode = replies_mode(plan, costs, depth, asked)
        return simulate(plan, costs, depth=depth, replies=mode,
                        intervals=LIVE_INTERVALS).period_mean_s

    now = period(placement)
    arithmetic = central_arithmetic(graph, placement, costs.block_s, cal["interval_s"])
    best: tuple[float, str, Placement] | None = None
    for why, cand in candidates(graph, placement, report["business"], arithmetic):
        if cand.axes != placement.axes:
            continue
        t = period(cand)
        if best is None or t < best[0]:
            best = (t, why, cand)
    if best is None or best[0] >= (1.0 - MARGIN) * now:
        return None
    return {"central_blocks": sorted(best[2].central_blocks), "why": best[1],
            "predicted_period_s": best[0], "model_period_s": now,
            "measured_period_s": cal["measured_period_s"]}


def judge_ready() -> bool:
    """Nothing but that the judge's process has started and imported this module (the
    central waits for it before its warm-up: runtime/central/rebalance.py)."""
    return True


def live_verdict(report: dict[str, Any]) -> tuple[dict[str, Any] | None, int]:
    """:func:`live_choice` as the central's judge runs it (in a process of its own,
    runtime/central/rebalance.py), with the CPU it took (ns). A window the model cannot read
    (a figure beyond its range, after a stall) calls for no move."""
    t0 = time.process_time_ns()
    try:
        choice = live_choice(report)
    except ValueError:
        choice = None
    return choice, time.process_time_ns() - t0


__all__ = ["LIVE_INTERVALS", "LIVE_STEPS", "judge_ready", "live_choice", "live_verdict"]
