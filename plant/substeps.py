"""How many RK4 sub-steps the simulated plant takes in one period when none are asked
for: at most :data:`MAX_SUBSTEP_S` long (:data:`MAX_SUBSTEP_BELT_S` with the belt), and
more where an arm turns fast (:func:`substeps_for`)."""

from __future__ import annotations

import math
from collections.abc import Sequence

MAX_SUBSTEP_S = 1e-3
"""Longest RK4 sub-step (s) of the rigid plant when no sub-step count is given; shorter
where an arm turns fast (:func:`substeps_for`).

What the plant must get right is what its encoders see. Against sub-steps 40 times
shorter, in closed loop at 1 ms (resolved acceleration): over 600 periods of pick & place
the platform paths differ by 3.6 nm at 1 ms and 0.22 nm at 0.5 ms, against an encoder
increment of 8 um at the arm's tip, and the commands come out the same; over 3000
periods, once an encoder reading flips, 3.5 um at 1 ms and 3.0 um at 0.5 ms (pick &
place, arms up to 18 rad/s), 57 and 38 um (the circle at 10 m/s, arms up to 46 rad/s),
with tracking errors of 6.6 um and 8.3 mm. In free fall (no stops) the energy drifts by
1.6e-3 of |E| over 2 s at 1 ms, 1e-4 at 0.5 ms, 1.6e-7 at 0.1 ms (RK4's h^4). Alternated
at a 2 ms period (``--plant-substeps 2`` against the 4 of 0.5 ms), the plant's CPU per
interval went from 829 to 600 us (docs/measurements/2026-11-28-cpu.md).
``--plant-substeps`` fixes the count."""

MAX_TURN_RAD = 0.05
"""Largest angle (rad) an arm may turn in one automatic sub-step, at its rate when the
period starts: a period of fast motion takes more sub-steps. Full torque on one arm with
no stops flings the others to 145 rad/s; 300 periods of it end 0.44 rad from a run 40
times finer with sub-steps of 1 ms, 0.018 rad with 0.5 ms (600 sub-steps), and 0.018 rad
with this rule (517 sub-steps; 0.02 rad: 4.5e-4 rad in 1074). The tasks' motions (arms up
to 46 rad/s) keep 1 ms. A period of such motion costs the plant more CPU (three sub-steps
at 145 rad/s and 1 ms; at most :data:`MAX_TURN_FACTOR` times the base count): a realtime
plant that falls behind skips the ticks it missed (runtime/roles/plant_ticks.py) rather
than integrate coarsely."""

MAX_TURN_FACTOR = 64
"""The turn rule asks for at most this many times a period's base count of sub-steps."""

MAX_SUBSTEP_BELT_S = 1e-4
"""Longest sub-step (s) with the elastic belt: its resonance (about 180 Hz, k_e = 8080
N m/rad against the motor inertia) needs it; at 0.25 ms one open-loop run is already
0.65 um off, at 0.1 ms 0.015 um."""


def substeps_for(period: float, base: int, rates: Sequence[float]) -> int:
    """Sub-steps for a period of ``period`` seconds starting at joint ``rates`` (rad/s):
    ``base`` (the count of :data:`MAX_SUBSTEP_S` or :data:`MAX_SUBSTEP_BELT_S`), or more,
    as many as keep each turn within :data:`MAX_TURN_RAD`, up to :data:`MAX_TURN_FACTOR`
    times ``base``. A rate that is not finite leaves ``base`` (the integration then stops
    the plant on its state, plant/simulator.py)."""
    if not all(map(math.isfinite, rates)):
        return base
    turn = max(map(abs, rates)) * period
    if turn > base * MAX_TURN_RAD:
        return min(MAX_TURN_FACTOR * base, math.ceil(turn / MAX_TURN_RAD))
    return base
