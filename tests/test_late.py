"""Late data in realtime: a per-block policy (hold the last values, or fault) and miss
counts per axis."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

import pytest
from runner import kill_unit, slow_task, unit_id, wait_status
from test_faults import role_pid

pytestmark = pytest.mark.zenoh


PERIOD_MS = 100
"""Long enough that the round deadlines (half a period and a period after the sample) lie
beyond this VM's stalls of up to ~45 ms: only the frozen peripheral is late."""


def freeze_briefly(tmp_path, policy: str, *extra: str) -> tuple[int, dict, str]:
    """Run a unit at 100 ms (the thesis's placement: two rounds) and freeze peripheral 2 for
    250 ms after 15 intervals. Whatever
    the phase of the freeze, both rounds of one interval miss their deadlines (50 and 100
    ms after the sample) while it lasts; the liveness limit is five periods (500 ms)."""
    unit = unit_id(f"late{policy}")
    report, status = tmp_path / f"{unit}.json", tmp_path / f"{unit}.status"
    proc = subprocess.Popen(
        [sys.executable, "-m", "ctrlunit.runtime.cli", "start", "--unit", unit, "--clock",
         "realtime", "--period", f"{PERIOD_MS}ms", "--no-admission", "--cycles", "40",
         "--task", slow_task(tmp_path), "--late-policy", policy, "--max-error", "1",
         "--fault-periods", "5", "--report", str(report), "--status-file", str(status),
         "--placement", "axes", *extra],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        wait_status(status, 15)
        if proc.poll() is None:
            pid = role_pid(unit, "peripheral", 2)
            os.kill(pid, signal.SIGSTOP)
            time.sleep(0.250)
            os.kill(pid, signal.SIGCONT)
        out, _ = proc.communicate(timeout=120)
    finally:
        kill_unit(unit)
        if proc.poll() is None:
            proc.kill()
    return proc.returncode, json.loads(report.read_text()) if report.exists() else {}, out


def test_hold_policy_uses_the_last_values_per_axis_and_replay_holds_them_too(tmp_path):
    """Under hold, the late rounds of the frozen peripheral (axis 1) are computed with that
    axis's last accepted values, as the recording shows; replay --verify re-executes the
    run with them and gets every command bit for bit."""
    from ctrlunit.runtime.recording.reader import read
    from ctrlunit.runtime.recording.replay import _index, verify

    mcap = tmp_path / "hold.mcap"
    code, rep, out = freeze_briefly(tmp_path, "hold", "--record", str(mcap))
    assert code == 0, out
    misses = rep["late"]["misses_per_axis"]
    print(f"hold: misses per axis {misses}, rejected {rep['rejected_messages']}")
    assert misses[1] > 0 and misses[0] == misses[2] == 0  # peripheral 2 owns axis 1
    rec = read(mcap)
    held = [m for _, m in rec.decoded("/faults/held")]
    assert held and {m["peripheral"] for m in held} == {1}
    assert len(held) == misses[1]  # peripheral 2 holds one axis: one miss per hold
    replies = _index(rec, "reply")
    for m in held:  # the last values accepted from peripheral 2 for that round
        earlier = [c for (p, c, s) in replies if p == 1 and s == m["stage"] and c < m["cycle"]
                   and (1, c, s) not in {(h["peripheral"], h["cycle"], h["stage"])
                                         for h in held}]
        assert earlier, m
        assert m["vals"] == replies[(1, max(earlier), m["stage"])]["vals"]
    n, div = verify(rec)
    assert div is None, div
    assert n == rep["cycles"]


def test_fault_policy_names_the_late_peripheral(tmp_path):
    code, _, out = freeze_briefly(tmp_path, "fault")
    assert code == 3, out
    assert "late data: peripheral 2" in out


def test_a_per_block_policy_overrides_the_default_for_its_round(tmp_path):
    """--late-policy hold with --late ik=fault: the round that runs ik (round 1 of resolved
    acceleration) faults when late, where hold alone runs on (the test above)."""
    code, _, out = freeze_briefly(tmp_path, "hold", "--late", "ik=fault")
    assert code == 3, out
    assert "late data: peripheral 2 missed the deadline of round 1 (ik, jinv" in out


def test_compute_policy_computes_the_late_rounds_and_replay_verifies_them(tmp_path):
    """Under compute the frozen peripheral's late rounds are run by the central (the
    recording names them); replay --verify re-executes the run without those replies and
    finds every command bit for bit."""
    from ctrlunit.runtime.recording.reader import read
    from ctrlunit.runtime.recording.replay import verify

    mcap = tmp_path / "compute.mcap"
    code, rep, out = freeze_briefly(tmp_path, "compute", "--record", str(mcap))
    assert code == 0, out
    computed = [m for _, m in read(mcap).decoded("/faults/computed")]
    print(f"compute: {len(computed)} rounds, misses per axis {rep['late']['misses_per_axis']}")
    assert computed and {m["peripheral"] for m in computed} == {1}
    assert rep["late"]["computed"] == len(computed) == rep["late"]["misses_per_axis"][1]
    assert "peripheral round(s) late for their deadline, computed by the central" in out
    n, div = verify(read(mcap))
    assert div is None, div
    assert n == rep["cycles"]


def test_waiting_for_a_frozen_peripheral_makes_the_plant_count_missed_deadlines(tmp_path):
    """The plant's deadline-miss counter, end to end: under ``wait`` the central holds
    every interval until the frozen peripheral answers, so for 250 ms (two and a half
    periods) no new command reaches the plant. The plant counts each period whose command
    was due and had not come (measured: 1; the command extrapolated the period before
    covers it), the sample carries the count, the report prints it. A counter stuck at 0
    (or lost on the way) fails here."""
    code, rep, out = freeze_briefly(tmp_path, "wait")
    assert code == 0, out
    print(f"wait: deadline misses {rep['deadline_misses']}, skipped {rep['skipped_samples']}")
    assert 1 <= rep["deadline_misses"] <= 6, out
    assert f"deadline misses {rep['deadline_misses']}" in out
