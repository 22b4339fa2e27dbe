"""Inverse kinematics and Jacobians against finite differences and the closed form."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import joint_angles, usable_point_from_q, velocities
from ctrlunit.kernels.forward import fk_closed_form, fk_newton
from ctrlunit.kernels.kinematics import (
    UnreachableError,
    ik_axis,
    inverse_jacobian,
    inverse_jacobian_dot,
    inverse_kinematics,
    jinvdot_pdot,
    joint_accelerations,
)
from ctrlunit.kernels.params import DELTA_IA as P
from hypothesis import assume, given, settings


def test_errata_reference_point_gives_minus_21_28_deg():
    q = inverse_kinematics(P, (0.0, 0.0, -0.35))
    assert np.allclose(np.degrees(q), -21.28, atol=0.005)


def test_unreachable_point_is_named():
    with pytest.raises(UnreachableError, match=r"\(0, 0, -2\)"):
        inverse_kinematics(P, (0.0, 0.0, -2.0))


def test_each_axis_is_callable_alone():
    p = (0.05, -0.1, -0.4)
    q = inverse_kinematics(P, p)
    for i in range(3):
        assert ik_axis(P, i, *p).q == q[i]


def d4(f, x, d, h=1e-4):
    """Fourth-order central difference of f at x along direction d."""
    return (-f(x + 2 * h * d) + 8 * f(x + h * d) - 8 * f(x - h * d) + f(x - 2 * h * d)) / (12 * h)


def _rel(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.abs(a - b).max() / max(np.abs(b).max(), 1e-12))


@settings(max_examples=1000, deadline=None)
@given(q=joint_angles)
def test_inverse_jacobian_matches_central_differences(q):
    p = usable_point_from_q(q)
    assume(p is not None)
    fd = np.column_stack([d4(lambda x: inverse_kinematics(P, x), p, e) for e in np.eye(3)])
    assert _rel(inverse_jacobian(P, p), fd) < 1e-6


@settings(max_examples=1000, deadline=None)
@given(q=joint_angles, v=velocities)
def test_jinv_dot_pdot_matches_central_differences(q, v):
    p = usable_point_from_q(q)
    assume(p is not None)
    pd = np.array(v)
    assume(np.linalg.norm(pd) > 1e-3)
    speed = np.linalg.norm(pd)
    fd = d4(lambda x: inverse_jacobian(P, x), p, pd / speed, h=3e-5) * speed
    assert _rel(inverse_jacobian_dot(P, p, pd), fd) < 1e-6
    assert _rel(jinvdot_pdot(P, p, pd), fd @ pd) < 1e-6


@settings(max_examples=200, deadline=None)
@given(q=joint_angles, v=velocities)
def test_acceleration_mapper_is_second_derivative_of_ik(q, v):
    """Eq. V.31 against d^2/dt^2 f^-1(p(t)) along p(t) = p + v t + a t^2 / 2."""
    p = usable_point_from_q(q)
    assume(p is not None)
    v = np.array(v)
    a = np.array([1.0, -2.0, 3.0])
    h = 2e-4

    def qt(t):
        return inverse_kinematics(P, p + v * t + 0.5 * a * t * t)

    def d2(h):
        return (-qt(2 * h) + 16 * qt(h) - 30 * qt(0.0) + 16 * qt(-h) - qt(-2 * h)) / (12 * h * h)

    # Richardson: the five-point error is O(h^4), so (16 d2(h/2) - d2(h)) / 15 removes it;
    # near the workspace's edge at 5 m/s (joint accelerations of 7000 rad/s^2) d2(h) alone
    # was 0.1 rad/s^2 off, converging on Eq. V.31 by 16x per halving
    fd = (16 * d2(h / 2) - d2(h)) / 15
    assert np.allclose(joint_accelerations(P, p, v, a), fd, rtol=1e-5, atol=1e-5)


@settings(max_examples=500, deadline=None)
@given(q=joint_angles)
def test_ik_then_fk_round_trips(q):
    p = usable_point_from_q(q)
    assume(p is not None)
    qq = inverse_kinematics(P, p)
    assert np.abs(fk_closed_form(P, qq) - p).max() < 1e-9
    start = p + np.array([0.002, -0.001, 0.0015])
    res = fk_newton(P, qq, start, tol=1e-12)
    assert np.abs(np.array(res.p) - p).max() < 1e-9
