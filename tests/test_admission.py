"""Admission control: the trial's verdict, the ladder, and a refusal before any motion."""

from __future__ import annotations

import numpy as np
import pytest
from ctrlunit.runtime.admission import (
    HEADROOM,
    LADDER_S,
    ladder_from,
    rung_verdict,
    trial_intervals,
)
from ctrlunit.runtime.config import EXIT_UNSUSTAINABLE
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


def test_the_ladder_climbs_from_the_period_asked_and_the_trial_is_bounded():
    assert ladder_from(1e-3) == list(LADDER_S)
    assert ladder_from(3e-3)[:2] == [3e-3, 3.2e-3]
    assert ladder_from(0.2)[1:] == []
    assert all(50 <= trial_intervals(p) <= 300 for p in (20e-6, 1e-3, 20e-3, 1.0))


def test_an_unsustainable_period_is_refused_before_the_plant_gets_a_command(tmp_path):
    code, rep, out = start_json(tmp_path, "--peripherals", "1", "--pipeline", "2",
                                "--clock", "realtime", "--period", "100us", tag="adm")
    assert code == EXIT_UNSUSTAINABLE, out
    msg = rep["fault"]["message"]
    assert rep["fault"]["process"] == "admission"
    assert "0.1 ms cannot be held" in msg and "trial" in msg
    assert rep["cycles"] == 0
    assert rep["plant_commands"] == 0  # the plant's own word
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
    # its period to the first that held
    final = [r for r in adm["rungs"] if r["start"] == adm["rungs"][-1]["start"]]
    assert final[-1]["held"] and final[-1]["period_s"] == adm["period_s"]
    assert not any(r["held"] for r in final[:-1])
    assert rep["cycles"] == 200 and rep["plant_commands"] > 0
    # --rt-priority auto: FIFO where permitted and the kernel throttles, and then the
    # admission held the machine's busy share to its limit
    from ctrlunit.runtime import sched

    fifo = sched.rt_budget() is not None and sched.fifo_permitted()
    choice = rep["scheduling_choice"]
    assert choice["asked"] == "auto" and choice["priority"] == (sched.AUTO_PRIORITY if fifo else 0)
    assert set(rep["scheduling"].values()) == {"SCHED_FIFO 10" if fifo else "SCHED_OTHER"}
    limit = final[-1]["busy_limit"]
    assert (limit == pytest.approx(sched.ADMIT_BUSY_SHARE * sched.rt_budget())) if fifo \
        else limit is None
    assert not fifo or final[-1]["busy_share"] <= limit


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


def test_latency_refuses_a_period_out_of_range():
    res = ctrlunit("latency", "--period", "5s", "--duration", "1s", timeout=30)
    assert res.returncode == 1
    assert "period" in res.stderr and "20us to 1s" in res.stderr


def test_the_tracking_prediction_of_a_long_run_simulates_one_loop_of_the_task(monkeypatch):
    """A 60 s or hour-long run repeats the task: its admission predicts the tracking from
    one loop (simulating every interval of the run took longer than the roles wait)."""
    from types import SimpleNamespace

    import ctrlunit.runtime.controller as controller
    from ctrlunit.kernels.params import DELTA_IA
    from ctrlunit.kernels.trajectory import get_task
    from ctrlunit.runtime.admission import predicted_tracking
    from ctrlunit.runtime.config import RunConfig

    asked: list[int] = []
    real = controller.simulate

    def counted(*a, cycles, **kw):
        asked.append(cycles)
        return real(*a, cycles=cycles, **kw)

    monkeypatch.setattr(controller, "simulate", counted)
    engine = SimpleNamespace(cfg=SimpleNamespace(params=DELTA_IA))
    loop = get_task("pick-place").period
    short = predicted_tracking(SimpleNamespace(rc=RunConfig.of(), engine=engine), 2e-3)
    long = predicted_tracking(SimpleNamespace(rc=RunConfig.of(duration=3600.0),
                                              engine=engine), 2e-3)
    assert asked == [round(loop / 2e-3) + 1] * 2
    assert long == short and 0 < short < 0.02
