"""Usable workspace of the Delta (thesis § V.4.2).

* Eq. V.33: the eigenvalues of ``l_a^2 J^-T J^-1`` (dimensionless; ``= W X^-2 W^T``) stay
  within ``[beta_min, beta_max]``, plus reachability. This is the definition used to accept
  or refuse targets and paths.
* Eq. V.32: the joint box ``q_min <= q_i <= q_max``, only a conservative inner
  approximation (errata.md: the circle task leaves the box yet stays in V.33).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from .kinematics import UnreachableError, ik_all, jinv_row
from .params import DeltaParams


class WorkspaceError(ValueError):
    """A point lies outside the usable workspace; the message names the point and bound."""


def stiffness_eigenvalues(params: DeltaParams, p: object) -> np.ndarray:
    """Eigenvalues of ``l_a^2 J^-T J^-1`` at ``p`` (Eq. V.33), ascending, shape (3,).

    Raises
    ------
    UnreachableError
        If ``p`` is out of reach.
    """
    axes = ik_all(params, p)
    ji = np.array([jinv_row(params, i, ax) for i, ax in enumerate(axes)]) * params.l_a
    return np.linalg.eigvalsh(ji.T @ ji)


class PointCheck(NamedTuple):
    """Result of :func:`check_point`."""

    ok: bool
    reason: str
    min_eig: float
    max_eig: float
    q: np.ndarray


def check_point(params: DeltaParams, p: object) -> PointCheck:
    """Is ``p`` in the usable workspace of Eq. V.33? Never raises for a finite point."""
    pa = np.asarray(p, dtype=float)
    try:
        axes = ik_all(params, pa)
    except UnreachableError as exc:
        return PointCheck(False, str(exc), math.nan, math.nan, np.full(3, math.nan))
    q = np.array([a.q for a in axes])
    eig = stiffness_eigenvalues(params, pa)
    lo, hi = float(eig[0]), float(eig[-1])
    where = f"point ({pa[0]:.4f}, {pa[1]:.4f}, {pa[2]:.4f}) m"
    if lo < params.beta_min:
        return PointCheck(
            False,
            f"{where}: smallest eigenvalue of l_a^2 J^-T J^-1 is {lo:.4g}, below "
            f"beta_min = {params.beta_min} (Eq. V.33)",
            lo,
            hi,
            q,
        )
    if hi > params.beta_max:
        return PointCheck(
            False,
            f"{where}: largest eigenvalue of l_a^2 J^-T J^-1 is {hi:.4g}, above "
            f"beta_max = {params.beta_max} (Eq. V.33)",
            lo,
            hi,
            q,
        )
    return PointCheck(True, "", lo, hi, q)


def require_point(params: DeltaParams, p: object, *, what: str = "target") -> None:
    """Raise :class:`WorkspaceError` naming the point and the bound if ``p`` is not usable."""
    res = check_point(params, p)
    if not res.ok:
        raise WorkspaceError(f"{what} refused: {res.reason}")


def in_joint_box(params: DeltaParams, q: object) -> bool:
    """Eq. V.32: ``q_min <= q_i <= q_max`` for every axis."""
    qa = np.asarray(q, dtype=float)
    return bool(np.all(qa >= params.q_min) and np.all(qa <= params.q_max))


def require_path(params: DeltaParams, points: np.ndarray, *, what: str = "path") -> float:
    """Check every point of a sampled path against Eq. V.33.

    Returns
    -------
    float
        The smallest eigenvalue met along the path.

    Raises
    ------
    WorkspaceError
        At the first point outside, naming its index, the point and the bound.
    """
    lo = math.inf
    for k, p in enumerate(np.asarray(points, dtype=float)):
        res = check_point(params, p)
        if not res.ok:
            raise WorkspaceError(f"{what} refused at sample {k}: {res.reason}")
        lo = min(lo, res.min_eig)
    return lo


def slice_map(
    params: DeltaParams, z: float, *, half_width: float = 0.6, n: int = 61
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """det J^-1 scaled by ``l_a^3`` and the smallest eigenvalue of ``l_a^2 J^-T J^-1`` on
    an ``n x n`` grid of the horizontal slice at height ``z`` (Fig. 28).

    Returns ``xs, ys, det, min_eig`` with NaN where the point is out of reach.
    """
    xs = np.linspace(-half_width, half_width, n)
    ys = np.linspace(-half_width, half_width, n)
    det = np.full((n, n), np.nan)
    eig = np.full((n, n), np.nan)
    for iy, y in enumerate(ys):
        for ix, x in enumerate(xs):
            try:
                axes = ik_all(params, (x, y, z))
            except UnreachableError:
                continue
            ji = np.array([jinv_row(params, i, ax) for i, ax in enumerate(axes)]) * params.l_a
            det[iy, ix] = np.linalg.det(ji)
            eig[iy, ix] = np.linalg.eigvalsh(ji.T @ ji)[0]
    return xs, ys, det, eig


def box_min_eigenvalue(
    params: DeltaParams, q_min: float, q_max: float, *, n: int = 13
) -> float:
    """Smallest eigenvalue of ``l_a^2 J^-T J^-1`` over the joint box ``[q_min, q_max]^3``
    (Fig. 29), sampled on an ``n^3`` grid through the closed-form forward kinematics."""
    from .forward import fk_closed_form

    lo = math.inf
    grid = np.linspace(q_min, q_max, n)
    for a in grid:
        for b in grid:
            for c in grid:
                try:
                    p = fk_closed_form(params, (a, b, c))
                    lo = min(lo, float(stiffness_eigenvalues(params, p)[0]))
                except (UnreachableError, np.linalg.LinAlgError):
                    continue
    return lo
