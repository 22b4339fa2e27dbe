"""Usable workspace (Eq. V.33) and the joint box (Eq. V.32)."""

from __future__ import annotations

import numpy as np
import pytest
from ctrlunit.kernels.kinematics import inverse_kinematics
from ctrlunit.kernels.params import DELTA_IA as P
from ctrlunit.kernels.trajectory import circle_task
from ctrlunit.kernels.workspace import (
    WorkspaceError,
    check_point,
    in_joint_box,
    require_path,
    require_point,
    slice_map,
    stiffness_eigenvalues,
    sym3_eigenvalues,
)
from hypothesis import example, given, settings
from hypothesis import strategies as st


def test_eigenvalues_equal_w_x2_wt_form():
    p = (0.1, 0.0, -0.4)
    from ctrlunit.kernels.kinematics import inverse_jacobian

    ji = inverse_jacobian(P, p) * P.l_a
    assert np.allclose(stiffness_eigenvalues(P, p), np.linalg.eigvalsh(ji.T @ ji))


finite = st.floats(-1e3, 1e3, allow_nan=False, allow_infinity=False)


@settings(max_examples=500, deadline=None)
@given(st.lists(finite, min_size=6, max_size=6), st.sampled_from([0, 1, 2, 3]))
@example([9.815267738898107e-229, 3.0, 0.0, 2.829381516064368e-25, 7.34087590310714e-91,
          0.0], 0)
def test_closed_form_eigenvalues_match_eigvalsh(a, degenerate):
    """Also with repeated eigenvalues (diagonal, identity multiples, rank one), where the
    trigonometric form is only good to about sqrt(eps) of the largest magnitude. Separated
    eigenvalues within 1e-10 of the scale: the reference itself is not exact (for the
    example above, entries near 1e-228 beside 3, eigvalsh gave -2.999999999993871, 0,
    2.999999999993871 where the eigenvalues are -3, 0, 3, as the closed form gives to
    1e-15: CI, 2026-11-28)."""
    m = np.array([[a[0], a[1], a[2]], [a[1], a[3], a[4]], [a[2], a[4], a[5]]])
    if degenerate == 1:
        m = np.diag([a[0], a[0], a[3]])
    elif degenerate == 2:
        m = a[0] * np.eye(3)
    elif degenerate == 3:
        v = np.array(a[:3])
        m = np.outer(v, v)
    got = sym3_eigenvalues(m[0, 0], m[0, 1], m[0, 2], m[1, 1], m[1, 2], m[2, 2])
    ref = np.linalg.eigvalsh(m)
    scale = max(1.0, float(np.abs(ref).max()))
    assert np.all(np.diff(got) >= -1e-12 * scale)
    separated = np.diff(ref).min() > 1e-2 * scale
    assert np.allclose(got, ref, rtol=0, atol=(1e-10 if separated else 1e-7) * scale)


def test_circle_leaves_joint_box_but_stays_usable():
    """errata § V.6.1: a joint passes 15 deg, yet min eig stays near 0.24."""
    task = circle_task()
    pts = np.array([task.sample_path(t)[0] for t in np.linspace(0, task.duration, 301)])
    lo = require_path(P, pts)
    assert 0.2 < lo < 0.3
    assert not all(in_joint_box(P, inverse_kinematics(P, p)) for p in pts)


def test_low_stiffness_point_is_refused_with_point_and_bound():
    xs, ys, _, eig = slice_map(P, -0.32, n=41)
    iy, ix = np.unravel_index(np.nanargmin(eig), eig.shape)
    assert eig[iy, ix] < P.beta_min
    msg = r"point \(.*\) m: smallest eigenvalue.*beta_min = 0.1"
    with pytest.raises(WorkspaceError, match=msg):
        require_point(P, (xs[ix], ys[iy], -0.32))


def test_near_forward_singularity_is_refused_by_beta_max():
    with pytest.raises(WorkspaceError, match=r"point \(0.0000, 0.0000, -0.1500\).*beta_max"):
        require_point(P, (0.0, 0.0, -0.15))


def test_unreachable_point_is_not_usable():
    res = check_point(P, (0.0, 0.0, -1.5))
    assert not res.ok and "out of reach" in res.reason
