"""Validation is a contract: a payload built from the exchange plan's own value names, with
any one field wrong (type, shape, element type, magnitude), is a counted rejection, never
an exception, and leaves the peripheral answering the next good request exactly as an
undisturbed one does."""

from __future__ import annotations

import math
from typing import Any

import msgpack
import pytest
from ctrlunit.kernels.kinematics import inverse_kinematics
from ctrlunit.kernels.laws import Gains
from ctrlunit.kernels.params import DELTA_IA as P
from ctrlunit.kernels.trajectory import Task, pick_place_task
from ctrlunit.runtime.central.fault import role_report
from ctrlunit.runtime.compute.controller import Controller, build_engine
from ctrlunit.runtime.compute.engine import Engine
from ctrlunit.runtime.compute.setup import make_setup
from ctrlunit.runtime.config import ConfigError, RunConfig
from ctrlunit.runtime.roles.peripheral import Peripheral
from ctrlunit.runtime.transport.codec import (
    MAX_ABS,
    SCHEMA_VERSION,
    BadMessage,
    check_vals,
    decode,
    encode,
)
from ctrlunit.topology.graph import LAWS
from hypothesis import assume, given, settings
from hypothesis import strategies as st

UNIT = "t-validation"


def real_requests(law: str) -> tuple[Engine, list[dict[str, Any]]]:
    """The engine of a 3-peripheral unit and the parts of every round of its first interval,
    as the central would send them (each part: cycle, stage, vals)."""
    task = pick_place_task()
    engine = build_engine(P, task, law=law, model="complete", gains=Gains.from_bandwidth(20.0),
                          period=1e-3, peripherals=3)
    return engine, first_interval(engine, task)


def first_interval(engine: Engine, task: Task) -> list[dict[str, Any]]:
    """The parts of every round of ``engine``'s first interval on ``task``."""
    ctl = Controller(engine, 1e-3, P.increment, tuple(task.start()))
    q = inverse_kinematics(P, task.start())
    ctx = ctl.sources(0, [round(float(x) / P.increment) + 3 for x in q])
    parts = []
    gen = engine.cycle(ctx)
    try:
        rnd = next(gen)
        while True:
            parts.append({"cycle": 0, "stage": rnd.index,
                          "vals": Engine.request_vals(rnd, ctx, (0, 1, 2))})
            engine.run_round(rnd, ctx, (0, 1, 2))
            rnd = gen.send(None)
    except StopIteration:
        pass
    assert parts
    return parts


def request(part: dict[str, Any], **envelope: Any) -> bytes:
    return encode(UNIT, part["cycle"], part["stage"], parts=[part], **envelope)


def replies_vals(payloads: list[bytes]) -> list[Any]:
    """The values of replies, without their compute spans."""
    return [[p["vals"] for p in decode(b, UNIT)["parts"]] for b in payloads]


def answers_of_a_good_interval(per: Peripheral, parts: list[dict[str, Any]]) -> list[Any]:
    return [replies_vals(per.on_request(request(p))) for p in parts]


ENGINE_BY_LAW = {law: real_requests(law) for law in LAWS}
ENGINE, PARTS = ENGINE_BY_LAW["resolved-acceleration"]


@pytest.mark.parametrize("bad", [[0, "x", 0.0], [1, True, 2.0], [True, 1.0, 2.0],
                                 [1.0, None, 2.0], [1.0, 2**63 - 1, 0.0], [1.0, math.inf, 0.0],
                                 [1.0, 2.0], [[1.0], 2.0, 3.0]])
def test_a_round_with_a_wrong_element_is_counted_not_raised(bad):
    """The request that once ended a peripheral (a string in ``p_lin0``) and its kin."""
    part = PARTS[0]
    assert "p_lin0" in part["vals"], "the real round 0 sends p_lin0"
    per = Peripheral(ENGINE, 0, UNIT)
    assert list(per.on_request(request({**part, "vals": {**part["vals"], "p_lin0": bad}}))) == []
    assert per.rejected == {"bad_value": 1}
    assert per.served == 0


def test_bool_is_not_a_number_anywhere():
    with pytest.raises(BadMessage, match="not bool"):
        check_vals({"p": [1, True, 2.0]}, ["p"], 1)
    with pytest.raises(BadMessage, match="not bool"):
        check_vals({"q_i": [0.0, False, 1.0]}, ["q_i"], 3)
    assert check_vals({"p": [1, 2, 3.5]}, ["p"], 1) == {"p": [1.0, 2.0, 3.5]}


WRONG = st.one_of(
    st.booleans(), st.none(), st.text(max_size=4),
    st.floats(allow_nan=True, allow_infinity=True).filter(lambda x: not abs(x) <= MAX_ABS),
    st.integers(min_value=int(MAX_ABS) + 1, max_value=2**64 - 1),
    st.integers(max_value=-int(MAX_ABS) - 1, min_value=-(2**63)),
    st.dictionaries(st.text(max_size=3), st.integers(-(2**63), 2**64 - 1), max_size=2),
    st.lists(st.floats(allow_nan=False, allow_infinity=False, width=32), max_size=4),
)


def spoil(value: Any, data: st.DataObject) -> Any:
    """``value`` with one element (or the whole) replaced by something it may not hold,
    or its shape changed (a tuple is a list on the wire)."""
    if type(value) not in (list, tuple) or not value or data.draw(st.integers(0, 4)) == 0:
        return data.draw(WRONG)
    how = data.draw(st.integers(0, 2))
    if how == 0:  # one element wrong, maybe a nested one
        i = data.draw(st.integers(0, len(value) - 1))
        return [*value[:i], spoil(value[i], data), *value[i + 1:]]
    if how == 1:  # one element too many or too few
        return [*value, 0.0] if data.draw(st.booleans()) else list(value[:-1])
    return {"x": list(value)}  # not a list at all


def well_formed_like(x: Any, like: Any) -> bool:
    """Whether ``x`` has the nested shape of ``like`` with finite numbers of at most 1e12
    (not bool): a value the codec must accept, so no spoiled one. The central's values are
    often tuples: on the wire they are lists like any other, so a drawn ``[0.0, 0.0, 0.0]``
    in place of a 3-tuple is well formed (it once failed the test as a "spoiled" value)."""
    if type(like) in (list, tuple):
        return type(x) is list and len(x) == len(like) and all(
            well_formed_like(a, b) for a, b in zip(x, like, strict=True))
    return (type(x) in (int, float) and math.isfinite(x) and abs(x) <= 1e12)


@pytest.mark.parametrize("law", LAWS)
@settings(max_examples=60, deadline=None)
@given(data=st.data())
def test_a_plan_derived_payload_with_one_wrong_field_is_a_counted_rejection(law, data):
    engine, parts = ENGINE_BY_LAW[law]
    index = data.draw(st.integers(0, 2))
    per, undisturbed = Peripheral(engine, index, UNIT), Peripheral(engine, index, UNIT)
    part = parts[data.draw(st.integers(0, len(parts) - 1))]
    where = data.draw(st.sampled_from(["value", "envelope", "part"]))
    if where == "value":
        name = data.draw(st.sampled_from(sorted(part["vals"])))
        spoiled = spoil(part["vals"][name], data)
        # e.g. one 3-vector replaced by [0.0, 0.0, 0.0]: still a valid value
        assume(not well_formed_like(spoiled, part["vals"][name]))
        bad = request({**part, "vals": {**part["vals"], name: spoiled}})
    elif where == "envelope":
        field = data.draw(st.sampled_from(["each", "parts", "v", "cycle"]))
        msg = {"v": SCHEMA_VERSION, "unit": UNIT, "cycle": part["cycle"],
               "stage": part["stage"], "parts": [part]}
        msg[field] = data.draw(WRONG.filter(lambda x: field != "each" or type(x) is not bool))
        bad = msgpack.packb(msg, use_bin_type=True)
    else:
        field = data.draw(st.sampled_from(["vals", "stage", "cycle"]))
        # a part's cycle may be any number in [0, 2**62): the envelope names it too
        bad = request({**part, field: data.draw(WRONG.filter(
            lambda x: field != "cycle" or not (type(x) is int and 0 <= x < 2**62)))})
    try:
        assert list(per.on_request(bad)) == []
    except BadMessage:
        pytest.fail("a BadMessage escaped the role")
    assert sum(per.rejected.values()) == 1, per.rejected
    assert answers_of_a_good_interval(per, parts) == answers_of_a_good_interval(undisturbed,
                                                                                 parts)


def test_a_forged_role_report_keeps_only_well_typed_fields():
    forged = {"cpu_s": True, "rejected": {"a": 1, "b": "x", "c": True}, "sched": ["x"],
              "rss_kb": {"warm": 1}, "safe_stop": 3, "exit": "stop", "extra": 1}
    assert role_report(forged) == {"rejected": {"a": 1}, "rss_kb": {"warm": 1}, "exit": "stop"}


def test_a_place_order_switches_the_plan_before_the_run_and_nothing_else_does():
    """``--placement auto`` re-places the roles where they are: a peripheral given the
    blocks of the first round answers the next interval as one built with that placement;
    unknown names, a non-list, an order after the run started, or a role that cannot
    re-place are counted rejections that leave its plan as it was."""
    setup = make_setup(RunConfig.of(unit=UNIT, peripherals=3, pipeline=2, clock="lockstep"))
    moved = sorted(b.name for b in setup.plan.rounds[0].blocks)
    placed = setup.with_central_blocks(moved)
    assert placed.plan.round_trips == setup.plan.round_trips - 1
    assert placed.rc.schedule.central_blocks == moved
    parts = first_interval(placed.engine(), placed.task)
    engine = setup.engine()
    built: list[Engine] = []  # the engines of the placements it was ordered to take

    def place(blocks: Any) -> Engine:
        built.append(setup.with_central_blocks(blocks).engine())
        return built[-1]

    per = Peripheral(engine, 1, UNIT, place=place)
    for order, started, reason in (({"central_blocks": ["nope"]}, False, "bad_value"),
                                   ({"central_blocks": "ik_obs0"}, False, "bad_value"),
                                   ({}, False, "bad_value"),
                                   ({"central_blocks": moved}, True, "bad_stage")):
        before = sum(per.rejected.values())
        assert per.on_place(order, "peripheral-2", started=started) is None
        assert per.rejected[reason] >= 1 and sum(per.rejected.values()) == before + 1
        assert per.engine is engine  # its plan as it was
    ack = decode(per.on_place({"central_blocks": moved}, "peripheral-2", started=False), UNIT)
    assert (ack["stage"], ack["role"], ack["central_blocks"]) == ("placed", "peripheral-2", moved)
    assert per.engine is built[-1] and built[-1].plan.round_trips == placed.plan.round_trips
    fresh = Peripheral(placed.engine(), 1, UNIT)
    assert answers_of_a_good_interval(per, parts) == answers_of_a_good_interval(fresh, parts)
    assert Peripheral(setup.engine(), 1, UNIT).on_place(
        {"central_blocks": moved}, "peripheral-2", started=False) is None
    with pytest.raises(ConfigError, match=r"central_blocks \['nope'\] .* allowed: "):
        setup.with_central_blocks(["nope"])
