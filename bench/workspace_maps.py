"""Workspace maps (thesis Fig. 28-29) computed from the kernels, with optional PNG."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from ..kernels.params import DeltaParams
from ..kernels.workspace import box_min_eigenvalue, slice_map

SLICES_Z = (-0.25, -0.32, -0.39, -0.46, -0.53, -0.60, -0.67)
"""Seven equidistant horizontal slices (Fig. 28), m."""


def workspace_report(
    params: DeltaParams, *, png: Path | None = None, grid: int = 61
) -> dict[str, Any]:
    """det J and eigenvalue maps on the slices of Fig. 28 and the Fig. 29 curve.

    Returns a JSON-ready dictionary; writes a PNG with the maps when ``png`` is given.
    """
    scale = (params.l_a + params.l_b) / 0.74
    slices = []
    maps = []
    for z0 in SLICES_Z:
        z = z0 * scale
        xs, ys, det, eig = slice_map(params, z, half_width=0.6 * scale, n=grid)
        reach = np.isfinite(eig)
        usable = reach & (eig >= params.beta_min)
        slices.append(
            {
                "z_m": z,
                "reachable_fraction": float(reach.mean()),
                "usable_fraction": float(usable.mean()),
                "min_eig": float(np.nanmin(eig)) if reach.any() else math.nan,
                "det_range": [float(np.nanmin(det)), float(np.nanmax(det))] if reach.any()
                else [math.nan, math.nan],
            }
        )
        maps.append((z, xs, ys, det, eig))
    # Fig. 29: smallest eigenvalue over the box [q_min, q_max]^3 as one bound moves
    q_lows = np.radians(np.arange(-135.0, -84.0, 5.0))
    q_highs = np.radians(np.arange(-10.0, 41.0, 5.0))
    curve_low = [box_min_eigenvalue(params, ql, params.q_max, n=7) for ql in q_lows]
    curve_high = [box_min_eigenvalue(params, params.q_min, qh, n=7) for qh in q_highs]
    box = box_min_eigenvalue(params, params.q_min, params.q_max, n=11)
    out: dict[str, Any] = {
        "slices": slices,
        "q_min_deg": math.degrees(params.q_min),
        "q_max_deg": math.degrees(params.q_max),
        "box_min_eig": box,
        "fig29": {
            "q_min_deg": np.degrees(q_lows).tolist(),
            "min_eig_vs_q_min": curve_low,
            "q_max_deg": np.degrees(q_highs).tolist(),
            "min_eig_vs_q_max": curve_high,
        },
        "thesis": {"beta_min": 0.1, "q_min_deg": -125.0, "q_max_deg": 15.0,
                   "stiffening_up_to": 9.0},
    }
    if png is not None:
        _plot(png, maps, out, params)
    return out


def _plot(png: Path, maps: list, data: dict[str, Any], params: DeltaParams) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 4, figsize=(16, 8), constrained_layout=True)
    for ax, (z, xs, ys, det, _eig) in zip(axes.flat, maps):
        det_j = np.where(_eig >= params.beta_min, 1.0 / det, np.nan)  # det(J / l_a)
        im = ax.pcolormesh(xs, ys, det_j, shading="auto", cmap="viridis")
        ax.set_title(f"det(J / l_a) where usable, z = {z:.2f} m", fontsize=9)
        ax.set_aspect("equal")
        fig.colorbar(im, ax=ax, shrink=0.8)
    ax = axes.flat[-1]
    f29 = data["fig29"]
    ax.plot(f29["q_min_deg"], f29["min_eig_vs_q_min"], "o-", label="vs q_min (q_max fixed)")
    ax.plot(f29["q_max_deg"], f29["min_eig_vs_q_max"], "s-", label="vs q_max (q_min fixed)")
    ax.axhline(params.beta_min, color="r", ls="--", label=f"beta_min = {params.beta_min}")
    ax.axvline(-125, color="gray", ls=":", label="thesis bounds -125 / 15 deg")
    ax.axvline(15, color="gray", ls=":")
    ax.set_xlabel("joint bound (deg)")
    ax.set_ylabel("min eig l_a^2 J^-T J^-1")
    ax.set_title("Fig. 29 (computed)", fontsize=9)
    ax.legend(fontsize=7)
    fig.suptitle("Delta workspace (thesis Fig. 28-29, computed by ctrlunit)")
    fig.savefig(png, dpi=80)
    plt.close(fig)
