"""The ``/signals/state`` message: one interval as a control engineer plots it.

The same JSON message goes to the recording (``--record``) and to the live view
(``--foxglove``), under the schema :data:`SIGNALS_SCHEMA` (JSON Schema, draft 2020-12):
platform position and reference, measured joint angles, torques, tracking error, period
and traversal. NaN and infinities are written as ``null``.

Taking an interval apart costs the central's thread a tuple (:func:`capture`); building
the message (:func:`state_message`) can then happen on another thread.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any, NamedTuple

if TYPE_CHECKING:
    from ..central.snapshot import Progress

SIGNALS_SCHEMA: dict[str, Any] = {
    "title": "ctrlunit.State",
    "type": "object",
    "properties": {
        "cycle": {"type": "integer", "minimum": 0},
        "t": {"type": "number", "description": "reference time (s)"},
        "p": {"$ref": "#/$defs/vec3_or_null", "description": "platform position (m)"},
        "reference": {"$ref": "#/$defs/vec3_or_null", "description": "p_c (m)"},
        "q": {"type": "array", "items": {"type": ["number", "null"]}, "minItems": 3,
              "maxItems": 3, "description": "measured joint angles (rad)"},
        "torque": {"type": "array", "items": {"type": ["number", "null"]}, "minItems": 3,
                   "maxItems": 3, "description": "command (N m)"},
        "tracking_error": {"type": ["number", "null"], "description": "|p - p_c| (m)"},
        "period": {"type": ["number", "null"], "description": "since previous command (s)"},
        "traversal": {"type": ["number", "null"], "description": "sample to command (s)"},
    },
    "required": ["cycle", "t", "q", "torque"],
    "$defs": {
        "vec3_or_null": {
            "oneOf": [
                {"type": "null"},
                {"type": "object", "properties": {"x": {"type": ["number", "null"]},
                                                  "y": {"type": ["number", "null"]},
                                                  "z": {"type": ["number", "null"]}},
                 "required": ["x", "y", "z"]},
            ]
        }
    },
}


class Interval(NamedTuple):
    """What the central knows of one finished interval (no copies of its arrays' data
    beyond three floats each)."""

    cycle: int
    cmd_ns: int
    """When its command left (host monotonic clock, ns)."""
    traversal_ns: int
    """Sample to command (ns)."""
    true_p: tuple[float, float, float] | None
    """The plant's true platform position (m), when the clock has it."""
    q: tuple[float, ...]
    """Measured joint angles (rad)."""
    torque: tuple[float, ...]
    """The command (N m)."""
    misses: int
    """Deadline misses so far."""
    skipped: int
    """Samples skipped so far."""
    previous_cmd_ns: int | None = None
    """When the previous interval's command left (ns), if there was one."""
    qd: tuple[float, ...] | None = None
    """Measured joint velocities (rad/s), when the interval has them."""


def capture(p: Progress, ctx: dict) -> Interval:
    """The interval that the central has just finished (call from its ``on_cycle``)."""
    qd = ctx.get("qdmeas_i")
    return Interval(p.cycle, p.cmd_ns, p.traversal_ns, p.true_p,
                    tuple(float(x) for x in ctx["qmeas_i"]),
                    tuple(float(x) for x in ctx["cmd"]),
                    p.misses, p.skipped, p.previous_cmd_ns,
                    None if qd is None else tuple(float(x) for x in qd))


def finite_or_none(x: float) -> float | None:
    """``x``, or ``None`` for NaN and infinities (JSON has no such numbers)."""
    return x if math.isfinite(x) else None


def _vec(v: Any) -> dict[str, float | None] | None:
    if v is None:
        return None
    return {k: finite_or_none(float(x)) for k, x in zip("xyz", v, strict=False)}


def state_message(iv: Interval, *, period_s: float, task: Any | None,
                  previous_cmd_ns: int | None) -> dict[str, Any]:
    """The ``/signals/state`` message of one interval.

    Parameters
    ----------
    iv : the interval.
    period_s : the nominal period (s); the reference time is ``cycle * period_s``.
    task : the task whose ``position(t)`` is the reference ``p_c`` (m); ``None`` when
        the run has no reference (freerun).
    previous_cmd_ns : when the previous interval's command left, or ``None``.
    """
    t = iv.cycle * period_s
    ref = task.position(t) if task is not None else None  # the fresh value, bit for bit
    err = math.dist(iv.true_p, ref) if (iv.true_p is not None and ref is not None) \
        else math.nan
    period = (iv.cmd_ns - previous_cmd_ns) / 1e9 if previous_cmd_ns is not None else math.nan
    return {
        "cycle": iv.cycle,
        "t": t,
        "p": _vec(iv.true_p),
        "reference": _vec(ref),
        "q": [finite_or_none(x) for x in iv.q],
        "torque": [finite_or_none(x) for x in iv.torque],
        "tracking_error": finite_or_none(err),
        "period": finite_or_none(period),
        "traversal": finite_or_none(iv.traversal_ns / 1e9),
    }
