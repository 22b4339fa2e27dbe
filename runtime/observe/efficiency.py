"""Eq. IV.23's efficiency of a run: its t_parallel (:func:`parallel_time`) and whether the
run measures it at all (:func:`efficiency_unmeasured`), for the report and its summary."""

from __future__ import annotations

import math
from typing import Any

from ..config import RunConfig


def parallel_time(rc: RunConfig, *, traversal_p50: float,
                  period_mean: float) -> tuple[float, str]:
    """Eq. IV.23's t_parallel for this run, and what it is.

    In realtime the clock imposes the period, so the period says how the unit was paced,
    not how fast it computed: t_parallel is the traversal (sample to command, p50), the
    time the N processors took for one interval. In freerun and lockstep: at depth 1 the
    traversal too (one interval at a time); at depth 2 the time per interval, the mean
    period (when two intervals share an exchange their commands come in pairs, and the
    median period is either gap, not the rate)."""
    if rc.schedule.clock == "realtime":
        return traversal_p50, "traversal p50; the realtime clock imposes the period"
    if rc.schedule.pipeline == 1:
        return traversal_p50, "traversal p50"
    return period_mean, "period mean"


EFFICIENCY_BASIS = ("t_parallel is one interval's time on the N processors: the traversal "
                    "p50, or the mean period in freerun at depth 2 (two intervals overlap)")
"""How the summary's efficiency takes t_parallel (runtime/observe/report.py,
``parallel_time``), the same words in every run that shows it."""


def efficiency_unmeasured(r: dict[str, Any]) -> str | None:
    """Why this run does not measure Eq. IV.23's efficiency, or None when it does.

    Eq. IV.23, ``t_1 / (t_parallel x N)``, compares N processors with one on the same
    work. It needs N >= 2, and a ``t_parallel`` that is the unit's own time for an
    interval: in freerun (no plant paces the intervals), or under the T-800 cost model
    where t_parallel is the traversal (realtime, or depth 1), whose block times the
    exchanges do not swamp. In lockstep the plant's simulation paces every interval, and
    in realtime on native costs the clock sets the pace and the traversal is mostly the
    exchange: there the figure would read as a failure of a run that went well."""
    if not math.isfinite(r.get("efficiency", math.nan)):
        return "t_1 was not measured"
    if r.get("efficiency_n", 1) < 2:
        return "one processor (--peripherals 0): Eq. IV.23 compares N processors with one"
    t800 = r.get("cost_model") == "t800"
    if r["clock"] == "lockstep" and not (t800 and r["pipeline"] == 1):
        return "lockstep paces every interval by the plant's simulation step"
    if r["clock"] == "realtime" and not t800:
        return ("the realtime clock sets the pace, and on native costs the traversal is "
                "mostly the exchange")
    return None


__all__ = ["EFFICIENCY_BASIS", "efficiency_unmeasured", "parallel_time"]
