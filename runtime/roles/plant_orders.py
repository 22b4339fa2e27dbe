"""What the plant takes from the central outside its ticks (:mod:`.plant_node`): an
admission trial's order, checked; the stop order, waited for when a signal of its own
stopped the plant; the safe stop it then makes; and the report that names a plant fault
at once (docs/faults-and-errors.md)."""

from __future__ import annotations

import math
import queue
import time
from typing import Any

from ...plant.simulator import Plant
from ..transport.codec import encode
from ..transport.node import Node, is_stop

TRIAL_MAX_S = 60.0
"""Longest admission trial the plant runs on one order (a forged order cannot hold it)."""

STOP_ORDER_WAIT_S = 0.5
"""How long a plant stopped by a signal of its own waits for the central's stop order
before it brakes (the simulated robot does not move meanwhile). The order carries the
torques to hold (gravity compensation at the central's estimate); the last command also
carries the path's inertial torques, and braking on it left the platform at 0.47 m/s
instead of under 2 mm/s. A signal to the whole job reaches the central too, whose order
follows within milliseconds; a plant run by hand and stopped alone waits it out."""


def announce_fault(node: Node, report: dict[str, Any]) -> None:
    """Send the plant's report naming its fault at once, once (the central stops the
    unit on it and then waits for the final report, sent after the safe stop; copies of
    this one, as ``say_bye`` sends, could stand in for that one)."""
    node.publisher(node.keys.hello(node.role)).put(
        encode(node.unit, 0, "bye", role=node.role, report=report))


def trial_order(node: Node, ev: Any) -> tuple[float, int, int] | None:
    """``(period, ticks, base)`` of an admission trial order, else None (a malformed one is
    counted and dropped)."""
    if ev.kind != "control":
        return None
    msg = node.decode(ev.data)
    if msg is None or msg["stage"] != "probe":
        return None
    period, ticks, base = msg.get("period"), msg.get("ticks"), msg.get("base")
    if not (isinstance(period, float) and 20e-6 <= period <= 1.0
            and type(ticks) is int and 1 <= ticks <= 100_000
            and ticks * period <= TRIAL_MAX_S
            and type(base) is int and 0 <= base < 1 << 62):
        node.reject("bad_value")
        return None
    return period, ticks, base


def wait_for_stop(node: Node, timeout: float) -> bool:
    """Read the inbox for up to ``timeout`` seconds until the central's stop order comes
    (:attr:`Node.stop_msg` then holds it); whether it came."""
    end = time.monotonic() + timeout
    while node.stop_msg is None and (left := end - time.monotonic()) > 0:
        try:
            ev = node.events.get(timeout=left)
        except queue.Empty:
            break
        is_stop(node, ev)
    return node.stop_msg is not None


def safe_stop(plant: Plant, *, hold_s: float = 0.05, damping: float = 5.0,
              drive_period: float = 2.5e-4) -> dict[str, Any]:
    """The documented stop: for ``hold_s``, gravity compensation (the torques the central
    sent with its stop order, computed at its last estimate; the last command if the
    central is gone) plus drive-level damping ``-damping * qdot`` (N m s/rad, updated
    every ``drive_period`` as a drive's own loop would, whatever the control period) so
    that a moving robot brakes instead of coasting; then zero torque.

    At the fastest point of pick & place (3.75 m/s) the platform travels 34 mm and is
    left at under 2 mm/s; the damping of 1 N m s/rad used before left it at 0.39 m/s.
    Returns the hold time, the distance moved and the platform speed at the end of it."""
    p0 = list(plant.state.p)
    hold = list(plant.command)
    # integrated with sub-steps no longer than the plant's base ones (the belt needs 0.1
    # ms): a quarter of the drive's period; the turn rule (plant/substeps.py) would ask
    # for shorter ones only above about 200 rad/s, which the braking drive does not meet
    inner = max(1, math.ceil(drive_period * plant.config.n_substeps / plant.config.period
                             - 1e-9))
    for _ in range(max(1, round(hold_s / drive_period))):
        # a drive damps what its encoder sees: the motor, behind a belt
        qd = plant.state.motor_d if plant.config.belt else plant.state.qd
        plant.set_command([hold[i] - damping * qd[i] for i in range(3)])
        for _ in range(inner):
            plant.substep(drive_period / inner)
        plant.project()
    plant.set_command([0.0, 0.0, 0.0])
    return {"hold_s": hold_s, "drift_m": math.dist(p0, plant.state.p),
            "speed_m_s": math.hypot(*plant.state.pd)}


__all__ = ["STOP_ORDER_WAIT_S", "TRIAL_MAX_S", "announce_fault", "safe_stop", "trial_order",
           "wait_for_stop"]
