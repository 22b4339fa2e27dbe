"""The central's intake: every sample and reply it receives, checked field by field
before use (docs/faults-and-errors.md). A message that fails a check is counted under its
reason (:attr:`~ctrlunit.runtime.transport.node.Node.rejected`) and dropped; nothing malformed
reaches the scheduler.

:class:`Intake` also keeps the samples taken and not yet started from (bounded: in
realtime the scheduler starts from the newest and skips the rest).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any, NamedTuple

from ...kernels.kinematics import ik_axis
from ...kernels.params import DeltaParams
from ..transport.codec import BadMessage, check_span, check_vals, check_vector, parts_of
from ..transport.node import Node
from .warmup import WARMUP_BASE

SAMPLES_KEPT = 64
"""Samples kept waiting for their interval; beyond it the oldest is dropped."""


class Sample(NamedTuple):
    """A checked sample of the plant."""

    cycle: int
    counts: list[int]
    t_ns: int
    p: tuple[float, float, float]
    """The plant's true position (for the tracking error)."""
    span: list[int]
    misses: int | None
    """The plant's count of commands that missed their deadline, when it sent one."""


def check_sample(msg: dict[str, Any]) -> Sample:
    """The fields of a decoded sample, checked (counts: three integers under 10^9 in
    magnitude; ``t_ns`` an integer; ``p`` three finite numbers; ``span`` two ordered
    times). Raises :class:`~ctrlunit.runtime.transport.codec.BadMessage` naming the field."""
    counts = msg.get("counts")
    if not isinstance(counts, list) or len(counts) != 3 or not all(
        isinstance(c, int) and not isinstance(c, bool) and abs(c) < 10**9
        for c in counts
    ):
        raise BadMessage("bad_value", "counts")
    t_ns = msg.get("t_ns")
    if isinstance(t_ns, bool) or not isinstance(t_ns, int):
        raise BadMessage("bad_value", "t_ns")
    p = check_vector(msg.get("p"), 3, "p")
    span = check_span(msg.get("span"))
    misses = msg.get("misses")
    return Sample(msg["cycle"], counts, t_ns, (p[0], p[1], p[2]), span,
                  misses if isinstance(misses, int) and not isinstance(misses, bool)
                  else None)


def synthetic_counts(params: DeltaParams, p: Sequence[float]) -> list[int]:
    """The joint counts a sample at position ``p`` would carry: each axis's inverse
    kinematics (Eq. V.16-V.21), quantised to the encoder's increment (freerun,
    where there is no plant, and the admission's trial, where the robot rests)."""
    x, y, z = float(p[0]), float(p[1]), float(p[2])
    return [round(ik_axis(params, i, x, y, z).q / params.increment) for i in range(3)]


class Intake:
    """Checked samples and replies of one central (``trial``: the admission's trial,
    which takes only the plant's trial samples, flagged ``probe``)."""

    def __init__(self, node: Node, *, trial: bool = False) -> None:
        self.node = node
        self.trial = trial
        self.samples: dict[int, tuple[list[int], int]] = {}
        """Samples taken, by cycle: (counts, t_ns)."""
        self.newest_sample = -1

    def sample(self, data: bytes, *, first: int, end: int,
               on_grid: Callable[[int], bool]) -> Sample | None:
        """Check a sample and keep it if its cycle is from ``first`` (the next interval)
        to before ``end`` and on the control rate's grid; None if it is not taken."""
        msg = self.node.decode(data)
        if msg is None:
            return None
        if msg["stage"] != "sample":
            self.node.reject("bad_stage")
            return None
        if (msg.get("probe") is True) != self.trial:
            return None  # the admission trial's samples are its own (a stray one is no fault)
        try:
            s = check_sample(msg)
        except BadMessage as exc:
            self.node.reject(exc.reason, str(exc))
            return None
        if not on_grid(s.cycle):
            return None  # the rate is halved and the plant has yet to hear it: not taken
        if s.cycle < first or s.cycle >= end:
            self.node.reject("stale_cycle" if s.cycle < first else "future_cycle")
            return None
        self.newest_sample = max(self.newest_sample, s.cycle)
        self.samples[s.cycle] = (s.counts, s.t_ns)
        if len(self.samples) > SAMPLES_KEPT:  # realtime and far behind: keep the newest
            del self.samples[min(self.samples)]
        return s

    def newest_waiting(self) -> int | None:
        """The newest sample taken and not yet started from, if any."""
        return max(self.samples) if self.samples else None

    def keep_only(self, cycle: int) -> None:
        """Drop every sample waiting but ``cycle``'s (the scheduler skips them)."""
        self.samples = {cycle: self.samples[cycle]}

    def take(self, cycle: int) -> tuple[list[int], int] | None:
        """The sample of ``cycle`` (counts, time), no longer waiting; None if it has not
        come."""
        return self.samples.pop(cycle, None)

    def reply(self, data: bytes) -> tuple[dict[str, Any], list[dict[str, Any]]] | None:
        """A reply's message and its parts (one per round answered), or None."""
        msg = self.node.decode(data)
        if msg is None:
            return None
        try:
            return msg, parts_of(msg)
        except BadMessage as exc:
            self.node.reject(exc.reason, str(exc))
            return None

    def reply_part(self, part: dict[str, Any], recv: Any, axes: int
                   ) -> tuple[dict[str, Any], list[int]] | None:
        """A part's values (the names ``recv`` for ``axes`` axes) and compute span,
        checked; None if a field fails its check."""
        try:
            vals = check_vals(part.get("vals"), recv, axes)
            if "trace" in part and not isinstance(part["trace"], dict):
                raise BadMessage("bad_value", "trace")
            return vals, check_span(part.get("span"))
        except BadMessage as exc:
            self.node.reject(exc.reason, str(exc))
            return None

    def reject(self, reason: str) -> None:
        """Count a message dropped for ``reason``."""
        self.node.reject(reason)

    def unexpected_reply(self, cycle: int) -> None:
        """Count a reply part for ``cycle`` that no interval waits for: a straggler of the
        warm-up's or the admission trials' throw-away intervals (numbered from
        ``WARMUP_BASE`` up: runtime/central/warmup.py, runtime/launch/admission.py), or an
        unexpected one. Neither is malformed: the flood watch (:class:`~.flood.FloodWatch`)
        counts neither against its sender."""
        self.node.reject("straggler" if cycle >= WARMUP_BASE else "unexpected_reply")


__all__ = ["SAMPLES_KEPT", "Intake", "Sample", "check_sample"]
