"""The star over Zenoh: identical arithmetic, pipeline, clocks, tracking, clean exits."""

from __future__ import annotations

import contextlib
import json
import math
import os
import queue
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from ctrlunit.kernels.laws import Gains
from ctrlunit.kernels.params import DELTA_IA as P
from ctrlunit.kernels.trajectory import pick_place_task
from ctrlunit.runtime.compute.controller import simulate
from ctrlunit.runtime.observe.report import command_digest
from ctrlunit.topology.graph import LAWS
from runner import kill_unit, pids_of, slow_task, start_json, unit_id, wait_gone, wait_status

pytestmark = pytest.mark.zenoh
CYCLES = 150


@pytest.mark.parametrize("law", LAWS)
def test_lockstep_commands_are_bit_identical_for_n_0_to_3(tmp_path, law):
    """Every spread of the axes (n = 1, 2: a peripheral with several) for the default law;
    the others at n = 0 and 3 here, at n = 1 and 2 in process (tests/test_loopback.py)."""
    digests = set()
    for n in ((0, 1, 2, 3) if law == "resolved-acceleration" else (0, 3)):
        code, rep, out = start_json(tmp_path, "--peripherals", str(n), "--clock", "lockstep",
                                    "--cycles", str(CYCLES), "--law", law, "--max-error", "1",
                                    tag=f"bit{n}")
        assert code == 0, out
        assert rep["cycles"] == CYCLES
        digests.add(rep["command_digest"])
    ref = simulate(P, pick_place_task(), law=law, gains=Gains.from_bandwidth(20.0),
                   cycles=CYCLES, delay=1)  # depth 1, full delay: the period after the next
    digests.add(command_digest([x for c in ref.commands for x in c]))
    assert len(digests) == 1


@pytest.mark.parametrize(("convention", "delay"), [("full", 2), ("short", 1)])
def test_depth_two_equals_one_process_with_the_commands_delay(tmp_path, convention, delay):
    code, rep, out = start_json(tmp_path, "--peripherals", "3", "--pipeline", "2", "--clock",
                                "lockstep", "--cycles", str(CYCLES), "--command-delay",
                                convention, tag=f"depth2{convention}")
    assert code == 0, out
    assert rep["command_delay"] == {"convention": convention, "periods": delay}
    ref = simulate(P, pick_place_task(), gains=Gains.from_bandwidth(20.0), cycles=CYCLES,
                   delay=delay)
    assert rep["command_digest"] == command_digest([x for c in ref.commands for x in c])
    other = simulate(P, pick_place_task(), gains=Gains.from_bandwidth(20.0), cycles=CYCLES,
                     delay=3 - delay)
    assert rep["command_digest"] != command_digest([x for c in other.commands for x in c])


def test_resolved_acceleration_tracks_pick_place_far_better_than_pd(tmp_path):
    results = {}
    for law in ("resolved-acceleration", "pd"):
        code, rep, out = start_json(tmp_path, "--peripherals", "3", "--clock", "lockstep",
                                    "--law", law, tag=law[:4])
        assert code == 0, out
        results[law] = rep["tracking_error_m"]["max"]
    ra, pd = results["resolved-acceleration"], results["pd"]
    print(f"pick & place, lockstep 1 kHz: resolved acceleration {ra * 1e3:.3f} mm, "
          f"PD (same gains, no model) {pd * 1e3:.3f} mm, ratio {pd / ra:.1f}")
    assert ra <= 0.5e-3
    assert pd >= 5 * ra


@pytest.mark.parametrize("depth", [1, 2])
def test_realtime_at_1ms_reports_misses(tmp_path, depth):
    code, rep, out = start_json(tmp_path, "--peripherals", "3", "--pipeline", str(depth),
                                "--clock", "realtime", "--period", "1ms", "--no-admission",
                                "--cycles", "600",
                                "--fault-periods", "50", tag=f"rt{depth}")
    # Either it keeps up, or it stops the robot safely and says that deadlines were missed
    # (on a 2-core machine five Python processes do not sustain 1 ms). The liveness limit
    # is widened so that this VM's multi-millisecond stalls let the misses be counted
    # (with the default 3 periods they stop the unit first, tests/test_faults.py).
    assert code in (0, 5), out
    assert isinstance(rep["deadline_misses"], int)
    # the clock imposes the period: Eq. IV.23 on the traversal in the report; on native
    # costs the summary shows no efficiency, and says why
    assert rep["t_parallel_s"] == rep["traversal_s"]["p50"] != rep["period_mean_s"]
    assert rep["efficiency"] == pytest.approx(
        rep["t1_s"] / (rep["traversal_s"]["p50"] * rep["processors"]), rel=1e-12)
    assert "efficiency  not measured here: the realtime clock sets the pace" in out
    if code == 0:
        assert rep["cycles"] + rep["skipped_samples"] >= 600 - 5
    else:
        assert "missed their deadline" in rep["fault"]["message"], out
        assert rep["deadline_misses"] > 0
    print(f"realtime 1 ms, depth {depth}: exit {code}, misses {rep['deadline_misses']} in "
          f"{rep['cycles']} intervals, skipped {rep['skipped_samples']}, period p50 "
          f"{rep['period_s']['p50'] * 1e6:.0f} us")


def test_freerun_depth_two_completes_and_reports_round_trips(tmp_path):
    cycles = int(os.environ.get("CTRLUNIT_FREERUN_CYCLES", "4000"))
    code, rep, out = start_json(tmp_path, "--peripherals", "3", "--pipeline", "2", "--clock",
                                "freerun", "--cycles", str(cycles), "--placement", "axes",
                                tag="free", timeout=400)
    assert code == 0, out
    assert rep["cycles"] == cycles
    assert rep["round_trips"] == 2
    assert rep["period_s"]["p50"] > 0
    # CPU per interval of every process; all of it fits in cores x wall time, so the bound
    # it sets cannot exceed the period measured (5 %: the roles' windows run from start
    # to stop, a little longer than the central's intervals)
    cpu = rep["cpu_per_interval_s"]
    assert set(cpu) == {"central", "peripheral_1", "peripheral_2", "peripheral_3", "total"}
    assert all(v > 0 for v in cpu.values())
    assert math.isclose(cpu["total"], sum(v for k, v in cpu.items() if k != "total"))
    assert rep["cpu_cores"] >= 1
    assert rep["cpu_bound_period_s"] == pytest.approx(cpu["total"] / rep["cpu_cores"])
    assert rep["cpu_bound_period_s"] <= 1.05 * rep["period_mean_s"]
    print(f"freerun n=3 depth 2: period p50 {rep['period_s']['p50'] * 1e6:.0f} us, mean "
          f"{rep['period_mean_s'] * 1e6:.0f} us over {cycles} intervals; CPU per interval "
          f"{cpu['total'] * 1e6:.0f} us on {rep['cpu_cores']} cores: bound "
          f"{rep['cpu_bound_period_s'] * 1e6:.0f} us")


LOCKSTEP = ("--clock", "lockstep")
MOVING_IN_REALTIME = ("--period", "4ms", "--no-admission")  # light on a 2-core machine


def _default_stop_signals() -> None:
    for s in (signal.SIGINT, signal.SIGHUP, signal.SIGTERM):
        signal.signal(s, signal.SIG_DFL)


@pytest.mark.parametrize(("signum", "code", "whom", "clock"), [
    (signal.SIGINT, 130, "group", LOCKSTEP),  # a terminal's Ctrl-C: every process of the job
    (signal.SIGHUP, 129, "group", LOCKSTEP),  # the terminal closed
    (signal.SIGTERM, 143, "group", LOCKSTEP),  # a service manager ending the control group
    (signal.SIGTERM, 143, "group", MOVING_IN_REALTIME),
    (signal.SIGTERM, 143, "launcher", LOCKSTEP),  # kill, timeout
])
def test_a_stop_signal_stops_the_robot_safely_and_keeps_report_and_recording(
        signum, code, whom, clock, tmp_path):
    """The run ends as after the central's stop order: the plant held and braked (its
    safe stop confirmed in the report, the platform left nearly still), the report
    written, the recording closed with its footer, exit 128 + the signal's number, and no
    process left. Sent to the whole process group, the roles used to end on the signal
    themselves: the plant was gone before the stop order and the report said "safe stop
    NOT confirmed"; then a plant that got SIGTERM braked on its last command, path
    torques included, and left the platform at up to 0.47 m/s."""
    unit = unit_id(f"sig{signum}-{whom}")
    report, rec = tmp_path / "report.json", tmp_path / "run.mcap"
    out_file = tmp_path / "output"  # what the run said, for a failure's message
    out = out_file.open("w")
    proc = subprocess.Popen(
        [sys.executable, "-m", "ctrlunit.runtime.cli", "start", "--unit", unit, *clock,
         "--duration", "600s", "--no-progress", "--report", str(report),
         "--record", str(rec), "--status-file", str(tmp_path / "status")],
        stdout=out, stderr=subprocess.STDOUT, start_new_session=True,
        # as from a terminal, whatever this runner ignores (under nohup SIGHUP is ignored,
        # and a run that inherits that keeps running on purpose: the next test)
        preexec_fn=_default_stop_signals)
    try:
        # moving: every role up, the warm-up and placement done (a count of processes
        # saw a role between fork and exec once)
        assert wait_status(tmp_path / "status", 200, timeout=30) >= 200
        if whom == "group":
            os.killpg(proc.pid, signum)
        else:
            os.kill(proc.pid, signum)
        # a bound on "left behind", not a speed target (a loaded 2-core CI machine took
        # over 2 s once)
        assert proc.wait(timeout=20) == code, out_file.read_text()[-3000:]
        assert not wait_gone(unit)
    finally:
        kill_unit(unit)
        if proc.poll() is None:
            proc.kill()
        out.close()
    rep = json.loads(report.read_text())
    name = "interrupted" if signum == signal.SIGINT else \
        f"terminated ({signal.Signals(signum).name})"
    assert rep["fault"] == {"process": "user", "code": code, "message": name}
    assert rep["cycles"] > 0
    assert rep["safe_stop"] is not None and rep["safe_stop"]["hold_s"] > 0
    # docs/faults-and-errors.md: under 2 mm/s from the fastest point of the path
    assert rep["safe_stop"]["speed_m_s"] < 0.02, rep["safe_stop"]
    res = subprocess.run([sys.executable, "-m", "ctrlunit.runtime.cli", "report", str(rec)],
                         capture_output=True, text=True, timeout=120)
    assert "cut off" not in res.stdout + res.stderr  # the footer was written
    assert name in res.stdout


def _ignoring(signum: int) -> None:
    signal.signal(signum, signal.SIG_IGN)


def test_a_run_started_under_nohup_keeps_running_when_the_terminal_closes(tmp_path):
    """``nohup`` starts a program with SIGHUP ignored: a closed terminal must not stop the
    robot then (it did: the stop handlers replaced the ignored disposition); SIGTERM still
    stops it safely."""
    unit = unit_id("nohup")
    status = tmp_path / "status"
    proc = subprocess.Popen(
        [sys.executable, "-m", "ctrlunit.runtime.cli", "start", "--unit", unit, "--clock",
         "lockstep", "--duration", "600s", "--no-progress", "--status-file", str(status)],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True,
        preexec_fn=lambda: _ignoring(signal.SIGHUP))
    try:
        assert wait_status(status, 200, timeout=30) >= 200
        os.killpg(proc.pid, signal.SIGHUP)  # the terminal closed: every process gets it
        with contextlib.suppress(subprocess.TimeoutExpired):
            proc.wait(timeout=2.0)
        assert proc.poll() is None, "the run stopped on SIGHUP under nohup"
        done = wait_status(status, 0)
        assert wait_status(status, done + 100, timeout=10) >= done + 100  # still moving
        os.kill(proc.pid, signal.SIGTERM)
        assert proc.wait(timeout=20) == 143
        assert not wait_gone(unit)
    finally:
        kill_unit(unit)
        if proc.poll() is None:
            proc.kill()


def test_ctrl_c_just_after_the_unit_is_re_placed_ends_it_with_exit_130():
    """--placement auto re-places the roles after the warm-up; a Ctrl-C just after (the
    central warming the new plan up, or its first intervals) ends the run, no role left."""
    unit = unit_id("sigint2")
    proc = subprocess.Popen(
        [sys.executable, "-m", "ctrlunit.runtime.cli", "start", "--unit", unit, "--clock",
         "lockstep", "--duration", "600s", "--no-progress"],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True)
    lines: queue.Queue[str] = queue.Queue()
    reader = threading.Thread(target=lambda: [lines.put(x) for x in proc.stdout], daemon=True)
    reader.start()
    try:
        seen = ""
        deadline = time.monotonic() + 30
        while "--placement auto:" not in seen and time.monotonic() < deadline:
            with contextlib.suppress(queue.Empty):
                seen += lines.get(timeout=0.1)
        assert "--placement auto:" in seen, seen
        assert "starting again" not in seen, seen
        os.killpg(proc.pid, signal.SIGINT)
        assert proc.wait(timeout=20) == 130, seen
        assert not wait_gone(unit)
    finally:
        kill_unit(unit)
        if proc.poll() is None:
            proc.kill()


def _threads_cpus(pid: int) -> set[frozenset[int]]:
    """The CPU sets of every thread of ``pid`` (Zenoh's included)."""
    out = set()
    for t in Path(f"/proc/{pid}/task").iterdir():
        with contextlib.suppress(OSError):
            out.add(frozenset(os.sched_getaffinity(int(t.name))))
    return out


@pytest.mark.skipif(len(os.sched_getaffinity(0)) < 2 or not {0, 1} <= os.sched_getaffinity(0),
                    reason="needs CPUs 0 and 1")
@pytest.mark.parametrize(("cpus", "central", "others"), [("split", {0}, {1}),
                                                         ("same", {0}, {0})])
def test_cpus_option_pins_the_central_and_the_other_roles(cpus, central, others, tmp_path):
    """--cpus split: every thread of the central on CPU 0, every thread of the plant and
    the peripherals on CPU 1 (they once inherited the central's CPU 0)."""
    unit = unit_id(f"cpus-{cpus}")
    status = tmp_path / "status"
    proc = subprocess.Popen(
        [sys.executable, "-m", "ctrlunit.runtime.cli", "start", "--unit", unit, "--clock",
         "lockstep", "--duration", "600s", "--cpus", cpus, "--status-file", str(status)],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    try:
        assert wait_status(status, 20) >= 20  # running: every role's threads exist
        pids = pids_of(unit)
        assert len(pids) == 5  # launcher (central) + plant + 3 peripherals
        for pid in pids:
            want = central if pid == proc.pid else others
            assert _threads_cpus(pid) == {frozenset(want)}, (pid, pid == proc.pid)
    finally:
        kill_unit(unit)
        if proc.poll() is None:
            proc.kill()
        proc.wait(timeout=5)


def test_realtime_at_6ms_tracks_without_fault(tmp_path):
    """A period this shared 2-core machine sustains: the loop stays closed for a whole move.

    The task is the slow pick & place (2 m/s^2): the 80 m/s^2 one sampled at 6 ms tracks
    within 10 mm of the 20 mm fault limit, so one of this VM's 45 ms stalls (seen in CI:
    14 late commands in 41 periods) ended the run. The silence limit is widened to 10
    periods for the same reason; tests/test_faults.py checks the 3-period detection. The
    admission trial is off: this is the loop itself at a fixed period (the trial, whose
    margin refused 6 ms once in CI, is tests/test_admission.py's subject)."""
    code, rep, out = start_json(tmp_path, "--peripherals", "3", "--pipeline", "2", "--clock",
                                "realtime", "--period", "6ms", "--fault-periods", "10",
                                "--no-admission",
                                "--task", slow_task(tmp_path), tag="rt6")
    assert code == 0, out
    print(f"realtime 6 ms depth 2: misses {rep['deadline_misses']}, tracking max "
          f"{rep['tracking_error_m']['max'] * 1e3:.2f} mm")
    assert rep["cycles"] >= 300  # the whole move and its dwell, not a cut-short run
    assert rep["tracking_error_m"]["max"] < 0.01  # about 0.5 mm; a 45 ms stall adds ~2


def test_plant_options_reach_the_plant(tmp_path):
    """Lag and friction the model does not know make tracking worse (lockstep: exact)."""
    args = ("--peripherals", "1", "--clock", "lockstep", "--cycles", "300")
    _, ideal, _ = start_json(tmp_path, *args, tag="ideal")
    code, real, out = start_json(tmp_path, *args, "--plant-lag", "2ms", "--plant-friction",
                                 "0.05", tag="lag")
    assert code == 0, out
    print(f"tracking: ideal plant {ideal['tracking_error_m']['max'] * 1e3:.3f} mm, 2 ms lag "
          f"+ friction {real['tracking_error_m']['max'] * 1e3:.3f} mm")
    assert real["tracking_error_m"]["max"] > 1.5 * ideal["tracking_error_m"]["max"]


def test_a_finished_run_leaves_no_run_directory(tmp_path):
    """The run directory (spec, socket, role logs) goes when the run ends well and stays,
    named on stderr, when it fails."""
    env = {**os.environ, "TMPDIR": str(tmp_path)}
    cli = [sys.executable, "-m", "ctrlunit.runtime.cli", "start", "--unit", unit_id("rdir"),
           "--peripherals", "1", "--clock", "lockstep"]
    ok = subprocess.run([*cli, "--cycles", "30"], env=env, capture_output=True, text=True,
                        timeout=120)
    assert ok.returncode == 0, ok.stdout + ok.stderr
    assert not list(tmp_path.glob("ctrlunit-*"))
    # a fault: a tracking limit no run can meet
    bad = subprocess.run([*cli, "--cycles", "300", "--max-error", "1e-5"], env=env,
                         capture_output=True, text=True, timeout=120)
    assert bad.returncode == 5, bad.stdout + bad.stderr
    kept = list(tmp_path.glob("ctrlunit-*"))
    assert len(kept) == 1 and str(kept[0]) in bad.stderr


def test_a_launcher_killed_outright_leaves_a_directory_the_next_start_removes(tmp_path):
    """SIGKILL gives the launcher no chance to remove its run directory; the next start
    removes it (its launcher is gone) and leaves alone a directory kept for a fault's
    diagnosis and one of a launcher still running (runtime/launch/run_dir.py)."""
    env = {**os.environ, "TMPDIR": str(tmp_path)}
    cli = [sys.executable, "-m", "ctrlunit.runtime.cli", "start", "--peripherals", "1",
           "--clock", "lockstep"]
    kept = subprocess.run([*cli, "--unit", unit_id("rkept"), "--cycles", "300",
                           "--max-error", "1e-5"], env=env, capture_output=True, text=True,
                          timeout=120)
    assert kept.returncode == 5, kept.stdout + kept.stderr
    unit, running = unit_id("rkill"), unit_id("rrun")
    procs = [subprocess.Popen([*cli, "--unit", u, "--cycles", "1000000", "--status-file",
                               str(tmp_path / f"{u}.status")], env=env,
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                              start_new_session=True) for u in (unit, running)]
    try:
        for u in (unit, running):
            assert wait_status(tmp_path / f"{u}.status", 20) >= 20
        os.kill(procs[0].pid, signal.SIGKILL)
        procs[0].wait(timeout=10)
        before = set(tmp_path.glob("ctrlunit-*"))
        assert len(before) == 3, before
        ok = subprocess.run([*cli, "--unit", unit_id("rnext"), "--cycles", "30"], env=env,
                            capture_output=True, text=True, timeout=120)
        assert ok.returncode == 0, ok.stdout + ok.stderr
        after = set(tmp_path.glob("ctrlunit-*"))
        assert len(after) == 2 and after < before, (before, after)
        assert any(str(d) in kept.stderr for d in after)  # the kept one is still there
    finally:
        for u in (unit, running):
            kill_unit(u)
        for p in procs:
            if p.poll() is None:
                p.kill()
                p.wait(timeout=10)


def test_placement_auto_moves_the_observer_round_when_messages_cost_more_same_commands(
        tmp_path):
    """--placement auto (the default): here a round trip costs far more than the observer's
    round of arithmetic, so that round runs on the central, the roles re-placed where they
    are, with the commands of the thesis's placement bit for bit; with T-800 block times
    ten times over the round stays on the peripherals."""
    args = ("--peripherals", "3", "--pipeline", "2", "--clock", "lockstep", "--cycles", "60")
    code, auto, out = start_json(tmp_path, *args, tag="pauto")
    assert code == 0, out
    choice = auto["placement_choice"]
    assert choice["rounds"][0]["moved"], choice
    assert auto["placement"]["central_blocks"] == choice["central_blocks"] != []
    assert auto["round_trips"] == 1 and "--placement auto: round 0" in out
    # a peripheral left on the old plan would read the new round 0 as its old one
    assert "starting again" not in out and not auto["rejected_messages"], out
    code, axes, out = start_json(tmp_path, *args, "--placement", "axes", tag="paxes")
    assert code == 0, out
    assert "placement_choice" not in axes and axes["round_trips"] == 2
    assert axes["command_digest"] == auto["command_digest"]
    code, slow, out = start_json(tmp_path, *args, "--cost-model", "t800", "--cost-scale", "10",
                                 tag="pt800")
    assert code == 0, out
    assert slow["placement_choice"]["central_blocks"] == [] and slow["round_trips"] == 2
    assert "starting again" not in out
