"""Which samples run an interval: the control rate, full or halved, cycle by cycle.

A realtime run that keeps missing its deadlines halves its control rate (``--overload``,
docs/architecture.md, Overload): from a cycle the central names, only every second sample
runs an interval and each command acts for two periods; after a calm spell it may go back
to every sample. The central (through its controller), the plant and replay each keep a
:class:`StrideSchedule` built from the same ``stride`` orders, so that they agree on every
cycle. Knows nothing of Zenoh or of the controller's model.
"""

from __future__ import annotations

STRIDES = (1, 2)
"""The control rates: every sample (1) or every second one (2)."""


class StrideSchedule:
    """The stride from each change on: ``[(start, stride), ...]``, starts increasing.

    Until the first change every sample runs an interval. A change takes effect at a
    sample of the current grid (so that the last interval before it holds its command
    exactly up to the change) after every earlier change.
    """

    __slots__ = ("changes",)

    def __init__(self) -> None:
        self.changes: list[tuple[int, int]] = []

    def check(self, stride: object, start: object) -> str | None:
        """Why ``(stride, start)`` cannot be the next change (a message naming the field
        and the allowed values), or None."""
        if type(stride) is not int or stride not in STRIDES:
            return f"stride must be one of {', '.join(map(str, STRIDES))}, got {stride!r}"
        if type(start) is not int or start < 0:
            return f"start must be a cycle >= 0, got {start!r}"
        if stride == self.stride:
            return f"the stride is {stride} already"
        if self.changes and start <= self.changes[-1][0]:
            return f"start must come after the last change at {self.changes[-1][0]}, got {start}"
        if not self.on_grid(start):
            return f"start must be a sample of the current grid, got {start}"
        return None

    def change(self, stride: int, start: int) -> None:
        """From sample ``start`` on, every ``stride``-th sample runs an interval.

        Raises
        ------
        ValueError
            If it cannot be the next change (:meth:`check`).
        """
        why = self.check(stride, start)
        if why is not None:
            raise ValueError(why)
        self.changes.append((start, stride))

    @property
    def stride(self) -> int:
        """The stride of the latest change (1 before any)."""
        return self.changes[-1][1] if self.changes else 1

    def _segment(self, cycle: int) -> tuple[int, int]:
        for start, stride in reversed(self.changes):
            if cycle >= start:
                return start, stride
        return 0, 1

    def on_grid(self, cycle: int) -> bool:
        """Whether sample ``cycle`` runs an interval (its command is due)."""
        if not self.changes:
            return True
        start, stride = self._segment(cycle)
        return (cycle - start) % stride == 0

    def hold_of(self, cycle: int) -> int:
        """The periods the command of the interval at sample ``cycle`` acts for."""
        return self._segment(cycle)[1] if self.changes else 1

    def halved_spans(self, end: int) -> list[tuple[int, int]]:
        """``[(start, stop), ...]``: the cycles run at the halved rate, the last span open
        to ``end``."""
        spans = []
        for i, (start, stride) in enumerate(self.changes):
            if stride == 2:
                stop = self.changes[i + 1][0] if i + 1 < len(self.changes) else end
                spans.append((start, max(start, stop)))
        return spans

    def next_on_grid(self, cycle: int) -> int:
        """The first sample at or after ``cycle`` on the current grid."""
        while not self.on_grid(cycle):
            cycle += 1
        return cycle
