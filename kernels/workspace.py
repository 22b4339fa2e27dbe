"""Usable workspace of the Delta (thesis § V.4.2).

* Eq. V.33: the eigenvalues of ``l_a^2 J^-T J^-1`` (dimensionless; ``= W X^-2 W^T``) stay
  within ``[beta_min, beta_max]``, plus reachability. This is the definition used to accept
  or refuse targets and paths.
* Eq. V.32: the joint box ``q_min <= q_i <= q_max``, only a conservative inner
  approximation (docs/thesis-notes.md: the circle task leaves the box yet stays in V.33).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from .kinematics import UnreachableError, ik_all, jinv_row
from .params import DeltaParams


class WorkspaceError(ValueError):
    """A point lies outside the usable workspace; the message names the point and bound."""


def sym3_eigenvalues(a11: float, a12: float, a13: float, a22: float, a23: float,
                     a33: float) -> tuple[float, float, float]:
    """Eigenvalues of the symmetric 3x3 matrix ``[[a11, a12, a13], [., a22, a23],
    [., ., a33]]``, ascending, in closed form (trigonometric solution of the
    characteristic cubic, O. K. Smith, Comm. ACM 4(4), 1961).

    Plain floats: about 2 us against 40 us for ``numpy.linalg.eigvalsh`` on one matrix
    (the central checks the state with it every 10th interval). Absolute error about
    ``1e-15`` times the largest eigenvalue magnitude, up to ``1e-8`` times it where two
    eigenvalues (nearly) coincide (``acos`` near +-1): far below what the bounds of
    Eq. V.33 resolve. A property test compares it with ``eigvalsh``. Entries must lie
    within about 1e-150 to 1e150 in magnitude (their squares are summed).
    """
    p1 = a12 * a12 + a13 * a13 + a23 * a23
    q = (a11 + a22 + a33) / 3.0
    d11, d22, d33 = a11 - q, a22 - q, a33 - q
    p2 = d11 * d11 + d22 * d22 + d33 * d33 + 2.0 * p1
    if p2 == 0.0:  # a multiple of the identity
        return (q, q, q)
    p = math.sqrt(p2 / 6.0)
    # B = (A - q I) / p has entries of order 1 (no over- or underflow in its determinant);
    # r = det(B) / 2 lies in [-1, 1] up to rounding
    b11, b22, b33, b12, b13, b23 = d11 / p, d22 / p, d33 / p, a12 / p, a13 / p, a23 / p
    det = (b11 * (b22 * b33 - b23 * b23) - b12 * (b12 * b33 - b23 * b13)
           + b13 * (b12 * b23 - b22 * b13))
    r = max(-1.0, min(1.0, 0.5 * det))
    phi = math.acos(r) / 3.0
    hi = q + 2.0 * p * math.cos(phi)
    lo = q + 2.0 * p * math.cos(phi + 2.0 * math.pi / 3.0)
    return (lo, 3.0 * q - hi - lo, hi)


def _stiffness(params: DeltaParams, axes: tuple) -> tuple[float, float, float]:
    """Eigenvalues of ``l_a^2 J^-T J^-1`` from the chains' inverse kinematics (Eq. V.33)."""
    r = [jinv_row(params, i, ax) for i, ax in enumerate(axes)]
    la2 = params.l_a * params.l_a

    def g(j: int, k: int) -> float:  # (J^-T J^-1)_jk = sum_i row_i[j] row_i[k]
        return la2 * (r[0][j] * r[0][k] + r[1][j] * r[1][k] + r[2][j] * r[2][k])

    return sym3_eigenvalues(g(0, 0), g(0, 1), g(0, 2), g(1, 1), g(1, 2), g(2, 2))


def stiffness_eigenvalues(params: DeltaParams, p: object) -> np.ndarray:
    """Eigenvalues of ``l_a^2 J^-T J^-1`` at ``p`` (Eq. V.33), ascending, shape (3,).

    Raises
    ------
    UnreachableError
        If ``p`` is out of reach.
    """
    return np.array(_stiffness(params, ik_all(params, p)))


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
    lo, _, hi = _stiffness(params, axes)
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
