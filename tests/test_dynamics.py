"""The complete model (re-derived), checked by energy balance and Theorems 1-3."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import joint_angles, usable_point_from_q, velocities
from ctrlunit.kernels.dynamics import (
    coefficients,
    gravity_torques,
    inverse_dynamics,
    mechanical_energy,
    operational_model,
    two_space_model,
)
from ctrlunit.kernels.kinematics import inverse_jacobian, inverse_kinematics, jacobian
from ctrlunit.kernels.params import DELTA_IA as P
from ctrlunit.kernels.trajectory import circle_task, pick_place_task
from hypothesis import assume, given, settings


def test_qa_equals_eq_v46_when_jb_is_a_thin_rod():
    thin = P.with_(j_b=P.m_b * P.l_b**2 / 12)
    assert np.isclose(coefficients(thin).q_a, thin.j_a + thin.m_b * thin.l_a**2 / 3)
    # and then the complete qA equals the simplified one with g_b/l_b = 2/3 (§ V.5.4)
    codourey = thin.with_(g_b=2 * thin.l_b / 3)
    assert np.isclose(coefficients(thin).q_a, coefficients(codourey, "simplified").q_a)


def test_power_equals_rate_of_energy_along_circle_task():
    """u . pdot = tau . qdot = d/dt (T + V), energy from the bodies' own expressions."""
    task = circle_task()

    def energy(t):
        p, v, _ = task.sample_path(t)
        q = inverse_kinematics(P, p)
        qd = inverse_jacobian(P, p) @ v
        return sum(mechanical_energy(P, q, qd, p, v))

    worst = 0.0
    h = 1e-5
    for t in np.linspace(0.01, task.duration - 0.01, 60):
        p, v, a = task.sample_path(t)
        tau = inverse_dynamics(P, p, v, a)
        power = tau @ (inverse_jacobian(P, p) @ v)
        # fourth-order central difference of the energy
        de = (-energy(t + 2 * h) + 8 * energy(t + h) - 8 * energy(t - h) + energy(t - 2 * h)) / (
            12 * h
        )
        worst = max(worst, abs(power - de) / max(abs(power), 1.0))
    print(f"worst relative power/energy-rate mismatch along circle: {worst:.2e}")
    assert worst < 1e-6


@settings(max_examples=300, deadline=None)
@given(q=joint_angles, v=velocities)
def test_operational_inertia_is_spd_and_adot_minus_2c_is_skew(q, v):
    p = usable_point_from_q(q)
    assume(p is not None)
    v = np.array(v)
    om = operational_model(P, p, v)
    assert np.allclose(om.M, om.M.T, atol=1e-12)
    assert np.linalg.eigvalsh(om.M)[0] > 0.0
    h = 1e-5

    def d4(f):  # fourth-order central difference along v
        return (-f(p + 2 * h * v) + 8 * f(p + h * v) - 8 * f(p - h * v) + f(p - 2 * h * v)) / (
            12 * h
        )

    Mdot = d4(lambda x: operational_model(P, x, v).M)
    scale = np.abs(om.M).max() * np.linalg.norm(v) / P.l_a  # natural size of dM/dt
    S = Mdot - 2 * om.C
    assert np.abs(S + S.T).max() <= 1e-6 * scale + 1e-9
    m2 = two_space_model(P, p, v)
    Adot = d4(lambda x: two_space_model(P, x, v).p_a)
    S2 = Adot - 2 * m2.p_c
    assert np.abs(S2 + S2.T).max() <= 1e-6 * np.abs(m2.p_a).max() * np.linalg.norm(v) / P.l_a + 1e-9


@settings(max_examples=100, deadline=None)
@given(q=joint_angles, v=velocities)
def test_two_space_and_operational_forms_give_the_same_torques(q, v):
    p = usable_point_from_q(q)
    assume(p is not None)
    v, a = np.array(v), np.array([3.0, -1.0, 7.0])
    m = two_space_model(P, p, v)
    Ji = inverse_jacobian(P, p)
    from ctrlunit.kernels.kinematics import joint_accelerations

    qdd = joint_accelerations(P, p, v, a)
    tau_two = m.q_a @ qdd + m.q_g + jacobian(P, p).T @ (m.p_a @ a + m.p_c @ v + m.p_g)
    om = operational_model(P, p, v)
    tau_op = jacobian(P, p).T @ (om.M @ a + om.C @ v + om.h)
    tau_blocks = inverse_dynamics(P, p, v, a)
    assert np.allclose(tau_two, tau_blocks, rtol=1e-9, atol=1e-9)
    assert np.allclose(tau_op, tau_blocks, rtol=1e-9, atol=1e-9)
    assert Ji.shape == (3, 3)


def test_gravity_torques_are_static_equilibrium_by_virtual_work():
    """tau . dq = dV for a small motion, V from the bodies."""
    p = np.array([0.05, 0.08, -0.42])
    tau = gravity_torques(P, p)
    for e in np.eye(3):
        h = 1e-6
        pp, pm = p + h * e, p - h * e
        vp = mechanical_energy(P, inverse_kinematics(P, pp), np.zeros(3), pp, np.zeros(3))[1]
        vm = mechanical_energy(P, inverse_kinematics(P, pm), np.zeros(3), pm, np.zeros(3))[1]
        dq = inverse_kinematics(P, pp) - inverse_kinematics(P, pm)
        assert np.isclose(tau @ dq, vp - vm, rtol=1e-6)


@pytest.mark.parametrize("task", [pick_place_task(), circle_task()], ids=lambda t: t.name)
def test_simplified_versus_complete_torques_are_reported(task):
    ts = np.linspace(0.0, task.duration, 400)
    tc = np.array([inverse_dynamics(P, *task.sample_path(t)) for t in ts])
    tsim = np.array([inverse_dynamics(P, *task.sample_path(t), model="simplified") for t in ts])
    diff = np.abs(tc - tsim).max()
    peak = np.abs(tc).max()
    print(f"{task.name}: peak |tau| complete {peak:.2f} N m, max |complete - simplified| "
          f"{diff:.3f} N m ({100 * diff / peak:.1f} % of peak)")
    assert 0.0 < diff < 0.25 * peak  # a few percent to some tens of percent, not zero
