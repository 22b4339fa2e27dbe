"""Pictures of a run (``ctrlunit plot``, ``ctrlunit start --plot``).

From a recording alone (whole, compressed or salvaged after a crash), six PNGs and an
``index.html`` that shows them with the run's summary:

``path.png``
    The platform's path against the reference, x-z and x-y views (the plant's true
    position from the samples; freerun has no plant, and says so).
``tracking_error.png``
    ``|p - p_c|`` against time, with ``--max-error`` (the fault threshold) drawn.
``torques.png``
    The three commanded torques against time, with the joint limit ``tau_max``.
``timing.png``
    Histograms of the period (command to command) and of the traversal (sample to
    command), with the nominal period and the deadline (the command of sample k is due
    at tick k + d, d the command delay in periods) marked. The series and their p50 and
    p99 are the report's (:func:`.plot_data.timing`: the same intervals, the start-up left
    out, the same quantiles), so the titles say what the summary says.
``events.png``
    The period over the run, with each deadline miss, skipped sample and the fault (if
    any) where it fell, the spans at the halved control rate (``--overload``), and each
    change of who computes what (a live re-placement, a peripheral taken over or back).
``gantt.png``
    The processes' compute spans over a few intervals of the middle of the run.

Every figure but the timing one is drawn from the arrays in :class:`Plots.series`, which
the caller (and the tests) can read: ``tracking_error_m`` is the recorded
``/signals/state`` error, an account independent of the report's (rebuilt from the
samples); the timing figure's are in :attr:`Plots.timing`. No title overlaps another or
passes its figure's edge (:func:`title_clashes`, checked as each figure is saved).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import matplotlib
import numpy as np

matplotlib.use("Agg")
import matplotlib.pyplot as plt

from ..config import RunConfig
from ..observe.summary_end import how_it_ended
from .gantt import COLORS, DPI, gantt_figure
from .plot_data import changes, events, gantt_spans, halved_spans, sample_tracking, signals, timing
from .plot_index import write_index
from .reader import Recording

FIGURES = ("path", "tracking_error", "torques", "timing", "events", "gantt")
"""The PNGs :func:`plot_recording` writes, in the order index.html shows them."""



@dataclass
class Plots:
    """What :func:`plot_recording` wrote and the arrays it drew.

    Attributes
    ----------
    images : figure name (one of :data:`FIGURES`) -> PNG path.
    index : the index.html path.
    series : the drawn arrays: ``cycle`` (n,), ``t_s`` (n,), ``p_m`` and ``reference_m``
        (n, 3; NaN where absent), ``tracking_error_m`` (n,), ``torque_nm`` (n, 3),
        ``period_s`` (n,), ``traversal_s`` (n,).
    notes : what a figure could not show (e.g. no plant in freerun).
    timing : the timing figure's series and figures (:func:`.plot_data.timing`), the
        report's own.
    titles : figure name -> the titles of its panels, as drawn (the timing figure's and
        the events figure's).
    clashes : titles that overlapped another or passed a figure's edge (none expected).
    marks : the events figure's changes of placement, ``(time s, what)``, as drawn.
    """

    images: dict[str, Path] = field(default_factory=dict)
    index: Path | None = None
    series: dict[str, np.ndarray] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    timing: dict[str, Any] = field(default_factory=dict)
    titles: dict[str, list[str]] = field(default_factory=dict)
    clashes: list[str] = field(default_factory=list)
    marks: list[tuple[float, str]] = field(default_factory=list)


def _empty(ax: Any, text: str) -> None:
    ax.text(0.5, 0.5, text, ha="center", va="center", transform=ax.transAxes, wrap=True)
    ax.set_xticks([])
    ax.set_yticks([])


def _path(path: Path, s: dict[str, np.ndarray], plots: Plots) -> None:
    notes = plots.notes
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.6), constrained_layout=True)
    p, ref = s["p_m"] * 1e3, s["reference_m"] * 1e3
    have_p, have_ref = np.isfinite(p).all(axis=1), np.isfinite(ref).all(axis=1)
    if not have_p.any() and not have_ref.any():
        notes.append("path: no platform position in this recording (freerun has no plant)")
    for ax, (i, j, name) in zip(axes, ((0, 2, "x-z"), (0, 1, "x-y"))):
        if not have_p.any() and not have_ref.any():
            _empty(ax, "no platform position: a freerun run has no plant")
            continue
        ax.plot(ref[have_ref, i], ref[have_ref, j], "--", color="#555555", lw=1.2,
                label="reference p_c")
        ax.plot(p[have_p, i], p[have_p, j], color="#1f77b4", lw=1.0, label="platform p")
        ax.set_xlabel(f"{'xyz'[i]} (mm)")
        ax.set_ylabel(f"{'xyz'[j]} (mm)")
        ax.set_title(f"path, {name} view")
        ax.set_aspect("equal", adjustable="datalim")
        ax.legend(fontsize=8)
    _save(fig, path, plots)


def _tracking(path: Path, s: dict[str, np.ndarray], max_error: float,
              plots: Plots) -> None:
    notes = plots.notes
    fig, ax = plt.subplots(figsize=(11, 3.8), constrained_layout=True)
    by_sample = s.get("sample_error_m") is not None and s["sample_error_m"].size > 0
    e, t, cyc = ((s["sample_error_m"], s["sample_t_s"], s["sample_cycle"]) if by_sample
                 else (s["tracking_error_m"], s["t_s"], s["cycle"]))
    ok = np.isfinite(e)
    if not ok.any():
        notes.append("tracking error: none recorded (freerun has no plant)")
        _empty(ax, "no tracking error: a freerun run has no plant")
    else:
        ax.plot(t[ok], e[ok] * 1e3, color="#1f77b4", lw=1.0, label="|p - p_c|")
        k = int(np.nanargmax(e))
        ax.plot(t[k], e[k] * 1e3, "o", color="#d62728", ms=4,
                label=f"max {e[k] * 1e3:.3f} mm at cycle {int(cyc[k])}")
        if max_error <= 4 * e[k]:  # the fault threshold in view
            ax.axhline(max_error * 1e3, color="#d62728", ls="--", lw=1.0,
                       label=f"--max-error {max_error * 1e3:g} mm (fault)")
            top = max(max_error, float(e[k]))
        else:  # far above: scale to the error and say where the threshold is
            ax.plot([], [], color="#d62728", ls="--",
                    label=f"--max-error {max_error * 1e3:g} mm (fault), above the plot")
            top = float(e[k])
        ax.set_xlabel("reference time (s)")
        ax.set_ylabel("tracking error (mm)")
        ax.set_ylim(0, top * 1e3 * 1.12 or 1e-6)  # all zero (the first cycles): a scale
        ax.legend(fontsize=8, loc="upper right")
    ax.set_title("tracking error")
    _save(fig, path, plots)


def _torques(path: Path, s: dict[str, np.ndarray], tau_max: float, kind: str,
             plots: Plots) -> None:
    fig, ax = plt.subplots(figsize=(11, 3.8), constrained_layout=True)
    tau = s["torque_nm"]
    for i in range(3):
        ax.plot(s["t_s"], tau[:, i], lw=1.0, label=f"axis {i + 1}")
    if kind == "torque":
        for sign in (1, -1):
            ax.axhline(sign * tau_max, color="#d62728", ls="--", lw=1.0,
                       label="tau_max" if sign == 1 else None)
        ax.set_ylabel("torque (N m)")
        ax.set_title(f"commanded torques (limit +/- {tau_max:g} N m)")
    else:
        ax.set_ylabel("joint acceleration (rad/s^2)")
        ax.set_title("commands of the kinematics law (joint accelerations, not torques)")
    ax.set_xlabel("reference time (s)")
    ax.legend(fontsize=8, loc="upper right")
    _save(fig, path, plots)


CLOCK_NOTES = {
    "lockstep": "wall time: lockstep runs in virtual time (no deadline), this is the "
                "processes' pace",
    "freerun": "wall time: freerun has no plant and no deadline, the unit runs as fast "
               "as it can",
}
"""What the timing figure's times are, by clock (realtime: its period and deadline)."""


def timing_titles(figures: dict[str, Any], clock: str = "realtime") -> dict[str, str]:
    """The timing figure's panel titles: what each histogram is, and the figures the
    summary prints of it (runtime/observe/summary.py, to 0.1 us): p50 and p99; in
    lockstep, which keeps no deadline, the wall time's spread only and the traversal's
    p50, as its summary gives them."""
    def line(q: dict[str, float]) -> str:
        return f"p50 {q['p50'] * 1e6:.1f} us   p99 {q['p99'] * 1e6:.1f} us"

    if clock == "lockstep":
        return {"period_s": "wall time per interval (command to command)\nno deadline: "
                            "how fast the processes ran",
                "traversal_s": "sample to command (wall time)\n"
                               f"p50 {figures['traversal_s']['p50'] * 1e6:.1f} us"}
    return {"period_s": f"period (command to command)\n{line(figures['period_s'])}",
            "traversal_s": f"traversal (sample to command)\n{line(figures['traversal_s'])}"}


def _timing(path: Path, t: dict[str, Any], rc: RunConfig, plots: Plots) -> None:
    """Histograms of the period and the traversal: the series and quantiles the report
    takes (:func:`.plot_data.timing`: the same start-up left out)."""
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2), constrained_layout=True)
    nominal_us = rc.schedule.period * 1e6
    due = max(rc.delay_periods, 1)
    titles = timing_titles(t["figures"], rc.schedule.clock)
    plots.titles["timing"] = list(titles.values())
    for ax, key in zip(axes, ("period_s", "traversal_s"), strict=True):
        v = t[key] * 1e6
        if v.size == 0:
            _empty(ax, f"no {key[:-2]} recorded")
            continue
        ax.hist(v, bins=min(80, max(10, v.size // 20)), color="#1f77b4", alpha=0.85)
        if rc.schedule.clock == "realtime":
            ax.axvline(nominal_us, color="#2ca02c", ls="--", lw=1.0,
                       label=f"period {nominal_us:g} us")
        if key == "traversal_s" and rc.schedule.clock == "realtime":
            ax.axvline(due * nominal_us, color="#d62728", ls="--", lw=1.0,
                       label=f"deadline {due * nominal_us:g} us (tick k + {due})")
        ax.set_title(titles[key], fontsize=10)
        ax.set_xlabel("us")
        ax.set_ylabel("intervals")
        ax.set_yscale("log")
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=8)
    fig.suptitle(CLOCK_NOTES.get(rc.schedule.clock, f"realtime, period {nominal_us:g} us: "
                                 f"the command of sample k is due at tick k + {due}"),
                 fontsize=10)
    _save(fig, path, plots)


def title_clashes(fig: Any) -> list[str]:
    """Titles of ``fig`` (each axes' and the figure's) that overlap another or pass the
    figure's edge, drawn as they are saved; empty when every title stands clear."""
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    texts = [t for ax in fig.axes for t in (ax.title, ax._left_title, ax._right_title)
             if t.get_text()]
    if fig._suptitle is not None and fig._suptitle.get_text():
        texts.append(fig._suptitle)
    boxes = [(t.get_text(), t.get_window_extent(renderer)) for t in texts]
    frame = fig.bbox
    out = [f"{name!r} passes the figure's edge" for name, b in boxes
           if b.x0 < frame.x0 - 0.5 or b.x1 > frame.x1 + 0.5 or b.y1 > frame.y1 + 0.5
           or b.y0 < frame.y0 - 0.5]
    for i, (a, ba) in enumerate(boxes):
        out += [f"{a!r} overlaps {b!r}" for b, bb in boxes[i + 1:] if ba.overlaps(bb)]
    return out


def _save(fig: Any, path: Path, plots: Plots) -> None:
    """Save ``fig`` to ``path`` and close it; titles that clash go to ``plots.clashes``."""
    fig.savefig(path, dpi=DPI)
    plots.clashes += [f"{path.name}: {c}" for c in title_clashes(fig)]
    plt.close(fig)


def _events_figure(path: Path, s: dict[str, np.ndarray], ev: list[tuple[int, int, int]],
                   fault: dict[str, Any] | None, rc: RunConfig, plots: Plots,
                   moved: list[tuple[int, str]]) -> None:
    fig, ax = plt.subplots(figsize=(11, 3.8), constrained_layout=True)
    t = s["cycle"] * rc.schedule.period
    for a, b in s.get("halved_spans_s", np.empty((0, 2))):
        ax.axvspan(a, b, color="#1f77b4", alpha=0.12, lw=0)
    if len(s.get("halved_spans_s", ())):
        ax.fill_between([], [], color="#1f77b4", alpha=0.12, label="control rate halved")
    ax.plot(t, s["period_s"] * 1e6, lw=0.6, color="#7f7f7f", label="period")
    if rc.schedule.clock == "realtime":
        ax.axhline(rc.schedule.period * 1e6, color="#2ca02c", ls="--", lw=0.8, label="nominal")
    prev_m = prev_s = 0
    miss_t, skip_t = [], []
    for k, m, sk in ev:
        if m > prev_m:
            miss_t.append(k * rc.schedule.period)
        if sk > prev_s:
            skip_t.append(k * rc.schedule.period)
        prev_m, prev_s = max(prev_m, m), max(prev_s, sk)
    for x in miss_t:
        ax.axvline(x, color="#d62728", lw=0.8, alpha=0.7)
    for x in skip_t:
        ax.axvline(x, color="#ff7f0e", lw=0.8, alpha=0.7, ls=":")
    at: dict[int, list[str]] = {}  # changes at one interval: one line, one label
    for k, what in moved:
        at.setdefault(k, []).append(what)
    for k, whats in at.items():
        what = "; ".join(whats)
        x = k * rc.schedule.period
        ax.axvline(x, color="#9467bd", lw=1.0, ls="--")
        ax.annotate(what, (x, 0.03), xycoords=("data", "axes fraction"), rotation=90,
                    ha="right", va="bottom", fontsize=7, color="#9467bd",
                    bbox={"facecolor": "white", "edgecolor": "none", "alpha": 0.7, "pad": 1})
        plots.marks.append((x, what))
    if moved:
        ax.plot([], [], color="#9467bd", ls="--", label="placement changed")
    realtime = rc.schedule.clock == "realtime"
    title = (f"deadline misses {prev_m}, skipped samples {prev_s}" if realtime else
             f"{rc.schedule.clock}: wall time per interval (no deadline)")
    if fault:
        x = t[-1] if t.size else 0.0
        kind, ended = how_it_ended(fault)
        ax.axvline(x, color="black", lw=2.0)
        ax.annotate(f"{kind}: {str(fault.get('message', ''))[:70]}", (x, 0.95),
                    xycoords=("data", "axes fraction"), ha="right", fontsize=8)
        title += f" - the run {ended}"
    if miss_t:
        ax.plot([], [], color="#d62728", label="deadline miss")
    if skip_t:
        ax.plot([], [], color="#ff7f0e", ls=":", label="skipped sample")
    ax.set_xlabel("time of the interval, k T (s)")
    ax.set_ylabel("period (us)" if realtime else "wall time per interval (us)")
    ax.set_title(title)
    plots.titles["events"] = [title]
    ax.legend(fontsize=8, loc="upper left")
    _save(fig, path, plots)


def plot_recording(rec: Recording, out: str | Path, *,
                   cycles: tuple[int, int] | None = None,
                   summary: str | None = None) -> Plots:
    """Draw the six figures of :data:`FIGURES` and ``index.html`` into ``out``.

    Parameters
    ----------
    rec : the recording (see :func:`ctrlunit.runtime.recording.reader.read`).
    out : a directory, created if missing.
    cycles : draw intervals ``A <= cycle < B`` only.
    summary : the run's text summary for index.html (default: rebuilt from the
        recording with :func:`ctrlunit.runtime.recording.recorded_report.report_from_recording`).

    Raises
    ------
    ValueError
        If the recording has no interval (in ``cycles``) or no configuration.
    """
    cfg = rec.config
    if not cfg:
        raise ValueError(f"{rec.path}: no ctrlunit configuration in the recording")
    from .recorded_config import run_config

    rc = run_config(rec)
    from ...kernels.params import DELTA_IA, load_params
    from ..compute.setup import make_setup

    path = rc.control.params
    params = load_params(path) if path and Path(path).exists() else DELTA_IA
    setup = make_setup(rc)  # the task as the run's engine follows it
    s = signals(rec, cycles=cycles) | sample_tracking(
        rec, period=rc.schedule.period, task=setup.task, cycles=cycles, end=setup.cycles)
    s["halved_spans_s"] = halved_spans(rec, rc.schedule.period,
                                       int(s["cycle"][-1]) + 1 if s["cycle"].size else 0)
    ev, fault = events(rec, cycles)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    plots = Plots(series=s)
    images = plots.images
    images["path"] = out / "path.png"
    _path(images["path"], s, plots)
    images["tracking_error"] = out / "tracking_error.png"
    _tracking(images["tracking_error"], s, rc.control.max_error, plots)
    images["torques"] = out / "torques.png"
    _torques(images["torques"], s, params.tau_max,
             "acceleration" if rc.control.law == "kinematics" else "torque", plots)
    images["timing"] = out / "timing.png"
    plots.timing = timing(rec, cycles)
    _timing(images["timing"], plots.timing, rc, plots)
    images["events"] = out / "events.png"
    _events_figure(images["events"], s, ev, fault, rc, plots, changes(rec, cycles))
    from ..observe.report import gantt_window

    window = gantt_window(gantt_spans(rec, cycles))
    images["gantt"] = out / "gantt.png"
    if window:
        sch = rc.schedule
        gantt_figure(images["gantt"],
                     {f"n = {sch.peripherals}, depth {sch.pipeline} (measured)": window})
    else:
        fig, ax = plt.subplots(figsize=(11, 2.6), constrained_layout=True)
        _empty(ax, "no compute spans in this recording")
        fig.savefig(images["gantt"], dpi=DPI)
        plt.close(fig)
        plots.notes.append("gantt: no compute spans in the recording")
    if summary is None:
        from ..observe.summary import summary as summary_text
        from .recorded_report import report_from_recording

        try:
            summary = summary_text(report_from_recording(rec))
        except Exception as exc:  # a damaged recording still gets its pictures
            summary = f"(no summary: {type(exc).__name__}: {exc})"
    plots.index = out / "index.html"
    write_index(plots.index, rec, images, summary, plots.notes, FIGURES)
    return plots


__all__ = ["COLORS", "FIGURES", "Plots", "gantt_figure", "plot_recording", "title_clashes"]
