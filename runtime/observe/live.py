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
import shutil
import threading
import time
from typing import TYPE_CHECKING, Any, TextIO

import numpy as np

BIN_NS = 1000
"""Histogram bin of the period (1 us)."""
BIN_S = BIN_NS * 1e-9
TOP_S = 0.1
"""Periods from this up land in the last bin (shown as ">= 100000 us")."""
REFRESH_S = 0.25
"""The line is rebuilt at most this often."""
COARSE = 1000
"""Fine bins per coarse bin: a percentile reads the coarse counts (101) and then one
coarse bin's fine counts, not all 100 001 of them (reading them all took 1.3 ms per line
in the central's thread)."""

if TYPE_CHECKING:
    from ..central.snapshot import Progress


class LiveStats:
    """Figures of a run so far, updated once per interval.

    Parameters
    ----------
    total : intervals planned (for "interval k/total").
    """

    def __init__(self, total: int) -> None:
        self.total = total
        self.hist = np.zeros(round(TOP_S / BIN_S) + 1, dtype=np.int64)  # 800 KB
        self.coarse = np.zeros(self.hist.size // COARSE + 1, dtype=np.int64)
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
            i = min(max((cmd_ns - self._last_ns) // BIN_NS, 0), self.hist.size - 1)
            self.hist[i] += 1
            self.coarse[i // COARSE] += 1
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
            self.coarse += np.bincount(i // COARSE, minlength=self.coarse.size)
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
        cum = np.cumsum(self.coarse)
        j = int(np.searchsorted(cum, rank))
        before = int(cum[j - 1]) if j else 0
        fine = np.cumsum(self.hist[j * COARSE:(j + 1) * COARSE])
        return (j * COARSE + int(np.searchsorted(fine, rank - before))) * BIN_S

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
    ``show(text, reached, total)`` (periods covered of those planned) at most every
    :data:`REFRESH_S` (and at the last interval)."""

    def __init__(self, show: Any) -> None:
        self.show = show
        self.stats: LiveStats | None = None
        self._next = 0.0

    def __call__(self, progress: Progress, ctx: dict) -> None:
        p = progress
        if self.stats is None:
            self.stats = LiveStats(p.planned)
        self.stats.add(done=p.done, cmd_ns=p.cmd_ns, misses=p.misses, skipped=p.skipped,
                       p=ctx.get("p"), pc=ctx.get("pc"))
        now = time.monotonic()
        # the bar counts periods covered: intervals fall behind them where samples were
        # skipped or the control rate was halved (``--overload``)
        if now >= self._next or p.reached >= p.planned:
            self._next = now + REFRESH_S
            lost = p.lost  # peripherals taken over (degraded), first:
            self.show(("taken over " + ",".join(f"P{k + 1}" for k in lost) + "  " if lost
                       else "") + self.stats.line(), p.reached, p.planned)  # a cut keeps it


class TerminalLine:
    """The live line drawn on a terminal: a bar, the figures so far and the time left.

    It shares a process with the central, so it must cost the central next to nothing.
    :meth:`show` (the central's thread, a few times a second) only formats a string and
    hands it over; a thread of its own writes it, so a terminal that blocks never holds
    the central, and the write gives the GIL back while it waits. A progress-bar library
    that lays its columns out in Python on each refresh (rich: 1.1 ms here, holding the
    GIL) made the main job at 2 ms miss 70 deadlines in six runs against 19 without a
    line (docs/measurements/2026-11-23-realtime.md).

    Parameters
    ----------
    stream : the terminal (text stream).
    width : columns; ``None``: the terminal's, read at each write.
    """

    BAR = 24
    """Width of the bar in characters."""

    def __init__(self, stream: TextIO, *, width: int | None = None) -> None:
        self._stream = stream
        self._width = width
        self._cond = threading.Condition()  # the newest line: never held while writing
        self._write = threading.Lock()  # the stream
        self._pending: tuple[float, str] | None = None  # (done's share, the text)
        self._drawn = False
        self._closed = False
        self._t0: float | None = None
        self._thread = threading.Thread(target=self._run, name="ctrlunit-line", daemon=True)
        self._thread.start()

    def show(self, text: str, done: int, total: int) -> None:
        """Show ``text`` after a bar at ``done`` of ``total`` (the :class:`LiveLine`
        callback); the newest line replaces one not yet written."""
        now = time.monotonic()
        if self._t0 is None:
            self._t0 = now
        frac = min(max(done / total, 0.0), 1.0) if total > 0 else 0.0
        left = ""
        if 0 < done < total:
            left = f"  {(now - self._t0) * (total - done) / done:.0f} s left"
        with self._cond:
            self._pending = (frac, text + left)
            self._cond.notify()

    @classmethod
    def fit(cls, frac: float, text: str, cols: int) -> str:
        """The line in ``cols - 1`` columns: the bar narrows, then goes, before the text
        (the misses and the error come after the period) is cut."""
        room = max(cols - 1, 1)
        head = f"] {frac:4.0%}  "
        bar = min(cls.BAR, room - len("ctrlunit [") - len(head) - len(text))
        if bar >= 6:
            full = round(frac * bar)
            return f"ctrlunit [{'#' * full}{'-' * (bar - full)}{head}{text}"
        return f"ctrlunit {frac:4.0%}  {text}"[:room]

    def above(self, message: str, stream: TextIO) -> None:
        """Write ``message`` (and a newline) on ``stream`` with the line cleared first; the
        next :meth:`show` draws it again."""
        locked = self._write.acquire(timeout=1.0)  # a write stuck on the terminal: skip
        try:
            if locked:
                self._clear()
            stream.write(message + "\n")
            stream.flush()
        finally:
            if locked:
                self._write.release()

    def close(self) -> None:
        """Write what is pending, clear the line and stop the thread."""
        with self._cond:
            self._closed = True
            self._cond.notify()
        self._thread.join(timeout=1.0)
        if self._write.acquire(timeout=1.0):  # not if a write is stuck on the terminal
            try:
                self._clear()
            finally:
                self._write.release()

    def __enter__(self) -> TerminalLine:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _clear(self) -> None:
        """Erase the drawn line (the caller holds the stream's lock)."""
        if self._drawn:
            self._stream.write("\r\x1b[2K")
            self._stream.flush()
            self._drawn = False

    def _run(self) -> None:
        while True:
            with self._cond:
                while self._pending is None and not self._closed:
                    self._cond.wait(0.5)
                pending, self._pending, closed = self._pending, None, self._closed
            if pending is not None:
                cols = self._width or shutil.get_terminal_size((100, 24)).columns
                with self._write:
                    self._stream.write("\r\x1b[2K" + self.fit(*pending, cols))
                    self._stream.flush()
                    self._drawn = True
            if closed:
                return
