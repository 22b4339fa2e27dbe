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


def freeze_briefly(tmp_path, policy: str) -> tuple[int, dict, str]:
    unit = unit_id(f"late{policy}")
    report, status = tmp_path / f"{policy}.json", tmp_path / f"{policy}.status"
    proc = subprocess.Popen(
        [sys.executable, "-m", "ctrlunit.runtime.cli", "start", "--unit", unit, "--clock",
         "realtime", "--period", "20ms", "--cycles", "120", "--task", slow_task(tmp_path),
         "--late-policy", policy,
         "--max-error", "1", "--report", str(report), "--status-file", str(status)],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        wait_status(status, 40)
        pid = role_pid(unit, "peripheral", 2)
        os.kill(pid, signal.SIGSTOP)  # 30 ms: past the round deadlines (10 and 20 ms after
        time.sleep(0.030)             # the sample), short of the 60 ms liveness limit; the
        os.kill(pid, signal.SIGCONT)  # 10 ms margin keeps this VM's hiccups from others' axes
        out, _ = proc.communicate(timeout=120)
    finally:
        kill_unit(unit)
        if proc.poll() is None:
            proc.kill()
    return proc.returncode, json.loads(report.read_text()) if report.exists() else {}, out


def test_hold_policy_keeps_running_and_counts_misses_per_axis(tmp_path):
    code, rep, out = freeze_briefly(tmp_path, "hold")
    assert code == 0, out
    misses = rep["late"]["misses_per_axis"]
    print(f"hold: misses per axis {misses}, rejected {rep['rejected_messages']}")
    assert misses[1] > 0  # peripheral 2 owns axis 1
    assert misses[0] == misses[2] == 0


def test_fault_policy_names_the_late_peripheral(tmp_path):
    code, _, out = freeze_briefly(tmp_path, "fault")
    assert code == 3, out
    assert "late data: peripheral 2" in out
