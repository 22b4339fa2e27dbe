"""The codec's promises at their exact edges: each limit accepted at its value and refused
one step past it, each refusal under its own counter key, each value's shape taken from the
values the unit really computes. (Found with mutation testing: tests/mutation.py; the
score is in docs/measurements/2026-11-23-mutation.md.)"""

from __future__ import annotations

import math

import msgpack
import numpy as np
import pytest
from ctrlunit.kernels.laws import Gains
from ctrlunit.kernels.params import DELTA_IA as P
from ctrlunit.kernels.trajectory import pick_place_task
from ctrlunit.runtime.compute.controller import build_engine
from ctrlunit.runtime.transport import codec
from ctrlunit.runtime.transport.codec import (
    MAX_ABS,
    MAX_CYCLE,
    MAX_MESSAGE_BYTES,
    MAX_PARTS,
    MAX_STR_BYTES,
    BadMessage,
    check_float,
    check_span,
    check_vals,
    check_vector,
    decode,
    encode,
    parts_of,
    shape_of,
    short_text,
)
from ctrlunit.topology.graph import LAWS

U = "t-codec"


def reason(fn, *args) -> str:
    with pytest.raises(BadMessage) as exc:
        fn(*args)
    return exc.value.reason


def raw(**msg) -> bytes:
    return msgpack.packb(msg, use_bin_type=True, use_single_float=False)


def envelope(**over) -> dict:
    return {"v": codec.SCHEMA_VERSION, "unit": U, "cycle": 0, "stage": 0, **over}


# --- the error ---------------------------------------------------------------------------


def test_bad_message_says_its_reason_and_detail():
    assert str(BadMessage("too_large", "70000 bytes")) == "too_large: 70000 bytes"
    assert str(BadMessage("not_a_map")) == "not_a_map"
    assert BadMessage("x", "y").reason == "x"
    assert isinstance(BadMessage("x"), ValueError)


# --- encode and the envelope -----------------------------------------------------------


def test_encode_writes_the_envelope_and_float64():
    msg = msgpack.unpackb(encode(U, 5, "hello", x=0.1), raw=False)
    assert msg == {"v": codec.SCHEMA_VERSION, "unit": U, "cycle": 5, "stage": "hello",
                   "x": 0.1}
    assert msg["x"] == 0.1  # float32 would give 0.10000000149011612
    assert decode(encode(U, 5, "hello", x=0.1), U) == msg


def exactly(size: int) -> bytes:
    """A well-formed message of exactly ``size`` bytes (strings of at most 200 characters,
    lists of at most 60: inside every container limit)."""
    rows = [["x" * 200] * 60]
    while len(raw(**envelope(pad=rows))) + 12_200 < size:
        rows.append(["x" * 200] * 60)
    rows = rows[:60]
    for tail in range(200 * 60):
        words = [*["x" * 200] * (tail // 200), "x" * (tail % 200)]
        data = raw(**envelope(pad=rows, tail=words))
        if len(data) == size:
            return data
    raise AssertionError(f"no message of {size} bytes")


def test_message_size_limit_is_inclusive():
    fits = exactly(MAX_MESSAGE_BYTES)
    assert decode(fits, U)["tail"]
    with pytest.raises(BadMessage, match=rf"too_large: {MAX_MESSAGE_BYTES + 1} bytes"):
        decode(fits + b"\x00", U)
    exact = b"\xc0" * MAX_MESSAGE_BYTES  # the size test passes; the bytes are nonsense
    assert reason(decode, exact, U) == "undecodable"


@pytest.mark.parametrize(("field", "ok", "bad"), [
    ("array", [0] * 64, [0] * 65),
    ("map", {str(i): 0 for i in range(60)}, {str(i): 0 for i in range(65)}),
    ("str", "x" * MAX_STR_BYTES, "x" * (MAX_STR_BYTES + 1)),
])
def test_container_limits_are_inclusive(field, ok, bad):
    decode(raw(**envelope(f=ok)), U)
    assert reason(decode, raw(**envelope(f=bad)), U) == "undecodable"


def test_binary_is_refused_and_every_envelope_field_has_its_reason():
    assert reason(decode, raw(**envelope(f=b"x")), U) == "undecodable"
    assert reason(decode, msgpack.packb([1, 2]), U) == "not_a_map"
    assert reason(decode, raw(**envelope(v=1)), U) == "schema_version"
    assert reason(decode, raw(**{k: v for k, v in envelope().items() if k != "v"}), U) \
        == "schema_version"
    assert reason(decode, raw(**envelope(unit="other")), U) == "foreign_unit"
    with pytest.raises(BadMessage, match="foreign_unit: 'other'"):
        decode(raw(**envelope(unit="other")), U)


@pytest.mark.parametrize(("cycle", "ok"), [(0, True), (MAX_CYCLE - 1, True), (-1, False),
                                           (MAX_CYCLE, False), (True, False), (1.0, False),
                                           ("1", False), (None, False)])
def test_cycle_is_an_integer_from_0_below_2_to_the_62(cycle, ok):
    data = raw(**envelope(cycle=cycle))
    if ok:
        assert decode(data, U)["cycle"] == cycle
    else:
        with pytest.raises(BadMessage, match=r"bad_cycle: " + repr(cycle)[:40]):
            decode(data, U)


@pytest.mark.parametrize(("stage", "ok"), [(0, True), (7, True), ("sample", True),
                                           (False, False), (1.5, False), (None, False),
                                           ([1], False)])
def test_stage_is_an_integer_or_a_name(stage, ok):
    data = raw(**envelope(stage=stage))
    if ok:
        assert decode(data, U)["stage"] == stage
    else:
        assert reason(decode, data, U) == "bad_stage"


# --- parts ------------------------------------------------------------------------------


def part(cycle=0, stage=0) -> dict:
    return {"cycle": cycle, "stage": stage, "vals": {}}


@pytest.mark.parametrize("n", range(1, MAX_PARTS + 1))
def test_one_to_four_parts_are_a_message(n):
    parts = [part(c, 0) for c in range(n)]
    assert parts_of(envelope(parts=parts)) == parts


@pytest.mark.parametrize("parts", [[], [part()] * (MAX_PARTS + 1), None, "parts",
                                   (part(),), [part(), [1]], [part(), "x"]])
def test_anything_else_is_bad_parts(parts):
    assert reason(parts_of, envelope(parts=parts)) == "bad_parts"


@pytest.mark.parametrize(("cycle", "stage", "why"), [
    (-1, 0, "bad_cycle"), (MAX_CYCLE, 0, "bad_cycle"), (True, 0, "bad_cycle"),
    ("0", 0, "bad_cycle"), (0, "0", "bad_stage"), (0, True, "bad_stage"),
    (0, None, "bad_stage"), (0, 0.0, "bad_stage")])
def test_each_part_has_its_own_cycle_and_stage(cycle, stage, why):
    assert reason(parts_of, envelope(parts=[part(), part(cycle, stage)])) == why
    assert reason(parts_of, envelope(parts=[part(cycle, stage)])) == why


def test_the_envelope_names_the_first_part():
    assert parts_of(envelope(cycle=3, stage=1, parts=[part(3, 1), part(4, 0)]))
    assert reason(parts_of, envelope(cycle=3, stage=1, parts=[part(4, 0), part(3, 1)])) \
        == "bad_parts"
    assert reason(parts_of, envelope(cycle=3, stage=0, parts=[part(3, 1)])) == "bad_parts"
    assert parts_of(envelope(cycle=MAX_CYCLE - 1, parts=[part(MAX_CYCLE - 1)]))


# --- values -----------------------------------------------------------------------------


@pytest.mark.parametrize(("span", "ok"), [([0, 1], True), ([5, 2], True), ([0], False),
                                          ([0, 1, 2], False), ((0, 1), False),
                                          ([0, 1.0], False), ([True, 1], False),
                                          ([0, False], False), (None, False)])
def test_a_span_is_two_integers(span, ok):
    if ok:
        assert check_span(span) is span
    else:
        with pytest.raises(BadMessage, match="bad_value: span must be two integers"):
            check_span(span)


@pytest.mark.parametrize(("x", "ok"), [
    (0.0, True), (-0.0, True), (3, True), (MAX_ABS, True), (-MAX_ABS, True),
    (math.nextafter(MAX_ABS, math.inf), False), (math.nextafter(-MAX_ABS, -math.inf), False),
    (10**13, False), (-(10**13), False), (math.nan, False), (math.inf, False),
    (True, False), ("1", False), (None, False), ([1.0], False)])
def test_a_number_is_a_finite_int_or_float_up_to_1e12(x, ok):
    if ok:
        y = check_float(x, "p")
        assert type(y) is float and y == x
    else:
        with pytest.raises(BadMessage) as exc:
            check_float(x, "p")
        assert exc.value.reason == "bad_value" and "p must be" in str(exc.value)


def test_the_refusal_says_which_rule():
    with pytest.raises(BadMessage, match="p must be a number, not bool"):
        check_float(True, "p")
    with pytest.raises(BadMessage, match="p must be finite with magnitude <= 1e"):
        check_float(math.nan, "p")


def test_a_vector_has_exactly_its_length_of_numbers():
    assert check_vector([1, 2.0, -3], 3, "v") == [1.0, 2.0, -3.0]
    assert all(type(x) is float for x in check_vector([1, 2, 3], 3, "v"))
    for bad in ([1.0, 2.0], [1.0] * 4, (1.0, 2.0, 3.0), [1.0, True, 2.0], None):
        with pytest.raises(BadMessage, match="bad_value"):
            check_vector(bad, 3, "v")
    with pytest.raises(BadMessage, match="v must be a list of 3 numbers"):
        check_vector([1.0], 3, "v")


def test_short_text_keeps_a_string_that_fits_and_cuts_one_that_does_not():
    fits = "x" * MAX_STR_BYTES
    assert short_text(fits) is fits
    cut = short_text("x" * (MAX_STR_BYTES + 1))
    assert cut == "x" * (MAX_STR_BYTES - 3) + "..." and len(cut.encode()) == MAX_STR_BYTES
    assert short_text("abcdef", 5) == "ab..."
    assert short_text("abcde", 5) == "abcde"
    # never half a character: 'é' is two bytes; 6 bytes of it cut to 4 bytes at most
    assert short_text("é" * 5, 6) == "é" + "..." and short_text("é" * 3, 6) == "é" * 3


# --- the shapes of the exchanged values ------------------------------------------------


def _shape(v) -> tuple[int, ...]:
    return np.asarray(v, dtype=float).shape


@pytest.mark.parametrize("observer", ["predict", "previous"])
@pytest.mark.parametrize("law", LAWS)
def test_shape_of_each_exchanged_value_is_the_shape_the_unit_computes(law, observer):
    """Every value a round sends or receives, for every law and observer: the codec's
    expected shape equals that of the value a real interval computes."""
    task = pick_place_task()
    engine = build_engine(P, task, law=law, model="complete", gains=Gains.from_bandwidth(20.0),
                          period=1e-3, observer=observer, peripherals=3)
    from ctrlunit.kernels.kinematics import inverse_kinematics
    from ctrlunit.runtime.compute.controller import Estimate

    q = [float(x) for x in inverse_kinematics(P, task.start())]
    ctx = engine.run_local(engine.new_ctx(0.01, Estimate(tuple(task.start()), (0.0,) * 3,
                                                         (0.0,) * 3), q, [0.0] * 3))
    names = {n for r in engine.plan.rounds for n in (*r.send, *r.recv)}
    assert names
    for name in names:
        v = ctx[name]
        got = _shape(v[0]) if name.endswith("_i") else _shape(v)
        assert shape_of(name) == got, name
        # and check_vals takes exactly that value, per axis for per-axis names
        vals = {name: [list(np.asarray(x, dtype=float).tolist()) if got else float(x)
                       for x in v] if name.endswith("_i")
                else np.asarray(v, dtype=float).tolist()}
        check_vals(vals, [name], 3)


@pytest.mark.parametrize(("name", "shape"), [
    ("t", ()), ("est", (3, 3)), ("J", (3, 3)), ("p", (3,)), ("pd", (3,)), ("pdd", (3,)),
    ("p_lin0", (3,)), ("tau", (3,)), ("ax_i", (9,)), ("axo0_i", (9,)), ("axr_i", (9,)),
    ("row_i", (3,)), ("rowo1_i", (3,)), ("rowr_i", (3,)), ("f_i", (3,)), ("q_i", ()),
    ("qo0_i", ()), ("r0_i", ()), ("qdmeas_i", ()), ("tauq_i", ()), ("qddcmd_i", ()),
    ("x", (3,)), ("t2", ())])
def test_shape_of_by_name(name, shape):
    assert shape_of(name) == shape


def test_check_vals_wants_exactly_its_names_and_axis_count():
    good = {"p": [0.0, 0.0, 0.0], "q_i": [0.1, 0.2]}
    out = check_vals(good, ["p", "q_i"], 2)
    assert out == good
    assert reason(check_vals, {"p": [0.0] * 3}, ["p", "q_i"], 2) == "bad_vals"
    assert reason(check_vals, {**good, "x": 1.0}, ["p", "q_i"], 2) == "bad_vals"
    assert reason(check_vals, {"p": [0.0] * 3, "x": [0.1, 0.2]}, ["p", "q_i"], 2) == "bad_vals"
    assert reason(check_vals, [good], ["p", "q_i"], 2) == "bad_vals"
    assert reason(check_vals, {"p": [0.0] * 3, "q_i": [0.1]}, ["p", "q_i"], 2) == "bad_vals"
    assert reason(check_vals, {"p": [0.0] * 3, "q_i": (0.1, 0.2)}, ["p", "q_i"], 2) \
        == "bad_vals"
    with pytest.raises(BadMessage, match="q_i must hold 2 entries"):
        check_vals({"p": [0.0] * 3, "q_i": [0.1]}, ["p", "q_i"], 2)
    assert reason(check_vals, {"p": [0.0] * 2, "q_i": [0.1, 0.2]}, ["p", "q_i"], 2) \
        == "bad_value"


def test_check_vals_turns_ints_into_floats_at_every_depth():
    out = check_vals({"t": 1, "J": [[1, 0, 0], [0, 1, 0], [0, 0, 1]], "row_i": [[1, 2, 3]]},
                     ["t", "J", "row_i"], 1)
    assert type(out["t"]) is float
    assert all(type(x) is float for r in out["J"] for x in r)
    assert all(type(x) is float for x in out["row_i"][0])
    for bad in ([[1.0] * 3] * 2, [[1.0] * 3] * 3 + [[1.0] * 3], [[1.0] * 2] * 3, "J"):
        assert reason(check_vals, {"J": bad}, ["J"], 1) == "bad_value"
    with pytest.raises(BadMessage, match="J must be 3 rows"):
        check_vals({"J": [[1.0] * 3]}, ["J"], 1)
    assert reason(check_vals, {"t": MAX_ABS * 2}, ["t"], 1) == "bad_value"
    assert reason(check_vals, {"row_i": [[1.0, math.inf, 0.0]]}, ["row_i"], 1) == "bad_value"
    assert reason(check_vals, {"row_i": [[1.0, 2e12, 0.0]]}, ["row_i"], 1) == "bad_value"


@pytest.mark.parametrize(("name", "shape"), [
    (n, ()) for n in ("t", "q", "qo", "qc", "r", "qd", "jdp", "qdd", "tauq", "taufb", "qdc",
                      "qddc", "qddcmd", "qmeas", "qdmeas")] + [
    (n + "_i", ()) for n in ("qc", "qd", "jdp", "qdd", "taufb", "qdc", "qddc", "r1", "qo2")] + [
    (n, (3,)) for n in ("rowo", "rowr", "row", "f", "rowo0_i", "rowr_i", "f_i", "pc", "vc")] + [
    ("J", (3, 3)), ("est", (3, 3)), ("ax", (9,)), ("axr", (9,)), ("axo2_i", (9,))])
def test_the_whole_shape_table(name, shape):
    assert shape_of(name) == shape


def test_map_keys_must_be_strings():
    data = msgpack.packb({**envelope(), 1: "x"}, use_bin_type=True)
    assert reason(decode, data, U) == "undecodable"


def test_each_refusal_carries_its_detail():
    """The counter key is what the unit counts; the detail is what a log shows."""
    def text(fn, *args) -> str:
        with pytest.raises(BadMessage) as exc:
            fn(*args)
        return str(exc.value)

    assert text(decode, b"\xc1", U) == "undecodable: FormatError"
    assert text(decode, raw(**envelope(v=7)), U) == "schema_version: 7"
    assert text(decode, raw(**envelope(unit="u" * 60)), U) == "foreign_unit: " + repr("u" * 60)[:40]
    assert text(decode, raw(**envelope(cycle="c" * 60)), U) == "bad_cycle: " + repr("c" * 60)[:40]
    assert text(decode, raw(**envelope(stage=[0] * 30)), U) == "bad_stage: " + repr([0] * 30)[:40]
    assert text(parts_of, envelope(parts=[])) == "bad_parts: parts must be a list of 1 to 4 maps"
    assert text(parts_of, envelope(parts=[part(), 3])) == "bad_parts: a part must be a map"
    assert text(parts_of, envelope(parts=[part(), part(cycle="c" * 60)])) \
        == "bad_cycle: " + repr("c" * 60)[:40]
    assert text(parts_of, envelope(parts=[part(), part(stage=[1] * 30)])) \
        == "bad_stage: " + repr([1] * 30)[:40]
    assert text(parts_of, envelope(cycle=1, parts=[part()])) \
        == "bad_parts: the envelope must name the first part"
    assert text(check_vals, {"a": 1.0}, ["b"], 3) == "bad_vals: expected ['b']"
    assert text(check_vals, {"a": 1.0, "b": 1.0}, ["b"], 3) == "bad_vals: expected ['b']"
    assert text(check_vals, {"p": [1.0]}, ["p"], 3) == "bad_value: p must be a list of 3 numbers"
    assert text(check_vals, {"t": "x"}, ["t"], 3) == "bad_value: t must be a number, not str"
    assert text(check_vals, {"q_i": [0.0, 0.0, "x"]}, ["q_i"], 3) \
        == "bad_value: q_i must be a number, not str"
    assert text(check_vals, {"row_i": [[1.0, 2.0, "x"]]}, ["row_i"], 1) \
        == "bad_value: row_i must be a number, not str"
    assert text(check_vals, {"J": [[1.0, "x", 0.0]] * 3}, ["J"], 1) \
        == "bad_value: J must be a number, not str"
    assert text(check_vector, [1.0, "x", 2.0], 3, "v") == "bad_value: v must be a number, not str"
    assert text(check_vector, [1.0], 3, "v") == "bad_value: v must be a list of 3 numbers"


def test_shapes_are_right_from_a_cold_cache():
    """check_vals caches each name's shape; a process's first message must be checked
    with the right one too (mutation testing runs warm processes and found this unpinned)."""
    codec._SHAPES.clear()
    assert reason(check_vals, {"p": 1.0}, ["p"], 3) == "bad_value"
    codec._SHAPES.clear()
    assert check_vals({"p": [0.0, 1.0, 2.0], "q_i": [0.5]}, ["p", "q_i"], 1) \
        == {"p": [0.0, 1.0, 2.0], "q_i": [0.5]}
    assert codec._SHAPES == {"p": (3,), "q_i": ()}
