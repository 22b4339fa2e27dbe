"""What the plots read of a recording (:mod:`.plots`): the ``/signals/state`` messages
as arrays, the deadline and fault events, the changes of placement (live moves,
take-overs), the compute spans and the spans at the halved control rate. A malformed
message is skipped, never a crash."""

from __future__ import annotations

import json
import math
from typing import Any

import numpy as np

from .reader import Recording
from .result_record import fault as record_fault


def _num(x: Any) -> float:
    """A number of a ``/signals/state`` message; anything else (null, a forged string) is
    a gap in the plot."""
    return float(x) if type(x) in (int, float) else math.nan


def _vec(v: Any) -> list[float]:
    if not isinstance(v, dict):
        return [math.nan] * 3
    return [_num(v.get("x")), _num(v.get("y")), _num(v.get("z"))]


def _three(v: Any) -> list[float]:
    return [_num(x) for x in v] if isinstance(v, list) and len(v) == 3 else [math.nan] * 3


def signals(rec: Recording, *, cycles: tuple[int, int] | None = None
            ) -> dict[str, np.ndarray]:
    """The ``/signals/state`` messages as arrays, in cycle order (see :class:`Plots`).

    Parameters
    ----------
    rec : a recording.
    cycles : keep intervals ``A <= cycle < B`` only.

    Raises
    ------
    ValueError
        If the recording (or the range) holds no interval.
    """
    rows: dict[int, dict[str, Any]] = {}
    for _, data in rec.topics.get("/signals/state", []):
        try:
            m = json.loads(data)
            k = m["cycle"]
        except (ValueError, KeyError, TypeError):
            continue
        if type(k) is not int or not 0 <= k < 1 << 62:  # forged: 1e308 overflowed numpy
            continue
        if cycles is None or cycles[0] <= k < cycles[1]:
            rows[k] = m
    if not rows:
        where = f" in cycles {cycles[0]}:{cycles[1]}" if cycles else ""
        raise ValueError(f"{rec.path}: no interval to plot{where}")
    ks = sorted(rows)
    ms = [rows[k] for k in ks]
    return {
        "cycle": np.array(ks, dtype=np.int64),
        "t_s": np.array([_num(m.get("t")) for m in ms]),
        "p_m": np.array([_vec(m.get("p")) for m in ms]).reshape(-1, 3),
        "reference_m": np.array([_vec(m.get("reference")) for m in ms]).reshape(-1, 3),
        "tracking_error_m": np.array([_num(m.get("tracking_error")) for m in ms]),
        "torque_nm": np.array([_three(m.get("torque")) for m in ms]).reshape(-1, 3),
        "period_s": np.array([_num(m.get("period")) for m in ms]),
        "traversal_s": np.array([_num(m.get("traversal")) for m in ms]),
    }


def sample_tracking(rec: Recording, *, period: float, task: Any, end: int,
                    cycles: tuple[int, int] | None = None) -> dict[str, np.ndarray]:
    """The tracking error at every recorded sample of the run (``k < end``), as the
    summary and the report from a recording count it (runtime/observe/report.py,
    ``tracking_errors``): ``sample_cycle``, ``sample_t_s`` and ``sample_error_m``. The
    per-interval error of ``/signals/state`` stops at the last interval that completed;
    a run stopped by its tracking fault has samples after it, and its largest error among
    them. Empty where the samples hold no position (freerun)."""
    ks: list[int] = []
    errs: list[float] = []
    for _, m in rec.decoded("/central/sample"):
        k, p = m.get("cycle"), m.get("p")
        if not isinstance(k, int) or p is None or not 0 <= k < end:
            continue
        if cycles is None or cycles[0] <= k < cycles[1]:
            ks.append(k)
            errs.append(math.dist(p, task.position(k * period)))
    order = np.argsort(np.asarray(ks, dtype=np.int64), kind="stable")
    cyc = np.asarray(ks, dtype=np.int64)[order]
    return {"sample_cycle": cyc, "sample_t_s": cyc * period,
            "sample_error_m": np.asarray(errs, dtype=float)[order]}


def commands(rec: Recording, samples: dict[int, dict[str, Any]] | None = None
             ) -> dict[str, list]:
    """Every recorded command whose sample is recorded, in file order: ``cycle``,
    ``cmd_ns`` (when it left, its log time), ``sample_ns`` (when its sample was taken) and
    ``tau`` (its values, one command after the other). The report from a recording
    (:mod:`.recorded_report`) and the timing plot take their times from here.

    ``samples`` : the ``/central/sample`` messages by cycle, if already decoded."""
    if samples is None:
        samples = {m["cycle"]: m for _, m in rec.decoded("/central/sample")}
    out: dict[str, list] = {"cycle": [], "cmd_ns": [], "sample_ns": [], "tau": []}
    for t, m in rec.decoded("/plant/command"):
        s = samples.get(m["cycle"])
        if s is None:
            continue
        out["cycle"].append(m["cycle"])
        out["cmd_ns"].append(t)
        out["sample_ns"].append(s["t_ns"])
        out["tau"].extend(float(x) for x in m["tau"])
    return out


def timing(rec: Recording, cycles: tuple[int, int] | None = None) -> dict[str, Any]:
    """The period and traversal series (s) the report's timing figures are taken from
    (:func:`..compute.timing.timing_series`: the same start-up left out), as
    ``period_s``, ``traversal_s``, and their figures (``period_s`` and ``traversal_s``
    quantiles, ``period_mean_s``), within intervals ``A <= cycle < B`` if given (a period
    counts for the interval it ends at)."""
    from ..compute.timing import quantiles, timing_series

    c = commands(rec)
    period, trav, warm = timing_series(c["cmd_ns"], c["sample_ns"])
    ks = np.asarray(c["cycle"][warm:], dtype=np.int64)
    if cycles is not None:
        trav = trav[(ks >= cycles[0]) & (ks < cycles[1])]
        ends = ks[1:]
        period = period[(ends >= cycles[0]) & (ends < cycles[1])]
    return {"period_s": period, "traversal_s": trav,
            "figures": {"period_s": quantiles(period), "traversal_s": quantiles(trav),
                        "period_mean_s": float(period.mean()) if period.size else math.nan}}


def events(rec: Recording, cycles: tuple[int, int] | None
            ) -> tuple[list[tuple[int, int, int]], dict[str, Any] | None]:
    """``(cycle, deadline misses so far, skipped samples so far)`` as recorded, and the
    fault of the run (None if it ended well)."""
    ev = []
    for _, m in rec.decoded("/faults/deadline"):
        try:
            ev.append((int(m["cycle"]), int(m["deadline_misses"]), int(m["skipped_samples"])))
        except (KeyError, TypeError, ValueError):
            continue
    if cycles is not None:
        ev = [e for e in ev if cycles[0] <= e[0] < cycles[1]]
    try:
        fault = record_fault(rec.metadata.get("ctrlunit.result", {}).get("fault"))
    except ValueError:  # ctrlunit plot checks the record first (runtime/cli/recordings.py)
        fault = None
    if rec.salvaged and not fault:
        fault = {"process": "recording", "message": rec.note}
    return ev, fault


def changes(rec: Recording, cycles: tuple[int, int] | None = None
            ) -> list[tuple[int, str]]:
    """``(cycle, what)`` of each change of who computes what, once each, in cycle order: a
    live re-placement (``/central/placement``: the blocks then on the central), a
    peripheral lost and taken over, one standing by beside it, and each coming back
    (``/faults/degraded``)."""
    from .replay import placements

    out = {(k, f"placement: {len(blocks)} block(s) on the central")
           for k, blocks in placements(rec)}
    for _, m in rec.decoded("/faults/degraded"):  # a record again at each of its changes
        k = m.get("peripheral")
        if type(k) is not int:
            continue
        by = str(m.get("why", "")).startswith("stands by")  # beside a lost one, not lost
        if type(m.get("from_cycle")) is int:
            out.add((m["from_cycle"], f"peripheral {k} " + ("stands by" if by
                                                            else "taken over")))
        if type(m.get("back_from_cycle")) is int:
            out.add((m["back_from_cycle"], f"peripheral {k} back"))
    if cycles is not None:
        out = {c for c in out if cycles[0] <= c[0] < cycles[1]}
    return sorted(out)


def gantt_spans(rec: Recording, cycles: tuple[int, int] | None = None
                ) -> list[tuple[str, int, int, int]]:
    """Compute spans ``(process, cycle, t0_ns, t1_ns)`` from ``/timing/spans``."""
    out: list[tuple[str, int, int, int]] = []
    for _, m in rec.decoded("/timing/spans"):
        try:
            k = int(m["cycle"])
            if cycles is not None and not cycles[0] <= k < cycles[1]:
                continue
            out.extend((str(p), k, int(a), int(b)) for p, a, b in m["spans"])
        except (KeyError, TypeError, ValueError):
            continue
    return out


def halved_spans(rec: Recording, period: float, end_cycle: int) -> np.ndarray:
    """``[[t0, t1], ...]`` (s): the spans the recorded run spent at the halved control
    rate (its ``stride`` orders), the last one open to ``end_cycle``."""
    from .replay import stride_grid

    spans = stride_grid(rec).halved_spans(end_cycle)
    return np.array(spans, dtype=float).reshape(-1, 2) * period


__all__ = ["commands", "events", "gantt_spans", "halved_spans", "signals", "timing"]
