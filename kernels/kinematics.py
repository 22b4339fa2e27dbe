"""Delta kinematics in the two spaces (thesis § V.3), per axis and on plain floats.

Conventions (thesis Eq. V.7-V.15, docs/thesis-notes.md)
-------------------------------------------
* Chain ``i`` (0, 1, 2 here; 1, 2, 3 in the thesis) lives in an auxiliary frame rotated by
  ``gamma_i = 0, 120, 240 deg`` about z. ``ip = R_i^T p`` is the platform position in it.
* The arm unit vector is ``iv = (cos q_i, 0, sin q_i)`` (Eq. V.8), its derivative
  ``iv_perp = (-sin q_i, 0, cos q_i)`` (Eq. V.23).
* The forearm unit vector is ``iw = (ip - [r_r, 0, 0] - l_a iv) / l_b`` with
  ``r_r = r_a - r_b`` (Eq. V.14 as corrected in docs/thesis-notes.md: the arm term is ``l_a iv``).

Per-axis functions take and return floats: they are what a peripheral runs once per
interval and are 10-100x faster than numpy on 3-vectors. Whole-robot helpers return numpy
arrays for analysis.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from .params import DeltaParams

GAMMA = (0.0, 2.0 * math.pi / 3.0, 4.0 * math.pi / 3.0)
"""Angles of the three chains about z (thesis Table 7)."""
_COS = tuple(math.cos(g) for g in GAMMA)
_SIN = tuple(math.sin(g) for g in GAMMA)

Vec3 = tuple[float, float, float]
Mat3 = tuple[Vec3, Vec3, Vec3]


class UnreachableError(ValueError):
    """A platform position has no inverse kinematics solution."""


class AxisIK(NamedTuple):
    """Result of the inverse kinematics of one chain (Eq. V.16-V.21), auxiliary frame.

    Attributes
    ----------
    q : joint angle (rad).
    vx, vz : the arm unit vector ``iv = (vx, 0, vz)``.
    wx, wy, wz : the forearm unit vector ``iw``.
    ipx, ipy, ipz : the platform position in the auxiliary frame.
    """

    q: float
    vx: float
    vz: float
    wx: float
    wy: float
    wz: float
    ipx: float
    ipy: float
    ipz: float


def to_local(axis: int, x: float, y: float, z: float) -> Vec3:
    """``iR^T v`` (Eq. V.12): a world vector in the auxiliary frame of ``axis``."""
    c, s = _COS[axis], _SIN[axis]
    return (c * x + s * y, -s * x + c * y, z)


def to_world(axis: int, x: float, y: float, z: float) -> Vec3:
    """``iR v`` (Eq. V.7): a vector of the auxiliary frame of ``axis`` in the world frame."""
    c, s = _COS[axis], _SIN[axis]
    return (c * x - s * y, s * x + c * y, z)


def ik_axis(params: DeltaParams, axis: int, x: float, y: float, z: float) -> AxisIK:
    """Inverse kinematics of one chain (Eq. V.16-V.21, minus root of V.20 per errata).

    Parameters
    ----------
    params : robot parameters.
    axis : chain index 0, 1 or 2.
    x, y, z : platform position in the world frame (m).

    Returns
    -------
    AxisIK
        ``q_i`` and the unit vectors the Jacobian blocks reuse.

    Raises
    ------
    UnreachableError
        If the point is out of reach of this chain.
    """
    l_a, l_b = params.l_a, params.l_b
    c, s = _COS[axis], _SIN[axis]
    ipx = c * x + s * y
    ipy = -s * x + c * y
    ipz = z
    a = ipx - (params.r_a - params.r_b)
    n2 = a * a + ipz * ipz
    l_c = (l_a * l_a - l_b * l_b + n2 + ipy * ipy) / (2.0 * l_a)  # Eq. V.17
    disc = n2 - l_c * l_c
    # not (disc >= 0): also a NaN, when a point so far away overflows the squares
    if not 0.0 <= disc < math.inf or n2 == 0.0:
        raise UnreachableError(
            f"point ({x:.6g}, {y:.6g}, {z:.6g}) m is out of reach of chain {axis + 1}: "
            f"the forearm (l_b = {l_b} m) cannot close the loop"
        )
    root = math.sqrt(disc)
    vx = (l_c * a - ipz * root) / n2  # Eq. V.20, minus root
    vz = (l_c * ipz + a * root) / n2  # the matching root of V.18-V.19
    wx = (a - l_a * vx) / l_b  # Eq. V.14 (errata)
    wy = ipy / l_b
    wz = (ipz - l_a * vz) / l_b
    return AxisIK(math.atan2(vz, vx), vx, vz, wx, wy, wz, ipx, ipy, ipz)  # Eq. V.21


def x_diag(ax: AxisIK) -> float:
    """Diagonal element ``X_ii = iw . iv_perp`` (Eq. V.25)."""
    return -ax.wx * ax.vz + ax.wz * ax.vx


def jinv_row(params: DeltaParams, axis: int, ax: AxisIK) -> Vec3:
    """Row ``axis`` of the inverse Jacobian, ``(1/l_a) X_ii^-1 (iR iw)^T`` (Eq. V.24-V.26).

    Returns
    -------
    tuple of 3 floats
        ``dq_i/dp`` in the world frame (rad/m).
    """
    k = 1.0 / (params.l_a * x_diag(ax))
    wx, wy, wz = to_world(axis, ax.wx, ax.wy, ax.wz)
    return (k * wx, k * wy, k * wz)


def jinvdot_pdot_row(
    params: DeltaParams, axis: int, ax: AxisIK, pdot: Vec3, qdot_i: float
) -> float:
    """Row ``axis`` of ``d/dt(J^-1) . pdot`` (Eq. V.28-V.30 as corrected in docs/thesis-notes.md).

    ``iwdot = (ipdot - l_a iv_perp qdot_i) / l_b``,
    ``Xdot_ii = iwdot . iv_perp - (iw . iv) qdot_i`` and
    ``row = (iwdot . ipdot X_ii - Xdot_ii (iw . ipdot)) / (l_a X_ii^2)``.

    Parameters
    ----------
    pdot : platform velocity, world frame (m/s).
    qdot_i : joint velocity of this chain (rad/s), ``J^-1 pdot`` row ``axis``.
    """
    l_a, l_b = params.l_a, params.l_b
    dx, dy, dz = to_local(axis, pdot[0], pdot[1], pdot[2])
    vx, vz = ax.vx, ax.vz
    # iv_perp = (-vz, 0, vx)
    wdx = (dx + l_a * vz * qdot_i) / l_b
    wdy = dy / l_b
    wdz = (dz - l_a * vx * qdot_i) / l_b
    xii = -ax.wx * vz + ax.wz * vx
    xdot = (-wdx * vz + wdz * vx) - (ax.wx * vx + ax.wz * vz) * qdot_i
    wdot_p = wdx * dx + wdy * dy + wdz * dz
    w_p = ax.wx * dx + ax.wy * dy + ax.wz * dz
    return (wdot_p * xii - xdot * w_p) / (l_a * xii * xii)


def accel_row(row: Vec3, pddot: Vec3, jdp_i: float) -> float:
    """Acceleration mapper, one row: ``qddot_i = J^-1_i . pddot + (dJ^-1/dt . pdot)_i``
    (Eq. V.31)."""
    return row[0] * pddot[0] + row[1] * pddot[1] + row[2] * pddot[2] + jdp_i


def dot_row(row: Vec3, v: Vec3) -> float:
    """``row . v`` for a 3-vector (e.g. ``qdot_i = J^-1_i . pdot``)."""
    return row[0] * v[0] + row[1] * v[1] + row[2] * v[2]


def arm_vectors(axis: int, ax: AxisIK) -> tuple[Vec3, Vec3]:
    """World-frame arm unit vector ``v_i = iR iv`` and its derivative ``u_i = iR iv_perp``."""
    return to_world(axis, ax.vx, 0.0, ax.vz), to_world(axis, -ax.vz, 0.0, ax.vx)


# ---------------------------------------------------------------------------------------
# 3x3 helpers on floats (the central's sequential blocks)


def inv3(m: Mat3) -> Mat3:
    """Inverse of a 3x3 matrix by its adjugate (used for ``J = (J^-1)^-1``, Eq. V.27).

    Raises
    ------
    ZeroDivisionError
        If the matrix is exactly singular.
    """
    (a, b, c), (d, e, f), (g, h, i) = m
    A = e * i - f * h
    B = f * g - d * i
    C = d * h - e * g
    det = a * A + b * B + c * C
    k = 1.0 / det
    return (
        (A * k, (c * h - b * i) * k, (b * f - c * e) * k),
        (B * k, (a * i - c * g) * k, (c * d - a * f) * k),
        (C * k, (b * g - a * h) * k, (a * e - b * d) * k),
    )


def matvec3(m: Mat3, v: Vec3) -> Vec3:
    """``m . v`` for 3x3 ``m`` and 3-vector ``v``."""
    return (
        m[0][0] * v[0] + m[0][1] * v[1] + m[0][2] * v[2],
        m[1][0] * v[0] + m[1][1] * v[1] + m[1][2] * v[2],
        m[2][0] * v[0] + m[2][1] * v[1] + m[2][2] * v[2],
    )


def matTvec3(m: Mat3, v: Vec3) -> Vec3:
    """``m^T . v`` for 3x3 ``m`` and 3-vector ``v``."""
    return (
        m[0][0] * v[0] + m[1][0] * v[1] + m[2][0] * v[2],
        m[0][1] * v[0] + m[1][1] * v[1] + m[2][1] * v[2],
        m[0][2] * v[0] + m[1][2] * v[1] + m[2][2] * v[2],
    )


# ---------------------------------------------------------------------------------------
# Whole-robot helpers (numpy in, numpy out)


def _as_point(p: object, name: str = "p") -> tuple[float, float, float]:
    arr = np.asarray(p, dtype=float)
    if arr.shape != (3,):
        raise ValueError(f"{name} must have shape (3,), got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite, got {arr.tolist()}")
    return float(arr[0]), float(arr[1]), float(arr[2])


def ik_all(params: DeltaParams, p: object) -> tuple[AxisIK, AxisIK, AxisIK]:
    """Per-axis inverse kinematics of the three chains at ``p`` (shape (3,))."""
    x, y, z = _as_point(p)
    return (ik_axis(params, 0, x, y, z), ik_axis(params, 1, x, y, z), ik_axis(params, 2, x, y, z))


def inverse_kinematics(params: DeltaParams, p: object) -> np.ndarray:
    """Joint angles ``q = f^-1(p)`` (Eq. V.16-V.21), shape (3,), radians."""
    return np.array([ax.q for ax in ik_all(params, p)])


def inverse_jacobian(params: DeltaParams, p: object) -> np.ndarray:
    """``J^-1(p) = (1/l_a) X^-1 W^T`` (Eq. V.26), shape (3, 3), ``dq/dp``."""
    axes = ik_all(params, p)
    return np.array([jinv_row(params, i, ax) for i, ax in enumerate(axes)])


def jacobian(params: DeltaParams, p: object) -> np.ndarray:
    """``J(p) = (J^-1)^-1`` (Eq. V.27), shape (3, 3), ``dp/dq``."""
    return np.linalg.inv(inverse_jacobian(params, p))


def inverse_jacobian_dot(params: DeltaParams, p: object, pdot: object) -> np.ndarray:
    """The matrix ``d/dt J^-1`` (Eq. V.28), shape (3, 3), at position ``p`` and velocity
    ``pdot``."""
    axes = ik_all(params, p)
    pd = _as_point(pdot, "pdot")
    out = np.empty((3, 3))
    for i, ax in enumerate(axes):
        row = jinv_row(params, i, ax)
        qd = dot_row(row, pd)
        dx, dy, dz = to_local(i, *pd)
        wd = np.array([(dx + params.l_a * ax.vz * qd), dy, (dz - params.l_a * ax.vx * qd)])
        wd /= params.l_b
        xii = x_diag(ax)
        xdot = (-wd[0] * ax.vz + wd[2] * ax.vx) - (ax.wx * ax.vx + ax.wz * ax.vz) * qd
        w_world = np.array(to_world(i, ax.wx, ax.wy, ax.wz))
        wd_world = np.array(to_world(i, *wd))
        out[i] = (wd_world * xii - xdot * w_world) / (params.l_a * xii * xii)
    return out


def jinvdot_pdot(params: DeltaParams, p: object, pdot: object) -> np.ndarray:
    """``d/dt(J^-1) . pdot`` (Eq. V.28-V.30), shape (3,), from the per-axis kernel."""
    axes = ik_all(params, p)
    pd = _as_point(pdot, "pdot")
    out = np.empty(3)
    for i, ax in enumerate(axes):
        qd = dot_row(jinv_row(params, i, ax), pd)
        out[i] = jinvdot_pdot_row(params, i, ax, pd, qd)
    return out


def joint_accelerations(params: DeltaParams, p: object, pdot: object, pddot: object) -> np.ndarray:
    """``qddot = J^-1 pddot + d/dt(J^-1) pdot`` (Eq. V.31), shape (3,)."""
    axes = ik_all(params, p)
    pd = _as_point(pdot, "pdot")
    pdd = _as_point(pddot, "pddot")
    out = np.empty(3)
    for i, ax in enumerate(axes):
        row = jinv_row(params, i, ax)
        out[i] = accel_row(row, pdd, jinvdot_pdot_row(params, i, ax, pd, dot_row(row, pd)))
    return out


def arm_tip(params: DeltaParams, axis: int, q: float) -> Vec3:
    """World position of the tip of arm ``axis`` at joint angle ``q`` (Eq. V.10)."""
    return to_world(axis, params.r_a + params.l_a * math.cos(q), 0.0, params.l_a * math.sin(q))
