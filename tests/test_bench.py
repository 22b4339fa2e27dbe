"""Benchmark sweep, floor, T-800 cost model and the balance tool."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

import pytest
from runner import ctrlunit, kill_unit, pids_of, start_json

pytestmark = pytest.mark.zenoh


@pytest.mark.slow
def test_quick_bench_writes_reports_and_figures(tmp_path):
    """``ctrlunit bench --quick``, every stage but the thesis's and the realtime one, which
    the fast suite runs end to end (tests/test_thesis_figures.py, and
    test_bench_only_realtime_runs_the_main_job_and_its_baseline below; running them here
    too cost CI about 70 s and 20 s): under ``-m slow``, since the fast suite cannot hold
    it beside the rest; its parts (balance, the T-800 model, recording cost, the live
    view) have their own tests in CI."""
    out = tmp_path / "bench"
    t0 = time.monotonic()
    res = ctrlunit("bench", "--quick", "--stages", "floor,sweep,recording,balance,target",
                   "--out", str(out), timeout=600)
    assert res.returncode == 0, res.stdout + res.stderr
    print(f"bench --quick: {time.monotonic() - t0:.0f} s")  # reported, not asserted
    rep = json.loads((out / "report.json").read_text())
    assert {"machine", "floor", "runs"} <= set(rep)
    for run in rep["runs"]:
        for key in ("peripherals", "pipeline", "cost_model", "clock", "processors",
                    "round_trips", "period_s", "traversal_s", "t1_s", "efficiency",
                    "speedup", "deadline_misses", "business"):
            assert key in run, key
    combos = {(r["peripherals"], r["pipeline"], r["cost_model"]) for r in rep["runs"]
              if r["clock"] == "freerun" and r["tag"] == "sweep"}
    assert len(combos) == 16
    for n, f in rep["floor"]["by_n"].items():
        assert f["ratio_p50"] > 1.0, n  # Zenoh cannot beat raw pipes
    for name in ("efficiency.png", "distributions.png"):  # gantt.png: the thesis stage's
        assert (out / name).read_bytes()[:4] == b"\x89PNG"
    md = (out / "report.md").read_text()
    assert "Transport floor" in md and "Against the 1994 unit" not in md
    assert set(rep["floor"]["paced"]) >= {"pipe", "zenoh", "period_s", "rounds"}
    assert "At the unit's cadence" in md
    cost = rep["recording_cost"]  # a benchmark figure, reported (not a timed assertion)
    assert cost["period_p50_with_s"] > 0 and cost["period_p50_without_s"] > 0
    print(f"recording cost on the freerun period: {(cost['ratio'] - 1) * 100:+.1f} %")
    comps = cost["compressions"]
    assert set(comps) == {"none", "zstd"}
    # the chunks are compressed: a third of the bytes or less (float64 payloads bound it)
    assert comps["zstd"]["bytes_per_interval"] < 0.5 * comps["none"]["bytes_per_interval"]
    assert "| zstd |" in md
    live = cost["live_view"]  # the same run with --foxglove and a viewer reading it all
    assert live["period_p50_with_s"] > 0 and live["viewer_messages"] > 0
    print(f"live view cost on the freerun period: {(live['ratio'] - 1) * 100:+.1f} %, "
          f"{live['viewer_messages']:.0f} messages read for {live['cycles']:.0f} intervals")
    assert "What the live view costs" in md
    # the 0.5 ms target: default and balance's placement, each with SCHED_FIFO when
    # permitted, all measured (a benchmark figure, reported, not asserted against 0.5 ms)
    target = rep["target"]
    want = 4 if target["fifo_permitted"] else 2
    assert len(target["variants"]) == want
    assert {v["placement"] for v in target["variants"]} == {"default", "balance's (depth 2)"}
    for v in target["variants"]:
        assert v["ok"] == v["runs"] == 1, v
        assert 0 < v["period_mean_s"] < 0.1
        print(f"target: {v['placement']}, {v['scheduling']}: "
              f"{v['period_mean_s'] * 1e6:.0f} us")
    assert "us target: freerun period at n = 3, depth 2" in md
    # the realtime stage, run end to end in the fast suite (its runs' count given there:
    # test_bench_only_realtime_runs_the_main_job_and_its_baseline), is in --quick's plan
    # with two runs of the main job and their baselines
    plan = ctrlunit("bench", "--quick", "--check", timeout=120)
    assert "realtime: 2 main-job runs, each with its baseline" in plan.stdout, plan.stdout


def test_t800_cost_model_emulates_the_1994_single_processor_time(tmp_path):
    code, rep, out = start_json(tmp_path, "--peripherals", "0", "--clock", "freerun",
                                "--cycles", "200", "--cost-model", "t800", tag="t800")
    assert code == 0, out
    from ctrlunit.topology.graph import stage_graph

    expected = stage_graph().t_single_t800_us() * 1e-6
    print(f"t800 single processor: t_1 {rep['t1_s'] * 1e6:.0f} us for {expected * 1e6:.0f} us "
          f"of T-800 block times; emulation error p50 "
          f"{rep['cost_model_error_s']['p50'] * 1e6:.1f} us, p99 "
          f"{rep['cost_model_error_s']['p99'] * 1e6:.1f} us")
    # The debt is paid: no load makes an interval shorter than its T-800 time. What a busy
    # host adds is the settles' lateness, measured in this run (p50: 2-4 us on a calm host,
    # 209 us beside two busy loops and the test suite, when t_1 was 1960 us): the interval
    # may exceed the model by 10 % plus twice that.
    late = rep["cost_model_error_s"]["p50"]
    assert 0.97 * expected <= rep["t1_s"] <= 1.1 * expected + 2 * late


def _balance_pair(tmp_path, tag):
    """A run with the thesis's placement, balance on it, a re-run with its placement, and
    the comparison."""
    code, rep, out = start_json(tmp_path, "--peripherals", "3", "--clock", "freerun",
                                "--cycles", "2000", "--placement", "axes", tag=tag)
    assert code == 0, out
    report = tmp_path / f"{tag}-run.json"
    report.write_text(json.dumps(rep))
    placement = tmp_path / f"{tag}-placement.json"
    res = ctrlunit("balance", str(report), "--write", str(placement), "--json")
    assert res.returncode == 0, res.stderr
    a = json.loads(res.stdout)
    assert a["t_p_s"] < a["t_s_s"]
    assert a["placement"]["central_blocks"], a["recommendations"]  # it moved something
    # (the model's latency is fitted to this run's mean period, so its period for this
    # run says nothing of the model: it is judged on runs it was not fitted on, the
    # depth-2 run beside the depth-1 one it was calibrated on, in
    # tests/test_thesis_figures.py)
    code2, rep2, out2 = start_json(tmp_path, "--peripherals", "3", "--clock", "freerun",
                                   "--cycles", "2000", "--placement", str(placement),
                                   tag=tag + "2")
    assert code2 == 0, out2
    rerun = tmp_path / f"{tag}-rerun.json"
    rerun.write_text(json.dumps(rep2))
    fig = tmp_path / f"{tag}-gantt.png"
    res = ctrlunit("balance", str(report), "--write", str(tmp_path / f"{tag}-again.json"),
                   "--compare", str(rerun), "--figure", str(fig), "--json")
    assert res.returncode == 0, res.stderr
    assert fig.read_bytes()[:4] == b"\x89PNG"
    cmp = json.loads(res.stdout)["compare"]
    print(f"balance: {a['recommendations'][0]}; re-run {cmp['measured_period_s'] * 1e6:.0f} us "
          f"against {cmp['predicted_period_s'] * 1e6:.0f} us predicted "
          f"({cmp['error'] * 100:+.1f} %), before {cmp['before_period_s'] * 1e6:.0f} us")
    return cmp


def test_balance_moves_work_and_a_rerun_with_its_placement_is_compared(tmp_path):
    """Native arithmetic is ~100 us an interval against ~1 ms of messages: by § IV.7.2's
    rule (the central computes < 50 % of the time) balance moves per-axis work to it, the
    unit runs with the placement it wrote, and --compare sets the re-run against the
    prediction. Whether the re-run is faster, and by how much the prediction misses, is a
    benchmark figure on this machine, whose speed drifts by up to 3x within minutes: the
    bench's balance stage measures it over alternated runs (report.md, "Load balancing"); a test
    that asserted it once would fail by chance, and one that re-ran until it held would
    prove nothing."""
    cmp = _balance_pair(tmp_path, "bal")
    assert cmp["depth"] == 1
    assert cmp["predicted_period_s"] > 0 and cmp["measured_period_s"] > 0
    assert cmp["error"] == pytest.approx(
        cmp["measured_period_s"] / cmp["predicted_period_s"] - 1.0, rel=1e-12)
    assert cmp["gain"] == pytest.approx(
        1.0 - cmp["measured_period_s"] / cmp["before_period_s"], rel=1e-12)


def test_balance_refuses_a_rerun_with_another_placement(tmp_path):
    code, rep, out = start_json(tmp_path, "--peripherals", "2", "--clock", "freerun",
                                "--cycles", "300", tag="balx")
    assert code == 0, out
    report = tmp_path / "run.json"
    report.write_text(json.dumps(rep))
    other = dict(rep, placement={"peripherals": 1, "axes": [[0, 1, 2]], "central_blocks": []})
    rerun = tmp_path / "other.json"
    rerun.write_text(json.dumps(other))
    res = ctrlunit("balance", str(report), "--write", str(tmp_path / "p.json"), "--compare",
                   str(rerun))
    assert res.returncode != 0
    assert "placement" in res.stderr and "not the one balance wrote" in res.stderr


def test_the_realtime_stage_counts_runs_misses_and_refusals_over_every_run():
    """Misses per 1000 are over the periods of every run (not a mean of ratios; a run that
    halved its control rate covers more periods than it ran intervals); a refusal counts as
    a run that did not complete; medians skip runs that never moved; the worst tracking is
    the worst run's."""
    from ctrlunit.bench.realtime import markdown_lines, run_row, summary

    def res(code, cycles, misses, p999, cpu, period=1e-3, fault=None, track=4e-4,
            policy="SCHED_FIFO 10", fell=None, late=None, halved_at=None, idle="poll"):
        rep = {} if cycles == 0 else {"late_intervals": late,
            "periods": cycles + (cycles - halved_at if halved_at else 0),
            "overload": {"policy": "halve", "halved": halved_at and {
                "at_interval": halved_at, "from_cycle": halved_at + 4}},
            "nominal_period_s": period, "cycles": cycles, "deadline_misses": misses,
            "traversal_s": {"p999": p999},
            "cpu_per_interval_s": cpu and {"total": cpu, "central": cpu / 2, "plant": cpu / 4},
            "tracking_error_m": {"max": track}, "fault": fault and {"message": fault},
            "scheduling": {"central": policy}, "scheduling_fallback": fell,
            "scheduling_choice": {"priority": 10 if "FIFO" in policy else 0},
            "idle": {"asked": "auto", "in_force": idle}}
        return {"exit_code": code, "report": rep, "wall_s": 5.0, "output_tail": ""}

    rows = [run_row(res(0, 400, 1, 1.5e-3, 1.2e-3, late={
                "intervals": 1, "work_stretch": {"median": 3.1}, "machine_slower": True})),
            run_row(res(0, 500, 0, 1.7e-3, 1.0e-3, period=1.25e-3, policy="SCHED_OTHER",
                        fell={"cycle": 300}, halved_at=400, idle="default")),
            run_row(res(4, 200, 5, 9e-3, 2e-3, fault="no sample from the plant for 5 ms",
                        track=2e-3, late={"intervals": 5, "work_stretch": {"median": 1.5},
                                          "machine_slower": None})),
            run_row(res(7, 0, 0, None, None))]
    assert [r["rt_priority"] for r in rows] == [10, 0, 10, 0]  # the baseline's policy
    s = summary(rows)
    assert s["runs"] == 4 and s["completed"] == 2 and s["completed_fraction"] == 0.5
    assert s["refused"] == 1 and s["periods"] == 1200 and s["deadline_misses"] == 6
    assert s["misses_per_1000"] == pytest.approx(5.0)
    assert s["periods_chosen_s"] == [1e-3, 1.25e-3]
    assert s["traversal_p999_s"] == pytest.approx(1.7e-3)  # median of three runs
    assert s["cpu_per_interval_s"] == pytest.approx(1.2e-3)
    assert s["cpu_by_role_s"] == pytest.approx({"central": 6e-4, "plant": 3e-4})
    assert s["tracking_max_m"] == pytest.approx(4e-4) and s["tracking_worst_m"] == 2e-3
    assert s["scheduling"] == {"SCHED_FIFO 10": 2, "SCHED_OTHER": 1}  # the refusal ran none
    assert s["fell_back"] == 1 and s["halved"] == 1 and s["idle_poll"] == 2
    assert [r["idle"] for r in rows] == ["poll", "default", "poll", None]
    assert rows[1]["periods"] == 600 and rows[1]["halved_at_interval"] == 400
    assert s["late_runs"] == {"machine_slower": 1, "waiting": 0, "no_verdict": 1}
    st = {"command": "ctrlunit start --peripherals 3 --pipeline 2", "baseline_command": "b",
          "levers": {"period": "auto"}, "main_job": s, "baseline": summary(rows[:2]),
          "long": None, "long_s": 0, "rows": {"main_job": rows, "baseline": rows[:2]}}
    md = "\n".join(markdown_lines(st))
    assert ("| main job | 4 | 2 | 1 | 1200 | 6 | 5.00 | 1.00, 1.25 | 1700 | 1200 | 0.40 / 2.00 |"
            in md)
    assert "run 3 exit 4: no sample from the plant for 5 ms" in md and "run 4 exit 7" in md
    assert "CPU per interval by role, median (us): main job: central 600, plant 300; " \
        "baseline (n = 0): central 550, plant 275." in md
    assert "ran under SCHED_FIFO 10 in 2, SCHED_OTHER in 1; back to the default policy " \
        "during the run (the throttling guard) in 1; control rate halved on overload in 1; " \
        "idle CPUs polling (`--idle`) in 2." in md
    assert "stretched (the machine ran slower) in 1, as usual (time lost waiting) in 0, " \
        "in between in 1." in md


def test_the_long_run_is_followed_by_its_baseline_at_its_period_and_policy(monkeypatch):
    """The long run's baseline: one control process for as long, at the period the long
    run chose and under its policy; both get a line of the report, with misses per 1000."""
    from ctrlunit.bench import realtime

    started: list[tuple[str, ...]] = []

    def fake_start(args: tuple[str, ...], *, timeout_s: float) -> dict:
        started.append(args)
        periods = 1250 if "--duration" in args else 400
        halved = "--duration" in args and args[1] == "3"  # the long main job halved once
        rep = {"late_intervals": {"intervals": 5, "work_stretch": {"median": 1.94},
                                  "machine_slower": None} if halved else None,
               "nominal_period_s": 1.6e-3 if args[1] == "3" else
               float(args[args.index("--period") + 1]),
               "cycles": 900 if halved else periods, "periods": periods,
               "overload": {"halved": {"at_interval": 500}, "halved_periods": 700,
                            "changes": [{"stride": 2}, {"stride": 1}]} if halved else None,
               "deadline_misses": 5 if args[1] == "3" else 1,
               "traversal_s": {"p999": 1e-3}, "cpu_per_interval_s": {"total": 1e-3},
               "tracking_error_m": {"max": 1e-4}, "fault": None,
               "scheduling": {"central": "SCHED_FIFO 10"}, "scheduling_fallback": None,
               "scheduling_choice": {"priority": 10}, "idle": {"in_force": "poll"}}
        return {"exit_code": 0, "report": rep, "wall_s": 1.0, "output_tail": ""}

    monkeypatch.setattr(realtime, "run_start", fake_start)
    assert realtime.stage_steps(1, 2.0) == 6 and realtime.stage_steps(3, 0) == 12
    assert realtime.stage_steps(1, 2.0, ()) == 4
    assert realtime.stage_steps(3, 0, fixed_runs=1) == 8
    st = realtime.realtime_stage(runs=1, long_s=2.0)
    # the thesis's period: the main job asked for it, its baseline at it (not at the
    # period the run reported)
    assert started[2] == (*realtime.MAIN_JOB, "--period", "500us")
    assert started[3] == ("--peripherals", "0", "--pipeline", "2", "--period", "0.0005",
                          "--no-admission", "--rt-priority", "10", "--idle", "poll")
    assert [fx["period_s"] for fx in st["fixed"]] == [realtime.THESIS_PERIOD_S]
    assert st["fixed"][0]["main_job"]["runs"] == 1
    assert started[4] == (*realtime.MAIN_JOB, "--duration", "2s")
    assert started[5] == ("--peripherals", "0", "--pipeline", "2", "--period", "0.0016",
                          "--no-admission", "--rt-priority", "10", "--idle", "poll",
                          "--duration", "2s")
    assert st["long_baseline"]["deadline_misses"] == 1
    md = "\n".join(realtime.markdown_lines(st))
    assert "Long run (2 s): exit 0, period 1.60 ms, 1250 periods (900 intervals), 5 misses " \
        "(4.00 per 1000)" in md
    assert "control rate halved at interval 500 (2 change(s) of rate; 700 periods at the " \
        "halved rate); the late intervals' work took 1.9x its median (in between)." in md
    assert "Its baseline (2 s, n = 0): exit 0, period 1.60 ms, 1250 periods (1250 " \
        "intervals), 1 misses (0.80 per 1000)" in md
    assert "the same at `ctrlunit start --peripherals 3 --pipeline 2 --period 500us`" in md
    assert "| main job at 0.5 ms | 1 | 1 | 0 | 400 | 5 |" in md
    assert "| baseline at 0.5 ms (n = 0) | 1 | 1 | 0 | 400 | 1 |" in md


def test_bench_only_realtime_runs_the_main_job_and_its_baseline(tmp_path):
    """``ctrlunit bench --stages realtime --realtime-runs 1 --realtime-long 0``: one run of
    the main job as a user starts it, one baseline, a report that names the levers."""
    out = tmp_path / "rt"
    res = ctrlunit("bench", "--stages", "realtime", "--realtime-runs", "1", "--realtime-long",
                   "0", "--out", str(out), timeout=300)
    assert res.returncode == 0, res.stdout + res.stderr
    st = json.loads((out / "report.json").read_text())["realtime"]
    assert st["levers"]["period"] == "auto" and st["levers"]["command_delay"] == "full"
    assert st["levers"]["idle"] == "auto" and st["levers"]["missed_command"] == "extrapolate"
    (star,), (base,) = st["rows"]["main_job"], st["rows"]["baseline"]
    assert star["exit_code"] in (0, 3, 4, 7), star  # held, faulted or refused: all reported
    if star["exit_code"] != 7:
        assert star["cycles"] > 0 and star["cpu_per_interval_s"] > 0
    assert base["exit_code"] is not None and base["cycles"] > 0  # admission off: it runs
    assert base["period_s"] == (star["period_s"] or 1e-3)
    if star["exit_code"] != 7:  # the baseline under the main job's policy
        assert base["scheduling"] == star["scheduling"] or star["fell_back"]
        assert set(star["cpu_by_role_s"]) == {"central", "plant", "peripheral_1",
                                              "peripheral_2", "peripheral_3"}
    # the thesis's 0.5 ms: asked of the main job (held, faulted or refused), the baseline
    # at it whatever the main job did
    (fixed,) = st["fixed"]
    (star_fx,), (base_fx,) = fixed["rows"]["main_job"], fixed["rows"]["baseline"]
    assert fixed["period_s"] == 5e-4 and star_fx["exit_code"] in (0, 3, 4, 5, 7), star_fx
    assert base_fx["cycles"] > 0 and base_fx["period_s"] == 5e-4
    md = (out / "report.md").read_text()
    assert "Realtime: does the main job hold its period?" in md
    assert "| main job at 0.5 ms | 1 |" in md


def test_bench_rejects_a_negative_long_run():
    res = ctrlunit("bench", "--stages", "realtime", "--realtime-long", "-5s", "--check")
    assert res.returncode != 0 and "--realtime-long" in res.stdout + res.stderr


@pytest.mark.parametrize(("signum", "sigint"), [
    (signal.SIGTERM, "default"), (signal.SIGINT, "default"),
    (signal.SIGTERM, "ignored"),  # a background job of a script: SIGINT ignored
])
def test_a_stopped_bench_stops_its_run_and_runs_nothing_more(signum, sigint, tmp_path):
    """Ctrl-C or SIGTERM during the realtime stage ends the bench with the signal's exit
    code (130, 143), after its current run stopped; before, the run absorbed the stop
    and the bench went on to the next run. The bench passes on the signal it got: a run
    inherits an ignored SIGINT, and a forwarded Ctrl-C then went unheard until the bench
    killed the run unstopped, :data:`~ctrlunit.bench.realtime.STOP_WAIT_S` later."""
    from ctrlunit.bench.realtime import STOP_WAIT_S

    handler = "signal.default_int_handler" if sigint == "default" else "signal.SIG_IGN"
    proc = subprocess.Popen(
        [sys.executable, "-c", "import signal, runpy, sys; "
         f"signal.signal(signal.SIGINT, {handler}); "
         "sys.argv = ['ctrlunit'] + sys.argv[1:]; "
         "runpy.run_module('ctrlunit.runtime.cli', run_name='__main__')",
         "bench", "--stages", "realtime", "--realtime-runs", "0", "--realtime-long", "40s",
         "--out", str(tmp_path / "bench")],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True)
    unit = f"rt-{proc.pid}-"  # the runs' unit ids start so (bench/realtime.py)
    try:
        deadline = time.monotonic() + 60
        while not pids_of(unit) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert pids_of(unit), "no run started"
        time.sleep(2.0)
        os.kill(proc.pid, signum)  # the bench alone (a terminal's Ctrl-C reaches it too)
        t0 = time.monotonic()
        out, _ = proc.communicate(timeout=60)
        took = time.monotonic() - t0
        assert proc.returncode == 128 + signum, out
        name = "interrupted" if signum == signal.SIGINT else "terminated (SIGTERM)"
        assert f"ctrlunit: {name}" in out
        assert "Traceback" not in out
        assert not pids_of(unit)
        assert not (tmp_path / "bench" / "report.json").exists()  # no stage finished
        assert took < STOP_WAIT_S, f"the run was killed, not stopped ({took:.1f} s)"
    finally:
        kill_unit(unit)
        if proc.poll() is None:
            proc.kill()


@pytest.mark.parametrize("kind", ["pipe", "zenoh"])
def test_paced_link_counts_each_sides_cpu_per_round_after_the_warm_up(kind):
    """The floor's link at the unit's cadence: both sides' CPU per round is counted from
    the end of the warm-up (a child's start-up, its imports and Zenoh's session, would
    otherwise put milliseconds on each of 100 rounds), and every round is timed."""
    from ctrlunit.bench.floor import paced_link

    r = paced_link(kind, rounds=100, warmup=20)
    assert 0 < r["cpu_caller_s"] < 1e-3 and 0 < r["cpu_echo_s"] < 1e-3, r
    assert 0 < r["round_trip_s"]["p50"] <= r["round_trip_s"]["p99"]
    print(f"{kind}: CPU per round {r['cpu_caller_s'] * 1e6:.0f} + "
          f"{r['cpu_echo_s'] * 1e6:.0f} us, round trip p50 "
          f"{r['round_trip_s']['p50'] * 1e6:.0f} us")


def test_the_floor_times_the_units_cadence_with_the_idle_cpus_a_realtime_unit_gets(
        tmp_path, monkeypatch):
    """The paced rounds run while the idle request is held (``--idle``, as a realtime
    unit's); the report says which."""
    from ctrlunit.bench import floor as floor_mod
    from ctrlunit.runtime.host import idle

    dev = tmp_path / "cpu_dma_latency"
    dev.write_bytes(b"")
    states = tmp_path / "cpuidle"
    for k, (name, latency) in enumerate([("POLL", 0), ("C1", 3)]):
        (states / f"state{k}").mkdir(parents=True)
        for f, v in (("name", name), ("latency", latency), ("disable", 0)):
            (states / f"state{k}" / f).write_text(f"{v}\n")
    monkeypatch.setattr(idle, "CPU_LATENCY_DEV", dev)
    monkeypatch.setattr(idle, "CPUIDLE_DIR", states)

    def held() -> bool:
        return any(os.readlink(f"/proc/self/fd/{fd}") == str(dev)
                   for fd in os.listdir("/proc/self/fd")
                   if os.path.islink(f"/proc/self/fd/{fd}"))

    seen: list[tuple[str, bool]] = []
    monkeypatch.setattr(floor_mod, "paced_link",
                        lambda kind, **_: seen.append((kind, held())) or {"kind": kind})
    res = floor_mod.floor((), rounds=100, idle="auto")
    assert seen == [("pipe", True), ("zenoh", True)] and not held()
    assert res["paced"]["idle"]["in_force"] == "poll"
    seen.clear()
    res = floor_mod.floor((), rounds=100, idle="default")
    assert seen == [("pipe", False), ("zenoh", False)]
    assert res["paced"]["idle"]["in_force"] == "default"


def test_paced_link_names_the_links_it_knows():
    from ctrlunit.bench.floor import paced_link

    with pytest.raises(ValueError, match="kind = 'tcp': allowed 'pipe' or 'zenoh'"):
        paced_link("tcp")


def test_a_configuration_whose_runs_were_refused_reads_as_not_run_in_report_md(tmp_path):
    """A sweep row whose every run was refused (exit 7) said ``n/a ... | 0 | central
    100%`` in report.md, figures that read as measured (a new user's review): it now says
    it did not run and why; a row with some runs refused says how many ran."""
    import math

    from ctrlunit.bench.markdown import write_markdown

    def row(repeats: int, codes: list[int]) -> dict:
        nan = math.nan
        return {"tag": "sweep", "peripherals": 3, "processors": 4 if repeats else None,
                "pipeline": 2, "cost_model": "none", "clock": "realtime",
                "nominal_period_s": 0.003, "round_trips": 1, "repeats": repeats,
                "period_s": {"p50": 3e-3, "p99": 3.1e-3, "max": 4e-3},
                "period_mean_s": 3e-3, "cpu_bound_period_s": 1e-3,
                "traversal_s": {"p50": 5e-4}, "t1_s": 1e-4,
                "efficiency": 0.5 if repeats else nan, "efficiency_spread": [nan, nan],
                "speedup": 2.0 if repeats else nan, "deadline_misses": 0,
                "business": {"central": 1.0, "peripheral_1": 0.0}, "exit_codes": codes}

    path = tmp_path / "report.md"
    write_markdown(path, {"runs": [row(0, [7, 7]), row(2, [0, 7, 0])], "quick": True,
                          "machine": {"platform": "Linux", "cores": 2, "python": "3.11"},
                          "repeats": 3, "wall_s": 1.0, "method": {"sweep": "test"}})
    lines = [ln for ln in path.read_text().splitlines() if ln.startswith("| 3 |")]
    assert len(lines) == 2
    refused, partly = lines
    assert "not run: refused before any motion (exit 7), refused" in refused
    assert "central 100%" not in refused and refused.count("|") == partly.count("|") == 15
    assert "(2 of 3 runs: refused before any motion (exit 7))" in partly
