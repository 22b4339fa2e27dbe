"""Control laws as blocks that per-axis and central code can split (thesis § IV.3, V.5).

Every law is written with acceleration-level gains ``kp`` (1/s^2) and ``kd`` (1/s), so
that laws with and without a model can be compared "with the same gains": the model-free
PD scales its feedback by a constant nominal joint inertia ``a0``
(:func:`nominal_joint_inertia`).

=======================  ============================================================
law                      torque
=======================  ============================================================
``pd``                   ``a0 (kp q~ + kd q~dot)``: no model terms (reference)
``pd-gravity``           ``a0 (kp q~ + kd q~dot) + qg(q) + J^T pg``              (V.38)
``pd-feedforward``       model at the reference state ``+ a0 (kp q~ + kd q~dot)`` (IV.13)
``computed-torque``      model at the measured state with
                         ``qddot* = qddot_c + kp q~ + kd q~dot``                 (Fig. 18)
``resolved-acceleration`` model at the measured state with
                         ``pddot* = pddot_c + kp p~ + kd p~dot``                 (IV.14)
=======================  ============================================================

``q~ = q_c - q``; the joint reference ``q_c, qdot_c, qddot_c`` is the inverse kinematics of
the operational reference (Eq. V.16-V.31), computed per axis.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from .dynamics import coefficients
from .kinematics import Vec3, ik_all, inv3, jinv_row
from .params import DeltaParams

LAWS = ("resolved-acceleration", "computed-torque", "pd-feedforward", "pd-gravity", "pd")


@dataclass(frozen=True)
class Gains:
    """Acceleration-level PD gains: ``kp = w^2``, ``kd = 2 zeta w`` by default.

    Attributes
    ----------
    kp : stiffness gain (1/s^2).
    kd : damping gain (1/s).
    """

    kp: float
    kd: float

    @classmethod
    def from_bandwidth(cls, hz: float = 20.0, zeta: float = 1.0) -> Gains:
        """Critically damped gains for a closed-loop natural frequency of ``hz``."""
        if not (0.0 < hz <= 1000.0):
            raise ValueError(f"bandwidth must be in (0, 1000] Hz, got {hz!r}")
        if not (0.0 < zeta <= 10.0):
            raise ValueError(f"zeta must be in (0, 10], got {zeta!r}")
        w = 2.0 * math.pi * hz
        return cls(w * w, 2.0 * zeta * w)


DEFAULT_GAINS = Gains.from_bandwidth(20.0, 1.0)


def nominal_joint_inertia(params: DeltaParams) -> float:
    """Constant joint inertia ``a0`` (kg m^2) that scales the model-free PD: the mean
    diagonal of ``qA + J^T pA J`` of the simplified model (Eq. V.40-V.41) at the centre of
    the workspace, ``p = (0, 0, -0.35)`` m scaled to the robot size."""
    z = -(params.l_b * 0.5 + params.l_a * 0.4)
    axes = ik_all(params, (0.0, 0.0, z))
    j = inv3(tuple(jinv_row(params, i, ax) for i, ax in enumerate(axes)))  # type: ignore[arg-type]
    coef = coefficients(params, "simplified")
    diag = [coef.q_a + coef.m_p * sum(j[r][k] ** 2 for r in range(3)) for k in range(3)]
    return sum(diag) / 3.0


def operational_command(
    gains: Gains, p_c: Vec3, v_c: Vec3, a_c: Vec3, p: Vec3, pdot: Vec3
) -> Vec3:
    """Resolved-acceleration command ``pddot* = pddot_c + kp (p_c - p) + kd (pdot_c - pdot)``
    (Eq. IV.14, second line)."""
    kp, kd = gains.kp, gains.kd
    return (
        a_c[0] + kp * (p_c[0] - p[0]) + kd * (v_c[0] - pdot[0]),
        a_c[1] + kp * (p_c[1] - p[1]) + kd * (v_c[1] - pdot[1]),
        a_c[2] + kp * (p_c[2] - p[2]) + kd * (v_c[2] - pdot[2]),
    )


def joint_command(
    gains: Gains, q_c: float, qd_c: float, qdd_c: float, q: float, qd: float
) -> float:
    """Computed-torque joint acceleration command for one axis (Fig. 18):
    ``qddot* = qddot_c + kp (q_c - q) + kd (qdot_c - qdot)``."""
    return qdd_c + gains.kp * (q_c - q) + gains.kd * (qd_c - qd)


def joint_pd(gains: Gains, a0: float, q_c: float, qd_c: float, q: float, qd: float) -> float:
    """Joint PD torque for one axis, ``a0 (kp q~ + kd q~dot)`` (N m)."""
    return a0 * (gains.kp * (q_c - q) + gains.kd * (qd_c - qd))


def saturate(tau: Vec3, limit: float) -> Vec3:
    """Clamp each torque to ``[-limit, limit]`` (N m)."""
    return (
        min(max(tau[0], -limit), limit),
        min(max(tau[1], -limit), limit),
        min(max(tau[2], -limit), limit),
    )
