"""The figures README.md states, each written here as a literal.

Two halves: README still states them (a change of README fails here), and the unit still
gives them (a change of behaviour fails here or in the test named beside it). Behaviour
tests elsewhere use the same literals, never the code's own constants.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from ctrlunit.kernels.laws import Gains
from ctrlunit.runtime.compute.controller import simulate
from ctrlunit.runtime.compute.setup import make_setup
from ctrlunit.runtime.config import RunConfig

README = (Path(__file__).parents[1] / "README.md").read_text()
FLAT = " ".join(README.split())  # line breaks folded, so phrases may span lines

STATED = {
    # the silence rule: tests/test_guard.py (cap = 8, "24.0 ms")
    "up to 8 limits (24 ms at 1 ms": "test_guard",
    # overload: tests/test_overload.py (10 late of 100, a run counted once unless 10 long;
    # 2, 4, 8 s; three returns; 3 late on a 0.5 s trial)
    "once 10 of the last 100 intervals came late, late ones in a row counting once, and at "
    "once on 10 late in a row": "test_overload",
    "go back to every sample after 2 s without a late one (4 s after a second halving, "
    "8 s after a third; at most three returns), on trial for 0.5 s: 3 late intervals "
    "halve it again": "test_overload",
    # scheduling: tests/test_sched.py and tests/test_admission.py (0.75, 0.85, 0.95, 2 s, 3)
    "refuses a period at which the unit's own threads kept a CPU over 75 % of the kernel's "
    "real-time budget (71 % of the CPU": "test_admission",
    "a run whose CPU stays over 95 % of it for a second (or passes it in half a second) "
    "goes back to the default policy, and under FIFO again after 2 s under 85 % (at most "
    "three times": "test_sched",
    "`auto` puts every role under `SCHED_FIFO` 10": "test_admission",
    # tracking: below
    "0.019 mm at 1 ms, 0.033 at 1.25 ms, 0.054 at 1.6 ms, 0.089 at 2 ms, 6.0 mm at 8 ms":
        "here",
    "at 1 ms with the control rate halved throughout, 0.038 mm over two loops": "here",
}


@pytest.mark.parametrize("phrase", sorted(STATED))
def test_readme_states_the_figure(phrase):
    assert phrase in FLAT, f"README no longer says: {phrase!r} (tested in {STATED[phrase]})"


def tracking_max_mm(period: float, *, loops: int = 1, halved: bool = False) -> float:
    """The one-process closed loop of a lockstep run at ``period`` with depth 2's delay
    and every default (gains, model state, task, one loop's length)."""
    rc = RunConfig.of(clock="lockstep", peripherals=0, pipeline=2, period=period)
    s = make_setup(rc)
    res = simulate(s.params, s.task, gains=Gains.from_bandwidth(rc.bandwidth),
                   cycles=loops * s.cycles, period=period, delay=rc.delay_periods,
                   model_state=rc.resolved_model_state, halve_at=0 if halved else None)
    return max(res.tracking_error) * 1e3


@pytest.mark.parametrize("period, stated", [(1e-3, "0.019"), (1.25e-3, "0.033"),
                                            (1.6e-3, "0.054"), (2e-3, "0.089"),
                                            (8e-3, "6.0")])
def test_the_tracking_readme_states_is_the_loops(period, stated):
    """Deterministic: the figure at README's precision, not a range."""
    digits = len(stated.split(".")[1])
    assert f"{tracking_max_mm(period):.{digits}f}" == stated


def test_the_halved_rates_tracking_over_two_loops():
    assert f"{tracking_max_mm(1e-3, loops=2, halved=True):.3f}" == "0.038"
