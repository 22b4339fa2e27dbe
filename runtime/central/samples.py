"""Where each interval's sample comes from: the run's clock, chosen once
(docs/architecture.md, clocks).

- ``lockstep``: interval k starts from the plant's sample k, waited for.
- ``realtime``: from the newest sample taken; the ones it passes over are skipped (the
  central fell behind the plant's clock), told to ``on_skip`` and dropped, never queued.
- ``freerun``: there is no plant; each interval starts at once from a synthetic sample
  (the reference's inverse kinematics, quantised).

In the admission's trial the robot rests while the trial follows the reference: the
counts of each sample the plant sends are replaced by the synthetic ones (its time is
kept).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Protocol

from .intake import Intake

Taken = tuple[int, list[int], int]
"""An interval's sample: its cycle, joint counts and time (``time.monotonic_ns``)."""


class SampleSource(Protocol):
    """The samples intervals start from."""

    def take(self, cycle: int) -> Taken | None:
        """The sample interval ``cycle`` starts from, no longer waiting, or None while it
        has not come. Its cycle is ``cycle``'s, or later where samples were skipped."""

    def awaited(self, cycle: int) -> int | None:
        """``cycle`` while the interval waits for the plant's sample (none has come that
        it could start from), else None; never for a synthetic sample."""


class Synthetic:
    """Freerun: a synthetic sample at once; ``note(cycle, counts, t_ns)`` is told of each
    (the recording)."""

    def __init__(self, counts: Callable[[int], list[int]],
                 note: Callable[[int, list[int], int], None] | None = None) -> None:
        self.counts, self.note = counts, note

    def take(self, cycle: int) -> Taken:
        counts, t_ns = self.counts(cycle), time.monotonic_ns()
        if self.note is not None:
            self.note(cycle, counts, t_ns)
        return cycle, counts, t_ns

    def awaited(self, cycle: int) -> int | None:
        return None


class FromPlant:
    """Lockstep: the plant's sample of the cycle asked for. ``resting`` (the admission's
    trial) gives the counts to use instead of the plant's."""

    def __init__(self, intake: Intake, *,
                 resting: Callable[[int], list[int]] | None = None) -> None:
        self.intake, self.resting = intake, resting

    def take(self, cycle: int) -> Taken | None:
        taken = self.intake.take(cycle)
        if taken is None:
            return None
        counts, t_ns = taken
        if self.resting is not None:
            counts = self.resting(cycle)
        return cycle, counts, t_ns

    def awaited(self, cycle: int) -> int | None:
        return None if self.intake.samples else cycle


class Newest:
    """Realtime: the newest sample waiting when it is past the cycle asked for (those
    between are told to ``on_skip(cycle, newest)`` and dropped), else as
    :class:`FromPlant`."""

    def __init__(self, plant: FromPlant, on_skip: Callable[[int, int], None]) -> None:
        self.plant, self.on_skip = plant, on_skip

    def take(self, cycle: int) -> Taken | None:
        intake = self.plant.intake
        newest = intake.newest_waiting()
        if newest is not None and newest > cycle:
            self.on_skip(cycle, newest)
            intake.keep_only(newest)
            cycle = newest
        return self.plant.take(cycle)

    def awaited(self, cycle: int) -> int | None:
        return self.plant.awaited(cycle)


def sample_source(clock: str, intake: Intake, *, synthetic: Callable[[int], list[int]],
                  trial: bool, on_skip: Callable[[int, int], None],
                  note: Callable[[int, list[int], int], None] | None = None) -> SampleSource:
    """The source of ``clock`` (module notes); ``synthetic(cycle)`` gives a synthetic
    sample's counts (freerun, and the trial's resting robot)."""
    match clock:
        case "freerun":
            return Synthetic(synthetic, note)
        case "realtime":
            return Newest(FromPlant(intake, resting=synthetic if trial else None), on_skip)
        case _:
            return FromPlant(intake, resting=synthetic if trial else None)


__all__ = ["FromPlant", "Newest", "SampleSource", "Synthetic", "Taken", "sample_source"]
