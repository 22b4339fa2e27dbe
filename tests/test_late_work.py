"""Where a late interval's time went: the peripherals' work against its median
(runtime/observe/report.py, late_work_figures), and the central's record of it."""

from __future__ import annotations

import msgpack
import pytest
from ctrlunit.runtime.config import RunConfig
from ctrlunit.runtime.observe.report import STRETCH_SAME, STRETCH_SLOWER, late_work_figures
from ctrlunit.runtime.observe.summary import _late_lines
from loopback import LoopbackUnit
from runner import unit_id

US = 1000


def test_work_stretched_in_the_late_intervals_says_the_machine_ran_slower() -> None:
    fig = late_work_figures([100 * US] * 999 + [0], [300 * US, 350 * US, 250 * US], 7)
    assert fig == {"intervals": 7, "work_median_s": pytest.approx(100e-6),
                   "work_stretch": {"median": pytest.approx(3.0), "max": pytest.approx(3.5)},
                   "machine_slower": True}
    line = _late_lines({"late_intervals": fig})[0]
    assert "7 command(s)" in line and "3.0x its median of 100 us (max 3.5x)" in line
    assert line.endswith("the machine itself ran slower")
    # a new user's: "deadline misses 23" beside "late 17", unexplained
    assert len(_late_lines({"late_intervals": fig, "deadline_misses": 7})) == 1
    why = _late_lines({"late_intervals": fig, "deadline_misses": 9})[1]
    assert "the central's count" in why and "the plant's" in why and "transit" in why


@pytest.mark.parametrize(("late", "verdict", "ends"), [
    ([100 * US, 110 * US], False, "waiting, not to the work"),
    ([150 * US], None, "(max 1.5x)"),  # between the limits: the figures, no verdict
])
def test_work_as_usual_says_waiting_and_in_between_says_nothing(late, verdict, ends) -> None:
    assert STRETCH_SAME < 1.5 < STRETCH_SLOWER
    fig = late_work_figures([100 * US] * 100, late, len(late))
    assert fig is not None and fig["machine_slower"] is verdict
    assert _late_lines({"late_intervals": fig})[0].endswith(ends)


def test_no_late_interval_or_no_work_reported_gives_no_stretch() -> None:
    fig = late_work_figures([100 * US] * 10, [], 0)
    assert fig is not None and fig["work_stretch"] is None and fig["machine_slower"] is None
    assert _late_lines({"late_intervals": fig}) == []
    assert late_work_figures([0, 0], [5], 1) is None  # no peripheral reported work


def test_the_central_records_each_intervals_work_and_the_late_ones() -> None:
    """Realtime with peripherals: every finished interval's longest peripheral work goes to
    the log; an interval whose command left after the deadline is counted, its work kept."""
    u = LoopbackUnit(RunConfig.of(unit=unit_id("latework"), clock="realtime", peripherals=3,
                                  pipeline=1))
    c = u.central
    figures = c.snapshot().late
    assert figures.deadline_ns == int(u.rc.schedule.period * 1e9)  # depth 1
    assert u.server is not None
    # on time, then late whatever the machine: the plant's samples stamped a second ahead
    # of the central's clock, then a second behind it (the deadline: a period)
    for k, skew in ((0, 10**9), (1, -(10**9))):
        u.server.sample_no = k
        u.server.publish_sample((0, 0))
        ev = u.node.events.get_nowait()
        msg = msgpack.unpackb(ev.data)
        msg["t_ns"] += skew
        c.handle(ev._replace(data=msgpack.packb(msg, use_single_float=False)))
        for _ in range(50):
            c.start_ready()
            c.send_ready(0)
            u.pump()
            if not u.node.events.pending():
                break
            while u.node.events.pending():
                c.handle(u.node.events.get_nowait())
    late = c.snapshot().late
    assert c.done == 2 and len(late.work_ns) == 2
    work = list(late.work_ns)
    assert all(w > 0 for w in work)
    assert late.late == 1 and list(late.late_work_ns) == work[1:]
