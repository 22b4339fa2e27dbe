"""The schedule model behind ``ctrlunit balance``: chains, bounds and the latency fit."""

from __future__ import annotations

import math

import pytest
from ctrlunit.topology.graph import stage_graph
from ctrlunit.topology.placement import Placement, default_placement
from ctrlunit.topology.plan import exchange_plan
from ctrlunit.topology.schedule import Costs, fit_latency, simulate

GRAPH = stage_graph()
T800 = {b.name: b.t800_s() for b in GRAPH.blocks}
ROUND0 = frozenset({"ik_obs0", "jinv_obs0", "residual0"})


def _plan(n=3, central=frozenset()):
    base = default_placement(n)
    return exchange_plan(GRAPH, Placement(base.axes, central))


def test_depth_one_period_is_the_whole_chain():
    costs = Costs(T800, send_s=20e-6, reply_s=5e-6, step_s=3e-6, latency_s=100e-6)
    plan = _plan()
    s = simulate(plan, costs, depth=1)
    central = sum(T800[st.block.name] for st in plan.steps if st.block is not None)
    periph = sum(T800[b.name] / 3 for r in plan.rounds for b in r.blocks)
    rounds = plan.round_trips
    expected = (central + periph + rounds * (2 * 100e-6 + 20e-6 + 3 * 5e-6)
                + (rounds + 1) * 3e-6)
    assert s.period_mean_s == pytest.approx(expected, rel=1e-9)
    assert s.exchanges_per_interval == pytest.approx(rounds)


def test_single_processor_has_no_exchange_and_runs_the_sum_of_blocks():
    s = simulate(_plan(0), Costs(T800), depth=1)
    assert s.exchanges == 0
    assert s.period_mean_s == pytest.approx(sum(T800.values()), rel=1e-9)


@pytest.mark.parametrize("replies", ["fused", "each"])
def test_depth_two_is_faster_than_depth_one_but_not_than_its_busiest_process(replies):
    costs = Costs(T800, latency_s=50e-6)
    plan = _plan()
    d1 = simulate(plan, costs, depth=1).period_mean_s
    s2 = simulate(plan, costs, depth=2, replies=replies)
    d2 = s2.period_mean_s
    central = sum(T800[st.block.name] for st in plan.steps if st.block is not None)
    periph = sum(T800[b.name] / 3 for r in plan.rounds for b in r.blocks)
    assert max(central, periph) <= d2 * (1 + 1e-9)
    assert d2 < d1
    assert s2.exchanges_per_interval == pytest.approx(1.0, abs=0.05)  # fused rounds
    assert max(s2.business().values()) <= 1.0 + 1e-9


def test_one_round_per_interval_pairs_two_intervals_in_an_exchange_at_depth_two():
    s = simulate(_plan(central=ROUND0), Costs(T800, latency_s=100e-6), depth=2)
    assert s.exchanges_per_interval == pytest.approx(0.5, abs=0.05)


def test_moving_a_round_to_the_central_wins_only_when_messages_outweigh_its_work():
    cheap = {k: v / 100 for k, v in T800.items()}  # today's arithmetic: messages dominate
    for costs, wins in ((Costs(cheap, latency_s=300e-6), True),
                        (Costs(T800, latency_s=10e-6), False)):  # 1994: links were cheap
        now = simulate(_plan(), costs, depth=1).period_mean_s
        moved = simulate(_plan(central=ROUND0), costs, depth=1).period_mean_s
        assert (moved < now) is wins


@pytest.mark.parametrize("depth", [1, 2])
def test_fitted_latency_recovers_the_one_that_made_the_period(depth):
    plan = _plan()
    truth = Costs(T800, send_s=30e-6, reply_s=10e-6, step_s=5e-6, latency_s=240e-6)
    period = simulate(plan, truth, depth=depth, intervals=120).period_mean_s
    blind = Costs(T800, send_s=30e-6, reply_s=10e-6, step_s=5e-6)
    lat = fit_latency(plan, blind, period, depth=depth)
    assert lat == pytest.approx(240e-6, rel=0.02)


def test_bad_arguments_are_refused_with_the_allowed_values():
    with pytest.raises(ValueError, match="depth must be 1 or 2"):
        simulate(_plan(), Costs(T800), depth=3)
    with pytest.raises(ValueError, match="replies must be fused or each"):
        simulate(_plan(), Costs(T800), replies="some")
    assert math.isfinite(simulate(_plan(), Costs(T800), intervals=10).period_mean_s)


def test_moving_the_last_round_recommends_one_processor_not_idle_peripherals():
    """With every other per-axis block already on the central, the rules' move of the last
    round leaves the peripherals nothing: the candidate is n = 0, said in words."""
    from ctrlunit.topology.balance import candidates

    placement = Placement(default_placement(3).axes, ROUND0)
    business = {"central": 0.6, "peripheral_1": 0.08, "peripheral_2": 0.08,
                "peripheral_3": 0.08}
    found = candidates(GRAPH, placement, business, arithmetic=0.05)
    last = [(why, p) for why, p in found if "last round" in why]
    assert len(last) == 1
    why, p = last[0]
    assert p.peripherals == 0 and "n = 0" in why
    # the earlier round of the default placement is still moved as a round, peripherals kept
    first = candidates(GRAPH, default_placement(3), business, arithmetic=0.05)
    assert all(p.peripherals == 3 for why, p in first if "round 0" in why)


def test_placement_auto_moves_a_round_only_when_it_costs_less_than_its_round_trip():
    """--placement auto's rule: every round but the last goes to the central when its
    arithmetic for the three axes costs less than the round trip; the last never does,
    and a block without a measured cost stays."""
    from ctrlunit.topology.balance import auto_central_blocks

    plan = exchange_plan(GRAPH, default_placement(3))
    first, last = plan.rounds[0], plan.rounds[-1]
    cost = {b.name: 10e-6 for r in plan.rounds for b in r.blocks}
    moved, rounds = auto_central_blocks(plan, cost, 200e-6)  # 30 us against 200 us
    assert moved == {b.name for b in first.blocks}
    assert [r["round"] for r in rounds] == [first.index] and rounds[0]["moved"]
    assert math.isclose(rounds[0]["arithmetic_s"], 10e-6 * len(first.blocks))
    assert not moved & {b.name for b in last.blocks}
    kept, _ = auto_central_blocks(plan, cost, 10e-6 * len(first.blocks))  # not cheaper
    assert kept == frozenset()
    unknown, _ = auto_central_blocks(plan, {first.blocks[0].name: 1e-9}, 1.0)
    assert unknown == frozenset()
    alone, none = auto_central_blocks(exchange_plan(GRAPH, default_placement(0)), cost, 1.0)
    assert alone == frozenset() and none == []
