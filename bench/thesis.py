"""The comparison with the 1994 unit (§ IV.7, Table IV.5) and its guarded headline figures.

The runs compute the real kernels and then owe each block's 1994 T-800 time, scaled so
that arithmetic outweighs an exchange as it did on the Transputers (docs/thesis-notes.md).
Under those costs the figures are ratios of milliseconds, robust on a noisy 2-core host,
so each one is held to a bound (:data:`GUARDS`) and a regression fails
``tests/test_thesis_figures.py`` in CI:

- the two-stage pipeline's throughput, depth-2 mean period / depth-1 mean period
  (§ IV.7.2, Fig. 24: 0.5 as designed);
- Eq. IV.23's efficiency of the kinematics and of the whole cycle at depth 1, N = 4
  (57 % and 46 %: 1320 / (582 x 4) and 1604 / (866 x 4));
- the schedule model's depth-2 period, calibrated on the depth-1 run, against the
  depth-2 run measured beside it (what ``ctrlunit balance`` predicts from).

The configurations alternate within each repeat (a pair: depth 1 and depth 2 of the whole
cycle, with the kinematics at depth 1) and every figure is the median over the pairs.
"""

from __future__ import annotations

import math
import statistics
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

THESIS: dict[str, Any] = {
    "inverse_kinematics_3": {"t1_us": 240, "tp_us": 88, "n": 3, "efficiency": 0.91},
    "ik_and_jacobian_3": {"t1_us": 380, "tp_us": 128, "n": 3, "efficiency": 0.96},
    "all_kinematics_4": {"t1_us": 1320, "tp_us": 582, "n": 4, "efficiency": 0.57},
    "whole_cycle_4": {"t1_us": 1604, "tp_us": 866, "n": 4, "efficiency_printed": 0.54,
                      "efficiency_formula": 1604 / (866 * 4)},
    "period_1_us": 2000, "period_4_us": 1000, "period_pipeline_designed_us": 500,
}
"""The 1994 unit's figures (Table IV.5 and § IV.7.3; docs/thesis-notes.md)."""

THESIS_SCALE = 60.0
"""The T-800 cost scale of the thesis runs at the reference round (bench/sweep.py
``host_scale`` follows the host): an exchange then costs about 6 % of the arithmetic on the
kinematics' critical path, the Transputer links about 2 %. At x 30 it cost 12 % and the
kinematics' efficiency sat within a point or two of its bound on a slow host
(docs/measurements/2026-11-27-thesis-scale.md)."""

WHOLE = "resolved-acceleration"
KINEMATICS = "kinematics"


@dataclass(frozen=True)
class Guard:
    """One headline figure and the range it must stay in."""

    name: str
    what: str
    low: float
    high: float

    def check(self, value: float) -> dict[str, Any]:
        ok = math.isfinite(value) and self.low <= value <= self.high
        return {"name": self.name, "what": self.what, "value": value, "low": self.low,
                "high": self.high, "ok": ok}


GUARDS = (
    Guard("depth_ratio", "depth-2 / depth-1 mean period (0.5 designed)", 0.0, 0.60),
    Guard("kinematics_efficiency", "kinematics efficiency, N = 4, depth 1 (57 % in 1994)",
          0.57 - 0.08, 0.57 + 0.08),
    Guard("whole_cycle_efficiency", "whole-cycle efficiency, N = 4, depth 1 (46 % in 1994)",
          THESIS["whole_cycle_4"]["efficiency_formula"] - 0.08,
          THESIS["whole_cycle_4"]["efficiency_formula"] + 0.08),
    Guard("model_depth2_error", "schedule model's depth-2 period / measured - 1",
          -0.20, 0.20),
)
"""The bounds a regression must not cross (issue-level figures; docs/architecture.md)."""


def pair_configs(scale: float, config: Callable[..., Any]) -> list[Any]:
    """The configurations of one pair: the whole cycle at depth 1 and 2 and the
    kinematics at depth 1, n = 3, the thesis's graph (model state ``sample``)."""
    return [config(3, d, "t800", cost_scale=scale, law=law, tag="thesis",
                   model_state="sample")
            for law, d in ((WHOLE, 1), (WHOLE, 2), (KINEMATICS, 1))]


def pair_figures(whole1: dict[str, Any], whole2: dict[str, Any],
                 kin1: dict[str, Any]) -> dict[str, float]:
    """The guarded figures of one pair of runs (their reports)."""
    from ..topology.balance import analyse

    m1, m2 = whole1.get("period_mean_s", math.nan), whole2.get("period_mean_s", math.nan)
    try:
        predicted = analyse(whole1)["current"]["depth2"]["period_s"]
    except Exception:  # a report the model cannot read counts as a failed figure
        predicted = math.nan
    return {"depth_ratio": m2 / m1 if m1 else math.nan,
            "kinematics_efficiency": kin1.get("efficiency", math.nan),
            "whole_cycle_efficiency": whole1.get("efficiency", math.nan),
            "model_depth2_error": m2 / predicted - 1.0 if predicted else math.nan,
            "depth1_period_mean_s": m1, "depth2_period_mean_s": m2,
            "model_depth2_period_s": predicted,
            "depth2_business_peripherals": _peripherals_business(whole2)}


def _peripherals_business(rep: dict[str, Any]) -> float:
    vals = [v for k, v in (rep.get("business") or {}).items() if k.startswith("peripheral")]
    return statistics.median(vals) if vals else math.nan


def thesis_stage(*, scale: float, repeats: int, cycles: int,
                 run: Callable[[Any, int], tuple[dict[str, Any], Any]],
                 config: Callable[..., Any],
                 progress: Callable[[str, int, int], None] | None = None, done: int = 0,
                 total: int = 0) -> dict[str, Any]:
    """Run ``repeats`` pairs (their order reversed every other pair) and judge the medians.

    Parameters
    ----------
    scale : the T-800 cost scale.
    repeats : pairs to run (three or more for a median that one slow pair cannot move).
    cycles : intervals per run.
    run : ``run(config, cycles) -> (report, central)`` (:func:`.runs.run_one`).
    config : the bench's configuration class (:class:`.runs.Config`).

    Returns the runs' reports by configuration key, each pair's figures, their medians
    and :data:`GUARDS` checked on the medians (``ok`` on each).
    """
    configs = pair_configs(scale, config)
    reports: dict[str, list[dict[str, Any]]] = {c.key: [] for c in configs}
    pairs: list[dict[str, float]] = []
    for i in range(repeats):
        got: dict[str, dict[str, Any]] = {}
        for cfg in configs if i % 2 == 0 else configs[::-1]:
            if progress:
                progress(cfg.key, done, total)
            rep, _central = run(cfg, cycles)
            reports[cfg.key].append(rep)
            got[cfg.key] = rep if rep.get("exit_code") == 0 else {}
            done += 1
        pairs.append(pair_figures(*(got[c.key] for c in configs)))
    medians = {k: _median(p[k] for p in pairs) for k in pairs[0]} if pairs else {}
    return {"config": f"freerun, n = 3, t800 x {scale:g}, model state sample, {cycles} "
                      f"intervals; {repeats} alternated pair(s), medians",
            "configs": [c.key for c in configs], "reports": reports, "pairs": pairs,
            "figures": medians,
            "guards": [g.check(medians.get(g.name, math.nan)) for g in GUARDS]}


def _median(values: Any) -> float:
    vals = [v for v in values if v is not None and math.isfinite(v)]
    return statistics.median(vals) if vals else math.nan


def guard_lines(stage: dict[str, Any]) -> list[str]:
    """The guarded figures as text, one line each: value, allowed range and verdict."""
    return [f"{'ok  ' if g['ok'] else 'FAIL'} {g['what']}: {_shown(g['name'], g['value'])} "
            f"(allowed {_shown(g['name'], g['low'])} to {_shown(g['name'], g['high'])})"
            for g in stage["guards"]]


def _shown(name: str, v: float) -> str:
    if name == "depth_ratio":
        return f"{v:.3f}"
    return f"{v * 100:+.1f} %" if name == "model_depth2_error" else f"{v * 100:.1f} %"
