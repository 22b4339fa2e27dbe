"""PNG figures of a benchmark report."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt

from ..runtime.recording.plots import COLORS, gantt_figure

__all__ = ["COLORS", "gantt_figure", "write_figures"]


def write_figures(out: Path, report: dict[str, Any], samples: dict[str, dict],
                  gantt: dict[str, list]) -> list[str]:
    files = [_efficiency(out, report), _distributions(out, samples)]
    if gantt:
        files.append(_gantt(out, gantt))
    panels = (report.get("balance") or {}).get("gantt")
    if panels:
        gantt_figure(out / "balance_gantt.png", panels)
        files.append("balance_gantt.png")
    return [f for f in files if f]


def _efficiency(out: Path, report: dict[str, Any]) -> str:
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(12, 4.5), constrained_layout=True)
    for cm, style in (("native", "o-"), ("t800", "s--")):
        for d in (1, 2):
            rows = sorted((r for r in report["runs"] if r["tag"] == "sweep"
                           and r["cost_model"] == cm and r["pipeline"] == d),
                          key=lambda r: r["peripherals"])
            ns = [r["peripherals"] for r in rows]
            ax1.plot(ns, [100 * (r["efficiency"] or math.nan) for r in rows], style,
                     label=f"{cm}, depth {d}")
            ax2.plot(ns, [r["speedup"] or math.nan for r in rows], style,
                     label=f"{cm}, depth {d}")
    th = [r for r in report["runs"] if r["tag"] == "thesis" and r["peripherals"] == 3]
    for r in th:
        lab = f"t800 x{r['cost_scale']:g} {r['law'][:10]} d{r['pipeline']}"
        ax1.plot([3], [100 * (r["efficiency"] or math.nan)], "*", ms=12, label=lab)
    t = report["thesis_1994"]
    ax1.plot([3], [100 * t["all_kinematics_4"]["efficiency"]], "kX", ms=10,
             label="1994: all kinematics, 4 T-800 (57 %)")
    ax1.plot([3], [100 * t["whole_cycle_4"]["efficiency_formula"]], "kP", ms=10,
             label="1994: whole cycle, 4 T-800 (46 %)")
    ax1.set_xlabel("peripherals n (processors N = n + 1)")
    ax1.set_ylabel("efficiency (Eq. IV.23) %")
    ax1.set_title("Efficiency against n")
    ax1.legend(fontsize=7)
    ax2.set_xlabel("peripherals n")
    ax2.set_ylabel("speedup t_1 / t_parallel")
    ax2.axhline(1.0, color="gray", ls=":")
    ax2.set_title("Speedup against n")
    ax2.legend(fontsize=7)
    path = out / "efficiency.png"
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path.name


def _distributions(out: Path, samples: dict[str, dict]) -> str:
    keys = [k for k in samples if samples[k]["period_s"]]
    if not keys:
        return ""
    keys.sort()
    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(12, 8), constrained_layout=True)
    labels = [k.split(":", 1)[1].replace("resolved-acceleration", "RA") for k in keys]
    ax1.boxplot([[x * 1e3 for x in samples[k]["period_s"]] for k in keys], showfliers=False)
    ax2.boxplot([[x * 1e3 for x in samples[k]["traversal_s"]] for k in keys],
                showfliers=False)
    for ax, what in ((ax1, "period"), (ax2, "traversal")):
        ax.set_xticks(range(1, len(labels) + 1), labels, rotation=70, fontsize=6)
        ax.set_ylabel(f"{what} (ms)")
        ax.set_yscale("log")
        ax.set_title(f"{what} distributions (boxes: quartiles, whiskers: 1.5 IQR)")
    path = out / "distributions.png"
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path.name


def _gantt(out: Path, gantt: dict[str, list]) -> str:
    path = out / "gantt.png"
    gantt_figure(path, {f"n = 3, {k} (measured)": v for k, v in sorted(gantt.items())})
    return path.name
