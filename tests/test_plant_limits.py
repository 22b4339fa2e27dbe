"""The plant never raises on a command sequence (issue 56): its arms stop at their
mechanical stops, and a singular or unreachable configuration, a state no longer finite
or a command that is not three finite torques stops it with a named fault
(plant/limits.py). Before, a held full-torque command ran the arms round and round until
``_solve3`` raised ``ZeroDivisionError``.
"""

from __future__ import annotations

import dataclasses
import math

import pytest
from ctrlunit.kernels.params import DELTA_IA as P
from ctrlunit.plant import limits
from ctrlunit.plant.simulator import Plant, PlantConfig, PlantConfigError
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

LO, HI = limits.ARM_STOPS
NAMES = {limits.MECHANICAL_STOP, limits.SINGULAR, limits.UNREACHABLE,
         limits.NON_FINITE_STATE, limits.BAD_COMMAND}
FULL = P.tau_max

torque = st.one_of(
    st.sampled_from([FULL, -FULL, 0.0, 1e300, -1e300, math.inf, -math.inf, math.nan]),
    st.floats(allow_nan=True, allow_infinity=True),
    st.floats(-2 * FULL, 2 * FULL),
)
command = st.lists(torque, min_size=3, max_size=3)
# (command, how many periods it is held)
segment = st.tuples(command, st.integers(1, 400))


def check_plant(plant: Plant) -> None:
    """What holds after any command sequence: a finite state within the stops, and either
    no fault or a named one that left the robot at rest."""
    s = plant.state
    values = [*s.q, *s.p, *s.qd, *s.pd, *s.motor, *s.motor_d]
    assert all(math.isfinite(v) for v in values), values
    assert all(LO <= q <= HI for q in s.q), limits.degrees(s.q)
    assert all(isinstance(c, int) for c in plant.encoder_counts())
    for ev in plant.events:
        assert ev.name in NAMES and ev.message.startswith("plant: "), ev
    if plant.fault is not None:
        assert plant.fault.name in NAMES - {limits.MECHANICAL_STOP}
        assert s.qd == [0.0, 0.0, 0.0] and s.pd == [0.0, 0.0, 0.0]


def drive(plant: Plant, segments: list[tuple[list[float], int]]) -> None:
    """Apply each command for its periods, checking the plant after each."""
    for tau, periods in segments:
        plant.set_command(tau)
        for _ in range(periods):
            plant.step()
        check_plant(plant)


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(segment, min_size=1, max_size=6), st.booleans())
def test_any_command_sequence_integrates_or_stops_with_a_named_fault(segments, lag):
    plant = Plant(P, PlantConfig(lag=0.003 if lag else 0.0))
    drive(plant, segments)


@settings(max_examples=8, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(st.sampled_from([FULL, -FULL]), min_size=3, max_size=3),
       st.integers(2, 60))
def test_alternating_full_torque_never_raises(tau, half_period):
    """Full torque that changes sign every ``half_period`` periods, 3000 periods."""
    plant = Plant(P, PlantConfig())
    for k in range(3000 // half_period):
        sign = 1.0 if k % 2 == 0 else -1.0
        drive(plant, [([sign * t for t in tau], half_period)])


@pytest.mark.parametrize("tau", [(FULL, FULL, FULL), (FULL, 0.0, -FULL), (-FULL, 0.0, 0.0),
                                 (FULL, -FULL, 0.0), (0.0, 0.0, FULL)])
def test_full_torque_held_for_thousands_of_periods_never_raises(tau):
    """A frozen control unit's last command held (issue 56): before, each of these ran
    into ``ZeroDivisionError``, ``OverflowError`` or a state of NaN within 3000 periods."""
    plant = Plant(P, PlantConfig())
    drive(plant, [(list(tau), 3000)])
    assert plant.events  # every one reaches a stop (or stops on a fault)


def test_held_full_torque_drives_an_arm_into_its_stop_and_names_it():
    plant = Plant(P, PlantConfig())
    plant.set_command([-FULL, 0.0, 0.0])
    for _ in range(2000):
        plant.step()
    check_plant(plant)
    assert plant.fault is None
    first = plant.events[0]
    assert first.name == limits.MECHANICAL_STOP
    assert first.message == "plant: arm 1 at its mechanical stop -135 deg"
    assert plant.state.q[0] == LO  # held at the stop, against the torque
    assert plant.state.qd[0] == 0.0
    assert plant.constraint_error() < 1e-9  # the platform followed the stopped arm


def test_upper_stop_is_named_too():
    plant = Plant(P, PlantConfig())
    plant.set_command([0.0, FULL, 0.0])
    for _ in range(1000):
        plant.step()
    assert plant.events[0].message == "plant: arm 2 at its mechanical stop 45 deg"
    assert plant.state.q[1] == HI


@pytest.mark.parametrize("bad", [[math.nan, 0.0, 0.0], [0.0, math.inf, 0.0],
                                 [0.0, 0.0, -math.inf], [1.0, 2.0], ["x", 0.0, 0.0], None])
def test_a_command_that_is_not_three_finite_torques_stops_the_plant(bad):
    plant = Plant(P, PlantConfig())
    plant.set_command([1.0, 1.0, 1.0])
    q = list(plant.state.q)
    plant.set_command(bad)
    assert plant.fault is not None and plant.fault.name == limits.BAD_COMMAND
    assert plant.command == [1.0, 1.0, 1.0]  # never reached the integrator
    for _ in range(10):
        plant.step()
    assert plant.state.q == q  # stopped where it was
    check_plant(plant)


def test_huge_finite_torques_saturate():
    plant = Plant(P, PlantConfig())
    plant.set_command([1e300, -1e300, 5.0])
    assert plant.command == [FULL, -FULL, 5.0] and plant.fault is None


def test_a_singular_solve_stops_the_plant_with_its_name(monkeypatch):
    """Whatever the solve raises at a singular configuration is caught: the plant holds
    the last valid state, rates zero, and names the configuration."""
    plant = Plant(P, PlantConfig())
    plant.set_command([0.5, 0.5, 0.5])
    plant.step()
    q = list(plant.state.q)

    def singular(*_a, **_k):
        raise ZeroDivisionError("float division by zero")

    monkeypatch.setattr("ctrlunit.plant.mechanics.accelerations", singular)
    plant.step()
    assert plant.fault is not None and plant.fault.name == limits.SINGULAR
    assert plant.fault.message.startswith("plant: singular configuration at q = [")
    assert "ZeroDivisionError" in plant.fault.message
    assert plant.state.q == q and plant.state.qd == [0.0, 0.0, 0.0]
    monkeypatch.undo()
    for _ in range(5):  # stopped: time passes, nothing moves
        plant.step()
    assert plant.state.q == q
    check_plant(plant)


def test_a_projection_that_cannot_be_solved_stops_the_plant(monkeypatch):
    plant = Plant(P, PlantConfig())

    def singular(*_a, **_k):
        raise ZeroDivisionError("float division by zero")

    monkeypatch.setattr("ctrlunit.plant.mechanics.project", singular)
    plant.step()
    assert plant.fault is not None and plant.fault.name == limits.SINGULAR
    check_plant(plant)


def test_a_non_finite_state_stops_the_plant(monkeypatch):
    plant = Plant(P, PlantConfig())
    q = list(plant.state.q)
    monkeypatch.setattr("ctrlunit.plant.mechanics.accelerations",
                        lambda *_a: ([math.nan] * 3, [0.0] * 3))
    plant.step()
    assert plant.fault is not None and plant.fault.name == limits.NON_FINITE_STATE
    assert plant.state.q == q
    check_plant(plant)


def test_belt_plant_never_raises_at_full_torque():
    plant = Plant(P, PlantConfig(belt=True))
    drive(plant, [([FULL, FULL, -FULL], 500), ([-FULL, FULL, FULL], 500)])
    assert plant.events


def test_stops_are_checked_and_may_be_left_out():
    with pytest.raises(PlantConfigError, match="arm_stops"):
        PlantConfig(arm_stops=(1.0, -1.0))
    with pytest.raises(PlantConfigError, match="arm_stops"):
        PlantConfig(arm_stops=(math.nan, 1.0))
    free = dataclasses.replace(PlantConfig(), arm_stops=None)
    plant = Plant(P, free)
    plant.set_command([-FULL, 0.0, 0.0])
    for _ in range(300):
        plant.step()
    assert plant.state.q[0] < LO  # no stop: the arm swings past -135 deg


def test_the_stops_lie_outside_the_joint_box_of_eq_v32():
    assert LO < P.q_min and HI > P.q_max
    # the lower stop is before the arm tips meet on the robot's axis
    assert P.r_a + P.l_a * math.cos(LO) > 0.0


def test_the_central_takes_the_plant_fault_from_its_report_and_names_it():
    from ctrlunit.runtime.central.fault import plant_fault, role_report

    kept = role_report({"exit": "fault", "fault": limits.PlantEvent(
        limits.MECHANICAL_STOP, "plant: arm 2 at its mechanical stop -135 deg", 1.5).as_dict()})
    fault = plant_fault(kept)
    assert (fault.process, fault.code) == ("plant", 4)
    assert str(fault) == ("plant: arm 2 at its mechanical stop -135 deg (mechanical_stop, "
                          "at 1.500 s of plant time)")
    assert "fault" not in role_report({"fault": {"name": 3, "message": "x", "time": 0.0}})
