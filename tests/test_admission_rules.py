"""The admission's rules (runtime/launch/admission.py) with every figure written out: a trial's
length, the ladder, one trial's verdict at each of its edges, and how ``admit`` climbs,
repeats a trial once after one stall, and words a refusal. ``admit`` runs here on a
central reduced to what it reads, its trials and tracking predictions scripted; the real
trials run in tests/test_admission.py."""

from __future__ import annotations

import itertools
import math
import os
from collections import Counter
from types import SimpleNamespace
from typing import Any, ClassVar

import numpy as np
import pytest
from ctrlunit.runtime.central import Central, Supervision
from ctrlunit.runtime.config import RunConfig
from ctrlunit.runtime.host import sched
from ctrlunit.runtime.launch import admission
from ctrlunit.runtime.launch.admission import (
    LADDER_S,
    ShorterHeld,
    Unsustainable,
    admit,
    fifo_busy_limit,
    ladder_from,
    may_hold_at,
    rung_verdict,
    shorter_rungs,
    trial_intervals,
)

MS = 1e-3


def test_a_trial_lasts_0_3_s_within_50_and_1200_intervals():
    """0.3 s at every rung of the ladder, 0.25 ms (1200 intervals) included: a shorter
    trial would see fewer of the host's stalls at the shortest periods."""
    assert trial_intervals(1e-3) == 300
    assert trial_intervals(0.5e-3) == 600
    assert trial_intervals(0.25e-3) == 1200
    assert trial_intervals(0.2e-3) == 1200
    assert trial_intervals(2e-3) == 150
    assert trial_intervals(1.6e-3) == 187  # 0.3 / 0.0016 is 187.4999...: rounded down
    assert trial_intervals(10e-3) == 50
    assert trial_intervals(1e-3, seconds=0.1, least=20, most=90) == 90
    assert trial_intervals(1e-2, seconds=0.1, least=20, most=90) == 20


def test_the_ladder_and_where_a_period_asked_joins_it():
    assert LADDER_S == (0.25e-3, 0.32e-3, 0.4e-3, 0.5e-3, 0.64e-3, 0.8e-3, 1.0e-3, 1.25e-3,
                        1.6e-3, 2.0e-3, 2.5e-3, 3.2e-3, 4.0e-3, 5.0e-3, 6.4e-3, 8.0e-3,
                        10.0e-3)
    assert ladder_from(1e-3) == list(LADDER_S[6:])
    assert ladder_from(0.25e-3) == list(LADDER_S)
    assert ladder_from(0.45e-3)[:2] == [0.45e-3, 0.5e-3]
    assert ladder_from(1.2e-3) == [1.2e-3, *LADDER_S[7:]]
    assert ladder_from(1.2498e-3)[:2] == [1.2498e-3, 1.25e-3]
    assert ladder_from(1.24995e-3)[:2] == [1.24995e-3, 1.6e-3]  # within 1e-4: the same
    assert ladder_from(20e-3) == [20e-3]


def verdict(t: Any, **kw: Any) -> dict[str, Any]:
    args: dict[str, Any] = {"skipped": 0, "budget_s": 2 * MS, "transit_s": 0.0} | kw
    return rung_verdict(np.asarray(t, dtype=float), **args)


def test_a_verdict_reports_its_figures_with_the_transit_added():
    t = np.linspace(0.1, 1.0, 1000) * MS
    v = verdict(t, transit_s=0.1 * MS, skipped=2, busy_share=0.5, busy_limit=0.8)
    tt = t + 0.1 * MS
    assert v["intervals"] == 1002 and v["skipped"] == 2 and v["budget_s"] == 2 * MS
    assert v["busy_share"] == 0.5 and v["busy_limit"] == 0.8
    assert v["traversal_p50_s"] == float(np.median(tt))
    assert v["traversal_p99_s"] == float(np.quantile(tt, 0.99))
    assert v["traversal_p999_s"] == float(np.quantile(tt, 0.999))
    assert v["traversal_max_s"] == float(tt.max())
    assert v["late"] == 2 and v["held"]


def test_an_empty_trial_has_no_figures_and_does_not_hold():
    v = verdict([])
    assert v["intervals"] == 0 and not v["held"]
    assert v["traversal_p50_s"] == v["traversal_p99_s"] == v["traversal_p999_s"] == \
        v["traversal_max_s"] == math.inf


def test_one_late_interval_in_200_holds_and_the_p99_may_use_95_percent_of_the_budget():
    t = np.full(400, 1.0 * MS)
    t[:2] = 2.5 * MS  # 2 of 400 past the 2 ms budget: one in 200
    assert verdict(t)["late"] == 2 and verdict(t)["held"]
    t[2] = 2.5 * MS
    assert not verdict(t)["held"]
    edge = np.full(400, 0.95 * 2 * MS)
    assert verdict(edge)["held"]  # p99 at exactly 95 % of the budget
    assert not verdict(edge * 1.0001)["held"]
    # the late count is against the budget, the p99 against 95 % of it
    assert verdict(np.full(400, 1.99 * MS))["late"] == 0


def test_a_busy_cpu_under_fifo_refuses_at_its_limit_and_not_before():
    t = np.full(400, 1.0 * MS)
    assert verdict(t, busy_share=0.8, busy_limit=0.8)["held"]
    assert not verdict(t, busy_share=0.81, busy_limit=0.8)["held"]
    assert verdict(t, busy_share=None, busy_limit=0.8)["held"]
    assert verdict(t, busy_share=0.99, busy_limit=None)["held"]


def test_late_intervals_under_ten_apart_are_one_episode():
    t = np.full(400, 1.0 * MS)
    t[[100, 109]] = 3 * MS
    assert verdict(t)["late_episodes"] == 1
    t[109], t[110] = 1.0 * MS, 3 * MS
    assert verdict(t)["late_episodes"] == 2
    # a skip located at interval 105 joins the episode; one more skip not located: +1
    t[110] = 1.0 * MS
    t[109] = 3 * MS
    assert verdict(t, skipped=2, skip_marks=[(105, 2)])["late_episodes"] == 1
    assert verdict(t, skipped=3, skip_marks=[(105, 2)])["late_episodes"] == 2
    assert verdict(np.full(400, 1.0 * MS))["late_episodes"] == 0


def test_one_stall_is_one_episode_without_which_at_least_half_the_trial_holds():
    t = np.full(400, 1.0 * MS)
    t[200:210] = 5 * MS  # 10 late in one episode, the rest fine
    v = verdict(t)
    assert not v["held"] and v["late_episodes"] == 1 and v["one_stall"]
    assert not verdict(t, busy_share=0.9, busy_limit=0.8)["one_stall"]  # busy: no repeat
    t[[50, 350]] = 5 * MS  # two more episodes
    assert not verdict(t)["one_stall"]
    long = np.full(400, 1.0 * MS)
    long[150:351] = 5 * MS  # one episode, but the rest (199 of 400) is under half
    assert not verdict(long)["one_stall"]
    long[350] = 1.0 * MS  # the rest is 200 of 400: half
    assert verdict(long)["one_stall"]
    slow_rest = np.full(400, 1.96 * MS)
    slow_rest[200:210] = 5 * MS  # the rest's p99 past 95 % of the budget
    assert not verdict(slow_rest)["one_stall"]
    held = np.full(400, 1.0 * MS)
    held[7] = 5 * MS  # one late: held, nothing to repeat
    assert verdict(held)["held"] and not verdict(held)["one_stall"]


def test_the_fifo_busy_limit_is_75_percent_of_the_real_time_budget(monkeypatch):
    """A tenth below the guard's restore share (runtime/host/busy_guard.py)."""
    from ctrlunit.runtime.host.busy_guard import RESTORE_BUSY_SHARE

    monkeypatch.setattr(sched, "rt_budget", lambda: 0.95)
    monkeypatch.setattr(sched, "fifo_in_force", lambda: True)
    assert fifo_busy_limit() == pytest.approx(0.75 * 0.95)
    assert fifo_busy_limit() == pytest.approx((RESTORE_BUSY_SHARE - 0.1) * 0.95)
    monkeypatch.setattr(sched, "fifo_in_force", lambda: False)
    assert fifo_busy_limit() is None
    monkeypatch.setattr(sched, "fifo_in_force", lambda: True)
    monkeypatch.setattr(sched, "rt_budget", lambda: None)
    assert fifo_busy_limit() is None


# -- admit, its trials scripted --------------------------------------------------------


def rung(period: float, *, held: bool, one_stall: bool = False, busy: float | None = None,
         limit: float | None = None) -> dict[str, Any]:
    return {"period_s": period, "held": held, "one_stall": one_stall, "intervals": 300,
            "late": 0 if held else 12, "traversal_p99_s": 0.8 * period if held else
            2.4 * period, "budget_s": 2 * period, "busy_share": busy, "busy_limit": limit}


def scripted(monkeypatch, verdicts: list[dict[str, Any]], tracking: dict[float, float]
             | None = None, **rc: Any) -> tuple[Any, list[tuple[float, int]]]:
    calls: list[tuple[float, int]] = []
    queue = list(verdicts)

    def trial(central: Any, period: float, *, base: int, transit_s: float,
              unit_cpu: Any = None, rehearse: Any = None) -> dict:
        assert transit_s == 0.25 * MS  # half the median warm-up round trip
        assert rehearse is None  # admit() was given none
        calls.append((period, base))
        return dict(queue.pop(0))

    monkeypatch.setattr(admission, "trial", trial)
    monkeypatch.setattr(admission, "predicted_tracking",
                        lambda central, period: (tracking or {}).get(period, 1e-5))
    monkeypatch.setattr(sched, "fifo_in_force", lambda: False)
    monkeypatch.setattr(sched, "fifo_permitted", lambda: True)
    run = SimpleNamespace(times=SimpleNamespace(warm_rtt_s=(0.4 * MS, 0.5 * MS, 0.9 * MS)))
    central = SimpleNamespace(rc=RunConfig.of(clock="realtime", pipeline=2, **rc), run=run,
                              snapshot=lambda: run)
    return central, calls


def test_a_period_that_holds_at_once_is_admitted_with_the_rules_figures(monkeypatch):
    central, calls = scripted(monkeypatch, [rung(1e-3, held=True)])
    info = admit(central)
    assert calls == [(1e-3, 1 << 41)]
    assert info["period_s"] == info["sustainable_period_s"] == 1e-3
    assert (info["asked"], info["depth"], info["transit_s"]) == (1e-3, 2, 0.25 * MS)
    assert (info["headroom"], info["late_share"], info["tracking_share"]) == (0.95, 1 / 200,
                                                                              0.5)
    assert info["rungs"][0]["predicted_tracking_max_m"] == 1e-5


def test_one_stall_repeats_the_trial_once_and_only_once(monkeypatch):
    central, calls = scripted(monkeypatch, [rung(1e-3, held=False, one_stall=True),
                                            rung(1e-3, held=False, one_stall=True),
                                            rung(1.25e-3, held=True)], period_auto=True)
    with pytest.raises(Unsustainable) as e:
        admit(central)
    base = 1 << 41
    assert calls == [(1e-3, base), (1e-3, base + (1 << 20)), (1.25e-3, base + (2 << 20))]
    info = e.value.info
    assert [r.get("retry", False) for r in info["rungs"]] == [False, True, False]
    assert info["sustainable_period_s"] == 1.25e-3 and info["asked"] == "auto"
    assert e.value.code == 7
    assert "the shortest period measured to hold is 1.25 ms" in str(e.value)
    assert "Try" not in str(e.value)  # auto starts again at 1.25 ms by itself


def test_a_refusal_names_the_first_trials_figures_and_what_to_try(monkeypatch):
    """Each figure against its rule, a broken one with its limit: "the traversal p99 was
    2.86 ms of a 3.00 ms budget" read as a pass to a new user (the limit was 2.85 ms)."""
    central, _ = scripted(monkeypatch, [rung(1e-3, held=False), rung(1.25e-3, held=True)])
    with pytest.raises(Unsustainable) as e:
        admit(central)
    assert str(e.value) == (
        "the period of 1 ms cannot be held here: in a trial of 300 intervals before any "
        "motion, 12 were late, more than the 1 allowed; the traversal p99 was 2.40 ms, over "
        "the 1.90 ms allowed (95% of a 2.00 ms budget: 2 period(s)); the shortest period "
        "measured to hold is 1.25 ms. Try --period auto "
        "(it climbs to a period that holds at each start); or --period 1.25ms (measured to "
        "hold); or --rt-priority 10 (SCHED_FIFO: other programs then wait for the unit). "
        "ctrlunit latency --unit measures what this machine holds for the unit.")


@pytest.mark.parametrize(("held", "suggested"), [
    ({}, "--period 1.25ms (measured to hold)"),
    ({"traversal_p99_s": 0.9 * 0.95 * 2.5e-3 * 1.01}, "--period 1.6ms (1.25 ms held, near its "
                                                        "limit)"),
    ({"busy": 0.74, "limit": 0.8}, "--period 1.6ms (1.25 ms held, near its limit)"),
    ({"busy": 0.71, "limit": 0.8}, "--period 1.25ms (measured to hold)"),
])
def test_a_refusal_suggests_a_rung_higher_than_one_that_held_near_a_limit(monkeypatch, held,
                                                                          suggested):
    """A period that held within 90 % of a limit (the traversal p99 of its headroom, the
    busy share of its limit) was refused by the next start's trial as often as not on a
    busy host: the refusal then suggests the next rung; ``--period auto`` comes first."""
    ok = rung(1.25e-3, held=True, busy=held.get("busy"), limit=held.get("limit"))
    ok |= {k: v for k, v in held.items() if k == "traversal_p99_s"}
    central, _ = scripted(monkeypatch, [rung(1e-3, held=False), ok])
    with pytest.raises(Unsustainable) as e:
        admit(central)
    assert f"Try --period auto (it climbs to a period that holds at each start); or {suggested}" \
        in str(e.value)


def test_a_busy_cpu_is_named_in_the_refusal(monkeypatch):
    central, _ = scripted(monkeypatch, [rung(1e-3, held=False, busy=0.9, limit=0.7125)]
                          + [rung(p, held=False) for p in LADDER_S[7:]])
    with pytest.raises(Unsustainable) as e:
        admit(central)
    msg = str(e.value)
    assert ("; a CPU was 90% busy under SCHED_FIFO, over the limit of 71% of the CPU (75% "
            "of the kernel's real-time budget); ") in msg
    assert msg.endswith("or a placement from ctrlunit balance (less of the unit's CPU "
                        "time). ctrlunit latency --unit measures what this machine holds for the "
                        "unit.")
    assert "none of the ladder's periods up to 10 ms held either (the last: traversal " \
           "p99 24.00 ms of 20.00 ms)" in msg
    assert e.value.info["sustainable_period_s"] is None


def test_a_task_the_period_cannot_track_is_refused_before_any_trial(monkeypatch):
    central, calls = scripted(monkeypatch, [], tracking={1e-3: 0.011})
    with pytest.raises(Unsustainable) as e:
        admit(central)
    assert calls == []
    assert str(e.value).startswith(
        "the task cannot be tracked at 1 ms: the one-process simulation at it tracks "
        "within 11.0 mm, more than half (10 mm) of --max-error 20 mm; refused before any motion")
    assert e.value.info["untrackable_from_s"] == 1e-3


def test_the_climb_stops_where_tracking_gets_too_poor(monkeypatch):
    central, calls = scripted(monkeypatch, [rung(1e-3, held=False)],
                              tracking={1.25e-3: 0.0101})
    with pytest.raises(Unsustainable) as e:
        admit(central)
    assert calls == [(1e-3, 1 << 41)]
    assert "the longer periods that might hold track the task worse than half of " \
           "--max-error (at 1.25 ms the one-process simulation tracks within 10.1 mm)" in \
        str(e.value)
    assert e.value.info["untrackable_from_s"] == 1.25e-3


def test_the_tracking_a_period_predicts_is_the_one_process_loops_at_it():
    """1 ms with the main job's settings (depth 2, foreseen2): 0.019 mm, as README says;
    at 8 ms 5.8 mm (its default gains 5 Hz: the margin at twice the period); the kinematics
    law has no torques to track with (NaN)."""
    from ctrlunit.runtime.compute.setup import make_setup

    rc = RunConfig.of(clock="realtime", pipeline=2)
    engine = make_setup(rc).engine()
    central = SimpleNamespace(rc=rc, params=engine.cfg.params)
    assert f"{admission.predicted_tracking(central, 1e-3) * 1e3:.3f}" == "0.019"
    assert f"{admission.predicted_tracking(central, 8e-3) * 1e3:.1f}" == "5.8"
    kin = SimpleNamespace(rc=rc.replace(law="kinematics"), params=engine.cfg.params)
    assert math.isnan(admission.predicted_tracking(kin, 1e-3))
    # at 50 ms the loop loses the robot: its observer finds no pose (ObserverDiverged,
    # which a live start reported as "a damaged recording?", exit 1), now infinite
    assert admission.predicted_tracking(central, 50e-3) == math.inf
    assert "loses the robot" in admission.tracks(math.inf)


def test_a_trial_longer_than_two_seconds_is_said_before_it_runs(monkeypatch):
    """A long period's trial (50 intervals at least) would keep the user waiting in
    silence: at 50 ms, 2.5 s is said first; at 1 ms (0.3 s) nothing is."""
    said: list[str] = []
    central, _ = scripted(monkeypatch, [rung(50e-3, held=True)], period=50e-3)
    admit(central, note=said.append)
    assert said == ["ctrlunit: the admission's trial at 50 ms: 50 intervals, 2 s before the "
                    "first command (--no-admission skips it)"]
    central, _ = scripted(monkeypatch, [rung(1e-3, held=True)])
    admit(central, note=said.append)
    assert len(said) == 1


def test_auto_goes_down_the_ladder_while_the_shorter_periods_hold(monkeypatch):
    """``--period auto``'s first start, 1 ms held: a trial at each shorter rung, longest
    first, until one does not hold; the shortest that held is where the unit starts
    again (:class:`ShorterHeld`, a refusal of the period asked)."""
    central, calls = scripted(monkeypatch, [rung(1e-3, held=True), rung(0.8e-3, held=True),
                                            rung(0.64e-3, held=False)], period_auto=True)
    with pytest.raises(ShorterHeld) as e:
        admit(central, descend=True)
    base = 1 << 41
    assert calls == [(1e-3, base), (0.8e-3, base + (1 << 20)), (0.64e-3, base + (2 << 20))]
    info = e.value.info
    assert info["period_s"] == info["sustainable_period_s"] == 0.8e-3
    assert [r.get("descent", False) for r in info["rungs"]] == [False, True, True]
    assert str(e.value) == "1 ms held, and so did 0.8 ms" and e.value.code == 7
    central, calls = scripted(monkeypatch, [rung(1e-3, held=True)], period_auto=True)
    assert admit(central)["period_s"] == 1e-3 and len(calls) == 1  # not asked to descend


def test_the_descent_tries_no_period_the_last_one_held_says_will_not_hold(monkeypatch):
    """The busy share grows as the period shrinks: 60 % of a 71.25 % limit at 1 ms is 75 %
    at 0.8 ms, so no trial there. A traversal p99 of 0.9 ms fits 95 % of a 2-period budget
    down to 0.5 ms (0.95 ms), not at 0.4 ms (0.76 ms)."""
    central, calls = scripted(monkeypatch, [rung(1e-3, held=True, busy=0.6, limit=0.7125)],
                              period_auto=True)
    info = admit(central, descend=True)
    assert calls == [(1e-3, 1 << 41)] and info["period_s"] == 1e-3
    slow = {"traversal_p99_s": 0.9e-3}
    central, calls = scripted(monkeypatch, [rung(p, held=True) | slow
                                            for p in (1e-3, 0.8e-3, 0.64e-3, 0.5e-3)],
                              period_auto=True)
    with pytest.raises(ShorterHeld) as e:
        admit(central, descend=True)
    assert [p for p, _ in calls] == [1e-3, 0.8e-3, 0.64e-3, 0.5e-3]
    assert e.value.info["sustainable_period_s"] == 0.5e-3


def test_may_hold_at_scales_the_last_figures_to_the_shorter_period():
    held = rung(1e-3, held=True, busy=0.5, limit=0.625) | {"traversal_p99_s": 0.95e-3}
    assert may_hold_at(held, 0.8e-3)  # busy 0.625 of 0.625; p99 0.95 of 0.95 * 1.6 ms
    assert not may_hold_at(held, 0.79e-3)
    assert may_hold_at(held | {"busy_share": None}, 0.5e-3)  # p99 0.95 of 0.95 ms
    assert not may_hold_at(held | {"busy_share": None}, 0.49e-3)
    assert shorter_rungs(1e-3) == [0.8e-3, 0.64e-3, 0.5e-3, 0.4e-3, 0.32e-3, 0.25e-3]
    assert shorter_rungs(0.25e-3) == []


def test_a_shorter_period_not_tried_is_said_with_the_figure_that_ruled_it_out(monkeypatch):
    """``--period auto`` that stays at 1 ms said nothing of why (a new user's review):
    the rung keeps why the next shorter one was not tried, and the summary says it."""
    from ctrlunit.runtime.launch.admission import why_not_at
    from ctrlunit.runtime.observe.summary import _admission_lines

    held = rung(1e-3, held=True, busy=0.6, limit=0.71) | {"traversal_p99_s": 0.3e-3}
    assert why_not_at(held, 0.8e-3) == ("0.8 ms not tried: a CPU 60% busy at 1 ms would be "
                                        "75% there, over the limit of 71%")
    slow = held | {"busy_share": None, "traversal_p99_s": 1.6e-3}
    assert "the traversal p99 of 1.60 ms would pass 95% of its 1.60 ms budget" in \
        why_not_at(slow, 0.8e-3)
    central, calls = scripted(monkeypatch, [held], period=1e-3)
    info = admit(central, descend=True)
    assert calls == [(1e-3, 1 << 41)]  # no trial below
    line = _admission_lines({"admission": info})[0]
    assert line.endswith("; 0.8 ms not tried: a CPU 60% busy at 1 ms would be 75% there, "
                         "over the limit of 71%"), line


# -- edges of the verdict and the refusal's wording ------------------------------------


def test_a_verdict_at_its_exact_edges():
    assert verdict(np.full(400, 2 * MS))["late"] == 0  # at the budget: on time
    one = verdict([1.0 * MS])
    assert one["intervals"] == 1 and one["held"] is True  # a single interval can hold
    busy = verdict(np.full(400, 1.0 * MS), busy_share=0.9, busy_limit=0.8)
    assert busy["held"] is False and busy["one_stall"] is False
    edge = np.full(400, 0.95 * 2 * MS)
    edge[200:205] = 5 * MS  # one stall; the rest's p99 exactly at 95 % of the budget
    assert verdict(edge)["one_stall"] is True


def test_without_a_warm_up_round_trip_the_transit_is_zero(monkeypatch):
    central, _ = scripted(monkeypatch, [rung(1e-3, held=True)])
    central.run.times.warm_rtt_s = ()
    seen = []
    monkeypatch.setattr(admission, "trial",
                        lambda c, period, *, base, transit_s, unit_cpu, rehearse: (
                            seen.append((c, transit_s)) or rung(period, held=True)))
    info = admit(central)
    assert info["transit_s"] == 0.0 and seen == [(central, 0.0)]


def test_the_trials_and_the_tracking_are_asked_of_this_central(monkeypatch):
    central, _ = scripted(monkeypatch, [rung(1e-3, held=False, one_stall=True),
                                        rung(1e-3, held=True)],
                          tracking={1e-3: 0.01})  # exactly half of --max-error: fine
    asked = []
    monkeypatch.setattr(admission, "predicted_tracking",
                        lambda c, period: asked.append(c) or 0.01)
    inner = admission.trial
    monkeypatch.setattr(admission, "trial", lambda c, *a, **k: (
        asked.append(c) or inner(c, *a, **k)))
    info = admit(central)
    assert asked == [central, central, central]
    assert info["rungs"][1]["retry"] is True
    assert info["rungs"][1]["predicted_tracking_max_m"] == 0.01


def test_the_refusals_words_and_figures_in_full(monkeypatch):
    central, _ = scripted(monkeypatch, [rung(10e-3, held=False)], period=10e-3)
    with pytest.raises(Unsustainable) as e:
        admit(central)
    assert str(e.value) == (
        "the period of 10 ms cannot be held here: in a trial of 300 intervals before any "
        "motion, 12 were late, more than the 1 allowed; the traversal p99 was 24.00 ms, over "
        "the 19.00 ms allowed (95% of a 20.00 ms budget: 2 period(s)); none of the "
        "ladder's periods up to 10 ms held either (the last: "
        "traversal p99 24.00 ms of 20.00 ms). Try --rt-priority 10 (SCHED_FIFO: other "
        "programs then wait for the unit). ctrlunit latency --unit measures what this "
        "machine holds for the unit.")
    monkeypatch.setattr(sched, "fifo_in_force", lambda: True)
    central, _ = scripted(monkeypatch, [rung(10e-3, held=False)], period=10e-3)
    monkeypatch.setattr(sched, "fifo_in_force", lambda: True)
    with pytest.raises(Unsustainable) as e:
        admit(central)
    assert str(e.value).endswith("20.00 ms). ctrlunit latency --unit measures what this "
                                 "machine holds for the unit.")  # FIFO, not busy: nothing to try
    central, _ = scripted(monkeypatch, [], tracking={1e-3: 0.1234})
    with pytest.raises(Unsustainable, match="tracks within 123.4 mm"):
        admit(central)
    central, _ = scripted(monkeypatch, [rung(1e-3, held=False)], tracking={1.25e-3: 0.1234})
    with pytest.raises(Unsustainable,
                       match=r"\(at 1.25 ms the one-process simulation tracks within 123.4"):
        admit(central)
    central, _ = scripted(monkeypatch, [rung(1e-3, held=False), rung(1.25e-3, held=True)],
                          period_auto=True)
    with pytest.raises(Unsustainable) as e:
        admit(central)
    assert str(e.value).endswith("the shortest period measured to hold is 1.25 ms.")


def test_each_law_is_simulated_as_it_runs():
    """The prediction uses the run's law: PD + gravity tracks far worse than resolved
    acceleration at 1 ms."""
    from ctrlunit.runtime.compute.setup import make_setup

    rc = RunConfig.of(clock="realtime", pipeline=2, law="pd-gravity")
    central = SimpleNamespace(rc=rc, params=make_setup(rc).engine().cfg.params)
    assert admission.predicted_tracking(central, 1e-3) > 10 * 0.019e-3


# -- one trial, its probe scripted ------------------------------------------------------


class Publisher:
    """Stands for a Zenoh publisher the trial central declares."""

    def __init__(self, key: str) -> None:
        self.key = key
        self.undeclared = 0

    def undeclare(self) -> None:
        self.undeclared += 1


class TrialNode:
    """Stands for the run's node, which the trial central shares: what it rejected, and
    every publisher declared on it."""

    def __init__(self) -> None:
        self.rejected: Counter[str] = Counter()
        self.declared: list[Publisher] = []

    def publisher(self, key: str) -> Publisher:
        pub = Publisher(key)
        self.declared.append(pub)
        return pub


class Probe:
    """Stands for the trial central (runtime/central/, ``Central(trial=True)``): ``run``
    makes the traversals, skips and fault the test scripts."""

    script: ClassVar[dict[str, Any]] = {}
    made: ClassVar[list[Probe]] = []

    def __init__(self, node: Any, rc: Any, engine: Any, controller: Any, n: int, *,
                 trial: bool, supervision: Any, reply_each: bool, on_cycle: Any = None,
                 on_message: Any = None) -> None:
        assert trial is True
        self.on_cycle, self.on_message = on_cycle, on_message
        self.node, self.rc, self.engine, self.controller, self.n = node, rc, engine, \
            controller, n
        self.supervision, self.reply_each = supervision, reply_each
        # declared on the run's node, as the real one's outgoing and orders do
        self.outgoing = SimpleNamespace(publishers=[node.publisher("request"),
                                                    node.publisher("command")])
        self.orders = SimpleNamespace(pubs=[node.publisher("control"),
                                            node.publisher("plant")])
        Probe.made.append(self)

    def snapshot(self) -> Any:
        s = self.script
        times = SimpleNamespace(traversal_ns=tuple(int(t * 1e9) for t in s.get("traversal_s", [])),
                                skip_marks=tuple(s.get("marks", [])))
        return SimpleNamespace(times=times, skipped=s.get("skipped", 0))

    def run(self) -> None:
        self.node.rejected["late_reply"] += self.script.get("late_replies", 0)
        if self.script.get("fault"):
            from ctrlunit.runtime.central import Fault

            raise Fault(self.script["fault"], process="peripheral-1", code=3)


class Outside:
    """The central as the admission sees it: the run's :class:`Central` methods on parts
    that stand in for the real ones."""

    say = Central.say

    def __init__(self, **parts: Any) -> None:
        self.__dict__.update(parts)

    def snapshot(self) -> Any:
        return SimpleNamespace(rejected=dict(self.node.rejected))


def trial_central(monkeypatch, script: dict[str, Any], *, controller: Any = None,
                  supervision: Supervision | None = None, **rc: Any) -> Any:
    """The run's central as the admission sees it (:class:`Outside`), on a
    :class:`TrialNode`, with the run's ``controller`` and ``supervision`` where given;
    its trial centrals are :class:`Probe` running ``script``."""
    from ctrlunit.runtime.central import trial

    Probe.script, Probe.made = script, []
    monkeypatch.setattr(trial, "Central", Probe)
    monkeypatch.setattr(sched, "cpu_times", lambda: [(0, 0)])
    steal = itertools.cycle([[12.5, 3.0], [12.54, 3.01]])  # before and after each trial
    monkeypatch.setattr(sched, "stolen_s", lambda: next(steal))
    monkeypatch.setattr(sched, "busy_share", lambda a, b: 0.42)
    monkeypatch.setattr(admission, "fifo_busy_limit", lambda: None)
    said, drained = [], []
    cfg = RunConfig.of(clock="realtime", pipeline=2, **rc)
    ctl = SimpleNamespace(first_cycle=0, q_prev=[1, 2, 3], k_prev=0) if controller is None \
        else controller
    return Outside(
        rc=cfg, node=TrialNode(), engine="engine", ctl=ctl,
        silence=SimpleNamespace(supervision=Supervision() if supervision is None
                                 else supervision),
        outgoing=SimpleNamespace(reply_each=True),
        orders=SimpleNamespace(say=lambda stage, **kw: said.append((stage, kw)),
                               drain=lambda *, seconds: drained.append(seconds)),
        said=said, drained=drained)


def test_a_trial_runs_its_intervals_on_a_copy_of_the_controller_and_judges_them(monkeypatch):
    t = [0.4 * MS] * 299 + [3 * MS]
    run_ctl = SimpleNamespace(first_cycle=0, q_prev=[1, 2, 3], k_prev=0)
    c = trial_central(monkeypatch, {"traversal_s": t, "skipped": 1, "marks": [(10, 1)]},
                      controller=run_ctl)
    out = admission.trial(c, 1e-3, base=1 << 41, transit_s=0.1 * MS)
    probe = Probe.made[0]
    assert probe.n == 300 and probe.rc.schedule.period == 1e-3
    assert probe.rc.run.t1_cycles == 0 and probe.rc.run.record is None
    assert probe.node is c.node and probe.engine == "engine" and probe.reply_each is True
    trial_ctl = probe.controller
    assert trial_ctl is not run_ctl and run_ctl.first_cycle == 0  # a copy, the run's untouched
    assert (trial_ctl.first_cycle, trial_ctl.q_prev, trial_ctl.k_prev) == (1 << 41, None,
                                                                           1 << 41)
    assert c.said == [("probe", {"period": 1e-3, "ticks": 300, "base": 1 << 41})]
    assert out["period_s"] == 1e-3 and out["budget_s"] == 2e-3  # depth 2: two periods
    assert out["intervals"] == 301 and out["late"] == 2 and out["busy_share"] == 0.42
    assert out["traversal_max_s"] == pytest.approx(3.1 * MS)
    assert "fault" not in out and out["wall_s"] >= 0 and c.drained == [0.0]
    # what the trial central declared on the run's node is undeclared, once
    assert [p.undeclared for p in c.node.declared] == [1, 1, 1, 1]


def test_the_late_replies_of_a_trials_rounds_are_the_trials_not_the_runs(monkeypatch):
    """A new user's summary said 23 late replies for 1 late round: the other 22 were the
    admission trials' (rounds a trial computed itself), counted on the node the run
    shares."""
    c = trial_central(monkeypatch, {"traversal_s": [0.4 * MS] * 300, "late_replies": 22})
    c.node.rejected["late_reply"] = 1  # one of the run's (the warm-up has none; say one)
    out = admission.trial(c, 1e-3, base=5, transit_s=0.0)
    assert out["late_replies"] == 22 and c.node.rejected["late_reply"] == 1
    c = trial_central(monkeypatch, {"traversal_s": [0.4 * MS] * 300, "late_replies": 3})
    assert admission.trial(c, 1e-3, base=5, transit_s=0.0)["late_replies"] == 3
    assert "late_reply" not in c.node.rejected  # no count of 0 left in the report


def test_a_trial_that_faults_does_not_hold_and_drains_its_stragglers(monkeypatch):
    c = trial_central(monkeypatch, {"traversal_s": [0.4 * MS] * 100,
                                    "fault": "peripheral 1 has not answered"})
    out = admission.trial(c, 1e-3, base=5, transit_s=0.0)
    assert out["held"] is False and out["one_stall"] is False
    assert out["fault"] == "peripheral 1 has not answered"
    assert out["intervals"] == 300 and out["late"] == 200  # the 200 that never ran
    assert c.drained == [pytest.approx(0.05)]  # 50 periods, at most 0.2 s
    assert [p.undeclared for p in c.node.declared] == [1, 1, 1, 1]  # a fault's trial too
    c = trial_central(monkeypatch, {"fault": "x"})
    admission.trial(c, 10e-3, base=5, transit_s=0.0)
    assert c.drained == [0.2]


def test_a_run_that_records_does_the_recordings_work_in_each_trial(monkeypatch):
    """Each trial gets a rehearsal of its own: its callbacks are the trial central's, and
    it is discarded after the trial, a trial that faults included; without ``rehearse``
    the trial central has no callbacks."""
    made = []

    class Rehearsal:
        def __init__(self) -> None:
            self.discarded_with: Any = None
            made.append(self)

        def on_cycle(self, progress: Any, ctx: dict) -> None: ...

        def on_message(self, *args: Any) -> None: ...

        def discard(self, run: Any) -> None:
            self.discarded_with = run

    for script in ({"traversal_s": [0.4 * MS] * 300}, {"fault": "x"}):
        c = trial_central(monkeypatch, script)
        admission.trial(c, 1e-3, base=5, transit_s=0.0, rehearse=Rehearsal)
        probe, r = Probe.made[0], made[-1]
        assert probe.on_cycle == r.on_cycle and probe.on_message == r.on_message
        assert r.discarded_with.times == probe.snapshot().times
    assert len(made) == 2
    c = trial_central(monkeypatch, {"traversal_s": [0.4 * MS] * 300})
    admission.trial(c, 1e-3, base=5, transit_s=0.0)
    assert Probe.made[0].on_cycle is None and Probe.made[0].on_message is None


def test_a_recorders_rehearsal_writes_nowhere_and_ends(tmp_path):
    """``Recorder.rehearsal`` writes to /dev/null (nothing appears where the run records)
    and ``discard`` ends it: its writer's thread is gone."""
    import threading

    from ctrlunit.runtime.compute.setup import make_setup
    from ctrlunit.runtime.recording.recorder import Recorder

    rec = tmp_path / "run.mcap"
    setup = make_setup(RunConfig.of(clock="realtime", pipeline=2, record=str(rec)))
    before = {t.name for t in threading.enumerate()}
    r = Recorder.rehearsal(setup)
    assert r.path == os.devnull
    run = SimpleNamespace(next_cycle=0, rejected={}, plant_misses=0, skipped=0,
                          times=SimpleNamespace(t_end_ns=0, t_start_ns=0, wait_ns=0,
                                                periph_busy_ns=(), plant_busy_ns=0))
    r.discard(run)
    assert r.closed and not rec.exists()
    assert {t.name for t in threading.enumerate()} <= before


def test_a_trial_whose_child_died_is_the_runs_fault(monkeypatch):
    from ctrlunit.runtime.central import Fault

    def child_check(**_: Any) -> tuple[str, int]:
        return ("peripheral-1", 1)

    c = trial_central(monkeypatch, {"fault": "peripheral 1 exited"},
                      supervision=Supervision(child_check=child_check))
    with pytest.raises(Fault, match="peripheral 1 exited"):
        admission.trial(c, 1e-3, base=5, transit_s=0.0)
    assert Probe.made[0].supervision.child_check is child_check


def test_a_trial_judges_the_units_own_cpu_time_where_it_is_read(monkeypatch):
    """Under FIFO the kernel throttles only real-time time: the unit's own, read before
    the plant ticks and after the trial (runtime/host/unit_load.py); the machine's busy
    share (0.42 here: another program's time counted) is kept beside it."""
    c = trial_central(monkeypatch, {"traversal_s": [0.4 * MS] * 300})
    readings = iter([[(0.0, 0.0), (0.0, 0.0)], [(0.1, 0.5), (0.3, 0.5)]])
    out = admission.trial(c, 1e-3, base=1 << 41, transit_s=0.1 * MS,
                          unit_cpu=lambda: next(readings))
    assert out["busy_of"] == "unit" and out["machine_busy_share"] == 0.42
    assert out["stolen_s"] == 0.04  # the most one CPU lost between before and after
    monkeypatch.setattr(sched, "stolen_s", lambda: None)  # a kernel that does not count it
    assert admission.trial(c, 1e-3, base=1 << 41, transit_s=0.1 * MS)["stolen_s"] is None
    assert out["busy_share"] == 0.42  # busy_share itself is scripted here: the same call
    machine = admission.trial(c, 1e-3, base=1 << 41, transit_s=0.1 * MS)
    assert machine["busy_of"] == "machine"


def test_a_refusal_for_the_units_own_load_says_whose_time_it_was(monkeypatch):
    busy = rung(1e-3, held=False, busy=0.9, limit=0.7125) | {"busy_of": "unit"}
    central, _ = scripted(monkeypatch, [busy] + [rung(p, held=False) for p in LADDER_S[7:]])
    with pytest.raises(Unsustainable) as e:
        admit(central)
    assert "; the unit kept a CPU 90% busy under SCHED_FIFO, over the limit of 71% of the CPU" \
        in str(e.value)


def test_a_trials_findings_say_which_rule_it_broke():
    from ctrlunit.runtime.launch.refusal import trial_findings

    rung = {"intervals": 300, "late": 3, "traversal_p99_s": 1.0e-3, "budget_s": 2.0e-3,
            "busy_share": None, "busy_limit": None, "fault": "peripheral-2 silent 9.1 ms"}
    assert trial_findings(rung, 2) == (
        "3 were late, more than the 1 allowed; the traversal p99 was 1.00 ms, within the "
        "1.90 ms allowed (95% of a 2.00 ms budget: 2 period(s)); the trial faulted "
        "(peripheral-2 silent 9.1 ms)")
    rung |= {"late": 0, "traversal_p99_s": 2.86e-3, "budget_s": 3.0e-3, "fault": None}
    assert trial_findings(rung, 1) == (  # the new user's case: over by 0.01 ms
        "0 were late; the traversal p99 was 2.86 ms, over the 2.85 ms allowed (95% of a "
        "3.00 ms budget: 1 period(s))")
    # a virtual machine's host took CPU time during the trial: the cause measured, said
    assert trial_findings(rung | {"stolen_s": 0.04}, 1).endswith(
        "; the hypervisor took up to 40 ms from one of this machine's CPUs meanwhile (steal: "
        "what ran there stood still)")
    assert trial_findings(rung | {"stolen_s": 0.0}, 1) == trial_findings(rung, 1)


def test_auto_starts_again_at_the_shorter_period_once_and_never_descends_again(monkeypatch):
    """The launcher (runtime/launch/launcher.py): a first start whose admission found a
    shorter period held (:class:`ShorterHeld`: exit 7 with that period) starts again at it,
    saying so; that start, and any after it, climb but do not go down again."""
    from ctrlunit.runtime.launch import launcher
    from ctrlunit.runtime.launch.run_parts import every_start

    starts: list[tuple[float, bool]] = []
    outcomes = [(7, 0.64e-3), (7, 0.8e-3), (0, 0.8e-3)]  # held shorter; refused; ran

    class Start:
        def __init__(self, rc: RunConfig, **_: Any) -> None:
            self.period = rc.schedule.period

        def __call__(self, *, descend: bool, tried: list[dict]) -> tuple[int, dict]:
            starts.append((self.period, descend))
            code, held = outcomes[len(starts) - 1]
            rung = {"period_s": held, "held": True}
            return code, {"admission": every_start(tried, {
                "sustainable_period_s": held, "rungs": [rung]})}

    monkeypatch.setattr(launcher, "UnitStart", Start)
    said: list[str] = []
    code, report = launcher.start(RunConfig.of(clock="realtime", period_auto=True),
                                  echo=said.append)
    assert code == 0 and starts == [(1e-3, True), (0.64e-3, False), (0.8e-3, False)]
    assert said == [
        "ctrlunit: --period auto: 1 ms was held in this start's trial, and so was 0.64 ms; "
        "starting again at 0.64 ms",
        "ctrlunit: --period auto: 0.64 ms, held in the last start's trial, was not held in "
        "this start's trial, 0.8 ms was; starting again at 0.8 ms"]
    assert [r["start"] for r in report["admission"]["rungs"]] == [0, 1, 2]


def test_the_summary_says_where_the_descent_went():
    from ctrlunit.runtime.observe import summary

    rungs = [{"period_s": 1e-3, "held": True, "intervals": 300},
             {"period_s": 0.8e-3, "held": True, "descent": True, "intervals": 300},
             {"period_s": 0.64e-3, "held": False, "descent": True, "intervals": 300},
             {"period_s": 0.8e-3, "held": True, "intervals": 300, "start": 1}]
    adm = {"period_s": 0.8e-3, "asked": "auto", "rungs": rungs}
    assert summary._admission_lines({"admission": adm}) == [
        "  admission   0.8 ms held in a trial of 300 intervals before motion (asked: auto); "
        "below 1 ms the first start's trials held 0.8 ms, not 0.64 ms"]
    adm = {"period_s": 1e-3, "asked": "auto", "rungs": rungs[:1]}  # no descent tried
    assert summary._admission_lines({"admission": adm})[0].endswith("(asked: auto)")
    refused = [*rungs[:3], {"period_s": 0.8e-3, "held": False, "intervals": 300, "start": 1},
               {"period_s": 1e-3, "held": True, "intervals": 300, "start": 1}]
    adm = {"period_s": 1e-3, "asked": "auto", "rungs": refused}  # the start again refused
    assert summary._admission_lines({"admission": adm})[0].endswith(
        "below 1 ms the first start's trials held 0.8 ms, not 0.64 ms; started again at "
        "0.8 ms, its trial did not hold")
    # the run at 1 ms, with a shorter period tried after it and not held: the trial that
    # held 1 ms gives its size, not the last one tried
    tried = [{"period_s": 1e-3, "held": True, "intervals": 300},
             {"period_s": 0.8e-3, "held": False, "descent": True, "intervals": 375}]
    adm = {"period_s": 1e-3, "asked": "auto", "rungs": tried}
    assert summary._admission_lines({"admission": adm})[0].startswith(
        "  admission   1 ms held in a trial of 300 intervals before motion")


def test_a_start_again_does_not_say_the_placement_choice_again():
    """A new user saw the placement note once per admission start (three or four times);
    the first start says it, the summary gives the last one."""
    from ctrlunit.runtime.launch import launcher

    said: list[str] = []
    say = launcher._quieter(said.append, set())
    first = "ctrlunit: --placement auto: round 0 (ik_obs0) costs the central 12 us against 818 us"
    say(first)
    say("ctrlunit: --period auto: 1 ms was not held in this start's trial, 1.6 ms was")
    say("ctrlunit: --placement auto: round 0 (ik_obs0) costs the central 14 us against 790 us")
    other = "ctrlunit: --placement auto: round 0 (ik_obs0) costs the central 14 us: stays"
    say(other)  # another decision: said
    assert said == [first, "ctrlunit: --period auto: 1 ms was not held in this start's "
                    "trial, 1.6 ms was", other]


def test_every_start_s_trials_follow_the_earlier_starts():
    """A start again (``--period auto``) reports, and so records, the whole ladder: the
    earlier starts' trials, then its own marked with the next start's number; so
    ``ctrlunit report FILE.mcap`` says where the first start's descent went, as the live
    summary does."""
    from ctrlunit.runtime.launch.run_parts import every_start

    first = every_start([], {"period_s": 1e-3, "rungs": [{"period_s": 1e-3},
                                                         {"period_s": 0.8e-3}]})
    assert [r["start"] for r in first["rungs"]] == [0, 0] and first["period_s"] == 1e-3
    again = every_start(first["rungs"], {"period_s": 0.8e-3, "rungs": [{"period_s": 0.8e-3}]})
    assert [(r["period_s"], r["start"]) for r in again["rungs"]] == [
        (1e-3, 0), (0.8e-3, 0), (0.8e-3, 1)]
    assert again["period_s"] == 0.8e-3 and first["rungs"][0] == {"period_s": 1e-3, "start": 0}
