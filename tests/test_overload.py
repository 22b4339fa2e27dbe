"""Halving the control rate: every second sample runs an interval, each command acts for
two periods. The feed-forward lead and the state the model is evaluated at follow the
two-period hold (the source ``hold``); without that the halved loop tracks several times
worse than the full rate.
"""

from __future__ import annotations

import math

import pytest
from ctrlunit.kernels.laws import Gains
from ctrlunit.kernels.params import DELTA_IA as P
from ctrlunit.kernels.trajectory import pick_place_task
from ctrlunit.runtime import controller as ctl_mod


def _tracking(halve_at: int | None) -> tuple[float, float]:
    task = pick_place_task()
    res = ctl_mod.simulate(P, task, gains=Gains.from_bandwidth(20.0), period=1e-3, delay=2,
                           cycles=int(task.duration / 1e-3), halve_at=halve_at)
    e = res.tracking_error
    return max(e), math.sqrt(sum(x * x for x in e) / len(e))


def test_halved_rate_tracks_like_the_full_rate_when_the_hold_is_known(monkeypatch):
    full_max, _ = _tracking(None)
    halved_max, halved_rms = _tracking(0)
    mid_max, _ = _tracking(60)  # halved in the middle of the move
    print(f"pick & place, 1 ms, depth 2: full rate {full_max * 1e3:.4f} mm max; halved "
          f"{halved_max * 1e3:.4f} mm max, {halved_rms * 1e3:.4f} rms; halved at 60 "
          f"{mid_max * 1e3:.4f} mm")
    assert halved_max < 1.5 * full_max
    assert mid_max < 1.5 * full_max
    # what the hold-aware lead and ``ahead`` buy: a one-period hold assumed throughout
    monkeypatch.setattr(ctl_mod.Controller, "hold_of", lambda self, cycle: 1)
    unaware_max, _ = _tracking(0)
    print(f"one-period hold assumed: {unaware_max * 1e3:.4f} mm max")
    assert unaware_max > 3 * halved_max


def test_full_rate_commands_do_not_change_with_the_hold_source():
    """hold = 1 everywhere: the commands are those of a controller that never halves."""
    task = pick_place_task()
    a = ctl_mod.simulate(P, task, gains=Gains.from_bandwidth(20.0), cycles=120, delay=2)
    b = ctl_mod.simulate(P, pick_place_task(), gains=Gains.from_bandwidth(20.0), cycles=120,
                         delay=2, halve_at=10_000)
    assert a.commands == b.commands


def test_controller_halves_once_on_a_grid_from_its_start():
    task = pick_place_task()
    eng = ctl_mod.build_engine(P, task, law="resolved-acceleration", model="complete",
                               gains=Gains.from_bandwidth(20.0), period=1e-3, delay=2)
    ctl = ctl_mod.Controller(eng, 1e-3, P.increment, tuple(task.start()))
    assert all(ctl.on_grid(k) and ctl.hold_of(k) == 1 for k in range(10))
    ctl.halve(5)
    assert [k for k in range(12) if ctl.on_grid(k)] == [0, 1, 2, 3, 4, 5, 7, 9, 11]
    assert [ctl.hold_of(k) for k in (4, 5, 7)] == [1, 2, 2]
    assert ctl.context(7)["hold"] == 2 and ctl.context(4)["hold"] == 1
    ctl.halve(6)  # once a run
    assert ctl.on_grid(7) and not ctl.on_grid(6)
    with pytest.raises(ValueError, match="start must be a cycle >= 0"):
        ctl_mod.Controller(eng, 1e-3, P.increment, tuple(task.start())).halve(-1)
