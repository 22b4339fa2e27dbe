"""The pipeline's rules (topology/pipeline.py), which the central and the schedule model
share: what each allows at depth 1 and 2."""

from __future__ import annotations

import pytest
from ctrlunit.topology.graph import LAWS, stage_graph
from ctrlunit.topology.pipeline import (
    EST_NAMES,
    finishes_after_next_request,
    handoff_step,
    hold_rule,
    holds_lone_round,
    may_prime,
    may_start,
    prime_cycles,
    reply_mode,
    reply_order,
)
from ctrlunit.topology.placement import default_placement
from ctrlunit.topology.plan import exchange_plan


@pytest.mark.parametrize("law", LAWS)
def test_the_hand_off_is_the_step_that_finishes_the_estimate(law):
    plan = exchange_plan(stage_graph(law, "complete"), default_placement(3))
    k = handoff_step(plan)  # -1: the law keeps no estimate (the next may start at once)
    assert -1 <= k < len(plan.steps)
    later = [b for s in plan.steps[k + 1:]
             for b in (s.round.blocks if s.round is not None else [s.block])]
    assert not any(o in EST_NAMES for b in later for o in b.outputs)


def test_depth_one_never_overlaps_intervals():
    assert may_start(depth=1, live=0, next_cycle=3, cycles=10, newest_handed_off=None)
    assert not may_start(depth=1, live=1, next_cycle=3, cycles=10, newest_handed_off=True)
    assert not may_prime(depth=1, primed=False, next_cycle=3, cycles=10,
                         newest_handed_off=True)
    assert not holds_lone_round(depth=1, ready=1, handed_off=True, cycle=2, next_cycle=3,
                                cycles=10)
    assert not finishes_after_next_request(depth=1, round_index=1, last_round=1)
    assert reply_mode("each", depth=1, peripherals=3, between_s=1.0, round_trip_s=0.0)[0] \
        == "fused"


def test_depth_two_starts_the_next_interval_only_after_the_hand_off():
    assert not may_start(depth=2, live=1, next_cycle=3, cycles=10, newest_handed_off=False)
    assert may_start(depth=2, live=1, next_cycle=3, cycles=10, newest_handed_off=True)
    assert not may_start(depth=2, live=2, next_cycle=3, cycles=10, newest_handed_off=True)
    assert not may_start(depth=2, live=0, next_cycle=10, cycles=10, newest_handed_off=None)
    assert may_prime(depth=2, primed=False, next_cycle=3, cycles=10, newest_handed_off=True)
    assert not may_prime(depth=2, primed=True, next_cycle=3, cycles=10, newest_handed_off=True)


def test_a_lone_round_waits_only_for_the_interval_right_after_it():
    held = dict(depth=2, ready=1, handed_off=True, cycle=4, next_cycle=5, cycles=10)
    assert holds_lone_round(**held)
    assert not holds_lone_round(**(held | {"ready": 2}))  # already fused
    assert not holds_lone_round(**(held | {"handed_off": False}))
    assert not holds_lone_round(**(held | {"next_cycle": 6}))  # the next one started
    assert not holds_lone_round(**(held | {"cycles": 5}))  # no next interval to wait for


def test_auto_holds_lone_rounds_except_in_realtime_and_a_bad_rule_is_named():
    assert [hold_rule("auto", clock=c) for c in ("realtime", "lockstep", "freerun")] == [
        False, True, True]
    assert hold_rule("always", clock="realtime") and not hold_rule("never", clock="freerun")
    with pytest.raises(ValueError, match="'sometimes'.*auto, always, never"):
        hold_rule("sometimes", clock="realtime")


def test_replies_each_answer_first_rounds_first_and_auto_weighs_the_round_trip():
    assert reply_order([1, 0], each=True) == [1, 0]
    assert reply_order([1, 0], each=False) == [0, 1]
    kw = dict(depth=2, peripherals=3)
    assert reply_mode("auto", **kw, between_s=2e-4, round_trip_s=1e-4)[0] == "each"
    assert reply_mode("auto", **kw, between_s=1e-4, round_trip_s=2e-4)[0] == "fused"
    assert reply_mode("fused", **kw, between_s=1.0, round_trip_s=0.0) == ("fused", "asked")


@pytest.mark.parametrize("law", LAWS)
def test_the_hand_off_step_produces_the_last_of_the_estimate_or_is_minus_one(law):
    """The step ``handoff_step`` names is itself one that produces an estimate name; -1
    exactly where no step does (the PD laws keep no estimate). The estimate is the
    central's: no round produces it (so a round's blocks never decide the hand-off)."""
    plan = exchange_plan(stage_graph(law, "complete"), default_placement(3))
    k = handoff_step(plan)

    def produces(step) -> bool:
        blocks = step.round.blocks if step.round is not None else [step.block]
        return any(o in EST_NAMES for b in blocks for o in b.outputs)

    assert (k == -1) == (not any(produces(s) for s in plan.steps))
    assert k == -1 or produces(plan.steps[k])
    assert not any(produces(s) for s in plan.steps if s.round is not None)
    assert k == {"resolved-acceleration": 6, "computed-torque": 6, "pd-gravity": 3,
                 "pd-feedforward": -1, "pd": -1}[law]


def test_the_last_interval_is_neither_started_nor_primed_past_the_run():
    assert not may_prime(depth=2, primed=False, next_cycle=10, cycles=10,
                         newest_handed_off=True)
    assert may_prime(depth=2, primed=False, next_cycle=9, cycles=10, newest_handed_off=None)


def test_only_the_last_round_of_a_depth_two_interval_finishes_after_the_next_request():
    assert finishes_after_next_request(depth=2, round_index=1, last_round=1)
    assert not finishes_after_next_request(depth=2, round_index=0, last_round=1)
    assert not finishes_after_next_request(depth=1, round_index=0, last_round=0)


def test_reply_modes_and_their_reasons():
    one = dict(depth=2, between_s=1.0, round_trip_s=0.0)
    assert reply_mode("each", peripherals=0, **one) == ("fused", "one interval per exchange")
    assert reply_mode("each", peripherals=1, **one) == ("each", "asked")
    assert reply_mode("each", depth=1, peripherals=1, between_s=1.0, round_trip_s=0.0) == (
        "fused", "one interval per exchange")
    why = "each if the central's work between two rounds exceeds a round trip"
    kw = dict(depth=2, peripherals=1)
    assert reply_mode("auto", **kw, between_s=2e-4, round_trip_s=1e-4) == ("each", why)
    assert reply_mode("auto", **kw, between_s=1e-4, round_trip_s=1e-4) == ("fused", why)


def test_two_intervals_are_primed_only_where_foresight_2_lets_their_rounds_share_a_request():
    """Foresight 2 (the estimate two intervals back) primes the next interval and the one
    after it, when that one comes a period later and is on the control rate's grid, and
    still belongs to the run; otherwise the next one alone."""
    both = dict(next_cycle=4, cycles=10, foresight=2, next_is_one=True, after_on_grid=True)
    assert prime_cycles(**both) == [4, 5]
    assert prime_cycles(**both | {"foresight": 1}) == [4]
    assert prime_cycles(**both | {"next_is_one": False}) == [4]  # held two periods: halved
    assert prime_cycles(**both | {"after_on_grid": False}) == [4]
    assert prime_cycles(**both | {"next_cycle": 9}) == [9]  # the run's last interval
    assert prime_cycles(**both | {"next_cycle": 8}) == [8, 9]
