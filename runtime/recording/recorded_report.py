"""The run's report rebuilt from a recording alone (``ctrlunit report``, ``balance``):
the same numbers as the live run's, from the recorded messages, timing and result."""

from __future__ import annotations

import math
from typing import Any

from ..compute.engine import measure_t1
from ..compute.setup import make_setup
from ..compute.timing import timing_figures
from ..config import RunConfig
from ..observe.report import (
    CPU_KEYS,
    RESULT_KEYS,
    build_report,
    command_digest,
    error_stats,
    overload_figures,
    tracking_errors,
)
from . import result_record as record
from .plot_data import commands
from .reader import Recording
from .recorded_config import run_config
from .replay import recorded_inputs, stride_grid


def report_from_recording(rec: Recording) -> dict[str, Any]:
    """The run's report rebuilt from the recording alone (same numbers as the live one).

    ``t_1`` comes from the run's result record; if the run died before writing it, it is
    measured again here on the recorded intervals.
    """
    rc = run_config(rec)
    setup = make_setup(rc)
    samples = {m["cycle"]: m for _, m in rec.decoded("/central/sample")}
    sent = commands(rec, samples)
    cmd_ns, sample_ns, tau = sent["cmd_ns"], sent["sample_ns"], sent["tau"]
    true_p: dict[int, tuple[float, float, float]] = {}
    for k, s in samples.items():
        if "p" in s and k < setup.cycles:  # as live: the run's samples only
            p = s["p"]
            true_p[k] = (p[0], p[1], p[2])
    result = rec.metadata.get("ctrlunit.result", {})
    busy = record.busy(result, setup.placement.peripherals)
    t0, t1_ns = record.ns(result, "t_start_ns"), record.ns(result, "t_end_ns")
    wall = max(1, t1_ns - t0) if t0 else max(1, (cmd_ns[-1] - cmd_ns[0]) if cmd_ns else 1)
    n = setup.placement.peripherals
    if busy:
        business = {"central": max(0.0, 1.0 - busy["central_wait_ns"] / wall)}
        for k in range(n):
            business[f"peripheral_{k + 1}"] = busy["periph_busy_ns"][k] / wall
        if rc.schedule.clock != "freerun":
            business["plant"] = busy["plant_busy_ns"] / wall
    else:  # from the spans: a role's busy time; the central's are its blocks alone, not
        acc: dict[str, int] = {}  # its busy time (messaging, bookkeeping): left out
        for _, m in rec.decoded("/timing/spans"):
            for proc, a, b in m["spans"]:
                acc[proc] = acc.get(proc, 0) + (b - a)
        business = {k: v / wall for k, v in sorted(acc.items()) if k != "central"}
    deadline = rec.decoded("/faults/deadline")
    misses = deadline[-1][1]["deadline_misses"] if deadline else 0
    skipped = deadline[-1][1]["skipped_samples"] if deadline else 0
    rejected = record.rejected(result)
    if not rejected:
        rej = rec.decoded("/faults/rejected")
        rejected = rej[-1][1] if rej else {}
    t1 = record.t1(result)
    per_block = record.block_costs(result, {b.name for b in setup.plan.graph.blocks})
    if not math.isfinite(t1):
        t1, per_block = measure_t1(lambda: setup.engine(peripherals_plan=False),
                                   recorded_inputs(rec, setup)[: rc.run.t1_cycles])
    fault = record.fault(result.get("fault"))
    if rec.salvaged:
        fault = fault or {"process": "recording", "message": rec.note, "code": None}
    task = setup.task
    rep = build_report(
        rc=rc, plan=setup.plan, task=task, timing=timing_figures(cmd_ns, sample_ns),
        digest=command_digest(tau),
        torque_max=max((abs(x) for x in tau), default=math.nan),
        tracking=error_stats(tracking_errors(task, rc.schedule.period, true_p)), business=business,
        deadline_misses=misses,
        skipped=skipped, rejected=rejected, t1_s=t1, per_block_s=per_block, fault=fault,
        wall_s=wall / 1e9,
    )
    cpu = record.cpu(result)  # per process: only the run knew
    rep.update({k: cpu.get(k) for k in CPU_KEYS if k in cpu})
    _live_facts(rep, rec, rc, cpu_known=bool(cpu))
    grid = stride_grid(rec)
    last = max((m["cycle"] for _, m in rec.decoded("/plant/command")), default=-1)
    rep["periods"] = last + grid.hold_of(last) if last >= 0 else 0
    changes = [{"from_cycle": m.get("start"), **{k: v for k, v in m.items() if k not in (
        "v", "unit", "cycle", "stage", "start")}}
        for _, m in rec.decoded("/plant/control") if m.get("stage") == "stride"
        and type(m.get("start")) is int and m.get("stride") in (1, 2)]
    rep["overload"] = overload_figures(changes, rc.halves_on_overload, grid,
                                       end=rep["periods"])
    if not rep.get("fault") and rep["periods"] < setup.cycles:  # a whole file, cut inside
        rep["fault"] = {"process": "recording", "code": None, "message": (
            f"it holds intervals up to period {rep['periods']} of the {setup.cycles} "
            "planned and no fault: the rest is missing")}
    return rep


def _live_facts(rep: dict[str, Any], rec: Recording, rc: RunConfig, *, cpu_known: bool
                ) -> None:
    """Into ``rep``: what only the live run knew (:data:`RESULT_KEYS`), from the result
    record; without it (a recording cut off before the end, or made before ctrlunit kept
    them), ``not_recorded``: the summary lines this run would have had that the file
    cannot give, and why."""
    result = rec.metadata.get("ctrlunit.result")
    live = record.live(result or {}, RESULT_KEYS)
    if live is not None:
        rep.update(live)
        return
    rep.pop("link_list", None)  # the configuration's links, without the central's endpoint
    sch, n = rc.schedule, rep["peripherals"]
    relevant = {
        "exchanges_per_interval": n > 0, "replies": n > 0,
        "late": sch.clock == "realtime", "late_intervals": sch.clock == "realtime" and n > 0,
        "idle": sch.clock == "realtime" or sch.idle == "poll",
        "admission": sch.clock == "realtime" and sch.admission,
        "scheduling_fallback": sch.clock == "realtime",
        "placement_choice": sch.placement_auto and n > 0,
        "plant_spares": sch.clock == "realtime", "silences_excused": sch.clock == "realtime",
        "host_stolen_s": sch.clock == "realtime",
        "safe_stop": bool(rep.get("fault")) and sch.clock != "freerun",
        "links": False,  # the weakest protection: the configuration's, rebuilt
    }
    lines = [] if cpu_known else ["CPU / interval"]
    for key, line in RESULT_KEYS.items():
        if relevant.get(key, True) and line not in lines:
            lines.append(line)
    why = ("the recording was cut off before the run's end, where they are written"
           if rec.salvaged else "the recording holds no result record, which a run writes "
           "at its end" if result is None else
           "the recording was made by a ctrlunit that kept them in the live report only")
    rep["not_recorded"] = {"lines": lines, "why": why}
