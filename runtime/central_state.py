"""The central's records: one interval in flight through the pipeline, and the log of
every finished interval."""

from __future__ import annotations

import hashlib
from array import array
from collections.abc import Generator
from dataclasses import dataclass, field
from typing import Any

from ..topology.plan import Round


@dataclass
class InFlight:
    """One interval between its sample and its command: its steps (a generator that yields
    each round to exchange), values, and where it stands in the pipeline."""

    cycle: int
    gen: Generator[Round, None, Any]
    ctx: dict
    sample_ns: int
    start_ns: int
    round: Round | None = None
    waiting: set[int] = field(default_factory=set)
    deadline_ns: int = 0
    handed_off: bool = False
    started: bool = False
    late_ns: int = 0  # realtime: when this round's data is late (its share of the deadline)
    finishing: bool = False  # every exchange done; its last central steps are pending
    dropped: set[int] = field(default_factory=set)  # peripherals whose replies were held


@dataclass
class CycleLog:
    """Per-cycle measurements, compact so that long runs stay small: two integers per
    interval, one float per plant sample; the commands only as a running digest and peak.
    """

    cmd_ns: array = field(default_factory=lambda: array("q"))
    traversal_ns: array = field(default_factory=lambda: array("i"))  # saturates at 2.1 s
    errors: array = field(default_factory=lambda: array("d"))
    digest: Any = field(default_factory=hashlib.sha256)
    torque_max: float = 0.0
    true_p: dict[int, tuple[float, float, float]] = field(default_factory=dict)  # recent only

    @property
    def sample_ns(self) -> list[int]:
        """Sample times, from command times and traversals."""
        return [c - t for c, t in zip(self.cmd_ns, self.traversal_ns)]


__all__ = ["CycleLog", "InFlight"]
