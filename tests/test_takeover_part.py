"""The take-over's bookkeeping (runtime/central/takeover.py), driven on its own: the
requests going out again after a silence, the probation of the peripherals taken over
and its end, the requests stopped for good, and a peripheral's return after
:data:`REJOIN_PARTS` current replies, each at its exact figure. The whole unit's take-over
is tests/test_takeover.py."""

from __future__ import annotations

from types import SimpleNamespace
from typing import Any

from ctrlunit.runtime.central import Fault
from ctrlunit.runtime.central.silence import SilenceWatch
from ctrlunit.runtime.central.takeover import CURRENT_BEHIND, REJOIN_PARTS, RESUMES, TakeOver

MS = 1_000_000
TIMEOUT_NS = 300 * MS
"""The lockstep silence limit of these take-overs (``--timeout 300ms``)."""


class Unit:
    """A take-over with what it is given: a silence watch (lockstep), the intervals' part
    reduced to where the run stands (``next_cycle``, ``done``, nothing in flight), what
    goes out reduced to whether requests do, and late data that no round here needs."""

    def __init__(self, *, next_cycle: int = 42, done: int = 40) -> None:
        self.out: Any = SimpleNamespace(requests_on=True)
        self.pipeline: Any = SimpleNamespace(settings=SimpleNamespace(peripherals=3),
                                        next_cycle=next_cycle, done=done, inflight={})
        watch = SilenceWatch(peripherals=3, realtime=False, period_s=1e-3, fault_periods=3,
                             timeout_s=TIMEOUT_NS / 1e9, stride=lambda: 1)
        late: Any = SimpleNamespace(faults_key="u/faults")
        self.t = TakeOver(enabled=True, late=late, silence=watch, intervals=self.pipeline,
                          outgoing=self.out)

    def lose(self, k: int, how: str) -> None:
        """Peripheral ``k`` (0-based) lost: ``silent`` or ``exited``."""
        fault = Fault(f"peripheral {k + 1} {how}", process=f"peripheral-{k + 1}", code=3,
                      lost=how)
        assert self.t.take(fault, (), done=self.pipeline.done,
                           next_cycle=self.pipeline.next_cycle)

    def answer(self, k: int, n: int, *, at: int, cycle: int | None = None) -> list[dict]:
        """Peripheral ``k`` sends ``n`` parts at ``at`` (ns), of interval ``cycle`` (the
        newest begun unless given), one reply each; the parts the central takes."""
        cycle = self.pipeline.next_cycle - 1 if cycle is None else cycle
        kept: list[dict] = []
        for _ in range(n):
            kept += self.t.sift(k, [{"cycle": cycle, "stage": 0}],
                                next_cycle=self.pipeline.next_cycle, done=self.pipeline.done,
                                rx=at)
        return kept


def test_the_silent_ones_reply_sends_the_requests_again_and_each_back_leaves_probation():
    """Peripheral 2 falls silent: all three are taken over, no request goes out. Its first
    reply brings the requests back and puts the three on probation, each heard at that
    reply; each that comes back after :data:`REJOIN_PARTS` current replies leaves it at
    the silence watch's next turn; once all are back none is on probation, the requests
    go on, and it went out again once."""
    u = Unit()
    t = u.t
    u.lose(1, "silent")
    assert set(t.lost) == {0, 1, 2} and not u.out.requests_on and t.resumes == 0
    assert u.answer(1, 1, at=10 * MS) == []  # dropped: the central computes its rounds
    assert u.out.requests_on and t.resumes == 1
    assert t.on_probation == {0: 10 * MS, 1: 10 * MS, 2: 10 * MS}
    assert t.lost[1]["requests_again_at_interval"] == 40
    u.answer(1, REJOIN_PARTS - 2, at=20 * MS)
    assert 1 in t.lost  # one reply short
    u.answer(1, 1, at=21 * MS)
    assert 1 not in t.lost and t.back == {1: 42}
    assert t.on_probation == {0: 10 * MS, 1: 21 * MS, 2: 10 * MS}
    t.probation(10 * MS + TIMEOUT_NS)  # at the limit, not past it: nothing stops
    assert t.on_probation == {0: 10 * MS, 2: 10 * MS} and u.out.requests_on
    u.answer(0, REJOIN_PARTS, at=30 * MS)
    u.answer(2, REJOIN_PARTS, at=40 * MS)
    assert not t.lost and t.on_probation == {0: 30 * MS, 2: 40 * MS}
    t.probation(41 * MS)
    assert not t.on_probation and u.out.requests_on and t.resumes == 1
    assert not any("requests_stopped_again" in d for d in t.report())
    assert t.dropped_replies == 3 * REJOIN_PARTS


def test_one_on_probation_silent_past_the_limit_stops_the_requests_for_good():
    """After the requests went out again, peripheral 3 does not answer: a nanosecond past
    the silence limit from the reply that sent them again they stop for good (the
    resumes used up), peripheral 1, back since, stands by again, and a later reply of
    the one once silent sends them out no more."""
    u = Unit()
    t = u.t
    u.lose(1, "silent")
    u.answer(1, REJOIN_PARTS, at=10 * MS)
    u.answer(0, REJOIN_PARTS, at=20 * MS)
    assert set(t.lost) == {2} and u.out.requests_on
    t.probation(10 * MS + TIMEOUT_NS)
    assert u.out.requests_on and set(t.on_probation) == {2}
    t.probation(10 * MS + TIMEOUT_NS + 1)
    assert not u.out.requests_on and t.resumes == RESUMES and not t.on_probation
    assert set(t.lost) == {0, 1, 2}
    report = t.report()
    assert report[2]["requests_stopped_again"] == \
        "no answer for 300.0 ms after the requests went out again"
    assert [d["why"][:9] for d in report[3:]] == ["stands by", "stands by"]
    assert report[3]["peripheral"] == 1 and report[4]["peripheral"] == 2
    u.answer(1, 1, at=400 * MS)  # alive, but the requests stay off
    assert not u.out.requests_on and t.resumes == RESUMES


def test_a_restarted_peripheral_comes_back_after_rejoin_parts_current_replies_in_a_row():
    """Peripheral 3's process exited: only it is taken over, the requests go on. Its
    replies are dropped, counted towards its return while current (for an interval at
    most :data:`CURRENT_BEHIND` behind the newest begun; an older one starts the count
    again); after :data:`REJOIN_PARTS` in a row it serves the intervals from the next to
    begin, the central still computing its part of those begun before (covering) until
    none of them is in flight."""
    u = Unit(next_cycle=42)
    t = u.t
    u.lose(2, "exited")
    assert set(t.lost) == {2} and u.out.requests_on and t.covering
    u.answer(2, REJOIN_PARTS - 1, at=10 * MS, cycle=42 - CURRENT_BEHIND)
    u.answer(2, 1, at=11 * MS, cycle=42 - CURRENT_BEHIND - 1)  # too old: counted again
    u.answer(2, REJOIN_PARTS - 1, at=12 * MS)
    assert 2 in t.lost
    u.answer(2, 1, at=13 * MS)
    assert 2 not in t.lost and t.back == {2: 42}
    assert t.report()[0]["back_from_cycle"] == 42
    assert t.report()[0]["replies_while_lost"] == 2 * REJOIN_PARTS
    assert t.dropped_replies == 2 * REJOIN_PARTS
    assert u.answer(2, 1, at=14 * MS, cycle=41) == []  # begun before: still computed here
    assert u.answer(2, 1, at=15 * MS, cycle=42) == [{"cycle": 42, "stage": 0}]
    assert t.dropped_replies == 2 * REJOIN_PARTS + 1
    begun_before = SimpleNamespace(cycle=41, waiting=set(), round=None)
    after = SimpleNamespace(cycle=42, waiting=set(), round=None)
    t.cover([begun_before, after])
    assert t.covering
    t.cover([after])
    assert not t.covering
