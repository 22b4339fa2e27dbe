"""Message codec: exact round trip, and no crash whatever the bytes."""

from __future__ import annotations

import math

import msgpack
import pytest
from ctrlunit.runtime.codec import (
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


@settings(max_examples=500, deadline=None)
@given(st.recursive(st.none() | st.booleans() | st.floats() | st.integers() | st.text(max_size=5),
                    lambda c: st.lists(c, max_size=4) | st.dictionaries(st.text(max_size=5), c,
                                                                        max_size=4),
                    max_leaves=20))
def test_malformed_vals_are_rejected_not_crashing(vals):
    try:
        check_vals(vals, ["p", "row_i"], 2)
    except BadMessage:
        pass


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
    with pytest.raises(BadMessage):
        if len(text.encode()) > MAX_STR_BYTES:
            decode(encode("u1", 0, "stop", reason=text), "u1")
        else:
            raise BadMessage("fits")
    short = short_text(text)
    assert len(short.encode()) <= MAX_STR_BYTES
    assert text.startswith(short.removesuffix("..."))
    assert decode(encode("u1", 0, "stop", reason=short, hold=[0.1, 0.2, 0.3]),
                  "u1")["reason"] == short
