"""Admission control: the trial's verdict, the ladder, and a refusal before any motion."""

from __future__ import annotations

import machine
import numpy as np
import pytest
from ctrlunit.runtime.config import EXIT_UNSUSTAINABLE
from ctrlunit.runtime.launch.admission import (
    EPISODE_GAP,
    HEADROOM,
    LADDER_S,
    ladder_from,
    rung_verdict,
    trial_intervals,
)
from runner import ctrlunit, start_json


def test_a_trial_within_the_headroom_holds_and_one_late_interval_in_200_is_allowed():
    budget = 2e-3
    t = np.full(400, 0.5 * budget)
    assert rung_verdict(t, skipped=0, budget_s=budget, transit_s=0.0)["held"]
    t[:2] = 1.1 * budget  # 2 of 400 late: the share allowed
    v = rung_verdict(t, skipped=0, budget_s=budget, transit_s=0.0)
    assert v["late"] == 2 and v["held"]
    t[:3] = 1.1 * budget  # 3 of 400: more than one in 200
    assert not rung_verdict(t, skipped=0, budget_s=budget, transit_s=0.0)["held"]


def test_skipped_samples_and_the_transit_count_against_the_budget():
    budget = 2e-3
    t = np.full(400, 0.5 * budget)
    v = rung_verdict(t, skipped=3, budget_s=budget, transit_s=0.0)
    assert v["late"] == 3 and v["intervals"] == 403 and not v["held"]
    # every interval inside the budget, but the p99 past the headroom once the command's
    # transit to the plant is added
    assert not rung_verdict(t, skipped=0, budget_s=budget,
                            transit_s=(HEADROOM - 0.49) * budget)["held"]


def test_under_fifo_a_trial_that_kept_the_machine_too_busy_does_not_hold():
    budget = 2e-3
    t = np.full(400, 0.5 * budget)
    v = rung_verdict(t, skipped=0, budget_s=budget, transit_s=0.0, busy_share=0.7,
                     busy_limit=0.76)
    assert v["held"] and v["busy_share"] == 0.7
    assert not rung_verdict(t, skipped=0, budget_s=budget, transit_s=0.0, busy_share=0.8,
                            busy_limit=0.76)["held"]
    assert rung_verdict(t, skipped=0, budget_s=budget, transit_s=0.0, busy_share=None,
                        busy_limit=0.76)["held"]  # unmeasured: the traversal alone decides
    assert rung_verdict(t, skipped=0, budget_s=budget, transit_s=0.0, busy_share=0.99)["held"]


def test_an_empty_trial_never_holds():
    assert not rung_verdict(np.array([]), skipped=0, budget_s=1e-3, transit_s=0.0)["held"]


def _stalled(n: int = 300, *, budget: float = 2e-3, at: int = 100, length: int = 30,
             base: float = 0.5) -> np.ndarray:
    t = np.full(n, base * budget)
    t[at:at + length] = np.linspace(3.0, 1.1, length) * budget  # the queue behind a stall
    return t


def test_a_trial_late_only_in_one_stall_is_worth_repeating():
    budget = 2e-3
    v = rung_verdict(_stalled(budget=budget), skipped=0, budget_s=budget, transit_s=0.0)
    assert not v["held"] and v["late"] == 30
    assert v["late_episodes"] == 1 and v["one_stall"]


def test_skips_inside_the_stall_belong_to_it_and_unlocated_skips_do_not():
    budget = 2e-3
    t = _stalled(budget=budget)
    v = rung_verdict(t, skipped=12, budget_s=budget, transit_s=0.0, skip_marks=[(110, 12)])
    assert v["late"] == 42 and v["late_episodes"] == 1 and v["one_stall"]
    v = rung_verdict(t, skipped=12, budget_s=budget, transit_s=0.0)
    assert v["late_episodes"] == 2 and not v["one_stall"]
    v = rung_verdict(t, skipped=12, budget_s=budget, transit_s=0.0,
                     skip_marks=[(129 + EPISODE_GAP, 12)])  # a second episode
    assert v["late_episodes"] == 2 and not v["one_stall"]


def test_a_steady_lag_two_stalls_or_a_slow_rest_are_not_one_stall():
    budget = 2e-3
    spread = np.full(300, 0.5 * budget)
    spread[::EPISODE_GAP] = 1.1 * budget  # late every EPISODE_GAP intervals: a lag
    v = rung_verdict(spread, skipped=0, budget_s=budget, transit_s=0.0)
    assert v["late_episodes"] == 30 and not v["one_stall"]
    two = _stalled(budget=budget, at=50, length=5)
    two[200:205] = 1.5 * budget
    v = rung_verdict(two, skipped=0, budget_s=budget, transit_s=0.0)
    assert v["late_episodes"] == 2 and not v["one_stall"]
    slow = _stalled(budget=budget, base=HEADROOM * 1.01)  # the rest past the headroom
    assert not rung_verdict(slow, skipped=0, budget_s=budget, transit_s=0.0)["one_stall"]
    long = _stalled(budget=budget, at=10, length=160)  # more than half the trial
    v = rung_verdict(long, skipped=0, budget_s=budget, transit_s=0.0)
    assert v["late_episodes"] == 1 and not v["one_stall"]
    v = rung_verdict(_stalled(budget=budget), skipped=0, budget_s=budget, transit_s=0.0,
                     busy_share=0.9, busy_limit=0.76)  # too busy, besides the stall
    assert not v["one_stall"]
    v = rung_verdict(np.full(300, 0.5 * budget), skipped=0, budget_s=budget, transit_s=0.0)
    assert v["held"] and v["late_episodes"] == 0 and not v["one_stall"]


def _admit_with_trials(monkeypatch, verdicts: list[dict], *, period: float = 1e-3):
    """``admit`` on a stand-in central whose trials return ``verdicts`` in turn."""
    from types import SimpleNamespace

    import ctrlunit.runtime.launch.admission as admission

    tried: list[float] = []

    def fake_trial(central, p, *, base, transit_s, unit_cpu=None, rehearse=None):
        tried.append(p)
        return {"period_s": p} | verdicts[len(tried) - 1]

    monkeypatch.setattr(admission, "trial", fake_trial)
    monkeypatch.setattr(admission, "predicted_tracking", lambda central, p: 0.0)
    rc = SimpleNamespace(schedule=SimpleNamespace(period=period, period_auto=False, pipeline=2),
                         control=SimpleNamespace(max_error=0.02))
    run = SimpleNamespace(times=SimpleNamespace(warm_rtt_s=()))
    central = SimpleNamespace(rc=rc, snapshot=lambda: run)
    return admission, central, tried


def test_the_admission_repeats_a_trial_with_one_stall_once_and_admits_if_it_holds(
        monkeypatch):
    budget = 2e-3
    stall = rung_verdict(_stalled(budget=budget), skipped=0, budget_s=budget, transit_s=0.0)
    clean = rung_verdict(np.full(300, 0.5 * budget), skipped=0, budget_s=budget,
                         transit_s=0.0)
    admission, central, tried = _admit_with_trials(monkeypatch, [stall, clean])
    info = admission.admit(central)
    assert tried == [1e-3, 1e-3] and info["period_s"] == 1e-3
    first, second = info["rungs"]
    assert first["one_stall"] and not first["held"] and "retry" not in first
    assert second["retry"] and second["held"]


def test_the_admission_repeats_at_most_one_trial_then_climbs(monkeypatch):
    budget = 2e-3
    stall = rung_verdict(_stalled(budget=budget), skipped=0, budget_s=budget, transit_s=0.0)
    clean = rung_verdict(np.full(300, 0.5 * budget), skipped=0, budget_s=budget,
                         transit_s=0.0)
    admission, central, tried = _admit_with_trials(monkeypatch, [stall, stall, stall, clean])
    with pytest.raises(admission.Unsustainable) as exc:
        admission.admit(central)
    assert tried == [1e-3, 1e-3, LADDER_S[7], LADDER_S[8]]
    assert exc.value.info["sustainable_period_s"] == LADDER_S[8]
    assert [r.get("retry", False) for r in exc.value.info["rungs"]] == [False, True, False,
                                                                        False]


def test_the_ladder_climbs_from_the_period_asked_and_the_trial_is_bounded():
    assert ladder_from(1e-3) == list(LADDER_S[6:])
    assert ladder_from(3e-3)[:2] == [3e-3, 3.2e-3]
    assert ladder_from(0.2)[1:] == []
    assert all(50 <= trial_intervals(p) <= 1200 for p in (20e-6, 1e-3, 20e-3, 1.0))


def test_an_unsustainable_period_is_refused_before_the_plant_gets_a_command(tmp_path):
    code, rep, out = start_json(tmp_path, "--peripherals", "1", "--pipeline", "2",
                                "--clock", "realtime", "--period", "100us", tag="adm")
    assert code == EXIT_UNSUSTAINABLE, out
    msg = rep["fault"]["message"]
    assert rep["fault"]["process"] == "admission"
    assert "0.1 ms cannot be held" in msg and "trial" in msg
    assert msg.startswith(rep["fault"]["headline"]) and rep["fault"]["advice"] in msg
    assert rep["cycles"] == 0
    assert rep["plant_commands"] == 0  # the plant's own word
    assert rep["plant_trial_commands"] > 0  # the trials' commands: checked, dropped
    first = rep["admission"]["rungs"][0]
    assert first["period_s"] == pytest.approx(100e-6) and not first["held"]
    # the climb stopped at the first period that held, or named why it could not
    held = rep["admission"]["sustainable_period_s"]
    assert held is None or held > 100e-6
    assert (f"{held * 1e3:g} ms" in msg) if held else ("ladder" in msg or "track" in msg)


def test_period_auto_runs_at_the_period_the_trial_held_and_says_so(tmp_path):
    # what is checked is the choice of period; a stall of a few ms after the trial (this
    # machine has them) must not end the run, so silence is tolerated for 100 periods
    code, rep, out = start_json(tmp_path, "--peripherals", "0", "--clock", "realtime",
                                "--period", "auto", "--cycles", "200", "--max-error", "1",
                                "--fault-periods", "100", tag="auto")
    adm = rep.get("admission") or {}
    if code == EXIT_UNSUSTAINABLE:  # this machine held no period of the ladder today
        assert adm["sustainable_period_s"] is None, out
        pytest.skip(f"no period held: {rep['fault']['message']}")
    assert code == 0, out
    assert adm["asked"] == "auto"
    assert adm["period_s"] == rep["nominal_period_s"]
    assert adm["period_s"] in LADDER_S
    # the start that ran (earlier starts, which climbed to it, come first): it climbed from
    # its period to the first that held, then went down the ladder while shorter periods
    # held, and runs at the last that held (a descent ends at the first that did not)
    final = [r for r in adm["rungs"] if r["start"] == adm["rungs"][-1]["start"]]
    climb = [r for r in final if not r.get("descent")]
    down = [r for r in final if r.get("descent")]
    assert climb[-1]["held"] and not any(r["held"] for r in climb[:-1])
    assert all(r["held"] for r in down[:-1])
    held = [climb[-1], *(r for r in down if r["held"])]
    assert held[-1]["period_s"] == adm["period_s"]
    assert rep["cycles"] == 200 and rep["plant_commands"] > 0
    # the held trial's commands went out as the run's do, and the plant dropped them
    assert rep["plant_trial_commands"] >= held[-1]["intervals"] - 3, rep["admission"]
    # late commands the plant replaced with the one extrapolated the period before
    assert 0 <= rep["plant_spares"] <= rep["deadline_misses"]
    # --rt-priority auto: FIFO where permitted and the kernel throttles, and then the
    # admission held the machine's busy share to its limit
    # (what this machine allows is read by the test itself: tests/machine.py)
    fifo = machine.auto_takes_fifo()
    choice = rep["scheduling_choice"]
    assert choice["asked"] == "auto" and choice["priority"] == (10 if fifo else 0)
    assert set(rep["scheduling"].values()) == {"SCHED_FIFO 10" if fifo else "SCHED_OTHER"}
    limit = final[-1]["busy_limit"]
    assert (limit == pytest.approx(0.75 * machine.rt_throttles())) if fifo else limit is None
    assert not fifo or final[-1]["busy_share"] <= limit
    # --idle auto: idle CPUs poll for the run where the kernel's request changes something
    assert rep["idle"]["in_force"] == ("poll" if machine.idle_can_poll() else "default")


def test_latency_reports_ordered_quantiles_and_a_histogram(tmp_path):
    import json

    png = tmp_path / "lat.png"
    res = ctrlunit("latency", "--period", "2ms", "--duration", "0.4s", "--plot", str(png),
                   "--json", timeout=60)
    assert res.returncode == 0, res.stderr
    rep = json.loads(res.stdout)
    q = rep["wakeup_latency_s"]
    assert rep["period_s"] == 0.002 and 100 <= rep["ticks"] <= 200
    assert 0 <= q["p50"] <= q["p99"] <= q["p999"] <= q["max"]
    assert rep["sustainable_period_s"] is None or rep["sustainable_period_s"] in LADDER_S
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # auto: the policy the unit's roles would get, and their idle CPUs
    assert rep["scheduling"] == ("SCHED_FIFO 10" if machine.auto_takes_fifo()
                                 else "SCHED_OTHER")
    assert rep["idle"]["in_force"] == ("poll" if machine.idle_can_poll() else "default")


def test_latency_measures_under_the_policy_asked_and_leaves_the_caller_as_it_was(tmp_path):
    import json
    import os

    from ctrlunit.runtime.launch.latency import latency_report

    res = ctrlunit("latency", "--period", "2ms", "--duration", "0.1s", "--rt-priority", "0",
                   "--plot", str(tmp_path / "lat.png"), "--json", timeout=60)
    assert res.returncode == 0, res.stderr
    from ctrlunit.runtime.host import sched

    # 0: the policy as it is, the one this test (and its child) runs under
    assert json.loads(res.stdout)["scheduling"] == sched.policy_name()
    before = os.sched_getscheduler(0)
    rep, lat = latency_report(2e-3, 0.02)
    assert os.sched_getscheduler(0) == before and lat.size == rep["ticks"] > 0


def test_latency_s_unit_trial_is_the_unit_start_runs(monkeypatch):
    """``latency --unit`` tries what ``ctrlunit start`` with the same options would run,
    stopped after its trial: every setting equal (the unit's fresh id aside). Its own
    configuration had the thesis's placement, not start's ``auto``, and measured a unit
    ten times slower than the one start runs."""
    from ctrlunit.runtime.launch.latency import trial_config

    ours = trial_config(peripherals=3, pipeline=2, period_s=1e-3, idle="auto").to_dict()
    captured = {}

    def fake_start(rc, **kw):
        captured["rc"] = rc
        return 0, {}

    monkeypatch.setattr("ctrlunit.runtime.launch.launcher.start", fake_start)
    from click.testing import CliRunner
    from ctrlunit.runtime.cli import cli

    CliRunner().invoke(cli, ["start", "--peripherals", "3", "--pipeline", "2", "--period",
                             "1ms"])
    theirs = captured["rc"].to_dict()
    differ = {k for k in ours.keys() | theirs.keys() if ours.get(k) != theirs.get(k)}
    assert differ <= {"unit", "trial_only"}, {k: (ours.get(k), theirs.get(k)) for k in differ}
    assert ours["placement_auto"] and ours["trial_only"]


def test_latency_refuses_a_period_out_of_range():
    res = ctrlunit("latency", "--period", "5s", "--duration", "1s", timeout=30)
    assert res.returncode == 1
    assert "period" in res.stderr and "20us to 1s" in res.stderr


def test_the_tracking_prediction_of_a_long_run_simulates_one_loop_of_the_task(monkeypatch):
    """A 60 s or hour-long run repeats the task: its admission predicts the tracking from
    one loop (simulating every interval of the run took longer than the roles wait)."""
    from types import SimpleNamespace

    import ctrlunit.runtime.compute.controller as controller
    from ctrlunit.kernels.params import DELTA_IA
    from ctrlunit.kernels.task_file import get_task
    from ctrlunit.runtime.config import RunConfig
    from ctrlunit.runtime.launch.admission import predicted_tracking

    asked: list[int] = []
    real = controller.simulate

    def counted(*a, cycles, **kw):
        asked.append(cycles)
        return real(*a, cycles=cycles, **kw)

    monkeypatch.setattr(controller, "simulate", counted)
    loop = get_task("pick-place").period
    short = predicted_tracking(SimpleNamespace(rc=RunConfig.of(), params=DELTA_IA), 2e-3)
    long = predicted_tracking(SimpleNamespace(rc=RunConfig.of(duration=3600.0),
                                              params=DELTA_IA), 2e-3)
    assert asked == [round(loop / 2e-3) + 1] * 2
    assert long == short and 0 < short < 0.02
