"""The live terminal line: figures so far at a constant cost, shown only on a terminal."""

from __future__ import annotations

import os
import pty
import select
import subprocess
import sys
import time

import numpy as np
import pytest
from ctrlunit.runtime.live import LiveStats
from hypothesis import given, settings
from hypothesis import strategies as st
from runner import kill_unit, unit_id


@settings(max_examples=60, deadline=None)
@given(periods_us=st.lists(st.integers(1, 99_999), min_size=1, max_size=400))
def test_period_percentiles_so_far_match_the_exact_ones_to_a_bin(periods_us):
    s = LiveStats(len(periods_us) + 1)
    t = 10**9
    s.add(done=0, cmd_ns=t)
    for k, us in enumerate(periods_us, 1):
        t += us * 1000
        s.add(done=k, cmd_ns=t)
    a = np.array(periods_us) * 1e-6
    for q in (50, 99):
        exact = float(np.percentile(a, q, method="inverted_cdf"))
        assert exact - 1e-12 <= s.percentile_s(q) <= exact + 1e-12, q  # whole us: exact


def test_line_names_interval_misses_and_the_largest_error():
    s = LiveStats(10)
    s.add(done=1, cmd_ns=0, p=(0, 0, 0), pc=(0, 0, 0.001))
    s.add(done=2, cmd_ns=1_000_000, misses=3, skipped=1, p=(0, 0, 0), pc=(0.0004, 0, 0))
    line = s.line()
    assert "interval 2/10" in line and "misses 3" in line and "skipped 1" in line
    assert "error 0.40 mm (max 1.00)" in line and "p50 1000 us" in line


def _run(args: list[str], *, tty: bool, unit: str) -> str:
    """Output of ``ctrlunit start`` with stdout a pseudo-terminal or a pipe."""
    cmd = [sys.executable, "-m", "ctrlunit.runtime.cli", "start", "--unit", unit, *args]
    if not tty:
        res = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
        return res.stdout + res.stderr
    main, sub = pty.openpty()
    proc = subprocess.Popen(cmd, stdout=sub, stderr=sub, stdin=subprocess.DEVNULL,
                            start_new_session=True)
    os.close(sub)
    out = b""
    t0 = time.monotonic()
    try:
        while time.monotonic() - t0 < 120:
            r, _, _ = select.select([main], [], [], 0.5)
            if r:
                try:
                    chunk = os.read(main, 65536)
                except OSError:
                    break
                if not chunk:
                    break
                out += chunk
            elif proc.poll() is not None:
                break
    finally:
        os.close(main)
        if proc.poll() is None:
            proc.kill()
        proc.wait(timeout=10)
        kill_unit(unit)
    return out.decode(errors="replace")


@pytest.mark.zenoh
def test_the_live_line_shows_on_a_terminal_and_is_quiet_in_a_pipe():
    args = ["--clock", "lockstep", "--peripherals", "1", "--cycles", "400"]
    on_tty = _run(args, tty=True, unit=unit_id("livetty"))
    assert "period p50" in on_tty and "misses 0" in on_tty and "interval " in on_tty
    piped = _run(args, tty=False, unit=unit_id("livepipe"))
    assert "period p50" not in piped and "\x1b[" not in piped
    assert "400 intervals" in piped  # the summary itself
