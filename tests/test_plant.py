"""The simulated Delta: conservation, statics, the model cross-check, sensors, the belt."""

from __future__ import annotations

import ast
import math
import random
import struct
from pathlib import Path

import numpy as np
import pytest
from ctrlunit.kernels.dynamics import gravity_torques, inverse_dynamics
from ctrlunit.kernels.kinematics import inverse_kinematics
from ctrlunit.kernels.params import DELTA_IA as P
from ctrlunit.kernels.trajectory import circle_task, pick_place_task
from ctrlunit.plant.simulator import Plant, PlantConfig, PlantConfigError

PLANT_DIR = Path(__file__).resolve().parents[1] / "plant"


def test_plant_does_not_import_the_controllers_model():
    """Only the parameter record may come from kernels/."""
    for f in PLANT_DIR.glob("*.py"):
        tree = ast.parse(f.read_text())
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom) and node.module and "kernels" in node.module:
                assert node.module.endswith("kernels.params"), f"{f.name} imports {node.module}"
            if isinstance(node, ast.Import):
                for alias in node.names:
                    assert "kernels" not in alias.name or alias.name.endswith("params")


def free_fall(substeps: int | None) -> tuple[float, float, list[float]]:
    """Relative energy drift and largest constraint residual over 2 s of free fall at 1 ms
    periods, and the final arm angles. Without the mechanical stops: the arms swing past
    -180 deg, and a stop (inelastic) would take energy out of the fall."""
    plant = Plant(P, PlantConfig(quantise=False, substeps=substeps, arm_stops=None),
                  q0=(-0.3, -0.5, -0.4))
    e0 = plant.energy()
    drift = residual = 0.0
    for _ in range(2000):  # 2 s
        plant.step()
        drift = max(drift, abs(plant.energy() - e0))
        residual = max(residual, plant.constraint_error())
    return drift / abs(e0), residual, plant.state.q


def test_free_fall_conserves_energy_and_constraints():
    """Sub-steps of 0.5 ms and 0.1 ms: energy kept, constraints kept, and the drift falls
    as h^4 (RK4: (0.5 / 0.1)^4 = 625)."""
    coarse, res_coarse, q = free_fall(2)
    fine, res_fine, _ = free_fall(10)
    print(f"energy drift over 2 s: {coarse:.2e} of |E0| at h = 0.5 ms, {fine:.2e} at 0.1 ms "
          f"(ratio {coarse / fine:.1f}); constraint residual {max(res_coarse, res_fine):.1e} m;"
          f" arms now at {np.degrees(q).round(1)} deg")
    assert coarse < 2e-4
    assert fine < 1e-6
    assert 300 < coarse / fine < 1300
    assert max(res_coarse, res_fine) < 1e-9
    assert max(abs(a - b) for a, b in zip(q, (-0.3, -0.5, -0.4))) > 0.5  # it did move


def test_state_stays_plain_floats_from_numpy_inputs():
    """The launcher passes a task's start point (numpy) as the platform guess: a numpy
    scalar in the state once made every sub-step numpy arithmetic (3.4x slower)."""
    q0 = np.array(inverse_kinematics(P, (0.05, 0.0, -0.4)))
    plant = Plant(P, PlantConfig(), q0=tuple(q0), p_guess=tuple(np.array([0.05, 0.0, -0.4])))
    plant.set_command(np.array([0.5, 0.2, 0.1]))
    for _ in range(3):
        plant.step()
    plant.set_state(list(q0), list(np.zeros(3)), p_guess=list(np.array([0.05, 0.0, -0.4])))
    plant.step()
    s = plant.state
    values = [*s.q, *s.p, *s.qd, *s.pd, *s.tau_applied, *plant.command]
    assert all(type(v) is float for v in values), {type(v).__name__ for v in values}


def test_default_substep_keeps_the_free_fall_energy_within_its_stated_drift():
    """The default sub-step (1 ms at 1 ms periods): the energy drift of the harshest case
    is the one plant/substeps.py states (1.6e-3 of |E0| over 2 s), h^4 above 0.5 ms'."""
    assert PlantConfig().n_substeps == 1
    default, residual, _ = free_fall(None)
    half, _, _ = free_fall(2)
    print(f"energy drift over 2 s: {default:.2e} of |E0| at h = 1 ms, {half:.2e} at 0.5 ms")
    assert default < 3e-3
    assert 8 < default / half < 32  # (1 / 0.5)^4 = 16
    assert residual < 1e-9


def test_automatic_substeps_follow_the_period_and_the_belt():
    assert [PlantConfig(period=t).n_substeps for t in (1e-4, 1e-3, 1.1e-3, 6e-3)] == [1, 1, 2, 6]
    assert PlantConfig(belt=True).n_substeps == 10
    assert PlantConfig(substeps=3, belt=True).n_substeps == 3


def test_default_substep_changes_nothing_the_encoders_see():
    """Closed loop, pick & place, resolved acceleration at 1 ms: the platform path with
    the default sub-step (1 ms) against one 40 times shorter: nanometres, against an
    encoder increment of 8 um at the arm's tip."""
    from ctrlunit.kernels.laws import Gains
    from ctrlunit.runtime.compute.controller import simulate

    runs = [simulate(P, pick_place_task(), gains=Gains.from_bandwidth(20.0), cycles=600,
                     plant_config=PlantConfig(substeps=n)) for n in (None, 40)]
    diff = max(math.dist(a, b) for a, b in zip(runs[0].positions, runs[1].positions))
    moved = math.dist(runs[0].positions[0], runs[0].positions[-1])
    print(f"platform paths differ by {diff * 1e9:.2f} nm (moved {moved * 1e3:.0f} mm)")
    assert moved > 0.05
    assert diff < 1e-7


@pytest.mark.parametrize(
    "p", [(0, 0, -0.35), (0.15, 0, -0.4), (-0.1, 0.12, -0.45), (0.05, -0.2, -0.5), (0, 0, -0.6)]
)
def test_kernel_gravity_torques_hold_the_platform(p):
    q = inverse_kinematics(P, p)
    plant = Plant(P, PlantConfig(quantise=False), q0=tuple(q), p_guess=p)
    plant.set_command(list(gravity_torques(P, p)))
    drift = 0.0
    for _ in range(1000):
        plant.step()
        drift = max(drift, float(np.linalg.norm(np.array(plant.state.p) - np.array(p))))
    print(f"hold at {p}: drift {drift * 1e6:.4f} um over 1 s")
    assert drift < 1e-6


def open_loop_error(task, model: str) -> float:
    """Max platform error when the model's torques, evaluated from the reference at the
    plant's own sub-step times, drive the plant open loop (no lag, quantisation, friction,
    saturation)."""
    params = P.with_(tau_max=1e3)
    plant = Plant(params, PlantConfig(quantise=False))
    p0 = task.sample_path(0.0)[0]
    plant.set_state(list(inverse_kinematics(params, p0)), [0.0] * 3, p_guess=list(p0))
    h = plant.config.period / plant.config.n_substeps
    err, t = 0.0, 0.0
    for _ in range(int(task.duration / h) + 1):
        plant.set_command(list(inverse_dynamics(params, *task.sample_path(t + h / 2), model=model)))
        plant.substep(h)
        t += h
        err = max(err, float(np.linalg.norm(np.array(plant.state.p) - task.sample_path(t)[0])))
    return err


@pytest.mark.parametrize("task", [pick_place_task(), circle_task()], ids=lambda t: t.name)
def test_complete_model_drives_the_plant_along_the_task(task):
    complete = open_loop_error(task, "complete")
    simplified = open_loop_error(task, "simplified")
    print(f"{task.name}: open-loop error complete {complete * 1e3:.5f} mm, "
          f"simplified {simplified * 1e3:.2f} mm")
    assert complete < 1e-4
    assert simplified > 10 * complete


def test_circle_needs_more_than_the_torque_limit():
    """A finding: the § V.6.1 circle at 120 m/s^2 needs more than 20 N m (errata figures)."""
    task = circle_task()
    peak = max(
        np.abs(inverse_dynamics(P, *task.sample_path(t))).max()
        for t in np.linspace(0, task.duration, 300)
    )
    print(f"circle peak torque {peak:.2f} N m (limit {P.tau_max} N m)")
    assert peak > P.tau_max


def test_encoder_counts_agree_with_arm_angle_to_one_increment():
    plant = Plant(P, PlantConfig(), q0=(-0.3, -0.5, -0.4))
    for _ in range(200):
        plant.step()
        counts = plant.encoder_counts()
        for c, q in zip(counts, plant.state.q):
            assert isinstance(c, int)
            assert abs(c * P.increment - q) <= P.increment


def test_saturation_and_lag():
    plant = Plant(P, PlantConfig(lag=0.005), q0=(-0.4, -0.4, -0.4))
    plant.set_command([100.0, -100.0, 5.0])
    assert plant.command == [20.0, -20.0, 5.0]
    plant.step()
    # after 1 ms of a 5 ms lag: 1 - exp(-0.2) of the command
    assert math.isclose(plant.state.tau_applied[2], 5.0 * (1 - math.exp(-0.2)), rel_tol=1e-9)


def test_bad_config_names_the_field():
    with pytest.raises(PlantConfigError, match="substeps"):
        PlantConfig(substeps=0)
    with pytest.raises(PlantConfigError, match="lag"):
        PlantConfig(lag=-1.0)


def belt_resonance_hz() -> float:
    """Resonance of one chain measured from a simulated torque step on its motor."""
    p = (0.0, 0.0, -0.4)
    q = inverse_kinematics(P, p)
    cfg = PlantConfig(belt=True, quantise=False, period=1e-4, substeps=2)
    plant = Plant(P, cfg, q0=tuple(q), p_guess=p)
    hold = list(gravity_torques(P, p))
    plant.set_state(list(q))
    # pre-load the belt so that the hold is static, then step axis 1
    for i in range(3):
        plant.state.motor[i] = q[i] + hold[i] / cfg.belt_stiffness
    plant.set_command([hold[0] + 0.5, hold[1], hold[2]])
    defl = []
    for _ in range(2000):  # 0.2 s at 10 kHz
        plant.step()
        defl.append(plant.state.motor[0] - plant.state.q[0])
    x = np.array(defl) - np.mean(defl)
    spec = np.abs(np.fft.rfft(x * np.hanning(len(x))))
    freqs = np.fft.rfftfreq(len(x), 1e-4)
    return float(freqs[1 + np.argmax(spec[1:])])


def test_belt_resonance_is_measured_and_reported():
    f = belt_resonance_hz()
    print(f"single-chain belt resonance: {f:.0f} Hz (thesis § V.6.3: 125 Hz)")
    # two-mass bound: sqrt(k (1/j_m + 1/j_arm)) with j_arm between the bare arm and j_a
    lo = math.sqrt(8080 * (1 / 0.0065 + 1 / 0.05)) / (2 * math.pi)
    hi = math.sqrt(8080 * (1 / 0.0065 + 1 / (P.j_a - 0.0065))) / (2 * math.pi)
    assert lo * 0.9 < f < hi * 1.1


def _solve3_loop(a: list[list[float]], b: list[float]) -> list[float]:
    """The loop over columns plant/mechanics.py ``_solve3`` was written out from."""
    m = [a[0][:] + [b[0]], a[1][:] + [b[1]], a[2][:] + [b[2]]]
    for c in range(3):
        piv = max(range(c, 3), key=lambda r: abs(m[r][c]))
        if piv != c:
            m[c], m[piv] = m[piv], m[c]
        inv = 1.0 / m[c][c]
        for r in range(c + 1, 3):
            f = m[r][c] * inv
            if f != 0.0:
                for k in range(c, 4):
                    m[r][k] -= f * m[c][k]
    x = [0.0, 0.0, 0.0]
    for r in (2, 1, 0):
        x[r] = (m[r][3] - sum(m[r][k] * x[k] for k in range(r + 1, 3))) / m[r][r]
    return x


def _bits(v: float) -> bytes:
    """A float's bits, every NaN as one (a NaN's sign follows the order in which the C
    compiler put an addition's operands: not a property of the arithmetic)."""
    return b"nan" if math.isnan(v) else struct.pack("<d", v)


def test_written_out_solve_gives_the_loops_bits_and_raises_where_it_raised():
    """Random systems, and systems of zeros, ties, NaN and inf (pivot choice, skipped rows,
    singular pivots): the same bits (NaN where it gave NaN), or the same
    ZeroDivisionError."""
    from ctrlunit.plant.mechanics import _solve3

    rng = random.Random(7)
    special = [0.0, -0.0, 1.0, -1.0, 2.0, -2.0, 5e-324, 1e308, -1e308, math.nan, -math.nan,
               math.inf, -math.inf]
    raised = 0
    for i in range(20_000):
        pick = (lambda: rng.choice(special)) if i % 3 == 0 else (lambda: rng.gauss(0.0, 1.0))
        a = [[pick() for _ in range(3)] for _ in range(3)]
        b = [pick() for _ in range(3)]
        try:
            want = _solve3_loop(a, b)
        except ZeroDivisionError:
            with pytest.raises(ZeroDivisionError):
                _solve3(a, b)
            raised += 1
            continue
        got = _solve3(a, b)
        assert [_bits(v) for v in got] == [_bits(v) for v in want], (a, b)
    assert 100 < raised < 10_000  # both paths were taken


def test_fast_arms_take_more_substeps_where_none_were_asked_for():
    """Full torque on one arm with no stops flings the others to about 145 rad/s. The turn
    rule (plant/substeps.py) keeps 300 periods of it within 0.05 rad of
    a run 40 times finer; sub-steps of 1 ms alone end far off."""
    def fling(substeps: int | None) -> list[float]:
        plant = Plant(P, PlantConfig(substeps=substeps, arm_stops=None))
        plant.set_command([-P.tau_max, 0.0, 0.0])
        for _ in range(300):
            plant.step()
        assert plant.fault is None
        return plant.state.q

    fine, auto, coarse = fling(40), fling(None), fling(1)
    off = max(abs(a - b) for a, b in zip(auto, fine))
    off_coarse = max(abs(a - b) for a, b in zip(coarse, fine))
    print(f"after 300 periods: {off:.3f} rad from the fine run with the rule, "
          f"{off_coarse:.3f} rad with 1 ms sub-steps")
    assert off < 0.05
    assert off_coarse > 4 * off


def test_the_turn_rule_keeps_the_base_count_and_caps_its_own():
    from ctrlunit.plant.substeps import MAX_TURN_FACTOR, substeps_for

    assert substeps_for(1e-3, 1, [46.0, -20.0, 0.0]) == 1  # the circle task's fastest arm
    assert substeps_for(1e-3, 1, [0.0, -145.0, 0.0]) == 3
    assert substeps_for(2e-3, 2, [60.0, 0.0, 0.0]) == 3
    assert substeps_for(2e-3, 2, [10.0, 0.0, 0.0]) == 2
    assert substeps_for(1e-3, 1, [1e9, 0.0, 0.0]) == MAX_TURN_FACTOR
    assert substeps_for(0.2, 200, [60.0, 0.0, 0.0]) == 240  # a long period, as a short one
    assert substeps_for(0.2, 200, [1e9, 0.0, 0.0]) == 200 * MAX_TURN_FACTOR
    assert substeps_for(1e-3, 10, [600.0, 0.0, 0.0]) == 12  # the belt's base, and more
    for odd in ([math.inf, 0.0, 0.0], [0.0, math.nan, 1e9], [math.nan, 1e9, 0.0]):
        assert substeps_for(1e-3, 1, odd) == 1  # the integration stops on such a state
