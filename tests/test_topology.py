"""Stage graphs, placements and exchange plans."""

from __future__ import annotations

import json

import pytest
from ctrlunit.topology.graph import KINEMATICS, LAWS, MEASURED, stage_graph
from ctrlunit.topology.placement import (
    Placement,
    PlacementError,
    default_placement,
    load_placement,
    placement_from_mapping,
)
from ctrlunit.topology.plan import exchange_plan


@pytest.mark.parametrize("law", LAWS)
@pytest.mark.parametrize("n", [1, 2, 3])
def test_every_law_needs_at_most_three_round_trips(law, n):
    plan = exchange_plan(stage_graph(law), default_placement(n))
    assert 1 <= plan.round_trips <= 3


def test_resolved_acceleration_needs_two_rounds_with_predicted_observer():
    assert exchange_plan(stage_graph(), default_placement(3)).round_trips == 2
    thesis = stage_graph(observer="previous")  # n_s = 2 from the previous estimate
    assert exchange_plan(thesis, default_placement(3)).round_trips == 3


@pytest.mark.parametrize("law", (*LAWS, KINEMATICS))
@pytest.mark.parametrize("n", [1, 2, 3])
def test_sample_free_steps_are_central_and_need_nothing_measured(law, n):
    plan = exchange_plan(stage_graph(law), default_placement(n))
    k = plan.presample_steps
    assert k >= 1  # the reference never needs the sample
    for step in plan.steps[:k]:
        assert step.round is None and step.block is not None
        assert not set(step.block.inputs) & set(MEASURED), step.block.name
    nxt = plan.steps[k]  # the first step left needs the sample or is a round
    assert nxt.round is not None or set(nxt.block.inputs) & set(MEASURED)


def test_resolved_acceleration_runs_reference_and_prediction_before_its_sample():
    plan = exchange_plan(stage_graph(), default_placement(3))
    assert [s.block.name for s in plan.steps[:plan.presample_steps]] == [
        "reference", "predict"]


def test_single_processor_plan_has_no_round():
    assert exchange_plan(stage_graph(), default_placement(0)).round_trips == 0


def test_requests_carry_only_what_the_round_needs():
    plan = exchange_plan(stage_graph(), default_placement(3))
    r0, r1 = plan.rounds
    assert set(r0.send) == {"p_lin0", "qmeas_i"}
    assert set(r0.recv) == {"rowo0_i", "r0_i"}
    assert set(r1.send) == {"pa", "pda", "pdd"}  # the model at the state where it acts
    assert set(r1.recv) == {"row_i", "tauq_i", "f_i"}
    thesis = exchange_plan(stage_graph(model_state="sample"), default_placement(3))
    assert set(thesis.rounds[1].send) == {"p", "pd", "pdd"}


def test_the_model_state_moves_the_second_round_to_the_predicted_state():
    acting, sample = stage_graph(), stage_graph(model_state="sample")
    assert (acting.model_state, sample.model_state) == ("acting", "sample")
    names = [b.name for b in acting.blocks]
    assert names.index("velocity") < names.index("inflight") < names.index("law") < names.index(
        "ahead") < names.index("ik")
    # the law servoes the state predicted at the acting period's start to the reference
    # there, and the model is evaluated half a period further on
    assert acting.block("inflight").inputs == ("t", "p", "pd", "est")
    assert acting.block("inflight").outputs == ("p0", "v0")
    assert acting.block("reference").kernel == "reference_acting"
    assert acting.block("reference").outputs == ("pc", "vc", "ac", "pcd", "vcd")
    assert acting.block("law").inputs == ("pcd", "vcd", "ac", "p0", "v0")
    assert acting.block("ahead").inputs == ("p0", "v0", "pdd", "hold")
    assert acting.block("ik").inputs == ("pa",) and "pda" in acting.block("jdot").inputs
    assert "ahead" not in [b.name for b in sample.blocks]
    assert "inflight" not in [b.name for b in sample.blocks]
    assert sample.block("law").inputs == ("pc", "vc", "ac", "p", "pd")
    assert sample.block("ik").inputs == ("p",) and "pd" in sample.block("jdot").inputs
    # the velocity at the sample from the observed positions, not J qdot
    assert acting.block("velocity").kernel == "velocity_diff"
    assert acting.block("velocity").inputs == ("t", "p", "est")
    assert sample.block("velocity").kernel == "velocity"
    # every other block (the observer, the estimate handed off, the dynamics) is the same
    moved = ("reference", "inflight", "law", "ahead", "ik", "jdot", "velocity")
    assert [b for b in acting.blocks if b.name not in moved] == [
        b for b in sample.blocks if b.name not in moved]


@pytest.mark.parametrize("law", [x for x in LAWS if x != "resolved-acceleration"])
def test_the_other_laws_evaluate_their_model_at_the_sample(law):
    g = stage_graph(law)
    assert g.model_state == "sample" and "ahead" not in [b.name for b in g.blocks]
    assert g == stage_graph(law, model_state="sample")


def test_an_unknown_model_state_is_refused_with_the_allowed_list():
    with pytest.raises(ValueError, match="model state must be one of acting, sample"):
        stage_graph(model_state="later")


def test_moving_a_block_to_the_central_changes_the_plan():
    pl = Placement(((0,), (1,), (2,)), frozenset({"accel", "dyn_axis"}))
    plan = exchange_plan(stage_graph(), pl)
    r1 = plan.rounds[1]
    assert "accel" not in [b.name for b in r1.blocks]
    assert {"jdp_i", "ax_i", "qd_i"} <= set(r1.recv)


def test_placement_must_cover_each_axis_once():
    with pytest.raises(PlacementError, match="cover axes 0, 1, 2 exactly once"):
        Placement(((0, 1), (1, 2)))


def test_placement_file_errors_name_the_field(tmp_path):
    f = tmp_path / "p.json"
    f.write_text(json.dumps({"peripherals": 5}))
    with pytest.raises(PlacementError, match=r"peripherals = 5 must be an integer in \[0, 3\]"):
        load_placement(f)
    with pytest.raises(PlacementError, match="central_blocks.*not per-axis blocks"):
        placement_from_mapping({"peripherals": 3, "central_blocks": ["law"]},
                               block_names={"ik", "accel"})
    with pytest.raises(PlacementError, match="unknown field"):
        placement_from_mapping({"peripherals": 1, "speed": 3})


def test_placement_round_trips_through_a_file(tmp_path):
    pl = Placement(((0, 2), (1,)), frozenset({"accel"}))
    f = tmp_path / "p.json"
    f.write_text(json.dumps(pl.to_dict()))
    assert load_placement(f) == pl
    assert pl.processors == 3


def test_unknown_law_is_refused_with_the_allowed_list():
    with pytest.raises(ValueError, match="resolved-acceleration"):
        stage_graph("fuzzy")
