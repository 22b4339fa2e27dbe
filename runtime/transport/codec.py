"""Message codec: msgpack maps with schema version, unit id, cycle and stage.

Every decoded message is validated (types, lengths, finite numbers) before anything reads
it; a bad one raises :class:`BadMessage`, which the receiver counts and drops.
"""

from __future__ import annotations

from typing import Any

import msgpack

SCHEMA_VERSION = 2  # 2: requests and replies carry ``parts``
MAX_MESSAGE_BYTES = 64 * 1024
MAX_CYCLE = 2**62
MAX_PARTS = 4
MAX_STR_BYTES = 256
"""Longest string (UTF-8 bytes) a message may hold; a longer one makes it undecodable."""
WARMUP_BASE = 1 << 40
"""Cycle numbers of the central's warm-up, throw-away intervals (runtime/central/warmup.py),
from here to twice this; the admission's trials number theirs from twice this up."""


def is_warmup(cycle: int) -> bool:
    """Whether ``cycle`` numbers one of the central's warm-up intervals."""
    return WARMUP_BASE <= cycle < 2 * WARMUP_BASE


class BadMessage(ValueError):
    """A payload failed decoding or validation; ``reason`` is a short counter key."""

    def __init__(self, reason: str, detail: str = "") -> None:
        super().__init__(f"{reason}: {detail}" if detail else reason)
        self.reason = reason


def encode(unit: str, cycle: int, stage: int | str, **fields: Any) -> bytes:
    """Encode a message (floats as float64, so values round-trip bit for bit)."""
    msg = {"v": SCHEMA_VERSION, "unit": unit, "cycle": cycle, "stage": stage}
    msg.update(fields)
    return msgpack.packb(msg, use_bin_type=True, use_single_float=False)


def short_text(text: str, limit: int = MAX_STR_BYTES) -> str:
    """``text`` cut to at most ``limit`` UTF-8 bytes (on a character boundary), so that a
    message carrying it stays decodable."""
    raw = text.encode()
    return text if len(raw) <= limit else raw[: limit - 3].decode(errors="ignore") + "..."


def decode(data: bytes, unit: str) -> dict[str, Any]:
    """Decode and check the envelope of a message for ``unit``.

    Raises
    ------
    BadMessage
        On undecodable bytes, a missing or ill-typed envelope field, another schema
        version or another unit id.
    """
    if len(data) > MAX_MESSAGE_BYTES:
        raise BadMessage("too_large", f"{len(data)} bytes")
    try:
        msg = msgpack.unpackb(data, raw=False, strict_map_key=True, max_array_len=64,
                              max_map_len=64, max_str_len=MAX_STR_BYTES, max_bin_len=0)
    except Exception as exc:  # msgpack raises several unrelated types
        raise BadMessage("undecodable", type(exc).__name__) from None
    if not isinstance(msg, dict):
        raise BadMessage("not_a_map")
    if msg.get("v") != SCHEMA_VERSION:
        raise BadMessage("schema_version", repr(msg.get("v")))
    if msg.get("unit") != unit:
        raise BadMessage("foreign_unit", repr(msg.get("unit"))[:40])
    cycle = msg.get("cycle")
    if isinstance(cycle, bool) or not isinstance(cycle, int) or not 0 <= cycle < MAX_CYCLE:
        raise BadMessage("bad_cycle", repr(cycle)[:40])
    stage = msg.get("stage")
    if isinstance(stage, bool) or not isinstance(stage, int | str):
        raise BadMessage("bad_stage", repr(stage)[:40])
    return msg


def parts_of(msg: dict[str, Any]) -> list[dict[str, Any]]:
    """The parts of a request or reply.

    A part is one round of one interval: a map with its own ``cycle``, ``stage`` (the
    round) and ``vals`` (a reply part also ``span`` and, when recording, ``trace``). At
    pipeline depth 2 one exchange carries two parts, the second half of interval k and
    the first half of k+1 (§ IV.7.2, Fig. 24). The envelope's ``cycle`` and ``stage`` are
    those of the first part.

    Raises
    ------
    BadMessage
        On a missing or malformed parts list, or a part without a valid cycle or stage.
    """
    parts = msg.get("parts")
    if type(parts) is not list or not 1 <= len(parts) <= MAX_PARTS:
        raise BadMessage("bad_parts", f"parts must be a list of 1 to {MAX_PARTS} maps")
    for part in parts:
        if type(part) is not dict:
            raise BadMessage("bad_parts", "a part must be a map")
        cycle = part.get("cycle")
        if isinstance(cycle, bool) or not isinstance(cycle, int) or not 0 <= cycle < MAX_CYCLE:
            raise BadMessage("bad_cycle", repr(cycle)[:40])
        stage = part.get("stage")
        if isinstance(stage, bool) or not isinstance(stage, int):
            raise BadMessage("bad_stage", repr(stage)[:40])
    if parts[0]["cycle"] != msg["cycle"] or parts[0]["stage"] != msg["stage"]:
        raise BadMessage("bad_parts", "the envelope must name the first part")
    return parts


def check_span(span: Any) -> list[int]:
    """A compute span ``[t0, t1]`` in integer nanoseconds."""
    if not (type(span) is list and len(span) == 2 and all(
            isinstance(x, int) and not isinstance(x, bool) for x in span)):
        raise BadMessage("bad_value", "span must be two integers")
    return span


MAX_ABS = 1e12
"""Largest magnitude a value may have. Every quantity of the unit (positions in metres,
speeds, accelerations, Jacobian entries, torques) is many orders of magnitude below it; a
larger one is refused like a NaN, so that no arithmetic downstream overflows."""


def _number(y: Any, what: str) -> float:
    """``y`` as a float if it is a finite int or float with ``|y| <= MAX_ABS``.

    ``bool`` is not a number here (``True`` is an ``int`` to Python, not to the unit).
    """
    t = type(y)
    if t is not float and t is not int:
        raise BadMessage("bad_value", f"{what} must be a number, not {t.__name__}")
    if not -MAX_ABS <= y <= MAX_ABS:  # NaN fails both comparisons
        raise BadMessage("bad_value", f"{what} must be finite with magnitude <= {MAX_ABS:g}")
    return float(y)


def check_float(x: Any, what: str) -> float:
    """A finite float (ints accepted, bools not)."""
    return _number(x, what)


def check_vector(x: Any, n: int, what: str) -> list[float]:
    """A list of ``n`` finite floats."""
    if type(x) is not list or len(x) != n:
        raise BadMessage("bad_value", f"{what} must be a list of {n} numbers")
    return [_number(v, what) for v in x]


def shape_of(name: str) -> tuple[int, ...]:
    """Shape of one value (one axis's entry for per-axis values) by its name."""
    base = name[:-2] if name.endswith("_i") else name
    stem = base.rstrip("0123456789")
    if stem in ("axo", "axr", "ax"):
        return (9,)
    if stem in ("J", "est"):
        return (3, 3)
    if stem in ("t", "q", "qo", "qc", "r", "qd", "jdp", "qdd", "tauq", "taufb", "qdc", "qddc",
                "qddcmd", "qmeas", "qdmeas"):
        return ()
    return (3,)  # Jacobian rows, forces, positions, velocities, accelerations, torques


_SHAPES: dict[str, tuple[int, ...]] = {}


def _finite_floats(x: Any, n: int, name: str) -> list[float]:
    """``x`` must be a list of ``n`` numbers (see :func:`_number`); ints become floats."""
    if type(x) is not list or len(x) != n:
        raise BadMessage("bad_value", f"{name} must be a list of {n} numbers")
    out = x
    for i, y in enumerate(x):
        if type(y) is float and -MAX_ABS <= y <= MAX_ABS:
            continue  # the common case, without a call
        v = _number(y, name)
        if out is x:
            out = list(x)
        out[i] = v
    return out


def _check_shaped(x: Any, shape: tuple[int, ...], name: str) -> Any:
    if not shape:
        if type(x) is float and -MAX_ABS <= x <= MAX_ABS:
            return x
        return _number(x, name)
    if len(shape) == 1:
        return _finite_floats(x, shape[0], name)
    if type(x) is not list or len(x) != shape[0]:
        raise BadMessage("bad_value", f"{name} must be {shape[0]} rows")
    return [_finite_floats(r, shape[1], name) for r in x]


def check_vals(vals: Any, names: list[str], n_axes: int) -> dict[str, Any]:
    """Validate a ``vals`` map: exactly ``names``; per-axis ones hold ``n_axes`` entries."""
    if type(vals) is not dict or len(vals) != len(names):
        raise BadMessage("bad_vals", f"expected {sorted(names)}")
    out = {}
    for name in names:
        if name not in vals:
            raise BadMessage("bad_vals", f"expected {sorted(names)}")
        shape = _SHAPES.get(name)
        if shape is None:
            shape = _SHAPES[name] = shape_of(name)
        v = vals[name]
        if name.endswith("_i"):
            if type(v) is not list or len(v) != n_axes:
                raise BadMessage("bad_vals", f"{name} must hold {n_axes} entries")
            out[name] = [_check_shaped(e, shape, name) for e in v]
        else:
            out[name] = _check_shaped(v, shape, name)
    return out
