"""The bench's realtime stage: does the main job hold its period, run after run?

``ctrlunit start --peripherals 3 --pipeline 2`` (the main job, default options) is run
``runs`` times, each followed by the single-process baseline (the same command with
``--peripherals 0``, at the period and under the scheduling policy the main job ran
at, admission off so that it always runs): the machine's own stalls show in the baseline,
measured in the same minutes. The same again at each period of ``fixed`` (the thesis's
0.5 ms, § IV.7.2: ``--period 500us``, admission on as a user runs it, so a period the
machine cannot hold is a refusal). Then
one long run of the main job (task repeated), followed by the baseline for as long at the
long run's period. Every run is a ``ctrlunit start`` process of its own, as a user runs it,
and is ended by the stage if it overstays.

Figures: the fraction of runs that completed the task, deadline misses per 1000 periods
over all runs, traversal p99.9, CPU per interval (all processes, and each role's), the
period each run chose, and which levers were on.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import time
import uuid
from collections import Counter
from collections.abc import Callable
from pathlib import Path
from typing import Any

MAIN_JOB = ("--peripherals", "3", "--pipeline", "2")

THESIS_PERIOD_S = 5e-4
"""The sampling period the thesis designed its two-stage pipeline for (§ IV.7.2)."""


LEVERS = ("period", "admission", "command_delay", "hold_rounds", "replies", "rt_priority",
          "idle", "cpus", "pin", "placement", "late_policy", "missed_command", "fault_periods",
          "model_state", "overload")


def levers() -> dict[str, Any]:
    """The options of ``ctrlunit start`` that bear on holding the period, at the defaults
    the main job runs with (read from the command line's own definition)."""
    from ..runtime.cli.base import cli

    defaults = {p.name: p.default for p in cli.commands["start"].params}
    return {k: defaults[k] for k in LEVERS}


STOP_WAIT_S = 10.0
"""How long a stopped bench waits for its current run to stop the robot and exit."""


def run_start(args: tuple[str, ...], *, timeout_s: float) -> dict[str, Any]:
    """One ``ctrlunit start`` with ``args`` in a process group of its own; its report
    (``{}`` if it wrote none), exit code and wall time. Killed with its children if it
    runs past ``timeout_s``."""
    unit = f"rt-{os.getpid()}-{uuid.uuid4().hex[:8]}"
    with tempfile.TemporaryDirectory(prefix="ctrlunit-rt-") as tmp:
        report = Path(tmp) / "report.json"
        cmd = [sys.executable, "-m", "ctrlunit.runtime.cli", "start", *args, "--unit", unit,
               "--report", str(report), "--no-progress"]
        t0 = time.monotonic()
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                start_new_session=True, text=True)
        try:
            out, _ = proc.communicate(timeout=timeout_s)
            code = proc.returncode
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            out, _ = proc.communicate()
            code = None
        except KeyboardInterrupt as exc:  # the bench stopped: so does its run, safely
            # with the signal the bench got: the run inherited the bench's ignored
            # signals (a script's background job ignores SIGINT), not its handlers
            with contextlib.suppress(ProcessLookupError):
                os.killpg(proc.pid, getattr(exc, "signum", signal.SIGINT))
            with contextlib.suppress(subprocess.TimeoutExpired):
                proc.communicate(timeout=STOP_WAIT_S)
            raise
        finally:
            try:  # the roles of a run that died early, if any are left
                os.killpg(proc.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
        rep = json.loads(report.read_text()) if report.exists() else {}
    return {"exit_code": code, "report": rep, "wall_s": time.monotonic() - t0,
            "output_tail": out[-400:] if code else ""}


def run_row(res: dict[str, Any]) -> dict[str, Any]:
    """The figures of one run."""
    r = res["report"]
    fault = r.get("fault") or {}
    return {
        "exit_code": res["exit_code"],
        "completed": res["exit_code"] == 0,
        "period_s": r.get("nominal_period_s"),
        "cycles": r.get("cycles", 0) or 0,
        "periods": r.get("periods", r.get("cycles", 0)) or 0,
        "halved_at_interval": ((r.get("overload") or {}).get("halved") or {}).get(
            "at_interval"),
        "halved_periods": (r.get("overload") or {}).get("halved_periods", 0) or 0,
        "rate_changes": len((r.get("overload") or {}).get("changes") or []),
        "deadline_misses": r.get("deadline_misses", 0) or 0,
        "traversal_p999_s": (r.get("traversal_s") or {}).get("p999"),
        "cpu_per_interval_s": (r.get("cpu_per_interval_s") or {}).get("total"),
        "cpu_by_role_s": {k: v for k, v in (r.get("cpu_per_interval_s") or {}).items()
                          if k != "total"},
        "tracking_max_m": (r.get("tracking_error_m") or {}).get("max"),
        "fault": fault.get("message"),
        "wall_s": res["wall_s"],
        "scheduling": (r.get("scheduling") or {}).get("central"),
        "rt_priority": (r.get("scheduling_choice") or {}).get("priority", 0),
        "fell_back": bool(r.get("scheduling_fallback")),
        "idle": (r.get("idle") or {}).get("in_force"),
        "late_work_stretch": ((r.get("late_intervals") or {}).get("work_stretch")
                              or {}).get("median"),
        "machine_slower": (r.get("late_intervals") or {}).get("machine_slower"),
    }


def summary(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """Completed fraction, misses per 1000 periods over every run, medians."""
    cycles = sum(r["periods"] for r in rows)
    misses = sum(r["deadline_misses"] for r in rows)

    def med(key: str) -> float:
        v = [r[key] for r in rows if isinstance(r[key], (int, float)) and r["cycles"]]
        return statistics.median(v) if v else math.nan

    return {"runs": len(rows), "completed": sum(r["completed"] for r in rows),
            "completed_fraction": (sum(r["completed"] for r in rows) / len(rows)
                                   if rows else math.nan),
            "refused": sum(r["exit_code"] == 7 for r in rows),
            "periods": cycles, "deadline_misses": misses,
            "misses_per_1000": 1000 * misses / cycles if cycles else math.nan,
            "periods_chosen_s": sorted({r["period_s"] for r in rows
                                        if r["period_s"] and r["exit_code"] != 7}),
            "scheduling": dict(Counter(str(r.get("scheduling")) for r in rows
                                       if r["exit_code"] != 7)),
            "fell_back": sum(bool(r.get("fell_back")) for r in rows),
            "idle_poll": sum(r.get("idle") == "poll" for r in rows if r["exit_code"] != 7),
            "halved": sum(r.get("halved_at_interval") is not None for r in rows),
            "halved_periods": sum(r.get("halved_periods", 0) for r in rows),
            "late_runs": {"machine_slower": sum(r.get("machine_slower") is True for r in rows),
                          "waiting": sum(r.get("machine_slower") is False for r in rows),
                          "no_verdict": sum(r.get("late_work_stretch") is not None
                                            and r.get("machine_slower") is None
                                            for r in rows)},
            "traversal_p999_s": med("traversal_p999_s"),
            "cpu_per_interval_s": med("cpu_per_interval_s"),
            "cpu_by_role_s": {role: statistics.median(
                r["cpu_by_role_s"][role] for r in rows
                if r["cycles"] and role in r.get("cpu_by_role_s", {}))
                for role in sorted({k for r in rows if r["cycles"]
                                    for k in r.get("cpu_by_role_s", {})})},
            "tracking_max_m": med("tracking_max_m"),
            "tracking_worst_m": max((r["tracking_max_m"] for r in rows
                                     if isinstance(r["tracking_max_m"], (int, float))
                                     and r["cycles"]), default=math.nan)}


def stage_steps(runs: int, long_s: float, fixed: tuple[float, ...] = (THESIS_PERIOD_S,),
                fixed_runs: int | None = None) -> int:
    """How many ``ctrlunit start`` processes the stage runs (for progress)."""
    at = runs if fixed_runs is None else fixed_runs
    return 2 * runs + 2 * at * len(fixed) + (2 if long_s > 0 else 0)


def baseline_args(row: dict[str, Any], *extra: str,
                  period_s: float | None = None) -> tuple[str, ...]:
    """The baseline of a main-job run ``row``: one control process at the period it ran
    (``period_s`` where it was asked for: a refused run ran none) and under the policy it
    ran under (without the admission, ``--rt-priority auto`` would leave it at the
    default policy)."""
    period = period_s or row["period_s"] or 1e-3
    return ("--peripherals", "0", "--pipeline", "2", "--period", f"{period:g}",
            "--no-admission", "--rt-priority", str(row["rt_priority"] or 0),
            "--idle", row.get("idle") or "default", *extra)


def _series(runs: int, args: tuple[str, ...], period_s: float | None, *, what: str,
            progress: Callable[[str, int, int], None] | None, done: int, total: int,
            timeout_s: float) -> tuple[list[dict[str, Any]], list[dict[str, Any]], int]:
    """``runs`` main-job runs with ``args``, each followed by its baseline."""
    star: list[dict[str, Any]] = []
    base: list[dict[str, Any]] = []
    for i in range(runs):
        if progress:
            progress(f"realtime: {what} {i + 1}/{runs}", done, total)
        row = run_row(run_start(args, timeout_s=timeout_s))
        star.append(row)
        done += 1
        if progress:
            progress(f"realtime: baseline {i + 1}/{runs}", done, total)
        base.append(run_row(run_start(baseline_args(row, period_s=period_s),
                                      timeout_s=timeout_s)))
        done += 1
    return star, base, done


def realtime_stage(*, runs: int, long_s: float,
                   progress: Callable[[str, int, int], None] | None = None, done: int = 0,
                   total: int = 0, timeout_s: float = 120.0,
                   fixed: tuple[float, ...] = (THESIS_PERIOD_S,),
                   fixed_runs: int | None = None) -> dict[str, Any]:
    """``runs`` main-job runs, each followed by its baseline, the same at each period of
    ``fixed`` (``fixed_runs`` times where given), then a long run of ``long_s`` seconds
    and its baseline (none when 0). See the module's docstring."""
    star, base, done = _series(runs, MAIN_JOB, None, what="main job", progress=progress,
                               done=done, total=total, timeout_s=timeout_s)
    at: list[dict[str, Any]] = []
    for period in fixed:
        args = (*MAIN_JOB, "--period", f"{period * 1e6:g}us")
        s_rows, b_rows, done = _series(runs if fixed_runs is None else fixed_runs, args,
                                       period, what=f"main job at {period * 1e3:g} ms",
                                       progress=progress, done=done, total=total,
                                       timeout_s=timeout_s)
        at.append({"period_s": period, "command": "ctrlunit start " + " ".join(args),
                   "main_job": summary(s_rows), "baseline": summary(b_rows),
                   "rows": {"main_job": s_rows, "baseline": b_rows}})
    long_row = long_base = None
    if long_s > 0:
        if progress:
            progress(f"realtime: main job for {long_s:g} s", done, total)
        long_row = run_row(run_start((*MAIN_JOB, "--duration", f"{long_s:g}s"),
                                     timeout_s=timeout_s + 3 * long_s))
        done += 1
        if progress:
            progress(f"realtime: baseline for {long_s:g} s", done, total)
        long_base = run_row(run_start(baseline_args(long_row, "--duration", f"{long_s:g}s"),
                                      timeout_s=timeout_s + 3 * long_s))
    return {"command": "ctrlunit start " + " ".join(MAIN_JOB),
            "baseline_command": "ctrlunit start --peripherals 0 --pipeline 2 "
                                "--period <the main job's> --no-admission "
                                "--rt-priority <the main job's>",
            "levers": levers(), "main_job": summary(star), "baseline": summary(base),
            "fixed": at,
            "long": long_row, "long_baseline": long_base, "long_s": long_s,
            "rows": {"main_job": star, "baseline": base}}


def per_1000(row: dict[str, Any]) -> float:
    """A run's deadline misses per 1000 periods."""
    return 1000 * row["deadline_misses"] / row["periods"] if row["periods"] else math.nan


def _fmt(x: Any, scale: float = 1.0, digits: int = 0) -> str:
    if not isinstance(x, (int, float)) or not math.isfinite(x):
        return "-"
    return f"{x * scale:.{digits}f}"


def _late_words(r: dict[str, Any]) -> str:
    """What a run's late intervals' work took against its median, and the verdict
    (runtime/observe/report.py's ``late_work_figures``), or nothing without late intervals."""
    stretch = r.get("late_work_stretch")
    if stretch is None:
        return ""
    slower = r.get("machine_slower")
    verdict = "in between" if slower is None else (
        "the machine ran slower" if slower else "time lost waiting")
    return f"; the late intervals' work took {stretch:.1f}x its median ({verdict})"


def markdown_lines(st: dict[str, Any]) -> list[str]:
    """The stage as a section of ``report.md``."""
    lines = [
        "## Realtime: does the main job hold its period?",
        "",
        f"`{st['command']}` (default options), {st['main_job']['runs']} run(s), each "
        f"followed by the baseline `{st['baseline_command']}`"
        + "".join(f"; the same at `{fx['command']}`" for fx in st.get("fixed", []))
        + (f"; then the main job for {st['long_s']:g} s and its baseline as long."
           if st["long"] else "."),
        "Levers on: " + ", ".join(f"{k} {v}" for k, v in st["levers"].items()) + ".",
        "",
        "| | runs | completed | refused (exit 7) | periods | misses | misses / 1000 | "
        "periods run (ms) | traversal p99.9, median (us) | CPU / interval, median (us) | "
        "tracking max, median / worst run (mm) |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    series = [("main job", st["main_job"]), ("baseline (n = 0)", st["baseline"])]
    for fx in st.get("fixed", []):
        at = f"{fx['period_s'] * 1e3:g} ms"
        series += [(f"main job at {at}", fx["main_job"]),
                   (f"baseline at {at} (n = 0)", fx["baseline"])]
    for name, s in series:
        lines.append(
            f"| {name} | {s['runs']} | {s['completed']} | {s['refused']} | {s['periods']} | "
            f"{s['deadline_misses']} | {_fmt(s['misses_per_1000'], 1, 2)} | "
            f"{', '.join(_fmt(p, 1e3, 2) for p in s['periods_chosen_s'])} | "
            f"{_fmt(s['traversal_p999_s'], 1e6)} | {_fmt(s['cpu_per_interval_s'], 1e6)} | "
            f"{_fmt(s['tracking_max_m'], 1e3, 2)} / {_fmt(s['tracking_worst_m'], 1e3, 2)} |")
    by_role = [f"{name}: " + ", ".join(f"{k} {_fmt(v, 1e6)}" for k, v in
                                       s["cpu_by_role_s"].items())
               for name, s in series if s.get("cpu_by_role_s")]
    if by_role:
        lines += ["", "CPU per interval by role, median (us): " + "; ".join(by_role) + "."]
    sched = ", ".join(f"{k} in {v}" for k, v in st["main_job"].get("scheduling", {}).items())
    if sched:
        lines += ["", f"The main job's runs ran under {sched}; back to the default policy "
                  f"during the run (the throttling guard) in {st['main_job']['fell_back']}; "
                  f"control rate halved on overload in {st['main_job'].get('halved', 0)}; "
                  f"idle CPUs polling (`--idle`) in {st['main_job'].get('idle_poll', 0)}."]
    lr = st["main_job"].get("late_runs") or {}
    if any(lr.values()):
        lines += ["", "Runs with late commands (the report's `late_intervals`): the "
                  f"peripherals' work stretched (the machine ran slower) in "
                  f"{lr['machine_slower']}, as usual (time lost waiting) in {lr['waiting']}, "
                  f"in between in {lr['no_verdict']}."]
    for title, r in ((f"Long run ({st['long_s']:g} s)", st["long"]),
                     (f"Its baseline ({st['long_s']:g} s, n = 0)", st.get("long_baseline"))):
        if not r:
            continue
        lines += ["", f"{title}: exit {r['exit_code']}, period "
                  f"{_fmt(r['period_s'], 1e3, 2)} ms, {r['periods']} periods "
                  f"({r['cycles']} intervals), "
                  f"{r['deadline_misses']} misses ({_fmt(per_1000(r), 1, 2)} per 1000), "
                  f"traversal p99.9 {_fmt(r['traversal_p999_s'], 1e6)} us, CPU / interval "
                  f"{_fmt(r['cpu_per_interval_s'], 1e6)} us, tracking max "
                  f"{_fmt(r['tracking_max_m'], 1e3, 2)} mm"
                  + (f"; control rate halved at interval {r['halved_at_interval']} "
                     f"({r['rate_changes']} change(s) of rate; {r['halved_periods']} periods "
                     "at the halved rate)" if r.get("halved_at_interval") is not None else "")
                  + _late_words(r)
                  + (f"; fault: {r['fault']}" if r["fault"] else "") + "."]
    for what, rows in [("Main-job runs", st["rows"]["main_job"])] + [
            (f"Runs at {fx['period_s'] * 1e3:g} ms", fx["rows"]["main_job"])
            for fx in st.get("fixed", [])]:
        faults = [(i + 1, r["exit_code"], r["fault"]) for i, r in enumerate(rows)
                  if not r["completed"]]
        if faults:
            lines += ["", f"{what} that did not complete: " + "; ".join(
                f"run {i} exit {c}: {str(f).rstrip('.')}" for i, c, f in faults) + "."]
    return lines + [""]


__all__ = ["LEVERS", "MAIN_JOB", "THESIS_PERIOD_S", "baseline_args", "levers",
           "markdown_lines", "per_1000", "realtime_stage", "run_row", "run_start",
           "stage_steps", "summary"]
