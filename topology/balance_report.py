"""A run's report as ``ctrlunit balance`` reads it (:mod:`.balance`): only the fields the
analysis uses, each checked for type and range, so that a malformed or forged report is a
:class:`ReportError` naming the field, never a crash."""

from __future__ import annotations

import math
from typing import Any

from .graph import LAWS, MODEL_STATES, OBSERVERS, StageGraph, stage_graph
from .placement import Placement, placement_from_mapping

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
    if doc.get("rebalanced"):
        raise ReportError(f"{source}: the run moved its blocks while it ran (rebalanced: "
                          "--balance live), so its figures mix placements; analyse a run "
                          "made with --balance off")
    law, model, observer, model_state, graph, block = _graph_fields(doc, source)
    depth, placement = _placement_fields(doc, source, graph)
    return {
        "law": law, "model": model, "observer": observer, "model_state": model_state,
        "pipeline": depth,
        "placement": placement.to_dict(), "block_cost_s": block,
        **_cost_fields(doc, source), **_measured_fields(doc, source),
        "run": _run_fields(doc, source),
    }


def _run_fields(doc: dict[str, Any], source: str) -> dict[str, Any]:
    """How the run was made beyond its graph and placement, which its figures (and so a
    model calibrated on them) depend on: the clock, its period, the cost model, the
    replies and lone rounds asked, its length, its task's name. A report that does not
    say: freerun, the native costs, auto, the task's length, no name."""
    scale = doc.get("cost_scale")
    if scale is None:
        scale = 1.0
    if not _is_number(scale) or not math.isfinite(scale) or not 0.01 <= scale <= 1000:
        raise _bad(source, "cost_scale", scale, "a number in [0.01, 1000]")
    cycles = doc.get("cycles")
    if cycles is not None and (not isinstance(cycles, int) or isinstance(cycles, bool)
                               or not 1 <= cycles <= 10**9):
        raise _bad(source, "cycles", cycles, "an integer in [1, 1e9] or null")
    hold = _mapping(source, "hold_rounds", doc.get("hold_rounds"))
    return {
        "clock": _choice(source, "clock", doc.get("clock"),
                         ("freerun", "lockstep", "realtime"), "freerun"),
        "period_s": _seconds(source, "nominal_period_s", doc.get("nominal_period_s"),
                             positive=True),
        "cost_model": _choice(source, "cost_model", doc.get("cost_model"),
                              ("native", "t800"), "native"),
        "cost_scale": float(scale), "cycles": cycles,
        "hold_rounds": _choice(source, "hold_rounds.asked", hold.get("asked"),
                               ("auto", "always", "never"), "auto"),
        "task": doc["task"] if isinstance(doc.get("task"), str) else None,
    }


def _graph_fields(doc: dict[str, Any], source: str
                  ) -> tuple[str, str, str, str, StageGraph, dict[str, float]]:
    """The law, model, observer and model state of a report (each defaulted as the unit
    was before it recorded them), their stage graph, and the measured cost of each of its
    blocks."""
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
    return law, model, observer, model_state, graph, block


def _placement_fields(doc: dict[str, Any], source: str, graph: StageGraph
                      ) -> tuple[int, Placement]:
    """The pipeline depth (1 if absent) and the placement of a report."""
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
    return depth, placement


def _cost_fields(doc: dict[str, Any], source: str) -> dict[str, Any]:
    """The reply mode and the central's own costs of a report."""
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

    return {
        "replies": {"asked": _choice(source, "replies.asked", replies.get("asked"),
                                     ("auto", "each", "fused"), "auto"),
                    "mode": _choice(source, "replies.mode", replies.get("mode"),
                                    ("each", "fused"), "fused")},
        "central_costs_s": costs | per_interval, "exchanges_per_interval": exchanges,
    }


def _measured_fields(doc: dict[str, Any], source: str) -> dict[str, Any]:
    """The periods, traversals, business, CPU and Gantt window of a report."""
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
        "period_mean_s": _seconds(source, "period_mean_s", doc.get("period_mean_s"),
                                  positive=True),
        "period_s": quantiles("period_s"), "traversal_s": quantiles("traversal_s"),
        "business": business, "cpu_per_interval_s": cpu, "cpu_cores": cores,
        "cpu_bound_period_s": _seconds(source, "cpu_bound_period_s",
                                       doc.get("cpu_bound_period_s")),
        "gantt_ms": gantt,
    }


__all__ = ["MAX_COST_S", "ReportError", "read_report"]
