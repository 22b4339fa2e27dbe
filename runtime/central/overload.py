"""``--overload halve`` (realtime): when too many intervals are late the central halves
its control rate, and goes back to the full rate once the host is calm again
(docs/faults-and-errors.md).

:class:`Overload` counts late intervals and decides; the scheduler carries a decision
out (the controller's grid, the plant's order) through ``change_rate``.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable
from typing import Any

OVERLOAD_WINDOW = 100
"""The intervals over which :meth:`Overload.after_interval` counts late ones."""

OVERLOAD_LATE = 10
"""Late intervals (command after its deadline, or started behind, skipping samples) within
:data:`OVERLOAD_WINDOW` that make a realtime run with ``--overload halve`` halve its
control rate."""

OVERLOAD_SETTLE = 20
"""Real intervals before late ones count towards a halving: the first ones after the
warm-up meet the start of the motion and the peripherals' first real rounds."""

OVERLOAD_LEAD = 3
"""Periods between the newest sample and the first one of a new rate: the plant hears
the order before that tick."""

OVERLOAD_CALM_S = 2.0
"""Time at the halved rate without a late interval after which the run goes back to the
full rate (1000 intervals at 1 ms); doubled after each return."""

OVERLOAD_RETURNS = 3
"""Returns to the full rate per run; after the last one a halving stays."""

OVERLOAD_PROBE_S = 0.5
"""After a return to the full rate, the time during which it is on trial: there
:data:`OVERLOAD_PROBE_LATE` late intervals within :data:`OVERLOAD_WINDOW` halve the rate
again. A return into a host still slow then costs about that many late intervals instead
of the :data:`OVERLOAD_LATE` of a first halving (nothing tells beforehand whether the full
rate will hold again: the return is its own trial)."""

OVERLOAD_PROBE_LATE = 3
"""Late intervals within :data:`OVERLOAD_WINDOW` that end a return on trial
(:data:`OVERLOAD_PROBE_S`)."""


class Overload:
    """The halving rule of one realtime central.

    Parameters
    ----------
    enabled : ``--overload halve`` in a realtime run (not the admission's trial).
    period_s : the sampling period.
    change_rate : ``change_rate(stride, why)`` carries out a change of the control rate
        and returns its record (``stride``, ``from_cycle``, ``at_interval`` and ``why``).
    """

    def __init__(self, *, enabled: bool, period_s: float,
                 change_rate: Callable[[int, dict[str, int]], dict[str, Any]]) -> None:
        self.enabled = enabled
        self.period_s = period_s
        self.change_rate = change_rate
        self.rate_changes: list[dict[str, Any]] = []
        """Each change of the control rate: stride, first cycle, when and why."""
        self.late_marks: deque[int] = deque()
        """The interval count at the start of each run of late intervals (at the full
        rate)."""
        self.run_last = -2
        """The interval count of the newest late mark."""
        self.run_length = 0
        """Intervals in the newest run of late ones (consecutive interval counts)."""
        self.calm_since = 0
        """Halved: the interval count at the halving or the latest late interval."""
        self.calm_needed = 0
        """Halved: intervals without a late one before going back (0: stays halved)."""
        self.trial_until = 0
        """Full rate after a return: the interval count up to which it is on trial."""

    def mark_late(self, done: int, stride: int) -> None:
        """Note a late interval after ``done`` intervals at control-rate divisor
        ``stride``: its command left after its deadline, or it started behind, skipping
        samples (one mark for the skip). Marks at consecutive interval counts are one
        run of late intervals: a run counts once towards :data:`OVERLOAD_LATE`, so that
        one stall of the host, which makes the intervals in flight late together, does
        not halve the rate by itself (docs/measurements/2026-11-29-late-runs.md); a run
        that lasts as long as the count that halves is a unit that stays behind, and
        halves it (:meth:`after_interval`)."""
        if not self.enabled or done < OVERLOAD_SETTLE:
            return
        if stride != 1:
            self.calm_since = done
            return
        if done == self.run_last:  # a skip and the interval it began: one interval
            return
        if done - self.run_last == 1:
            self.run_length += 1
        else:
            self.late_marks.append(done)
            self.run_length = 1
        self.run_last = done

    def after_interval(self, done: int, stride: int) -> None:
        """After each interval. At the full rate, once :data:`OVERLOAD_LATE` of the last
        :data:`OVERLOAD_WINDOW` intervals were late, halve it: take only every second
        sample, and tell the plant, which then publishes those samples only and holds
        each command two periods (a deadline still ``depth`` periods after its sample).
        At the halved rate, after :data:`OVERLOAD_CALM_S` without a late interval (twice
        as long after each return), go back to every sample, at most
        :data:`OVERLOAD_RETURNS` times a run; for :data:`OVERLOAD_PROBE_S` after a
        return, :data:`OVERLOAD_PROBE_LATE` late intervals halve the rate again."""
        if not self.enabled:
            return
        if stride == 1:
            marks = self.late_marks
            if not marks:
                return
            while marks and marks[0] <= done - OVERLOAD_WINDOW:
                marks.popleft()
            on_trial = done <= self.trial_until
            needed = OVERLOAD_PROBE_LATE if on_trial else OVERLOAD_LATE
            in_a_row = self.run_length if done - self.run_last <= 1 else 0
            if len(marks) >= needed or in_a_row >= needed:
                why = ({"in_a_row": in_a_row} if in_a_row >= needed
                       else {"late": len(marks), "window": OVERLOAD_WINDOW})
                if on_trial:  # intervals since the return was decided
                    why["after_return"] = done - self.rate_changes[-1]["at_interval"]
                self.rate_changes.append(self.change_rate(2, why))
                marks.clear()
                self.run_length = 0
                self.calm_since = done
                returns = len(self.rate_changes) // 2  # changes alternate: 2, 1, 2, ...
                self.calm_needed = 0 if returns >= OVERLOAD_RETURNS else math.ceil(
                    OVERLOAD_CALM_S / (2 * self.period_s)) << returns
            return
        if self.calm_needed and done - self.calm_since >= self.calm_needed:
            self.rate_changes.append(self.change_rate(1, {"calm": self.calm_needed}))
            self.trial_until = done + OVERLOAD_LEAD + math.ceil(OVERLOAD_PROBE_S / self.period_s)


__all__ = ["OVERLOAD_CALM_S", "OVERLOAD_LATE", "OVERLOAD_LEAD", "OVERLOAD_PROBE_LATE",
           "OVERLOAD_PROBE_S", "OVERLOAD_RETURNS", "OVERLOAD_SETTLE", "OVERLOAD_WINDOW",
           "Overload"]
