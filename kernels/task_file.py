"""Task files: a path of lines, arcs and half ellipses (kernels/trajectory.py) read from
JSON, each field checked and a refusal naming the segment and field.

Format::

    {"name": "mine", "dwell": 0.05, "segments": [
        {"type": "line", "start": [x,y,z], "end": [x,y,z], "accel": 50},
        {"type": "arc", "centre": [...], "start": [...], "end": [...], "accel": 50},
        {"type": "half-ellipse", "start": [...], "top": [...], "end": [...], "accel": 50}]}

The path is continuous: each segment starts where the one before it ended (within
:data:`JOIN_M`). A gap would be a step of the reference, which no robot follows: the
tracking error at the step is the gap itself.
"""

from __future__ import annotations

import json
import math
from pathlib import Path as FsPath
from typing import Any, TypeGuard

from .small_file import read_small_text
from .trajectory import TASKS, Ellipse, Line, Segment, Task, Vec3, arc, half_ellipse

MAX_COORD_M = 10.0
"""Largest coordinate a task file may give (m): far beyond any Delta's reach, so that a
path out of reach is refused by the workspace check with its point and bound, and a
typing slip (1e308) never reaches the arithmetic."""

MAX_NAME_CHARS = 200
"""Longest task name a task file may give; reports quote it whole."""

MAX_SEGMENTS = 256
"""Most segments a task file may give (each costs its arc-length table when read)."""

JOIN_M = 1e-6
"""How far a segment may start from where the one before it ended (m): 1 um, an eighth
of an encoder increment at the arm's tip."""

KEYS = {"line": ("start", "end"), "arc": ("centre", "start", "end"),
        "half-ellipse": ("start", "top", "end")}
"""Each segment type's points, besides ``type`` and ``accel``."""


def _is_number(x: object) -> TypeGuard[float]:
    """A finite int or float from JSON (``true`` is not a number)."""
    return (type(x) is int or type(x) is float) and math.isfinite(x)


def _vec(s: dict[str, Any], key: str, where: str) -> Vec3:
    v = s.get(key)
    if not isinstance(v, list) or len(v) != 3 or not all(
            _is_number(x) and abs(x) <= MAX_COORD_M for x in v):
        raise ValueError(f"{where}.{key} must be a list of 3 numbers within "
                         f"+-{MAX_COORD_M:g} m, got {v!r}"[:300])
    return (float(v[0]), float(v[1]), float(v[2]))


def _segment(s: object, where: str) -> Segment:
    """One segment of a task file, or a ValueError naming ``where`` and the field."""
    if not isinstance(s, dict):
        raise ValueError(f"{where} must be an object")
    kind = s.get("type")
    if kind not in KEYS:
        raise ValueError(f"{where}.type must be line, arc or half-ellipse, got {kind!r}"[:300])
    unknown = sorted(str(k) for k in s if k not in ("type", "accel", *KEYS[kind]))
    if unknown:
        raise ValueError(f"{where}: unknown field {unknown[0]!r} (a {kind} has type, "
                         f"{', '.join(KEYS[kind])} and accel)"[:300])
    accel = s.get("accel")
    if not _is_number(accel) or not 0.0 < accel <= 1000.0:
        raise ValueError(f"{where}.accel must be in (0, 1000] m/s^2, got {accel!r}"[:300])
    points = [_vec(s, key, where) for key in KEYS[kind]]
    try:
        curve: Line | Ellipse = (Line(*points) if kind == "line" else arc(*points)
                                 if kind == "arc" else half_ellipse(*points))
        return Segment(curve, float(accel))
    except (ValueError, ArithmeticError) as exc:
        raise ValueError(f"{where}: {exc}") from None


def _joined(segs: list[Segment], path: str | FsPath) -> None:
    """Each segment starts where the one before it ended, else a ValueError naming both."""
    for k in range(1, len(segs)):
        end, start = segs[k - 1].curve.point(1.0)[0], segs[k].curve.point(0.0)[0]
        gap = math.dist(end, start)
        if not gap <= JOIN_M:
            raise ValueError(
                f"{path}: segments[{k}] starts {gap * 1e3:.3g} mm from where segments[{k - 1}] "
                f"ends ({', '.join(f'{x:g}' for x in end)}); the path must be continuous "
                f"(within {JOIN_M * 1e6:g} um)")


def task_from_json(path: str | FsPath) -> Task:
    """Load a task from a JSON file (the format above).

    Raises
    ------
    ValueError
        Naming the file, the segment and the field that is wrong.
    """
    p = FsPath(path)
    text = read_small_text(p, whose=f"task file {path}")
    try:
        data = json.loads(text)
    except (json.JSONDecodeError, RecursionError) as exc:
        raise ValueError(f"{path}: cannot read task: {exc}"[:300]) from None
    if not isinstance(data, dict) or not isinstance(data.get("segments"), list):
        raise ValueError(f"{path}: a task is an object with a 'segments' list")
    if not 0 < len(data["segments"]) <= MAX_SEGMENTS:
        raise ValueError(f"{path}: a task has 1 to {MAX_SEGMENTS} segments, this one "
                         f"{len(data['segments'])}")
    segs = [_segment(s, f"{path}: segments[{k}]") for k, s in enumerate(data["segments"])]
    _joined(segs, path)
    dwell = data.get("dwell", 0.05)
    if not _is_number(dwell) or not 0.0 <= dwell <= 60.0:
        raise ValueError(f"{path}: dwell must be in [0, 60] s, got {dwell!r}"[:300])
    name = data.get("name", p.stem)
    if not isinstance(name, str) or not 0 < len(name) <= MAX_NAME_CHARS:
        raise ValueError(f"{path}: name must be a string of 1 to {MAX_NAME_CHARS} characters, "
                         f"got {name!r}"[:300])
    return Task(name, segs, float(dwell))


def get_task(name: str) -> Task:
    """A built-in task by name (``circle``, ``pick-place``) or a JSON task file."""
    if name in TASKS:
        return TASKS[name]()
    if FsPath(name).exists():
        return task_from_json(name)
    if name.endswith(".json") or "/" in name:
        raise ValueError(f"no such file: {name!r}")
    raise ValueError(f"task must be one of {', '.join(TASKS)} or a JSON file, got {name!r}")


__all__ = ["JOIN_M", "MAX_COORD_M", "MAX_SEGMENTS", "get_task", "task_from_json"]
