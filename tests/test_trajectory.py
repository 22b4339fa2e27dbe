"""Reference generation and the two thesis tasks against docs/thesis-notes.md."""

from __future__ import annotations

import math

import numpy as np
import pytest
from ctrlunit.kernels.trajectory import Segment, arc, circle_task, half_ellipse, pick_place_task


@pytest.mark.parametrize(
    ("task", "length", "duration", "speed"),
    [(circle_task(), 1.257, 0.2565, 9.8), (pick_place_task(), 0.277, 0.147, None)],
    ids=["circle", "pick-place"],
)
def test_task_figures_agree_with_errata_to_two_percent(task, length, duration, speed):
    assert math.isclose(task.length, length, rel_tol=0.02)
    assert math.isclose(task.duration, duration, rel_tol=0.02)
    if speed is not None:
        ts = np.linspace(0, task.duration, 501)
        peak = max(np.linalg.norm(task.sample_path(t)[1]) for t in ts)
        assert math.isclose(peak, speed, rel_tol=0.02)


def test_cycloidal_profile_peaks():
    seg = Segment(half_ellipse((0.1, 0, -0.4), (0, 0, -0.35), (-0.1, 0, -0.4)), 50.0)
    ts = np.linspace(0.0, seg.duration, 2001)
    sd = [seg.profile(t)[1] for t in ts]
    sdd = [seg.profile(t)[2] for t in ts]
    assert math.isclose(max(sd), 2 * seg.length / seg.duration, rel_tol=1e-5)
    assert math.isclose(max(sdd), 50.0, rel_tol=1e-4)


@pytest.mark.parametrize("task", [circle_task(), pick_place_task()], ids=lambda t: t.name)
def test_velocity_and_acceleration_are_derivatives_of_position(task):
    h = 1e-6
    for t in np.linspace(0.01, task.duration - 0.01, 25):
        _, v, a = (np.asarray(x) for x in task.sample_path(t))
        pp, vp, _ = (np.asarray(x) for x in task.sample_path(t + h))
        pm, vm, _ = (np.asarray(x) for x in task.sample_path(t - h))
        assert np.allclose((pp - pm) / (2 * h), v, atol=1e-6)
        assert np.allclose((vp - vm) / (2 * h), a, atol=1e-4 * max(1.0, np.abs(a).max()))


def test_task_loops_forward_and_back_and_rests_at_ends():
    task = pick_place_task()
    assert np.allclose(task.sample(0.0)[0], (0.125, 0, -0.35))
    assert np.allclose(task.sample(task.duration + 0.5 * task.dwell)[0], (-0.125, 0, -0.35))
    assert np.allclose(task.sample(task.period)[0], (0.125, 0, -0.35))
    assert np.allclose(task.sample(task.duration + 0.5 * task.dwell)[1], 0.0)


def test_arc_rejects_inconsistent_radius():
    with pytest.raises(ValueError, match="same non-zero distance"):
        arc((0, 0, 0), (1, 0, 0), (0, 2, 0))


@pytest.mark.parametrize("make", [circle_task, pick_place_task])
def test_the_tracking_reference_is_one_value_per_grid_point_whatever_was_asked(make):
    """``Task.position`` on the aligned grid is a function of the grid point alone: the
    same value in every loop, for times a few ulps apart, and whatever ``sample`` or
    ``position`` was asked before and in which order, so that the central, the report
    and the plot agree on the tracking error bit for bit. It is the reference at that
    time: within a picometre of the value computed afresh at ``t`` (a few femtometres
    apart), and exactly the value computed afresh at the grid point's time in the loop."""
    import random

    period = 1e-3
    task = make().align(period / 2)
    rng = random.Random(1994)
    loop = round(task.period / period)
    times = [k * period for k in range(3 * loop)]
    nearby = [t + rng.choice((-2, -1, 1, 2)) * math.ulp(t or 1e-9) for t in times]
    shifted = [(k - 2) * period + 2 * period for k in range(2, 3 * loop)]  # the run's asks
    asks = times + nearby + shifted
    rng.shuffle(asks)
    for t in asks:
        task.sample(t)
        task.position(t)
    fresh = make().align(period / 2)  # asked nothing before, then in the reverse order
    for t in reversed(times + nearby + shifted):
        k = round(t / task._step)
        assert task.position(t) == fresh.position(t) == fresh._sample((k % task._grid)
                                                                      * task._step)[0], t
        assert math.dist(task.position(t), fresh._sample(t)[0]) < 1e-12, t
        assert task.position(t) == task.position(t + task._grid * task._step)  # next loop
    for t in [rng.uniform(0, 3 * task.period) for _ in range(200)]:  # off the grid
        assert task.position(t) == fresh._sample(t)[0], t
