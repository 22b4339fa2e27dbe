"""The simulated Delta's mechanical limits and faults: the arms' end stops, the check of a
command's torques, and the named events and faults the plant reports instead of raising.

Mechanical stops
----------------
The joint box of Eq. V.32 (``q_min = -125 deg``, ``q_max = 15 deg``) is a conservative
inner approximation of the usable workspace (Eq. V.33; docs/thesis-notes.md): the circle
task of § V.6.1 lifts an arm to 30.0 deg and lowers one to -111.8 deg. The stops lie
outside both:

* lower, :data:`ARM_STOP_LOW_DEG` = -135 deg: an arm turned down and inwards brings its
  tip to the robot's axis where ``r_a + l_a cos q = 0`` (Eq. II.8's arm tip radius), at
  -138.3 deg for the Delta-IA (``r_a = 0.194 m``, ``l_a = 0.26 m``), and there the three
  arm tips would meet; the stop is the last whole 5 deg before that, 10 deg beyond the
  box;
* upper, :data:`ARM_STOP_HIGH_DEG` = +45 deg: 30 deg above the box and 15 deg above the
  highest arm angle a task of the project reaches (the circle's 30 deg).

An arm that reaches a stop is stopped there (inelastic: its angle is clamped and its
rate into the stop set to zero) and the plant records a :class:`PlantEvent` naming the
arm and the stop. Only angles beyond a stop are touched, so a run that stays within them
integrates exactly as before.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from ..kernels.params import DeltaParams
from . import mechanics as mech

Vec = list[float]
ARM_STOP_LOW_DEG = -135.0
"""Lower mechanical stop of each arm (deg; module notes)."""

ARM_STOP_HIGH_DEG = 45.0
"""Upper mechanical stop of each arm (deg; module notes)."""

ARM_STOPS = (math.radians(ARM_STOP_LOW_DEG), math.radians(ARM_STOP_HIGH_DEG))
"""``(lower, upper)`` mechanical stops of each arm (rad)."""

NUMERIC_ERRORS = (ArithmeticError, ValueError)
"""What the solves raise at a singular configuration (``ZeroDivisionError`` in
``_solve3`` or ``_inv_sym3``, ``OverflowError`` squaring a runaway coordinate,
``ValueError`` from ``math`` on an infinity): caught, and the plant stops."""

REACH_TOL_M = 1e-6
"""Largest constraint error (m) after the projection that follows a stop: beyond it the
arm angles leave no platform position (:data:`UNREACHABLE`)."""

MAX_EVENTS = 100
"""Events a plant keeps (the first ones); later ones are only counted."""

MECHANICAL_STOP = "mechanical_stop"
"""An arm reached one of its stops (an event; the plant role reports it as a fault)."""

SINGULAR = "singular_configuration"
"""The equations of motion or the projection onto the constraints could not be solved:
a singular configuration (the forearms' constraint gradients dependent)."""

UNREACHABLE = "unreachable_configuration"
"""The arm angles leave no platform position that closes the three loops."""

NON_FINITE_STATE = "non_finite_state"
"""A sub-step left a NaN or an infinity in the state."""

BAD_COMMAND = "bad_command"
"""A command that is not three finite torques."""


@dataclass(frozen=True)
class PlantEvent:
    """Something the plant reports by name: an event (an arm at its stop) or a fault.

    Attributes
    ----------
    name : one of :data:`MECHANICAL_STOP`, :data:`SINGULAR`, :data:`UNREACHABLE`,
        :data:`NON_FINITE_STATE`, :data:`BAD_COMMAND`.
    message : one line naming the arm, value or configuration, starting with ``plant:``.
    time : plant time (s) at which it happened.
    """

    name: str
    message: str
    time: float

    def as_dict(self) -> dict[str, Any]:
        """The event as the plant role's report carries it."""
        return {"name": self.name, "message": self.message, "time": self.time}


def degrees(q: Sequence[float]) -> str:
    """Arm angles for a message, in degrees to 0.1 (``[-40.0, 12.3, nan]``)."""
    return "[" + ", ".join(f"{math.degrees(x):.1f}" for x in q) + "] deg"


def check_command(tau: Any, n: int = 3) -> str | None:
    """Why ``tau`` is not a command of ``n`` finite torques, or None when it is one.
    Finite torques of any size are a command: the actuators saturate them."""
    try:
        values = list(tau)
    except TypeError:
        return f"plant: a command must be {n} torques, got {type(tau).__name__}"
    if len(values) != n:
        return f"plant: a command must be {n} torques, got {len(values)}"
    for i, t in enumerate(values):
        if isinstance(t, bool) or not isinstance(t, int | float):
            return f"plant: torque {i + 1} of the command is {type(t).__name__}, not a number"
        if not math.isfinite(t):
            return f"plant: torque {i + 1} of the command is {t!r} N m, not finite"
    return None


def clamp_to_stops(q: list[float], qd: list[float], stops: tuple[float, float]
                   ) -> list[tuple[int, float]]:
    """Stop each arm beyond a stop at that stop, inelastically: ``q[i]`` set to the stop,
    ``qd[i]`` to zero if it points further in (both lists changed in place). Returns
    ``(arm index, stop)`` of each arm clamped; an empty list (nothing changed) while
    every arm is within its stops."""
    lo, hi = stops
    hit: list[tuple[int, float]] = []
    for i in range(3):
        if q[i] < lo:
            q[i] = lo
            if qd[i] < 0.0:
                qd[i] = 0.0
            hit.append((i, lo))
        elif q[i] > hi:
            q[i] = hi
            if qd[i] > 0.0:
                qd[i] = 0.0
            hit.append((i, hi))
    return hit


def singular_message(q: Sequence[float], exc: BaseException) -> str:
    """The fault's message when a solve at arm angles ``q`` raised ``exc``."""
    return f"plant: singular configuration at q = {degrees(q)} ({type(exc).__name__}: {exc})"


def reproject(params: DeltaParams, q: Vec, p: Vec, qd: Vec, pd: Vec, *, time: float
              ) -> tuple[Vec, Vec] | PlantEvent:
    """The platform's ``(p, pdot)`` closing the loops of Eq. II.8 at arm angles ``q`` and
    rates ``qd`` (:func:`~.mechanics.project`, after an arm was stopped), or the fault at
    plant time ``time`` when they cannot be found: a singular or an unreachable
    configuration (the forearms miss their joints by more than :data:`REACH_TOL_M`)."""
    try:
        p, pd = mech.project(params, q, p, qd, pd)
        gap = max(abs(r) for r in mech.constraint_residual(params, q, p))
    except NUMERIC_ERRORS as exc:
        return PlantEvent(SINGULAR, singular_message(q, exc), time)
    if not gap <= REACH_TOL_M or not all(map(math.isfinite, pd)):  # NaN fails too
        return PlantEvent(UNREACHABLE, f"plant: unreachable configuration at q = "
                          f"{degrees(q)}: the forearms miss their joints by {gap:.3g} m", time)
    return p, pd


def stop_message(arm: int, stop: float) -> str:
    """The event's message for arm index ``arm`` at ``stop`` (rad)."""
    return f"plant: arm {arm + 1} at its mechanical stop {math.degrees(stop):.0f} deg"


__all__ = ["ARM_STOPS", "ARM_STOP_HIGH_DEG", "ARM_STOP_LOW_DEG", "BAD_COMMAND",
           "MAX_EVENTS", "MECHANICAL_STOP", "NON_FINITE_STATE", "NUMERIC_ERRORS",
           "REACH_TOL_M", "SINGULAR", "UNREACHABLE", "PlantEvent", "check_command",
           "clamp_to_stops", "degrees", "reproject", "singular_message", "stop_message"]
