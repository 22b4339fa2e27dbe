"""Placements: which process runs which block, and which axes each peripheral owns.

A placement is data: ``axes[k]`` lists the axes peripheral ``k+1`` owns (every axis exactly
once), and ``central_blocks`` lists per-axis blocks moved to the central (they then run
there for all axes). With no peripheral every block runs on the central: the
single-processor reference (n = 0).

File format (JSON or TOML)::

    peripherals = 2
    axes = [[0, 1], [2]]            # optional; default spreads the axes evenly
    central_blocks = ["accel"]      # optional
"""

from __future__ import annotations

import json
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..kernels.small_file import read_small_text


class PlacementError(ValueError):
    """A placement is invalid; the message names the field and the allowed values."""


@dataclass(frozen=True)
class Placement:
    """Assignment of axes and blocks to processes.

    Attributes
    ----------
    axes : per peripheral, the axes (0, 1, 2) it owns; empty tuple for n = 0.
    central_blocks : names of per-axis blocks that run on the central.
    """

    axes: tuple[tuple[int, ...], ...]
    central_blocks: frozenset[str] = field(default_factory=frozenset)

    def __post_init__(self) -> None:
        flat = [a for group in self.axes for a in group]
        if self.axes and sorted(flat) != [0, 1, 2]:
            raise PlacementError(
                f"placement axes {list(map(list, self.axes))} must cover axes 0, 1, 2 exactly "
                "once"
            )
        if any(len(g) == 0 for g in self.axes):
            raise PlacementError("placement axes: every peripheral must own at least one axis")
        if len(self.axes) > 3:
            raise PlacementError(f"placement peripherals = {len(self.axes)} must be in [0, 3]")

    @property
    def peripherals(self) -> int:
        return len(self.axes)

    @property
    def processors(self) -> int:
        """Processors taking part, the central included (N of Eq. IV.23)."""
        return 1 + self.peripherals

    def to_dict(self) -> dict[str, Any]:
        return {
            "peripherals": self.peripherals,
            "axes": [list(g) for g in self.axes],
            "central_blocks": sorted(self.central_blocks),
        }


def default_placement(peripherals: int) -> Placement:
    """Axes spread over ``peripherals`` processes (n < 3 groups axes), every per-axis
    block on the peripherals."""
    if peripherals not in (0, 1, 2, 3):
        raise PlacementError(f"peripherals = {peripherals!r} must be in [0, 3]")
    groups = {0: (), 1: ((0, 1, 2),), 2: ((0, 1), (2,)), 3: ((0,), (1,), (2,))}
    return Placement(groups[peripherals])


def placement_from_mapping(
    data: dict[str, Any], *, block_names: set[str] | None = None, source: str = "placement"
) -> Placement:
    """Build and validate a placement from a mapping (see the module docstring)."""
    if not isinstance(data, dict):
        raise PlacementError(f"{source}: expected a table/object")
    unknown = set(data) - {"peripherals", "axes", "central_blocks"}
    if unknown:
        raise PlacementError(
            f"{source}: unknown field(s) {', '.join(map(repr, sorted(unknown)))}; allowed: "
            "peripherals, axes, central_blocks"
        )
    n = data.get("peripherals")
    if isinstance(n, bool) or not isinstance(n, int) or not 0 <= n <= 3:
        raise PlacementError(f"{source}: peripherals = {n!r} must be an integer in [0, 3]")
    axes_raw = data.get("axes")
    if axes_raw is None:
        base = default_placement(n)
        axes = base.axes
    else:
        if not isinstance(axes_raw, list) or len(axes_raw) != n or not all(
            isinstance(g, list) and all(isinstance(a, int) and not isinstance(a, bool)
                                        for a in g) for g in axes_raw
        ):
            raise PlacementError(
                f"{source}: axes must be a list of {n} lists of axis indices in [0, 2]"
            )
        axes = tuple(tuple(g) for g in axes_raw)
    cb = data.get("central_blocks", [])
    if not isinstance(cb, list) or not all(isinstance(x, str) for x in cb):
        raise PlacementError(f"{source}: central_blocks must be a list of block names")
    if block_names is not None:
        bad = sorted(set(cb) - block_names)
        if bad:
            raise PlacementError(
                f"{source}: central_blocks {bad} are not per-axis blocks of this graph; "
                f"allowed: {', '.join(sorted(block_names))}"
            )
    try:
        return Placement(axes, frozenset(cb))
    except PlacementError as exc:
        raise PlacementError(f"{source}: {exc}") from None


def load_placement(path: str | Path, *, block_names: set[str] | None = None) -> Placement:
    """Load a placement from a JSON or TOML file, read as kernels/small_file.py reads an
    input file."""
    text = read_small_text(path, whose=f"placement file {path}", error=PlacementError)
    try:
        data = json.loads(text) if Path(path).suffix == ".json" else tomllib.loads(text)
    except (json.JSONDecodeError, tomllib.TOMLDecodeError, RecursionError) as exc:
        raise PlacementError(f"{path}: cannot read placement: {exc}"[:300]) from None
    return placement_from_mapping(data, block_names=block_names, source=str(path))


def save_placement(placement: Placement, path: str | Path) -> None:
    """Write a placement as JSON (readable by :func:`load_placement`)."""
    Path(path).write_text(json.dumps(placement.to_dict(), indent=2) + "\n")
