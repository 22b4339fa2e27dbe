"""What the admission predicts before it tries a period: the tracking of the task in the
one-process closed loop at that period (runtime/compute/controller.py, ``simulate``). A
period at which even that loop tracks worse than half of ``--max-error`` is refused
before any trial (runtime/launch/admission.py)."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from ..central import Central


def predicted_tracking(central: Central, period: float) -> float:
    """Max tracking error (m) of the task in the one-process closed loop at ``period`` with
    the run's law, model, observer, model state, gains and command delay
    (runtime/compute/controller.py's ``simulate``, lockstep: no misses), over the run or
    one loop of the task, whichever is shorter (a long run repeats the loop; simulating a
    60 s run took longer than the roles wait in silence). NaN for the kinematics law (no
    torques); infinite where the loop loses the robot (a period so long that the observer
    finds no pose, ``ObserverDiverged``: a live run's check refused it as "a damaged
    recording?")."""
    from ...kernels.laws import Gains
    from ...kernels.task_file import get_task
    from ..compute.blocks import ObserverDiverged
    from ..compute.controller import simulate

    rc = central.rc.replace(period=period)
    if rc.control.law == "kinematics":
        return math.nan
    task = get_task(rc.control.task)
    try:
        res = simulate(central.params, task, law=rc.control.law, model=rc.control.model,
                       gains=Gains.from_bandwidth(rc.bandwidth), period=period,
                       cycles=min(rc.total_cycles(task.period), round(task.period / period) + 1),
                       delay=rc.delay_periods,
                       observer=rc.control.observer, model_state=rc.resolved_model_state)
    except ObserverDiverged:
        return math.inf
    ref = np.asarray(res.references, dtype=float)
    pos = np.asarray(res.positions, dtype=float)
    return float(np.max(np.linalg.norm(ref - pos, axis=1))) if ref.size else math.nan


def tracks(err_m: float, max_error_m: float | None = None) -> str:
    """The prediction in words: ``tracks within 5.8 mm`` (``, more than half of --max-error
    ...`` given ``max_error_m``), or where the loop lost the robot (:func:`predicted_tracking`
    is then infinite) ``loses the robot``."""
    if not math.isfinite(err_m):
        return "loses the robot (its observer finds no pose that fits the samples)"
    return f"tracks within {err_m * 1e3:.1f} mm" + (
        "" if max_error_m is None else
        f", more than half ({max_error_m * 0.5e3:g} mm) of --max-error {max_error_m * 1e3:g} mm")


__all__ = ["predicted_tracking", "tracks"]
