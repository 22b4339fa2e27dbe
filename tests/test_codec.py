"""Message codec: exact round trip, and no crash whatever the bytes."""

from __future__ import annotations

import math

import msgpack
import pytest
from ctrlunit.runtime.transport.codec import (
    MAX_STR_BYTES,
    BadMessage,
    check_vals,
    decode,
    encode,
    short_text,
)
from hypothesis import given, settings
from hypothesis import strategies as st


def test_floats_round_trip_bit_for_bit():
    x = [0.1, -1e-300, 1.2345678901234567e10, math.pi]
    msg = decode(encode("u1", 7, 1, vals={"p": x}), "u1")
    assert msg["vals"]["p"] == x and msg["cycle"] == 7 and msg["stage"] == 1


def test_foreign_unit_and_wrong_schema_are_rejected():
    with pytest.raises(BadMessage, match="foreign_unit"):
        decode(encode("other", 0, 0), "u1")
    bad = msgpack.packb({"v": 99, "unit": "u1", "cycle": 0, "stage": 0})
    with pytest.raises(BadMessage, match="schema_version"):
        decode(bad, "u1")


@settings(max_examples=2000, deadline=None)
@given(st.binary(max_size=512))
def test_random_bytes_never_raise_anything_but_bad_message(data):
    try:
        msg = decode(data, "u1")
    except BadMessage:
        return
    assert isinstance(msg, dict)


def _number_ok(y: object) -> bool:
    """The codec's contract for a number, stated again: an int or a float (never a bool),
    finite, magnitude at most 1e12."""
    return type(y) in (int, float) and math.isfinite(y) and abs(y) <= 1e12


def _three_ok(v: object) -> bool:
    return type(v) is list and len(v) == 3 and all(_number_ok(y) for y in v)


def valid_p_and_rows(vals: object) -> bool:
    """What ``check_vals(vals, ["p", "row_i"], 2)`` must accept: exactly the keys ``p``
    (3 numbers) and ``row_i`` (2 entries of 3 numbers)."""
    return (type(vals) is dict and set(vals) == {"p", "row_i"} and _three_ok(vals["p"])
            and type(vals["row_i"]) is list and len(vals["row_i"]) == 2
            and all(_three_ok(r) for r in vals["row_i"]))


leaf = st.none() | st.booleans() | st.floats() | st.integers() | st.text(max_size=5)
number_or_not = st.one_of(st.floats(width=64), st.integers(-2 * 10**12, 2 * 10**12),
                          st.booleans(), st.none(), st.text(max_size=2))
three = st.lists(number_or_not, min_size=2, max_size=4)
near_valid = st.fixed_dictionaries(
    {"p": three, "row_i": st.lists(three, min_size=1, max_size=3)},
    optional={"extra": leaf})


@settings(max_examples=800, deadline=None)
@given(st.one_of(
    st.recursive(leaf, lambda c: st.lists(c, max_size=4)
                 | st.dictionaries(st.text(max_size=5), c, max_size=4), max_leaves=20),
    near_valid))
def test_check_vals_accepts_exactly_the_valid_maps(vals):
    """Anything: either BadMessage, or (for exactly the maps the contract allows) the
    same values as floats. The near-valid maps (right keys, elements of every kind, some
    lists too short or long) make both outcomes common."""
    try:
        out = check_vals(vals, ["p", "row_i"], 2)
    except BadMessage:
        assert not valid_p_and_rows(vals), vals
        return
    assert valid_p_and_rows(vals), (vals, out)
    assert out == {"p": [float(y) for y in vals["p"]],
                   "row_i": [[float(y) for y in r] for r in vals["row_i"]]}
    assert all(type(y) is float for y in out["p"])


def test_check_vals_accepts_a_valid_map_and_rejects_one_spoiled_element():
    good = {"p": [0.1, 2, -3.0], "row_i": [[1.0, 0.0, 0.0], [0, 1, 0]]}
    assert check_vals(good, ["p", "row_i"], 2)["row_i"][1] == [0.0, 1.0, 0.0]
    for spoiled in (True, None, "1", math.inf, 2e12, [1.0]):
        bad = {"p": [0.1, 2, -3.0], "row_i": [[1.0, 0.0, 0.0], [0, spoiled, 0]]}
        with pytest.raises(BadMessage):
            check_vals(bad, ["p", "row_i"], 2)


def test_nan_and_wrong_lengths_are_rejected():
    with pytest.raises(BadMessage):
        check_vals({"p": [1.0, float("nan"), 0.0]}, ["p"], 1)
    with pytest.raises(BadMessage):
        check_vals({"row_i": [[1.0, 2.0]]}, ["row_i"], 1)
    with pytest.raises(BadMessage):
        check_vals({"row_i": [[1.0, 2.0, 3.0]]}, ["row_i"], 2)


@pytest.mark.parametrize("text", ["done", "x" * 300, "silent for 3.1 ms; " * 30, "µ" * 200])
def test_a_stop_order_with_any_reason_stays_decodable(text):
    """A fault's message (300-600 characters with its hint) once made the stop order
    undecodable to the roles: they ran on and the plant made no safe stop."""
    too_long = len(text.encode()) > MAX_STR_BYTES
    assert too_long == (text != "done")  # the cases: one short reason, three long ones
    if too_long:  # the reason as it was sent before short_text: the roles refused it
        with pytest.raises(BadMessage):
            decode(encode("u1", 0, "stop", reason=text), "u1")
    else:
        assert decode(encode("u1", 0, "stop", reason=text), "u1")["reason"] == text
    short = short_text(text)
    assert len(short.encode()) <= MAX_STR_BYTES
    assert text.startswith(short.removesuffix("..."))
    assert decode(encode("u1", 0, "stop", reason=short, hold=[0.1, 0.2, 0.3]),
                  "u1")["reason"] == short
