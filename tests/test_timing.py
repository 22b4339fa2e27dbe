"""The run's per-interval series in bounded memory (runtime/compute/timing.py): what a long run
keeps, and that its figures match the exact ones of every interval."""

from __future__ import annotations

import math

import numpy as np
import pytest
from ctrlunit.runtime.compute.timing import (
    BoundedSeries,
    ErrorSeries,
    IntervalTimes,
    LogHistogram,
    timing_figures,
)

RES = 10 ** (0.5 / LogHistogram.PER_DECADE) - 1  # half a bin, relative


def run_times(n: int, *, seed: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Command and sample times (ns) of ``n`` intervals at about 1 ms, with the pairs of a
    depth-2 pipeline, stalls and a slow start."""
    rng = np.random.default_rng(seed)
    gaps = np.where(np.arange(n) % 2, 150_000, 1_850_000) + rng.normal(0, 20_000, n)
    gaps[rng.integers(0, n, n // 500)] += 3_000_000  # stalls
    gaps[:50] += 5_000_000  # start-up
    cmd = 10**12 + np.cumsum(np.maximum(gaps, 1_000)).astype(np.int64)
    trav = (1_400_000 + rng.lognormal(10, 1, n)).astype(np.int64)
    return cmd, cmd - trav


def fill(times: IntervalTimes, cmd: np.ndarray, sample: np.ndarray) -> None:
    for c, s in zip(cmd.tolist(), sample.tolist()):
        times.append(c, c - s)


def test_a_short_run_keeps_every_interval_and_its_figures_are_exact():
    cmd, sample = run_times(5000)
    t = IntervalTimes()
    fill(t, cmd, sample)
    assert t.cmd_ns.folded == 0 and list(t.cmd_ns) == cmd.tolist()
    assert t.figures() == timing_figures(cmd, sample)
    assert t.figures()["timing"]["exact"] is True


def test_a_long_run_keeps_a_bounded_window_and_its_figures_match_the_exact_ones():
    n, window, block = 60_000, 2048, 256
    cmd, sample = run_times(n)
    t = IntervalTimes(window=window, block=block)
    fill(t, cmd, sample)
    assert len(t) == n and t.cmd_ns.folded > 0
    assert window <= len(t.cmd_ns.recent) < window + block
    assert len(t.traversal_ns.recent) == len(t.cmd_ns.recent)
    got, exact = t.figures(), timing_figures(cmd, sample)
    assert got["cycles"] == exact["cycles"] == n
    assert got["timing"] == {"exact": False, "exact_last_intervals": len(t.cmd_ns.recent),
                             "quantile_resolution": pytest.approx(RES)}
    for key in ("period_s", "traversal_s"):
        for q in ("p50", "p99", "p999"):
            assert got[key][q] == pytest.approx(exact[key][q], rel=RES * 1.01), (key, q)
        assert got[key]["max"] == exact[key]["max"], key
    assert got["period_mean_s"] == pytest.approx(exact["period_mean_s"], rel=1e-12)
    assert got["jitter_std_s"] == pytest.approx(exact["jitter_std_s"], rel=1e-9)


def test_a_histogram_quantile_is_within_half_a_bin_over_its_whole_range():
    rng = np.random.default_rng(7)
    x = np.exp(rng.uniform(np.log(20.0), np.log(5e10), 100_000))
    h = LogHistogram()
    h.add(x[:40_000])
    h = h.merged(x[40_000:])
    assert h.n == x.size and h.max == x.max()
    for q in (0.001, 0.25, 0.5, 0.9, 0.99, 0.999):
        assert h.quantile(q) == pytest.approx(np.quantile(x, q), rel=RES * 1.01), q
    assert h.quantile(1.0) == x.max()
    small = LogHistogram()
    small.add(np.array([0, 3, 5]))
    assert small.quantile(0.5) == 0.0  # under 10 ns: the underflow bin
    assert math.isnan(LogHistogram().quantile(0.5))


def test_a_series_indexes_absolutely_and_names_what_it_no_longer_keeps():
    s = BoundedSeries("q", window=8, block=4)
    for k in range(30):
        s.append(k)
    assert len(s) == 30 and s[-1] == 29 and s[-2] == 28 and s[29] == 29
    assert list(s[s.first:30]) == list(range(s.first, 30))
    assert list(s[0:30]) == list(range(s.first, 30))  # what is kept of the range
    with pytest.raises(IndexError, match=r"index 3 is not kept \(kept: \d+\.\.29\)"):
        s[3]
    with pytest.raises(ValueError, match="window must be >= 2"):
        BoundedSeries("q", window=1)


def test_a_reader_gets_every_kept_value_once_in_order_across_folds():
    s = BoundedSeries("q", window=16, block=4)
    seen: list[int] = []
    i = 0
    rng = np.random.default_rng(3)
    for k in range(2000):
        s.append(k)
        if rng.random() < 0.2:
            vals, i = s.since(i)
            seen.extend(vals)
    vals, i = s.since(i)
    seen.extend(vals)
    assert i == len(s)
    assert seen == sorted(set(seen)) and seen[-1] == 1999  # in order, never twice
    assert len(seen) > 1900  # reads every few appends: little is folded unread


def test_errors_fold_into_the_same_max_and_rms_as_every_error():
    rng = np.random.default_rng(5)
    e = rng.exponential(1e-4, 10_000)
    s = ErrorSeries(window=100, block=10)
    for x in e.tolist():
        s.append(x)
    st = s.stats()
    assert st["max"] == e.max()
    assert st["rms"] == pytest.approx(float(np.sqrt((e * e).mean())), rel=1e-12)
    s.append(math.nan)  # a NaN error stays in the figures after it is folded
    for x in e[:500].tolist():
        s.append(x)
    assert s.folded > 10_000 and math.isnan(s.stats()["max"])
    assert ErrorSeries().stats() == {"max": pytest.approx(math.nan, nan_ok=True),
                                     "rms": pytest.approx(math.nan, nan_ok=True)}
