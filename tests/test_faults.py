"""Faults: a process killed or frozen is detected, named, and the robot stopped safely."""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from ctrlunit.runtime.recording import read
from runner import kill_unit, pids_of, unit_id, wait_status

pytestmark = pytest.mark.zenoh


def role_pid(unit: str, role: str, index: int | None = None) -> int:
    for pid in pids_of(unit):
        cmd = Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()
        if f" {role} " in cmd and (index is None or f"--index {index}" in cmd):
            return pid
    raise LookupError(role)


def run_and_break(tmp_path: Path, how: str, role: str, index: int | None, *,
                  clock: str = "lockstep", extra: tuple[str, ...] = ()) -> tuple[int, str, float,
                                                                                 Path]:
    unit = unit_id(f"f{how[:4]}")
    rec, status = tmp_path / "f.mcap", tmp_path / "status"
    proc = subprocess.Popen(
        [sys.executable, "-m", "ctrlunit.runtime.cli", "start", "--unit", unit, "--clock",
         clock, "--cycles", "1000000", "--timeout", "300ms", "--record", str(rec),
         "--status-file", str(status), "--max-error", "1", *extra],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True)
    try:
        wait_status(status, 300)
        pid = role_pid(unit, role, index)
        t0 = time.monotonic()
        os.kill(pid, signal.SIGKILL if how == "kill" else signal.SIGSTOP)
        out, _ = proc.communicate(timeout=30)
        detected = time.monotonic() - t0
        if how == "stop":  # the launcher ends frozen children itself; make sure
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
    finally:
        kill_unit(unit)
        if proc.poll() is None:
            proc.kill()
    return proc.returncode, out, detected, rec


@pytest.mark.parametrize("how", ["kill", "stop"])
def test_failed_peripheral_is_named_and_stops_the_unit(tmp_path, how):
    code, out, detected, rec = run_and_break(tmp_path, how, "peripheral", 2)
    print(f"peripheral 2 {how}: exit {code} after {detected:.2f} s")
    assert code == 3, out
    assert "peripheral-2" in out or "peripheral 2" in out
    assert detected < 3.0
    r = read(rec)
    assert not r.salvaged  # the central closed its recording properly
    assert len(r.topics["/plant/command"]) >= 300


def test_killed_plant_is_named_with_its_own_exit_code(tmp_path):
    code, out, detected, rec = run_and_break(tmp_path, "kill", "plant", None)
    print(f"plant kill: exit {code} after {detected:.2f} s")
    assert code == 4, out
    assert "plant" in out
    assert len(read(rec).topics["/plant/command"]) >= 300


def test_frozen_peripheral_in_realtime_is_detected_quickly(tmp_path):
    code, out, detected, _ = run_and_break(tmp_path, "stop", "peripheral", 1, clock="realtime",
                                           extra=("--period", "5ms"))
    print(f"realtime 5 ms, peripheral 1 frozen: exit {code} after {detected * 1e3:.0f} ms")
    assert code == 3, out
    assert detected < 2.0
