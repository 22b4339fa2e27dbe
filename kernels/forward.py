"""Forward kinematics of the Delta: the Newton-Raphson observer (Eq. II.20) and the
closed-form three-sphere intersection used as a test oracle.

The Newton-Raphson step, as corrected in docs/thesis-notes.md, is ``p <- p - J (f^-1(p) - q_meas)``:
the residual of the inverse kinematics at the current estimate, mapped back through the
Jacobian.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from .kinematics import (
    Mat3,
    UnreachableError,
    Vec3,
    arm_tip,
    ik_axis,
    inv3,
    jinv_row,
    matvec3,
    to_world,
)
from .params import DeltaParams


class NewtonResult(NamedTuple):
    """Outcome of :func:`fk_newton`.

    Attributes
    ----------
    p : the position estimate (m).
    jinv : ``J^-1`` rows evaluated at the last linearisation point.
    j : ``J`` at the last linearisation point (used for ``pdot = J qdot``).
    iterations : iterations done.
    residual : ``max_i |f^-1(p)_i - q_i|`` at the last linearisation point (rad), i.e.
        before the last update.
    """

    p: Vec3
    jinv: Mat3
    j: Mat3
    iterations: int
    residual: float


def newton_step(
    params: DeltaParams, p: Vec3, q_meas: Vec3
) -> tuple[Vec3, Mat3, Mat3, float]:
    """One Newton-Raphson iteration of Eq. II.20 (errata sign).

    Returns the updated position, ``J^-1`` and ``J`` at the input position, and the largest
    residual ``|f^-1(p)_i - q_meas_i|`` at the input position.
    """
    rows = []
    dq = []
    for i in range(3):
        ax = ik_axis(params, i, p[0], p[1], p[2])
        rows.append(jinv_row(params, i, ax))
        dq.append(ax.q - q_meas[i])
    jinv: Mat3 = (rows[0], rows[1], rows[2])
    j = inv3(jinv)
    step = matvec3(j, (dq[0], dq[1], dq[2]))
    new_p = (p[0] - step[0], p[1] - step[1], p[2] - step[2])
    return new_p, jinv, j, max(abs(d) for d in dq)


def fk_newton(
    params: DeltaParams,
    q_meas: object,
    p0: object,
    *,
    iterations: int = 2,
    tol: float | None = None,
    max_iterations: int = 50,
) -> NewtonResult:
    """Forward kinematics by Newton-Raphson from the initial estimate ``p0`` (Eq. II.20).

    Parameters
    ----------
    q_meas : measured joint angles, shape (3,), rad.
    p0 : initial position estimate, shape (3,), m (the previous sample, or a prediction).
    iterations : fixed iteration count ``n_s`` when ``tol`` is None.
    tol : if given, iterate until the residual falls below ``tol`` (rad), e.g. one encoder
        increment ``params.increment``, then do one last update; at most ``max_iterations``.

    Raises
    ------
    UnreachableError
        If an iterate leaves the reachable space.
    ValueError
        On a bad shape or a non-positive iteration count.
    """
    q = tuple(float(v) for v in np.asarray(q_meas, dtype=float).reshape(-1))
    p = tuple(float(v) for v in np.asarray(p0, dtype=float).reshape(-1))
    if len(q) != 3 or len(p) != 3:
        raise ValueError(f"q_meas and p0 must have shape (3,), got {len(q)} and {len(p)}")
    if iterations < 1:
        raise ValueError(f"iterations must be >= 1, got {iterations}")
    limit = iterations if tol is None else max_iterations
    jinv = j = None
    res = math.inf
    done = 0
    for _ in range(limit):
        p, jinv, j, res = newton_step(params, p, q)
        done += 1
        if tol is not None and res < tol:
            break
    assert jinv is not None and j is not None
    return NewtonResult(p, jinv, j, done, res)


def fk_closed_form(params: DeltaParams, q: object) -> np.ndarray:
    """Forward kinematics by intersecting three spheres (test oracle).

    Each forearm constrains the platform centre to a sphere of radius ``l_b`` centred at the
    arm tip moved inward by ``r_b``; of the two intersections the lower one (z smaller) is
    the working configuration.

    Raises
    ------
    UnreachableError
        If the spheres do not intersect.
    """
    qa = np.asarray(q, dtype=float)
    if qa.shape != (3,):
        raise ValueError(f"q must have shape (3,), got {qa.shape}")
    centres = []
    for i in range(3):
        tip = arm_tip(params, i, float(qa[i]))
        shift = to_world(i, params.r_b, 0.0, 0.0)
        centres.append(np.array(tip) - np.array(shift))
    c1, c2, c3 = centres
    r = params.l_b
    ex = c2 - c1
    d = np.linalg.norm(ex)
    ex = ex / d
    i_ = ex @ (c3 - c1)
    ey = c3 - c1 - i_ * ex
    ey = ey / np.linalg.norm(ey)
    ez = np.cross(ex, ey)
    j_ = ey @ (c3 - c1)
    x = d / 2.0  # equal radii
    y = (i_ * i_ + j_ * j_) / (2.0 * j_) - (i_ / j_) * x
    h2 = r * r - x * x - y * y
    if h2 < 0.0:
        raise UnreachableError(f"joint angles {qa.tolist()} rad do not close the three loops")
    h = math.sqrt(h2)
    a = c1 + x * ex + y * ey + h * ez
    b = c1 + x * ex + y * ey - h * ez
    return a if a[2] < b[2] else b


__all__ = ["NewtonResult", "UnreachableError", "fk_closed_form", "fk_newton", "newton_step"]
