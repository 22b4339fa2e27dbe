"""The live terminal line: figures so far at a constant cost, shown only on a terminal."""

from __future__ import annotations

import io
import os
import pty
import select
import subprocess
import sys
import time
from typing import Any

import numpy as np
import pytest
from ctrlunit.runtime.observe.live import LiveStats, TerminalLine
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


@settings(max_examples=40, deadline=None)
@given(periods_us=st.lists(st.integers(1, 150_000), min_size=1, max_size=300))
def test_intervals_added_at_once_give_the_percentiles_of_intervals_added_one_by_one(periods_us):
    one, many = LiveStats(1000), LiveStats(1000)
    t = np.cumsum([10**9] + [us * 1000 for us in periods_us])
    for k, c in enumerate(t):
        one.add(done=k, cmd_ns=int(c))
    many.add_many(done=len(t) - 1, cmd_ns=t[:5], misses=0, skipped=0)
    many.add_many(done=len(t) - 1, cmd_ns=t[5:], misses=0, skipped=0)
    assert np.array_equal(one.hist, many.hist) and np.array_equal(one.coarse, many.coarse)
    for q in (1, 50, 99, 100):
        assert one.percentile_s(q) == many.percentile_s(q)


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
    args = ["--clock", "lockstep", "--peripherals", "1", "--cycles", "3000"]
    on_tty = _run(args, tty=True, unit=unit_id("livetty"))
    assert "period p50" in on_tty and "misses 0" in on_tty and "interval " in on_tty
    piped = _run(args, tty=False, unit=unit_id("livepipe"))
    assert "period p50" not in piped and "\x1b[" not in piped
    assert "3000 intervals" in piped  # the summary itself


def _drawn(out: str) -> list[str]:
    """The lines drawn on the terminal (each write starts by erasing the line)."""
    return [x for x in out.split("\r\x1b[2K") if x]


def test_terminal_line_draws_bar_figures_and_time_left_then_clears_itself():
    out = io.StringIO()
    line = TerminalLine(out, width=200)
    line.show("interval 1/4", 1, 4)
    line.close()
    drawn = _drawn(out.getvalue())
    assert drawn and drawn[-1].startswith("ctrlunit [######------------------]  25%  interval 1/4")
    assert drawn[-1].endswith(" s left")
    assert out.getvalue().endswith("\r\x1b[2K")  # cleared: the report starts on a clean line


def test_terminal_line_writes_the_newest_line_last_and_cuts_it_to_the_width():
    out = io.StringIO()
    with TerminalLine(out, width=50) as line:
        for k in range(1, 201):
            line.show(f"interval {k}/200 " + "x" * 50, k, 200)
    drawn = _drawn(out.getvalue())
    assert 1 <= len(drawn) <= 200 and all(len(d) <= 49 for d in drawn)
    # too narrow for the bar and the text: the bar goes first, the text is cut last
    assert drawn[-1].startswith("ctrlunit 100%  interval 200/200 x")


def test_the_bar_narrows_before_the_figures_are_cut():
    text = "interval 9/10  period p50 866 us  p99 1623 us  misses 0  skipped 0"
    assert TerminalLine.fit(1.0, text, 200) == f"ctrlunit [{'#' * 24}] 100%  {text}"
    narrow = TerminalLine.fit(0.5, text, 100)
    assert narrow.endswith(text) and len(narrow) == 99 and "[########-------]" in narrow
    assert TerminalLine.fit(0.5, text, 90) == f"ctrlunit  50%  {text}"


def test_a_message_during_the_run_is_written_on_a_cleared_line():
    out = io.StringIO()
    line = TerminalLine(out, width=200)
    line.show("interval 1/2", 1, 2)
    for _ in range(200):  # the writer thread draws it (bounded wait)
        if out.getvalue():
            break
        time.sleep(0.005)
    line.above("ctrlunit: a message", out)
    line.close()
    text = out.getvalue()
    assert "interval 1/2  0 s left\r\x1b[2Kctrlunit: a message\n" in text


def progress(cycle: int, done: int, *, planned: int, hold: int = 1,
             lost: tuple[int, ...] = ()) -> Any:
    """What the central hands ``on_cycle`` after interval ``cycle`` (runtime/central/
    snapshot.py), the interval's command a millisecond after the last."""
    from ctrlunit.runtime.central.records import CycleLog
    from ctrlunit.runtime.central.snapshot import History, Progress

    return Progress(cycle, done, cycle + hold, planned, 1e-3, done * 1_000_000, None, 0, None,
                    0, 0, {}, lost, (), History(CycleLog(), list))


def test_the_bar_counts_periods_covered_when_the_control_rate_is_halved():
    """Halved from cycle 10 of 20: 15 intervals cover the 20 periods, and the bar ends
    full, not at 15 of 20."""
    from ctrlunit.runtime.observe.live import LiveLine

    shown: list[tuple[int, int]] = []
    line = LiveLine(lambda text, done, total: shown.append((done, total)))
    cycles = list(range(10)) + list(range(10, 20, 2))
    for done, k in enumerate(cycles, 1):
        line(progress(k, done, planned=20, hold=2 if k >= 10 else 1), {})
    assert len(cycles) == 15
    assert shown[-1] == (20, 20)


def test_the_line_names_the_peripherals_taken_over():
    """A peripheral lost and taken over (runtime/central/takeover.py) is named on the
    live line from the next refresh on."""
    from ctrlunit.runtime.observe.live import LiveLine

    shown: list[str] = []
    line = LiveLine(lambda text, done, total: shown.append(text))
    for k in range(4):
        line(progress(k, k + 1, planned=4, lost=(1,) if k == 3 else ()), {})
    assert "taken over" not in shown[0]
    assert shown[-1].startswith("taken over P2  interval 4/4")  # first: a narrow line keeps it
