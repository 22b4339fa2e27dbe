"""Late data as a part (runtime/central/late.py, ``LateData``): the memory of replies
expected late, when the loop must wake for a late round, and that every waiting interval
is looked at, each under its round's policy."""

from __future__ import annotations

from types import SimpleNamespace

import pytest
from ctrlunit.runtime.central import Fault
from ctrlunit.runtime.central.late import HELD_KEPT, LateData
from ctrlunit.runtime.central.records import InFlight
from ctrlunit.runtime.compute.setup import make_setup
from ctrlunit.runtime.config import RunConfig

SETUP = make_setup(RunConfig.of(clock="realtime", peripherals=3, placement_auto=False)
                   .validate())
PLAN = SETUP.plan
"""The plan each late data here follows (its engine's)."""


def late_data(*, late: dict[str, str] | None = None, pending: bool = False,
              policy: str = "compute") -> tuple[LateData, list[InFlight]]:
    advanced: list[InFlight] = []
    ld = LateData(SETUP.engine(), late=late or {}, late_policy=policy,
                  faults_key="ctrlunit/u/faults", pending=lambda: pending,
                  advance=advanced.append, span=lambda *a: None)
    return ld, advanced


def interval(cycle: int, stage: int, late_ns: int) -> InFlight:
    rnd = SimpleNamespace(index=stage, blocks=PLAN.rounds[stage].blocks)
    return InFlight(cycle=cycle, gen=iter(()), ctx={}, sample_ns=0, start_ns=0, round=rnd,
                    waiting={1}, late_ns=late_ns)


def test_the_replies_expected_late_are_the_newest_1024_and_each_is_late_once():
    ld, _ = late_data()
    for cycle in range(HELD_KEPT + 1):
        ld.expect_late(cycle, 0, 1)
    assert len(ld.held) == HELD_KEPT == 1024 and (0, 0, 1) not in ld.held
    assert ld.came_late(1, 0, 1) and not ld.came_late(1, 0, 1)
    assert not ld.came_late(0, 0, 1)  # forgotten: the oldest


def test_the_loop_wakes_for_a_late_round_unless_its_policy_waits():
    ld, _ = late_data()
    assert ld.wake_at([interval(5, 0, 7_000), interval(6, 1, 9_000)]) == 7_000
    waits, _ = late_data(policy="wait")
    assert waits.wake_at([interval(5, 0, 7_000)]) is None


@pytest.mark.parametrize("pending", [True, False])
def test_a_round_computed_or_put_off_does_not_end_the_look_at_the_others(pending):
    """The first interval's round is ``compute`` (put off while replies are pending, or
    not computable from an empty context); the second's is ``fault``: its fault is raised
    all the same."""
    faulty = PLAN.rounds[1].blocks[0].name
    ld, _ = late_data(pending=pending, late={faulty: "fault"})
    first, second = interval(5, 0, 1_000), interval(6, 1, 1_000)
    with pytest.raises(Fault, match="late data: peripheral 2 missed the deadline of round 1"):
        ld.check(2_000, [first, second])
    assert first.waiting == {1}  # not computed: no values to compute it from
