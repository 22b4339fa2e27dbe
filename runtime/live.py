"""The live line of a run in a terminal (``ctrlunit start`` when stdout is a terminal).

:class:`LiveStats` keeps the run's figures so far at a constant cost per interval (a
histogram of the period in 1 us bins, not a list), so that a run of any length can show
its period p50/p99 since the start a few times a second without slowing the central:
the interval, the period p50 and p99, deadline misses and skipped samples, and the
tracking error the unit observes (``|p - p_c|``, the quantity ``--max-error`` guards),
now and its maximum so far.
"""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np

BIN_NS = 1000
"""Histogram bin of the period (1 us)."""
BIN_S = BIN_NS * 1e-9
TOP_S = 0.1
"""Periods from this up land in the last bin (shown as ">= 100000 us")."""
REFRESH_S = 0.25
"""The line is rebuilt at most this often."""


class LiveStats:
    """Figures of a run so far, updated once per interval.

    Parameters
    ----------
    total : intervals planned (for "interval k/total").
    """

    def __init__(self, total: int) -> None:
        self.total = total
        self.hist = np.zeros(round(TOP_S / BIN_S) + 1, dtype=np.int64)  # 800 KB
        self.count = 0
        self.done = 0
        self.misses = 0
        self.skipped = 0
        self.error = math.nan
        self.error_max = math.nan
        self._last_ns: int | None = None

    def add(self, *, done: int, cmd_ns: int, misses: int = 0, skipped: int = 0,
            p: Any = None, pc: Any = None) -> None:
        """One interval: its command time (ns), the counters so far, and the observed
        position ``p`` and reference ``p_c`` (3-vectors, m) when the interval has them."""
        self.done = done
        if self._last_ns is not None:
            i = (cmd_ns - self._last_ns) // BIN_NS
            self.hist[min(max(i, 0), self.hist.size - 1)] += 1
            self.count += 1
        self._last_ns = cmd_ns
        self.misses, self.skipped = misses, skipped
        if p is not None and pc is not None:
            e = math.dist(p, pc)
            self.error = e
            if not e <= self.error_max:  # the first, or a new maximum (NaN-safe)
                self.error_max = e

    def add_many(self, *, done: int, cmd_ns: Any, misses: int, skipped: int,
                 errors: Any = ()) -> None:
        """Many intervals at once (vectorised): their command times (ns, in order), the
        counters so far and their tracking errors (m)."""
        self.done, self.misses, self.skipped = done, misses, skipped
        c = np.asarray(cmd_ns, dtype=np.int64)
        if c.size:
            if self._last_ns is not None:
                c = np.concatenate(([self._last_ns], c))
            i = np.clip(np.diff(c) // BIN_NS, 0, self.hist.size - 1)
            self.hist += np.bincount(i, minlength=self.hist.size)
            self.count += int(i.size)
            self._last_ns = int(c[-1])
        e = np.asarray(errors, dtype=float)
        if e.size:
            self.error = float(e[-1])
            if not np.all(np.isnan(e)):
                m = float(np.nanmax(e))
                if not m <= self.error_max:  # the first, or a new maximum
                    self.error_max = m

    def percentile_s(self, q: float) -> float:
        """The period's ``q``-th percentile so far (s), to the bin: the lower edge of the
        bin that holds it (NaN before two intervals)."""
        if self.count == 0:
            return math.nan
        rank = max(1, math.ceil(q / 100.0 * self.count))
        i = int(np.searchsorted(np.cumsum(self.hist), rank))
        return i * BIN_S

    def line(self) -> str:
        """``interval k/N  period p50 X us  p99 Y us  misses M  skipped S  error E mm
        (max F)``."""
        def us(x: float) -> str:
            if not math.isfinite(x):
                return "-"
            return f">= {TOP_S * 1e6:.0f}" if x >= TOP_S else f"{x * 1e6:.0f}"

        def mm(x: float) -> str:
            return "-" if not math.isfinite(x) else f"{x * 1e3:.2f}"

        return (f"interval {self.done}/{self.total}  period p50 {us(self.percentile_s(50))} us"
                f"  p99 {us(self.percentile_s(99))} us  misses {self.misses}"
                f"  skipped {self.skipped}  error {mm(self.error)} mm"
                f" (max {mm(self.error_max)})")


class LiveLine:
    """The central's ``on_cycle`` callback that feeds :class:`LiveStats` and calls
    ``show(text, done, total)`` at most every :data:`REFRESH_S` (and at the last
    interval)."""

    def __init__(self, show: Any) -> None:
        self.show = show
        self.stats: LiveStats | None = None
        self._next = 0.0

    def __call__(self, central: Any, cycle: int, ctx: dict) -> None:
        if self.stats is None:
            self.stats = LiveStats(central.cycles)
        self.stats.add(done=central.done, cmd_ns=central.log.cmd_ns[-1],
                       misses=central.plant_misses, skipped=central.skipped,
                       p=ctx.get("p"), pc=ctx.get("pc"))
        now = time.monotonic()
        if now >= self._next or central.done == central.cycles:
            self._next = now + REFRESH_S
            self.show(self.stats.line(), central.done, central.cycles)
