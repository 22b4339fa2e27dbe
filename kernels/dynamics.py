"""Inverse dynamics of the Delta in the two spaces (thesis § V.5), derived again.

Derivation (docs/thesis-notes.md: the printed V.43-V.47 and V.49 are garbled)
-----------------------------------------------------------------
Forearm ``i`` is a thin rod of mass ``m_b`` and transverse inertia ``j_b`` about its centre
of mass, which lies at ``rho = g_b / l_b`` of its length from the arm tip. With ``vA`` the
arm-tip velocity ``l_a u_i qdot_i`` (``u_i = iR iv_perp``, Eq. V.23) and ``vB = pdot``::

    T_i = 1/2 (m_b (1-rho)^2 + j) |vA|^2 + 1/2 (m_b rho^2 + j) |vB|^2
          + (m_b rho (1-rho) - j) vA . vB,            j = j_b / l_b^2.

For ``rho = 1/2`` and ``j_b = m_b l_b^2 / 12`` this is ``(m_b/6)(|vA|^2 + vA.vB + |vB|^2)``.
Summing the arms (``j_a`` at the joint), forearms and platform (``m_c``)::

    T = 1/2 qA |qdot|^2 + 1/2 m_p |pdot|^2 + c sum_i qdot_i u_i . pdot,
    qA = j_a + l_a^2 (m_b (1-rho)^2 + j)                     (Eq. V.46 when j_b = m_b l_b^2/12)
    m_p = m_c + 3 (m_b rho^2 + j)
    c = l_a (m_b rho (1-rho) - j)

With ``qdot = J^-1 pdot`` the cross term is ``1/2 pdot^T c (U J^-1 + J^-T U^T) pdot``, so the
complete model in the two spaces (Eq. V.50) has

    qA (constant, diagonal), qC = 0,
    pA(p) = m_p I + c (U J^-1 + J^-T U^T)                    (replaces Eq. V.47)
    pC(p, pdot) = c d/dt(U J^-1) = c (Udot J^-1 + U d/dt(J^-1)),  Udot = -V diag(qdot)
                                                             (replaces Eq. V.49)

and ``d/dt pA - 2 pC = c (Ydot^T - Ydot)`` is skew-symmetric (``Y = U J^-1``, Theorem 3).
Lagrange's equations in (q, p) give the same torques in a form that splits per axis::

    tau = qA qddot + c U^T pddot + qg + J^T [m_p pddot + c (U qddot - V qdot^2) + pg]

which is what the distributed unit evaluates: the per-axis part ``qA qddot_i + c u_i.pddot +
qg_i`` and the per-axis contribution ``c (u_i qddot_i - v_i qdot_i^2)`` run on the
peripherals; the sum, ``m_p pddot + pg`` and the ``J^T`` mapping on the central.

Gravity (Eq. V.36-V.37): the potential energy is
``9.81 [(m_c + 3 m_b rho) p_z + sum_i (m_a g_a + m_b l_a (1-rho)) sin q_i]``.

Simplified model (Eq. V.39-V.42): each forearm lumped as two point masses, ``(1-rho) m_b``
at the arm tip and ``rho m_b`` at the platform, no cross term.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from .kinematics import (
    AxisIK,
    Vec3,
    arm_tip,
    arm_vectors,
    ik_all,
    inverse_jacobian,
    inverse_jacobian_dot,
    jacobian,
    jinv_row,
)
from .params import GRAVITY, DeltaParams

MODELS = ("complete", "simplified")


@dataclass(frozen=True)
class ModelCoefficients:
    """Constant coefficients of a dynamics model (see module docstring).

    Attributes
    ----------
    q_a : joint-space inertia ``qA`` (kg m^2), Eq. V.40 / V.46.
    m_p : operational-space mass on the diagonal of ``pA`` (kg), Eq. V.41 / V.47.
    c : coefficient of the arm-forearm coupling (kg m); 0 for the simplified model.
    q_g : joint gravity gain, ``qg_i = q_g cos q_i`` (N m), Eq. V.36.
    p_g : operational gravity force along z (N), Eq. V.37.
    """

    q_a: float
    m_p: float
    c: float
    q_g: float
    p_g: float


def coefficients(params: DeltaParams, model: str = "complete") -> ModelCoefficients:
    """Coefficients of the ``complete`` (Eq. V.46-V.50, re-derived) or ``simplified``
    (Eq. V.40-V.42) model."""
    rho = params.g_b / params.l_b
    q_g = GRAVITY * (params.m_a * params.g_a + params.m_b * params.l_a * (1.0 - rho))
    p_g = GRAVITY * (params.m_c + 3.0 * params.m_b * rho)
    if model == "complete":
        j = params.j_b / params.l_b**2
        return ModelCoefficients(
            q_a=params.j_a + params.l_a**2 * (params.m_b * (1.0 - rho) ** 2 + j),
            m_p=params.m_c + 3.0 * (params.m_b * rho**2 + j),
            c=params.l_a * (params.m_b * rho * (1.0 - rho) - j),
            q_g=q_g,
            p_g=p_g,
        )
    if model == "simplified":
        return ModelCoefficients(
            q_a=params.j_a + params.m_b * params.l_a**2 * (1.0 - rho),
            m_p=params.m_c + 3.0 * params.m_b * rho,
            c=0.0,
            q_g=q_g,
            p_g=p_g,
        )
    raise ValueError(f"model must be one of {MODELS}, got {model!r}")


# ---------------------------------------------------------------------------------------
# Per-axis blocks (floats)


class AxisDynamics(NamedTuple):
    """Per-axis part of the two-spaces model.

    Attributes
    ----------
    tau_q : ``qA qddot_i + c u_i . pddot + qg_i`` (N m).
    force : ``c (u_i qddot_i - v_i qdot_i^2)``, this chain's share of the operational
        force (N), world frame.
    """

    tau_q: float
    force: Vec3


def axis_dynamics(
    coef: ModelCoefficients,
    axis: int,
    ax: AxisIK,
    qdot_i: float,
    qddot_i: float,
    pddot: Vec3,
) -> AxisDynamics:
    """Joint-space part of the dynamics for one axis (``qA qddot_i + qg_i`` of Eq. V.42 /
    V.50, plus the coupling terms of the complete model, see the module docstring)."""
    (v0, v1, v2), (u0, u1, u2) = arm_vectors(axis, ax)
    c = coef.c
    tau_q = coef.q_a * qddot_i + coef.q_g * ax.vx  # cos q_i = vx
    if c == 0.0:
        return AxisDynamics(tau_q, (0.0, 0.0, 0.0))
    tau_q += c * (u0 * pddot[0] + u1 * pddot[1] + u2 * pddot[2])
    k = c * qdot_i * qdot_i
    cq = c * qddot_i
    return AxisDynamics(tau_q, (cq * u0 - k * v0, cq * u1 - k * v1, cq * u2 - k * v2))


def operational_force(coef: ModelCoefficients, pddot: Vec3, forces: list[Vec3]) -> Vec3:
    """Operational-space part: ``m_p pddot + pg + sum_i force_i`` (N), world frame."""
    fx = coef.m_p * pddot[0]
    fy = coef.m_p * pddot[1]
    fz = coef.m_p * pddot[2] + coef.p_g
    for f in forces:
        fx += f[0]
        fy += f[1]
        fz += f[2]
    return (fx, fy, fz)


# ---------------------------------------------------------------------------------------
# Whole-robot functions (numpy), for analysis and tests


def _vec(x: object, name: str) -> np.ndarray:
    a = np.asarray(x, dtype=float)
    if a.shape != (3,):
        raise ValueError(f"{name} must have shape (3,), got {a.shape}")
    return a


def joint_gravity(params: DeltaParams, q: object) -> np.ndarray:
    """``qg(q)`` (Eq. V.36), shape (3,), N m."""
    coef = coefficients(params)
    return coef.q_g * np.cos(_vec(q, "q"))


def operational_gravity(params: DeltaParams) -> np.ndarray:
    """``pg`` (Eq. V.37), shape (3,), N."""
    return np.array([0.0, 0.0, coefficients(params).p_g])


def gravity_torques(params: DeltaParams, p: object) -> np.ndarray:
    """Torques that hold the platform still at ``p``: ``qg(q) + J^T pg`` (Eq. V.38 with
    zero gains), shape (3,), N m."""
    p = _vec(p, "p")
    axes = ik_all(params, p)
    q = np.array([a.q for a in axes])
    return joint_gravity(params, q) + jacobian(params, p).T @ operational_gravity(params)


def _u_v(params: DeltaParams, p: np.ndarray) -> tuple[np.ndarray, np.ndarray, list[AxisIK]]:
    axes = list(ik_all(params, p))
    V = np.empty((3, 3))
    U = np.empty((3, 3))
    for i, ax in enumerate(axes):
        v, u = arm_vectors(i, ax)
        V[:, i] = v
        U[:, i] = u
    return U, V, axes


def inverse_dynamics(
    params: DeltaParams,
    p: object,
    pdot: object,
    pddot: object,
    *,
    model: str = "complete",
) -> np.ndarray:
    """Joint torques of the model in the two spaces (Eq. V.42 / V.50), shape (3,), N m.

    Uses the per-axis blocks exactly as the distributed unit does.
    """
    p, pdot, pddot = _vec(p, "p"), _vec(pdot, "pdot"), _vec(pddot, "pddot")
    coef = coefficients(params, model)
    axes = ik_all(params, p)
    pd = tuple(pdot.tolist())
    pdd = tuple(pddot.tolist())
    from .kinematics import accel_row, dot_row, jinvdot_pdot_row

    tau_q = np.empty(3)
    forces = []
    for i, ax in enumerate(axes):
        row = jinv_row(params, i, ax)
        qd = dot_row(row, pd)
        qdd = accel_row(row, pdd, jinvdot_pdot_row(params, i, ax, pd, qd))
        d = axis_dynamics(coef, i, ax, qd, qdd, pdd)
        tau_q[i] = d.tau_q
        forces.append(d.force)
    f = np.array(operational_force(coef, pdd, forces))
    return tau_q + jacobian(params, p).T @ f


class TwoSpaceModel(NamedTuple):
    """The matrices of Eq. V.50 at one state (complete model, re-derived)."""

    q_a: np.ndarray  # (3, 3)
    p_a: np.ndarray  # (3, 3)
    p_c: np.ndarray  # (3, 3)
    q_g: np.ndarray  # (3,)
    p_g: np.ndarray  # (3,)


def two_space_model(
    params: DeltaParams, p: object, pdot: object, *, model: str = "complete"
) -> TwoSpaceModel:
    """``qA``, ``pA(p)``, ``pC(p, pdot)``, ``qg``, ``pg`` of Eq. V.50 as matrices."""
    p, pdot = _vec(p, "p"), _vec(pdot, "pdot")
    coef = coefficients(params, model)
    U, V, axes = _u_v(params, p)
    Ji = inverse_jacobian(params, p)
    Jid = inverse_jacobian_dot(params, p, pdot)
    qdot = Ji @ pdot
    Y = U @ Ji
    Ydot = -V @ np.diag(qdot) @ Ji + U @ Jid
    p_a = coef.m_p * np.eye(3) + coef.c * (Y + Y.T)
    p_c = coef.c * Ydot
    q = np.array([a.q for a in axes])
    return TwoSpaceModel(
        coef.q_a * np.eye(3), p_a, p_c, coef.q_g * np.cos(q), np.array([0.0, 0.0, coef.p_g])
    )


class OperationalModel(NamedTuple):
    """Operational-space form ``u = M pddot + D pdot + h`` (Eq. III.43-III.44)."""

    M: np.ndarray  # (3, 3), "0A"
    C: np.ndarray  # (3, 3), "0C"
    h: np.ndarray  # (3,)


def operational_model(
    params: DeltaParams, p: object, pdot: object, *, model: str = "complete"
) -> OperationalModel:
    """``M = J^-T qA J^-1 + pA``, ``C = J^-T qA d/dt(J^-1) + pC``, ``h = J^-T qg + pg``
    (Eq. III.43-III.44), the force ``u = J^-T tau`` on the platform."""
    p, pdot = _vec(p, "p"), _vec(pdot, "pdot")
    m = two_space_model(params, p, pdot, model=model)
    Ji = inverse_jacobian(params, p)
    Jid = inverse_jacobian_dot(params, p, pdot)
    M = Ji.T @ m.q_a @ Ji + m.p_a
    C = Ji.T @ m.q_a @ Jid + m.p_c
    h = Ji.T @ m.q_g + m.p_g
    return OperationalModel(M, C, h)


# ---------------------------------------------------------------------------------------
# Energy from first principles (bodies, not the model's matrices)


def mechanical_energy(
    params: DeltaParams, q: object, qdot: object, p: object, pdot: object
) -> tuple[float, float]:
    """Kinetic and potential energy (J) of the bodies, from their own expressions.

    Arms: ``1/2 j_a qdot_i^2``, centre of mass at ``g_a``. Forearms: rigid rods between the
    arm tip and the platform joint, ``1/2 m_b |v_cm|^2 + 1/2 j_b |omega_perp|^2``. Platform:
    a point mass ``m_c``. Gravity along -z.
    """
    q, qdot, p, pdot = (_vec(x, n) for x, n in ((q, "q"), (qdot, "qdot"), (p, "p"), (pdot, "pdot")))
    rho = params.g_b / params.l_b
    ke = 0.5 * params.m_c * float(pdot @ pdot)
    pe = GRAVITY * params.m_c * p[2]
    for i in range(3):
        ke += 0.5 * params.j_a * qdot[i] ** 2
        pe += GRAVITY * params.m_a * params.g_a * math.sin(q[i])
        tip = np.array(arm_tip(params, i, q[i]))
        # arm tip velocity: d/dq of the tip times qdot
        c, s = math.cos(q[i]), math.sin(q[i])
        from .kinematics import to_world

        v_tip = np.array(to_world(i, -params.l_a * s, 0.0, params.l_a * c)) * qdot[i]
        v_cm = (1.0 - rho) * v_tip + rho * pdot
        omega_perp = (pdot - v_tip) / params.l_b  # rod axis rate (transverse part only)
        ke += 0.5 * params.m_b * float(v_cm @ v_cm)
        ke += 0.5 * params.j_b * float(omega_perp @ omega_perp)
        joint = p + np.array(to_world(i, params.r_b, 0.0, 0.0))
        pe += GRAVITY * params.m_b * ((1.0 - rho) * tip[2] + rho * joint[2])
    return ke, pe
