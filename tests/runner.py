"""Helpers to run ``ctrlunit`` in a subprocess and to find its processes."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
import uuid
from pathlib import Path


def unit_id(tag: str) -> str:
    """A unique unit id per test, so that runs cannot cross."""
    return f"t-{tag}-{uuid.uuid4().hex[:8]}"


def pids_of(unit: str) -> list[int]:
    """Processes whose command line mentions ``unit`` (from /proc)."""
    out = []
    for d in Path("/proc").iterdir():
        if not d.name.isdigit() or int(d.name) == os.getpid():
            continue
        try:
            cmd = (d / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
        except OSError:
            continue
        if unit in cmd and "ctrlunit" in cmd:
            out.append(int(d.name))
    return out


def kill_unit(unit: str) -> None:
    for pid in pids_of(unit):
        try:
            os.kill(pid, signal.SIGKILL)
        except ProcessLookupError:
            pass


def wait_gone(unit: str, *, timeout: float = 10.0) -> list[int]:
    """Wait up to ``timeout`` seconds for every process of ``unit`` to exit; the ones left."""
    deadline = time.monotonic() + timeout
    while (left := pids_of(unit)) and time.monotonic() < deadline:
        time.sleep(0.05)
    return left


def ctrlunit(*args: str, timeout: float = 300.0) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "ctrlunit.runtime.cli", *args],
                          capture_output=True, text=True, timeout=timeout)


def start_json(tmp_path: Path, *args: str, timeout: float = 300.0, tag: str = "run"
               ) -> tuple[int, dict, str]:
    """Run ``ctrlunit start`` with a unique unit and a report file; always cleans up."""
    unit = unit_id(tag)
    report = tmp_path / f"{unit}.json"
    try:
        res = ctrlunit("start", "--unit", unit, "--report", str(report), *args, timeout=timeout)
    finally:
        time.sleep(0.1)
        kill_unit(unit)
    data = json.loads(report.read_text()) if report.exists() else {}
    return res.returncode, data, res.stdout + res.stderr


def wait_status(path: Path, at_least: int, *, timeout: float = 60.0) -> int:
    """Wait until a run's --status-file says at least ``at_least`` intervals are done."""
    deadline = time.monotonic() + timeout
    done = 0
    while time.monotonic() < deadline:
        if path.exists():
            done = int(path.read_text() or 0)
            if done >= at_least:
                break
        time.sleep(0.01)
    return done


def slow_task(tmp_path: Path) -> str:
    """Pick & place at 2 m/s^2 instead of 80 (about 0.9 s a move): a task a unit sampled
    at 20 ms can follow, for realtime tests run at long periods on this noisy VM."""
    path = tmp_path / "slow-pick-place.json"
    path.write_text(json.dumps({"name": "slow-pick-place", "dwell": 0.05, "segments": [
        {"type": "half-ellipse", "start": [0.125, 0.0, -0.35], "top": [0.0, 0.0, -0.31],
         "end": [-0.125, 0.0, -0.35], "accel": 2.0}]}))
    return str(path)


def taken_over_and_back(rep: dict) -> bool:
    """No peripheral was taken over, or each one taken over (the silent one and those
    that stood by with it) served its rounds again before the end, the requests never
    stopped for good: a slow peripheral, not one cut off."""
    return all("back_from_cycle" in d and not d.get("requests_stopped_again")
               for d in rep.get("degraded") or [])
