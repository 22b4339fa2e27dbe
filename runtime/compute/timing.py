"""A run's per-interval series in bounded memory, and the timing figures of its report.

A run keeps, for every interval, when its command left and how long it took from its
sample (and, in the realtime clock, one tracking error per plant sample). A short run keeps
them all and its figures are exact. A long run (a soak of a million intervals, an hour at
1 ms) must not grow with its length, so each series keeps only its newest ``window``
values exactly and folds older ones, in blocks, into a summary: a log-spaced histogram for
the quantiles (1000 bins per decade: every quantile within 0.12 % of the exact one), exact
running sums for the mean and standard deviation, and the exact maximum.

Nothing here knows about processes or messages: the central appends, the report reads.
"""

from __future__ import annotations

import math
from array import array
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np

WINDOW = 16_384
"""Values of each series kept exactly (older ones are folded into the summary)."""
BLOCK = 1024
"""Values folded at once (a fold costs tens of microseconds, once per ``BLOCK``)."""
WARM_INTERVALS = 100
"""Intervals at the start of a run left out of its timing figures (start-up)."""


def warm_intervals(count: int) -> int:
    """Intervals left out at the start of a run of ``count``: 100, or a tenth of a short
    run."""
    return min(WARM_INTERVALS, count // 10)


class LogHistogram:
    """Counts of positive values (ns) in log-spaced bins from 10 ns to 100 s, 1000 per
    decade, plus an underflow and an overflow bin; the maximum exact.

    A quantile is the geometric middle of the bin that holds it, so it is within a half
    bin (0.12 %) of the exact value for any value in range.
    """

    PER_DECADE = 1000
    LO_LOG10 = 1.0  # 10 ns
    DECADES = 10  # to 1e11 ns

    def __init__(self) -> None:
        self.counts = np.zeros(self.PER_DECADE * self.DECADES + 2, dtype=np.int64)
        self.n = 0
        self.max = -math.inf

    def add(self, values_ns: np.ndarray) -> None:
        """Count ``values_ns`` (any shape, ns)."""
        v = np.asarray(values_ns, dtype=np.float64).ravel()
        if v.size == 0:
            return
        with np.errstate(divide="ignore", invalid="ignore"):
            pos = (np.log10(np.maximum(v, 1e-300)) - self.LO_LOG10) * self.PER_DECADE
        i = np.where(v < 10 ** self.LO_LOG10, 0,
                     np.clip(np.floor(pos).astype(np.int64) + 1, 1, self.counts.size - 1))
        self.counts += np.bincount(i, minlength=self.counts.size)
        self.n += int(v.size)
        self.max = max(self.max, float(v.max()))

    def merged(self, values_ns: np.ndarray) -> LogHistogram:
        """A copy of this histogram with ``values_ns`` counted too."""
        h = LogHistogram()
        h.counts, h.n, h.max = self.counts.copy(), self.n, self.max
        h.add(values_ns)
        return h

    def quantile(self, q: float) -> float:
        """The ``q``-quantile (0..1) in ns, NaN when empty; the exact maximum for q = 1."""
        if self.n == 0:
            return math.nan
        if q >= 1.0:
            return self.max
        rank = q * (self.n - 1)  # the same rank as numpy's linear quantile
        b = int(np.searchsorted(np.cumsum(self.counts), math.floor(rank) + 1))
        if b == 0:
            return 0.0
        if b >= self.counts.size - 1:
            return self.max
        lo = self.LO_LOG10 + (b - 1) / self.PER_DECADE
        return min(10 ** (lo + 0.5 / self.PER_DECADE), self.max)


class Moments:
    """Count, mean and standard deviation of values seen in blocks, exact to float64 (sums
    taken about the first value, so a large offset costs no precision)."""

    def __init__(self) -> None:
        self.n = 0
        self.shift = 0.0
        self.s1 = 0.0
        self.s2 = 0.0

    def add(self, values: np.ndarray) -> None:
        v = np.asarray(values, dtype=np.float64).ravel()
        if v.size == 0:
            return
        if self.n == 0:
            self.shift = float(v[0])
        d = v - self.shift
        self.n += int(v.size)
        self.s1 += float(d.sum())
        self.s2 += float((d * d).sum())

    def merged(self, values: np.ndarray) -> Moments:
        m = Moments()
        m.n, m.shift, m.s1, m.s2 = self.n, self.shift, self.s1, self.s2
        m.add(values)
        return m

    @property
    def mean(self) -> float:
        return self.shift + self.s1 / self.n if self.n else math.nan

    @property
    def std(self) -> float:
        if not self.n:
            return math.nan
        mu = self.s1 / self.n
        return math.sqrt(max(self.s2 / self.n - mu * mu, 0.0))


class BoundedSeries:
    """Values appended one at a time, the newest ``window`` kept exactly and older ones
    handed to ``fold`` in blocks of ``block`` and dropped.

    Indices are absolute (the n-th value appended has index n): ``len`` is the count
    appended, ``s[-1]`` the newest, ``s[a:b]`` the kept values in that range. One thread
    appends; another may read with :meth:`since` (a sequence number guards a fold).
    """

    def __init__(self, typecode: str, *, window: int = WINDOW, block: int = BLOCK,
                 fold: Callable[[array], None] | None = None) -> None:
        if window < 2 or block < 1:
            raise ValueError(f"window must be >= 2 and block >= 1, got {window}, {block}")
        self.recent = array(typecode)
        self.first = 0  # the index of recent[0]
        self.window = window
        self.block = block
        self._fold = fold
        self._seq = 0  # odd while a fold moves the window

    def append(self, x: Any) -> None:
        r = self.recent
        r.append(x)
        if len(r) >= self.window + self.block:
            self._fold_oldest()

    def _fold_oldest(self) -> None:
        r = self.recent
        if self._fold is not None:
            self._fold(r[:self.block])
        self._seq += 1
        del r[:self.block]
        self.first += self.block
        self._seq += 1

    @property
    def folded(self) -> int:
        """How many values have been folded into the summary."""
        return self.first

    def __len__(self) -> int:
        return self.first + len(self.recent)

    def __iter__(self) -> Iterator[Any]:
        """The kept values (all of them until the first fold)."""
        return iter(self.recent)

    def __getitem__(self, key: int | slice) -> Any:
        if isinstance(key, slice):
            if key.step not in (None, 1):
                raise ValueError("a series slices with step 1 only")
            n = len(self)
            a, b, _ = key.indices(n)
            return self.recent[max(a - self.first, 0):max(b - self.first, 0)]
        i = key + len(self) if key < 0 else key
        if not self.first <= i < len(self):
            raise IndexError(f"index {key} is not kept (kept: {self.first}..{len(self) - 1})")
        return self.recent[i - self.first]

    def since(self, start: int) -> tuple[array, int]:
        """The kept values from absolute index ``start`` (those folded meanwhile are
        skipped) and the index after the last; safe from a thread that does not append."""
        for _ in range(100):
            seq = self._seq
            if seq % 2 == 0:
                first = self.first
                vals = self.recent[max(start - first, 0):]
                if self._seq == seq:
                    return vals, max(start, first) + len(vals)
        return self.recent[:0], start


class IntervalTimes:
    """When each interval's command left and its traversal (sample to command), in bounded
    memory, with the run's timing figures (:meth:`figures`).

    Parameters
    ----------
    window, block
        Of each :class:`BoundedSeries` (the tests use small ones).
    """

    def __init__(self, *, window: int = WINDOW, block: int = BLOCK) -> None:
        self.period_hist = LogHistogram()
        self.period_moments = Moments()
        self.traversal_hist = LogHistogram()
        self._last_cmd: int | None = None
        self.cmd_ns = BoundedSeries("q", window=window, block=block, fold=self._fold_cmd)
        # a traversal saturates at 2**31 - 1 ns (2.1 s)
        self.traversal_ns = BoundedSeries("i", window=window, block=block,
                                          fold=self._fold_traversal)

    def append(self, cmd_ns: int, traversal_ns: int) -> None:
        self.cmd_ns.append(cmd_ns)
        self.traversal_ns.append(min(traversal_ns, 2**31 - 1))

    def __len__(self) -> int:
        return len(self.cmd_ns)

    def _fold_cmd(self, block: array) -> None:
        c = np.asarray(block, dtype=np.int64)
        if self._last_cmd is None:  # the run's first block: leave its start-up out
            c = c[WARM_INTERVALS:]
        else:
            c = np.concatenate(([self._last_cmd], c))
        p = np.diff(c)
        self.period_hist.add(p)
        self.period_moments.add(p)
        self._last_cmd = int(block[-1])

    def _fold_traversal(self, block: array) -> None:
        t = np.asarray(block, dtype=np.int64)
        if self.traversal_ns.folded == 0:
            t = t[WARM_INTERVALS:]
        self.traversal_hist.add(t)

    @property
    def sample_ns(self) -> list[int]:
        """Sample times of the kept intervals (command time minus traversal)."""
        return [c - t for c, t in zip(self.cmd_ns.recent, self.traversal_ns.recent)]

    def figures(self) -> dict[str, Any]:
        """The report's timing figures: ``cycles``, ``period_s`` and ``traversal_s``
        {p50, p99, p999, max}, ``period_mean_s``, ``jitter_std_s`` and ``timing`` (how
        they were computed: exactly, or from the histogram for a run longer than the
        window)."""
        c = np.asarray(self.cmd_ns.recent, dtype=np.int64)
        t = np.asarray(self.traversal_ns.recent, dtype=np.int64)
        if not self.cmd_ns.folded:
            return timing_figures(c, c - t)
        p = np.diff(np.concatenate((np.asarray([self._last_cmd], dtype=np.int64), c))) \
            if c.size else c
        ph, pm = self.period_hist.merged(p), self.period_moments.merged(p)
        th = self.traversal_hist.merged(t)

        def q(h: LogHistogram) -> dict[str, float]:
            return {k: h.quantile(x) / 1e9 for k, x in
                    (("p50", 0.5), ("p99", 0.99), ("p999", 0.999), ("max", 1.0))}

        return {"cycles": len(self), "period_s": q(ph), "period_mean_s": pm.mean / 1e9,
                "jitter_std_s": pm.std / 1e9, "traversal_s": q(th),
                "timing": {"exact": False, "exact_last_intervals": int(c.size),
                           "quantile_resolution": 10 ** (0.5 / LogHistogram.PER_DECADE) - 1}}


def quantiles(x: np.ndarray) -> dict[str, float]:
    """p50, p99, p99.9 and max of ``x`` (numpy's linear quantiles; NaN when empty)."""
    if x.size == 0:
        return {"p50": math.nan, "p99": math.nan, "p999": math.nan, "max": math.nan}
    q = np.quantile(x, [0.5, 0.99, 0.999])
    return {"p50": float(q[0]), "p99": float(q[1]), "p999": float(q[2]),
            "max": float(x.max())}


def timing_series(cmd_ns: Any, sample_ns: Any) -> tuple[np.ndarray, np.ndarray, int]:
    """The series the timing figures are taken from: the periods (command to command)
    and traversals (sample to command), in s, of every interval's command and sample
    time (ns) with the first intervals (start-up, :func:`warm_intervals`) left out, and
    the index of the first interval kept. ``period[i]`` ends at interval ``warm + i + 1``,
    ``traversal[i]`` is interval ``warm + i``'s. The report and the plots
    (runtime/recording/plots.py) both draw on it, so their figures agree."""
    cmd = np.asarray(cmd_ns, dtype=np.int64)
    warm = warm_intervals(cmd.size)
    c = cmd[warm:]
    s = np.asarray(sample_ns, dtype=np.int64)[warm:]
    period = np.diff(c) / 1e9 if c.size > 1 else np.array([])
    trav = (c - s) / 1e9 if c.size else np.array([])
    return period, trav, warm


def timing_figures(cmd_ns: Any, sample_ns: Any) -> dict[str, Any]:
    """The timing figures of :meth:`IntervalTimes.figures`, exactly, from every interval's
    command and sample time (ns); the first intervals (start-up) left out
    (:func:`timing_series`)."""
    cmd = np.asarray(cmd_ns, dtype=np.int64)
    period, trav, _ = timing_series(cmd, sample_ns)
    return {"cycles": int(cmd.size), "period_s": quantiles(period),
            "period_mean_s": float(period.mean()) if period.size else math.nan,
            "jitter_std_s": float(np.std(period)) if period.size else math.nan,
            "traversal_s": quantiles(trav),
            "timing": {"exact": True, "exact_last_intervals": int(cmd.size),
                       "quantile_resolution": 0.0}}


class ErrorSeries(BoundedSeries):
    """Tracking errors (m), one per plant sample, in bounded memory: max and RMS over all
    of them (NaN if any was NaN, as for exact arrays)."""

    def __init__(self, *, window: int = WINDOW, block: int = BLOCK) -> None:
        super().__init__("d", window=window, block=block, fold=self._fold_errors)
        self._n = 0
        self._max = -math.inf
        self._sq = 0.0

    def _fold_errors(self, block: array) -> None:
        e = np.asarray(block, dtype=np.float64)
        self._n += e.size
        self._sq += float((e * e).sum())
        if not math.isnan(self._max):  # NaN once, NaN for good
            self._max = math.nan if np.isnan(e).any() else max(self._max, float(e.max()))

    def stats(self) -> dict[str, float]:
        """``max`` and ``rms`` over every error appended (NaN when none)."""
        e = np.asarray(self.recent, dtype=np.float64)
        n = self._n + e.size
        if n == 0:
            return {"max": math.nan, "rms": math.nan}
        m = float(e.max()) if e.size else -math.inf
        mx = math.nan if math.isnan(self._max) or math.isnan(m) else max(self._max, m)
        return {"max": mx, "rms": math.sqrt((self._sq + float((e * e).sum())) / n)}


__all__ = ["BLOCK", "WINDOW", "BoundedSeries", "ErrorSeries", "IntervalTimes",
           "LogHistogram", "Moments", "quantiles", "timing_figures", "timing_series",
           "warm_intervals"]
