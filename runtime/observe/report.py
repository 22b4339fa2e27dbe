"""The run report: its keys (docs/architecture.md, Measurement), assembled from the
central's parts and the roles' final reports (the human summary of it: :mod:`.summary`)."""

from __future__ import annotations

import hashlib
import math
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from ...kernels.trajectory import Task
from ...topology.pipeline import hold_rule
from ..compute.engine import Engine, measure_t1
from ..compute.stride import StrideSchedule
from ..config import RunConfig
from .efficiency import efficiency_unmeasured, parallel_time

if TYPE_CHECKING:
    from ..central.snapshot import RunSnapshot
    from ..compute.setup import Setup

CPU_KEYS = ("cpu_per_interval_s", "cpu_cores", "cpu_bound_period_s")

T1_T800_S = 2.0
"""Under the T-800 cost model ``t_1`` is measured over as many of the run's first
intervals as take about this long (10 to 50): every one takes its emulated T-800 time,
and the thesis stage's take 100-200 ms each."""
"""Report keys of the CPU budget (:func:`cpu_budget`): only the live run measures
them; a recording keeps them for ``ctrlunit report``."""


RESULT_KEYS: dict[str, str] = {
    "exchanges_per_interval": "exchanges per interval",
    "replies": "replies per round",
    "silences_excused": "silences excused",
    "plant_spares": "misses covered by an extrapolated command",
    "late": "late data",
    "degraded": "degraded",
    "late_intervals": "late intervals",
    "scheduling": "scheduling",
    "scheduling_choice": "scheduling",
    "scheduling_fallback": "scheduling fallback",
    "idle": "idle CPUs",
    "placement_choice": "placement",
    "rebalanced": "placement",
    "live_balance": "placement",
    "admission": "admission",
    "link_list": "the links' endpoints",
    "links": "the links' endpoints",
    "safe_stop": "safe stop",
    "host_stolen_s": "host",
}
"""Report keys the summary reads that only the live run knows (what it decided, what the
central counted, the roles' own reports), each with the summary line it feeds: a
recording keeps them for ``ctrlunit report`` (runtime/recording/recorder.py), so that
it prints every line of the live summary."""


def quoted(name: str) -> str:
    """A user-given name (a task file's ``name``) as it appears in a human summary: in
    double quotes, with quotes, backslashes and unprintable characters escaped, so that
    a name such as ``INF`` or one with a line break cannot pass for a figure or a line."""
    body = "".join(c if c.isprintable() and c not in '"\\' else
                   ("\\" + c if c in '"\\' else repr(c)[1:-1]) for c in name)
    return f'"{body}"'


def command_digest(commands: list[float] | np.ndarray) -> str:
    """SHA-256 of the commands as float64 bytes (bit-identity checks)."""
    return hashlib.sha256(np.asarray(commands, dtype="<f8").tobytes()).hexdigest()


def tracking_errors(task: Task, period: float, true_p: dict[int, tuple[float, float, float]]
                    ) -> list[float]:
    """Platform error against the reference at each sample time (m), by sample number."""
    return [math.dist(p, task.position(k * period)) for k, p in sorted(true_p.items())]


def error_stats(errs: list[float] | np.ndarray) -> dict[str, float]:
    """Max and RMS of tracking errors (m)."""
    a = np.asarray(errs, dtype=float)
    if a.size == 0:
        return {"max": math.nan, "rms": math.nan}
    return {"max": float(a.max()), "rms": float(np.sqrt((a * a).mean()))}


STRETCH_SLOWER = 2.0
"""Late intervals whose peripherals' work took at least this many times its median (the
median over them): the machine itself ran slower. Under one SCHED_FIFO priority a role's
work is not preempted by the unit's other roles, so waiting (for a CPU the unit's other
roles or the host hold, or for a message) makes intervals late without stretching the
work. On the reference machine the late intervals at 1 ms stretched it 1.0-1.8 times at
the median (docs/measurements/2026-11-24-realtime.md)."""

STRETCH_SAME = 1.2
"""At most this stretch (the median over the late intervals): their time went to waiting,
not to the work. Between the two limits the report gives the figures and no verdict."""


def late_work_figures(work_ns: Sequence[int], late_work_ns: Sequence[int], late: int
                      ) -> dict[str, Any] | None:
    """Where the late intervals' time went: the longest work one peripheral reported in
    each (ns), against its median over ``work_ns`` (the newest intervals).

    Returns ``{intervals, work_median_s, work_stretch: {median, max} | None,
    machine_slower}`` (``work_stretch`` over the first late intervals kept;
    ``machine_slower`` True at :data:`STRETCH_SLOWER` and over, False at
    :data:`STRETCH_SAME` and under, None between or without late intervals); None without
    any work reported (no peripherals)."""
    ref = np.asarray(work_ns, dtype=float)
    ref = ref[ref > 0]
    if ref.size == 0:
        return None
    median = float(np.median(ref))
    stretch = np.asarray([w for w in late_work_ns if w > 0], dtype=float) / median
    figures = {"median": float(np.median(stretch)), "max": float(stretch.max())} \
        if stretch.size else None
    slower = None
    if figures is not None and figures["median"] >= STRETCH_SLOWER:
        slower = True
    elif figures is not None and figures["median"] <= STRETCH_SAME:
        slower = False
    return {"intervals": int(late), "work_median_s": median / 1e9, "work_stretch": figures,
            "machine_slower": slower}


def overload_figures(changes: list[dict[str, Any]], halves: bool, grid: StrideSchedule, *,
                     end: int) -> dict[str, Any]:
    """The report's ``overload``: ``policy`` (halve or continue), ``changes`` (each change
    of the control rate: ``stride``, ``from_cycle``, ``at_interval`` and why: ``late`` runs
    of late intervals within ``window`` intervals or ``in_a_row`` late intervals, with
    ``after_return`` where a return on trial ended, or ``calm`` intervals without a late
    one), ``halved`` (the first
    halving, or None) and ``halved_periods`` (periods run at the halved rate up to cycle
    ``end``, from ``grid``)."""
    return {"policy": "halve" if halves else "continue", "changes": list(changes),
            "halved": next((c for c in changes if c["stride"] == 2), None),
            "halved_periods": sum(b - a for a, b in grid.halved_spans(end))}


def gantt_window(spans: list[tuple[str, int, int, int]], *, intervals: int = 4
                 ) -> list[tuple[str, int, float, float]]:
    """Spans ``(process, cycle, t0_ns, t1_ns)`` of a few intervals after the start-up, as
    ``(process, cycle, t0_ms, t1_ms)`` from the first (Gantt charts)."""
    cycles = sorted({c for _, c, _, _ in spans})
    if len(cycles) < 20:
        chosen = set(cycles[:intervals])
    else:
        mid = len(cycles) // 2
        chosen = set(cycles[mid:mid + intervals])
    sel = [s for s in spans if s[1] in chosen]
    if not sel:
        return []
    t0 = min(s[2] for s in sel)
    return [(p, c, (a - t0) / 1e6, (b - t0) / 1e6) for p, c, a, b in sel]


def _what_ran(rc: Any, plan: Any, task: Task, *, cycles: int, exchanges: int | None,
              replies: dict[str, Any] | None) -> dict[str, Any]:
    """The report's description of the run: the unit, its configuration and its plan."""
    n = plan.placement.peripherals
    return {
        "processors": plan.placement.processors,
        "peripherals": n,
        "pipeline": rc.schedule.pipeline,
        "clock": rc.schedule.clock,
        "command_delay": command_delay(rc),
        "cycles": cycles,
        "nominal_period_s": rc.schedule.period,
        "law": rc.control.law,
        "model": rc.control.model,
        "observer": rc.control.observer,
        "model_state": plan.graph.model_state,
        "task": task.name,
        "cost_model": rc.control.cost_model,
        "cost_scale": rc.control.cost_scale,
        "unit": rc.transport.unit,
        "links": rc.link_security(check_files=False),  # the weakest of link_list's
        "link_list": rc.links(),
        "round_trips": plan.round_trips,
        "rounds_ahead": plan.ahead_rounds if n and rc.schedule.pipeline > 1 else 0,
        "exchanges_per_interval": (exchanges / cycles) if exchanges is not None
        and cycles else None,
        "replies": replies,
        "hold_rounds": {"asked": rc.schedule.hold_rounds,
                        "held": hold_rule(rc.schedule.hold_rounds, clock=rc.schedule.clock)}
        if n and rc.schedule.pipeline > 1 else None,
        "placement": plan.placement.to_dict(),
    }


def build_report(
    *,
    rc: Any,
    plan: Any,
    task: Task,
    timing: dict[str, Any],
    digest: str,
    torque_max: float,
    tracking: dict[str, float],
    business: dict[str, float],
    deadline_misses: int,
    skipped: int,
    rejected: dict[str, int],
    t1_s: float,
    per_block_s: dict[str, float],
    fault: dict[str, Any] | None,
    wall_s: float,
    cost_error_s: dict[str, Any] | None = None,
    exchanges: int | None = None,
    replies: dict[str, Any] | None = None,
    silences_excused: int = 0,
    central_costs: dict[str, float] | None = None,
    gantt: list[tuple[str, int, float, float]] | None = None,
) -> dict[str, Any]:
    """Assemble the report (its keys: docs/architecture.md, Measurement).

    ``timing`` holds the run's timing figures (:func:`..compute.timing.timing_figures` or
    :meth:`..compute.timing.IntervalTimes.figures`), ``tracking`` the tracking error's max and RMS
    (m).
    """
    n = plan.placement.peripherals
    processors = plan.placement.processors
    cycles = timing["cycles"]
    pq, tq = timing["period_s"], timing["traversal_s"]
    period_mean = timing["period_mean_s"]
    t_par, t_par_is = parallel_time(rc, traversal_p50=tq["p50"], period_mean=period_mean)
    eff = t1_s / (t_par * processors) if t_par and t_par > 0 else math.nan
    speedup = t1_s / t_par if t_par and t_par > 0 else math.nan
    graph = plan.graph
    central_s = sum(v for k, v in per_block_s.items() if not graph.block(k).per_axis)
    axis_s = sum(v for k, v in per_block_s.items() if graph.block(k).per_axis)
    t_s = central_s + axis_s
    t_p = central_s + axis_s / max(n, 1)
    jitter = timing["jitter_std_s"]
    out = _what_ran(rc, plan, task, cycles=cycles, exchanges=exchanges, replies=replies) | {
        "period_s": pq,
        "period_mean_s": period_mean,
        "jitter_s": {"std": jitter, "p99_minus_p50": pq["p99"] - pq["p50"]},
        "traversal_s": tq,
        "timing": timing["timing"],
        "deadline_misses": deadline_misses,
        "skipped_samples": skipped,
        "silences_excused": silences_excused,
        "business": business,
        "t1_s": t1_s,
        "t_parallel_s": t_par,
        "t_parallel_is": t_par_is,
        "efficiency": eff,
        "efficiency_n": processors,
        "speedup": speedup,
        "t_s_model_s": t_s,
        "t_p_model_s": t_p,
        "block_cost_s": per_block_s,
        "tracking_error_m": tracking if rc.schedule.clock != "freerun"
        else {"max": math.nan, "rms": math.nan},
        "torque_nm": {"max": torque_max if cycles else math.nan},
        "command_digest": digest,
        "rejected_messages": rejected,
        "cost_model_error_s": cost_error_s,
        "central_costs_s": central_costs,
        "gantt_ms": gantt or [],
        "wall_s": wall_s,
        "fault": fault,
        "zenoh": {},
    }
    # the figures above are the terms as measured; whether they are Eq. IV.23's is this
    out["efficiency_unmeasured"] = efficiency_unmeasured(out)
    return out


def command_delay(rc: RunConfig) -> dict[str, Any] | None:
    """When the plant applies a command (docs/architecture.md, Clocks): the convention and
    the periods from a sample to the period in which its command acts. None in freerun
    (no plant)."""
    if rc.schedule.clock == "freerun":
        return None
    return {"convention": rc.schedule.command_delay, "periods": rc.delay_periods}


def text_or_none(x: Any) -> str | None:
    """A role's word as text, or None when it said nothing usable."""
    return x if isinstance(x, str) else None


def cpu_budget(run: RunSnapshot, roles: list[str], cores: int | None) -> dict[str, Any]:
    """CPU time per interval of every process (all its threads, Zenoh's included) between
    the central's ``start`` and ``stop``, and what it implies: on ``cores`` CPUs, the
    freerun period cannot be shorter than the total divided by ``cores``, whatever the
    schedule. ``total`` and ``cpu_bound_period_s`` are there only when every role ran on
    this host and reported (not after a fault, nor for ``ctrlunit central`` alone).

    The CPU is averaged over every interval of the run, its first ones included (the
    period's figures leave those out), so a short run shows a higher figure. When units
    run inside another program (``ctrlunit bench``), the central's share also counts
    that program's other threads."""
    done = max(1, run.done)
    per: dict[str, float] = {}
    if run.times.cpu_s is not None:
        per["central"] = run.times.cpu_s / done
    for role in roles:
        cpu = (run.role_reports.get(role) or {}).get("cpu_s")
        if isinstance(cpu, (int, float)) and not isinstance(cpu, bool) and cpu >= 0:
            per[role.replace("-", "_")] = cpu / done
    complete = len(per) == len(roles) + 1
    total = sum(per.values())
    if complete:  # a total of the roles that reported would pass for the unit's
        per["total"] = total
    return {"cpu_per_interval_s": per,
            "cpu_cores": cores,
            "cpu_bound_period_s": total / cores if cores and complete and run.done
            else None}


def finish_report(setup: Setup, run: RunSnapshot, fault: dict | None) -> dict[str, Any]:
    """The report of a live run, from the central's ``run`` and the roles' final reports
    (``t_1`` is measured here, on the run's recorded inputs)."""
    rc = setup.rc
    t = run.times
    wall = max(1, t.t_end_ns - t.t_start_ns)
    business = {"central": max(0.0, 1.0 - t.wait_ns / wall)}
    for k in range(setup.placement.peripherals):
        business[f"peripheral_{k + 1}"] = t.periph_busy_ns[k] / wall
    if rc.schedule.clock != "freerun":
        business["plant"] = t.plant_busy_ns / wall
    t1 = math.nan
    per_block: dict[str, Any] = {}
    t1_engines: list[Engine] = []

    def t1_engine() -> Engine:
        t1_engines.append(setup.engine(peripherals_plan=False))
        return t1_engines[-1]

    if run.t1_inputs:
        count = None
        if rc.control.cost_model == "t800":  # each interval takes its T-800 time: 2 s at most
            t_single = sum(b.t800_s(rc.control.cost_scale) for b in setup.plan.graph.blocks)
            count = max(10, min(50, int(T1_T800_S / t_single))) if t_single > 0 else 50
        t1, per_block = measure_t1(t1_engine, list(run.t1_inputs[:count]))
    cost_err = None
    if rc.control.cost_model == "t800":
        # block costs are the emulated T-800 times; the emulation's error is measured
        per_block = {b.name: b.t800_s(rc.control.cost_scale) for b in setup.plan.graph.blocks}
        errs = sorted(list(t.cost_errors_ns) + [e for g in t1_engines for e in g.cost.errors_ns])
        if errs:
            cost_err = {"p50": errs[len(errs) // 2] / 1e9,
                        "p99": errs[int(len(errs) * 0.99)] / 1e9, "max": errs[-1] / 1e9,
                        "method": "sleep to twice the mean sleep overshoot (50 us to 1 ms) "
                                  "before the T-800 deadline, then spin; "
                                  "one settle per message sent"}
    rejected = dict(run.rejected)
    for role, rep in run.role_reports.items():
        for k, v in (rep.get("rejected") or {}).items():
            rejected[f"{role}:{k}"] = v
    report = build_report(
        rc=rc, plan=setup.plan, task=setup.task, timing=run.timing, digest=run.digest,
        torque_max=run.torque_max, tracking=run.tracking, business=business,
        deadline_misses=run.plant_misses, skipped=run.skipped,
        rejected=rejected,
        t1_s=t1, per_block_s=per_block, fault=fault,
        wall_s=(t.t_end_ns - t.t_start_ns) / 1e9,
        cost_error_s=cost_err,
        exchanges=run.exchanges if setup.placement.peripherals else None,
        replies=run.replies_info if setup.placement.peripherals else None,
        central_costs=t.central_costs, gantt=gantt_window(list(t.spans)),
        silences_excused=run.silences_excused,
    )
    report["periods"] = run.periods
    report["overload"] = overload_figures(list(run.late.rate_changes),
                                          run.late.halves_on_overload, run.late.grid,
                                          end=run.next_cycle)
    if run.late.deadline_ns:
        lf = run.late
        report["late_intervals"] = late_work_figures(lf.work_ns, lf.late_work_ns, lf.late)
    return report
