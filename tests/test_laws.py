"""The laws' small pieces at their edges: gains from a bandwidth, the nominal inertia of
the model-free PD, saturation. (The torques themselves: tests/test_law_oracles.py.)"""

from __future__ import annotations

import math

import numpy as np
import pytest
from ctrlunit.kernels.dynamics import coefficients
from ctrlunit.kernels.kinematics import jacobian
from ctrlunit.kernels.laws import (
    DEFAULT_GAINS,
    Gains,
    joint_command,
    joint_pd,
    nominal_joint_inertia,
    operational_command,
    saturate,
)
from ctrlunit.kernels.params import DELTA_IA as P


@pytest.mark.parametrize(("hz", "zeta"), [(20.0, 1.0), (1000.0, 10.0), (0.5, 0.05), (7.0, 0.7)])
def test_gains_from_a_bandwidth_are_w_squared_and_two_zeta_w(hz, zeta):
    g = Gains.from_bandwidth(hz, zeta)
    w = 2.0 * math.pi * hz
    assert g.kp == w * w and g.kd == 2.0 * zeta * w


def test_default_gains_are_20_hz_critically_damped():
    w = 2.0 * math.pi * 20.0
    assert DEFAULT_GAINS == Gains(w * w, 2.0 * w)
    assert Gains.from_bandwidth() == DEFAULT_GAINS


@pytest.mark.parametrize("hz", [0.0, -1.0, math.nextafter(1000.0, math.inf), math.nan,
                                math.inf])
def test_a_bandwidth_outside_0_to_1000_hz_is_refused_by_name(hz):
    with pytest.raises(ValueError, match=r"bandwidth must be in \(0, 1000\] Hz, got"):
        Gains.from_bandwidth(hz)


@pytest.mark.parametrize("zeta", [0.0, -0.5, math.nextafter(10.0, math.inf), math.nan])
def test_a_damping_outside_0_to_10_is_refused_by_name(zeta):
    with pytest.raises(ValueError, match=r"zeta must be in \(0, 10\], got"):
        Gains.from_bandwidth(20.0, zeta)


def test_nominal_inertia_is_the_mean_diagonal_of_the_simplified_joint_inertia():
    """``qA I + J^T m_p J`` (Eq. V.40-V.41) at the workspace centre, with the numpy
    Jacobian (not the per-axis rows the law uses)."""
    z = -(P.l_b * 0.5 + P.l_a * 0.4)
    j = jacobian(P, (0.0, 0.0, z))
    coef = coefficients(P, "simplified")
    m = coef.q_a * np.eye(3) + coef.m_p * j.T @ j
    assert nominal_joint_inertia(P) == pytest.approx(float(np.trace(m)) / 3.0, rel=1e-12)
    assert nominal_joint_inertia(P) > coef.q_a


def test_the_command_laws_are_their_equations():
    g = Gains(kp=4.0, kd=3.0)
    assert operational_command(g, (1, 2, 3), (4, 5, 6), (7, 8, 9), (0.5, 1.5, 2.0),
                               (1.0, 2.0, 7.0)) == (
        7 + 4 * 0.5 + 3 * 3.0, 8 + 4 * 0.5 + 3 * 3.0, 9 + 4 * 1.0 + 3 * -1.0)
    assert joint_command(g, 1.0, 2.0, 3.0, 0.25, 0.5) == 3.0 + 4 * 0.75 + 3 * 1.5
    assert joint_pd(g, 2.0, 1.0, 2.0, 0.25, 0.5) == 2.0 * (4 * 0.75 + 3 * 1.5)


def test_saturation_clamps_each_torque_at_the_limit_and_keeps_the_rest():
    assert saturate((25.0, -25.0, 3.0), 20.0) == (20.0, -20.0, 3.0)
    assert saturate((20.0, -20.0, -19.5), 20.0) == (20.0, -20.0, -19.5)
    assert saturate((-3.0, 30.0, -30.0), 20.0) == (-3.0, 20.0, -20.0)
