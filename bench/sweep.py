"""``ctrlunit bench``: the efficiency and latency argument of the thesis, measured.

Sweeps n = 0..3 x depth 1, 2 x cost model (native, t800) in freerun, plus realtime at
chosen periods, interleaved and repeated (so that the shared machine's noise shows as
spread, not bias); measures the transport floor in the same run; compares with the 1994
figures (docs/thesis-notes.md) where one exists; writes ``report.json``, ``report.md`` and PNG
figures (efficiency and speedup against n, period and traversal distributions, Gantt
charts of each process over a few intervals at depth 1 and 2).
"""

from __future__ import annotations

import json
import random
import statistics
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from ..runtime.compute.timing import warm_intervals
from ..runtime.observe.report import gantt_window
from .floor import floor, zenoh_round_trip
from .placement import balance_stage, target_stage
from .realtime import realtime_stage, stage_steps
from .runs import (
    Config,
    cycles_for,
    json_safe,
    machine_info,
    run_one,
    summarise,
    thesis_cycles,
    thesis_pairs,
)
from .thesis import THESIS, THESIS_SCALE, thesis_stage

STAGES = ("floor", "sweep", "recording", "thesis", "balance", "target", "realtime")
"""The bench's stages, in the order they run (``ctrlunit bench --stages``)."""

def plan_configs(*, quick: bool, realtime_periods: list[float], scale: float,
                 stages: tuple[str, ...] = STAGES) -> list[Config]:
    """The configurations run shuffled in each repeat: the sweep's and the recording's
    (the thesis stage runs its own alternated pairs, :mod:`.thesis`). The balance stage
    starts from the sweep's n = 3 native runs: they are planned for it alone too."""
    del quick, scale  # the same configurations in a quick bench
    out = []
    if "sweep" in stages:
        for n in (0, 1, 2, 3):
            for d in (1, 2):
                for cm in ("native", "t800"):
                    out.append(Config(n, d, cm))
        for per in realtime_periods:
            for d in (1, 2):
                out.append(Config(3, d, "native", "realtime", per, tag="realtime"))
    elif "balance" in stages:
        out += [Config(3, d, "native") for d in (1, 2)]
    if "recording" in stages:
        # what recording costs: the same freerun configuration without --record, and with
        # it uncompressed and compressed (the default)
        for rec in (None, "none", "zstd"):
            out.append(Config(3, 2, "native", tag="record", record=rec))
        # what the live view costs, with a viewer connected and reading
        out.append(Config(3, 2, "native", tag="live", foxglove=True))
    return out


def _sweep(configs: list[Config], repeats: int, *, quick: bool, out: Path,
           results: dict[str, list[dict]], samples: dict[str, dict[str, list[float]]],
           progress: Callable[[str, int, int], None] | None, done: int, total: int) -> int:
    """Run every configuration ``repeats`` times, shuffled in each repeat (no
    configuration always runs first or last), into ``results``; the first repeat's
    periods and traversals into ``samples`` (the distributions' figures). Returns the
    steps done."""
    rng = random.Random(1994)
    for rep_i in range(repeats if configs else 0):
        order = list(configs)
        rng.shuffle(order)
        for cfg in order:
            if progress:
                progress(cfg.key, done, total)
            rep, central = run_one(cfg, cycles_for(cfg, quick)
                                   * (3 if cfg.tag in ("record", "live") else 1), out)
            results[cfg.key].append(rep)
            done += 1
            if central is not None and rep_i == 0:
                times = central.snapshot().times
                c = np.asarray(times.cmd_ns, dtype=np.int64)
                s = np.asarray(times.sample_ns, dtype=np.int64)
                warm = warm_intervals(len(c))
                samples[cfg.key] = {"period_s": (np.diff(c[warm:]) / 1e9).tolist(),
                                    "traversal_s": ((c[warm:] - s[warm:]) / 1e9).tolist()}
    return done


REFERENCE_ROUND_S = 172e-6
"""The unit's own floor on the reference host: one scatter/gather round of 3 over Zenoh,
p50 (docs/message-costs.md: 168-176 us)."""


def host_scale(scale: float, *, rounds: int = 400) -> tuple[float, dict[str, float]]:
    """The thesis runs' T-800 cost scale on this host: ``scale`` times this host's round
    (measured now, :func:`.floor.zenoh_round_trip`, p50) over :data:`REFERENCE_ROUND_S`,
    kept within 1 to 4 times ``scale``. The scale makes arithmetic outweigh an exchange as
    it did on the Transputers (bench/thesis.py); on a slower host an exchange costs more,
    and a fixed scale would lower the efficiencies for the host's sake, not the code's
    (docs/measurements/2026-11-27-observers.md). Returns the scale and what it came from."""
    rtt = statistics.median(zenoh_round_trip(3, rounds=rounds, warmup=100))
    factor = min(4.0, max(1.0, rtt / REFERENCE_ROUND_S))
    return scale * factor, {"round_s": rtt, "reference_round_s": REFERENCE_ROUND_S,
                            "scale": scale * factor}


def bench(out_dir: str | Path, *, stages: tuple[str, ...] = STAGES, quick: bool = False,
          repeats: int | None = None, realtime_periods: list[float] | None = None,
          scale: float = THESIS_SCALE, realtime_runs: int | None = None,
          realtime_long_s: float | None = None,
          progress: Callable[[str, int, int], None] | None = None) -> dict[str, Any]:
    """Run the ``stages`` asked (:data:`STAGES`) and write the reports into ``out_dir``.

    ``realtime_runs`` main-job runs (default 20; 2 with ``quick``) and a
    ``realtime_long_s`` run (default 60 s; none with ``quick``) make the realtime stage
    (:mod:`.realtime`); the thesis stage's guarded figures are in ``report["thesis"]``."""
    unknown = [s for s in stages if s not in STAGES]
    if unknown:
        raise ValueError(f"stages {unknown}: allowed {', '.join(STAGES)}")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    realtime_periods = realtime_periods if realtime_periods is not None else [3e-3]
    repeats = repeats or (1 if quick else 3)
    configs = plan_configs(quick=quick, realtime_periods=realtime_periods, scale=scale,
                           stages=stages)
    results: dict[str, list[dict]] = {c.key: [] for c in configs}
    samples: dict[str, dict[str, list[float]]] = {}
    gantt: dict[str, list] = {}
    rt_runs = realtime_runs if realtime_runs is not None else (2 if quick else 20)
    rt_long = realtime_long_s if realtime_long_s is not None else (0.0 if quick else 60.0)
    pairs = thesis_pairs(quick, repeats)
    steps = {"floor": 1, "sweep": 0, "recording": 0, "thesis": 3 * pairs,
             "balance": 2 * 2 * repeats, "target": 4 * repeats,
             "realtime": stage_steps(rt_runs, rt_long, fixed_runs=1 if quick else None)}
    total = len(configs) * repeats + sum(steps[s] for s in stages)
    done = 0
    t_start = time.monotonic()
    report: dict[str, Any] = {"machine": machine_info(), "stages": list(stages),
                              "thesis_1994": THESIS, "quick": quick, "repeats": repeats,
                              "cost_scale_thesis_runs": scale}
    if "floor" in stages:
        if progress:
            progress("floor (pipes and Zenoh)", done, total)
        report["floor"] = floor((1, 2, 3), rounds=500 if quick else 3000,
                                paced_rounds=300 if quick else 3000)
        done += 1
    done = _sweep(configs, repeats, quick=quick, out=out, results=results, samples=samples,
                  progress=progress, done=done, total=total)
    report["runs"] = [summarise(results[c.key], c) for c in configs]
    if "thesis" in stages:
        scale, report["thesis_host"] = host_scale(scale)
        report["cost_scale_thesis_runs"] = scale
        th = thesis_stage(scale=scale, repeats=pairs, cycles=thesis_cycles(quick),
                          run=lambda cfg, n: _run_kept(cfg, n, out, gantt), config=Config,
                          progress=progress, done=done, total=total)
        done += 3 * pairs
        report["runs"] += [summarise(th["reports"][c.key], c)
                           for c in _thesis_configs(scale)]
        report["thesis"] = {k: v for k, v in th.items() if k != "reports"}
    if "balance" in stages:
        report["balance"] = balance_stage(results, configs, out, quick=quick,
                                           repeats=repeats, progress=progress, done=done,
                                           total=total)
        done += 2 * 2 * repeats
    if "target" in stages:
        report["target"] = target_stage(out, quick=quick, repeats=repeats,
                                         progress=progress, done=done, total=total)
        done += 4 * repeats
    if "realtime" in stages:
        report["realtime"] = realtime_stage(runs=rt_runs, long_s=rt_long, progress=progress,
                                            done=done, total=total,
                                            fixed_runs=1 if quick else None)
    if "recording" in stages:
        report["recording_cost"] = _recording_cost(report["runs"], configs, results)
    report["wall_s"] = time.monotonic() - t_start
    report["method"] = METHOD
    from .figures import write_figures
    from .markdown import write_markdown

    report["figures"] = write_figures(out, report, samples, gantt)
    (out / "report.json").write_text(json.dumps(json_safe(report), indent=2))
    write_markdown(out / "report.md", report)
    return report


METHOD = {
    "interleaving": "the sweep's and the recording's configurations shuffled anew for each "
                    "repeat; figures are medians over repeats with the min..max spread of "
                    "efficiency; the thesis stage alternates its configurations in pairs",
    "t800": "each block computes its real result and the process then owes the block's "
            "1994 T-800 time (per axis for per-axis blocks); before sending it sleeps until "
            "twice its mean sleep overshoot (50 us to 1 ms) before the debt is paid and "
            "spins the rest",
    "efficiency": "Eq. IV.23: t_1 / (t_parallel x N), N = processors taking part (central "
                  "included); t_parallel = traversal p50 at depth 1, mean period at depth 2; in "
                  "realtime, whose clock imposes the period, the traversal p50",
    "balance": "ctrlunit balance on the first n = 3 native freerun run of each depth "
               "recommends a placement; it is re-run alternately with the default one; its "
               "predicted period, from the model calibrated again on the median default "
               "re-run, against the measured mean period",
}


def _thesis_configs(scale: float) -> list[Config]:
    from .thesis import pair_configs

    return pair_configs(scale, Config)


def _run_kept(cfg: Config, cycles: int, out: Path,
              gantt: dict[str, list]) -> tuple[dict[str, Any], Any]:
    """:func:`run_one`, keeping the first Gantt window of the whole cycle at each depth."""
    rep, central = run_one(cfg, cycles, out)
    key = f"depth {cfg.pipeline}"
    if central is not None and cfg.law != "kinematics" and key not in gantt:
        gantt[key] = gantt_window(list(central.snapshot().times.spans))
    return rep, central


def _recording_cost(runs: list[dict[str, Any]], configs: list[Config],
                    results: dict[str, list[dict]]) -> dict[str, Any]:
    """What recording and the live view cost: the recording stage's runs against the same
    configuration not recorded."""
    recorded = {c.record: (r, results[c.key]) for r, c in zip(runs, configs)
                if c.tag == "record"}
    rec_off = recorded[None][0]
    cost: dict[str, Any] = {
        "period_p50_without_s": rec_off["period_s"]["p50"],
        "config": "freerun, n = 3, depth 2, native; interleaved with the sweep",
        "compressions": {
            comp: {"period_p50_with_s": r["period_s"]["p50"],
                   "ratio": r["period_s"]["p50"] / rec_off["period_s"]["p50"],
                   "bytes_per_interval": statistics.median(
                       x["record_bytes_per_interval"] for x in reps
                       if "record_bytes_per_interval" in x)}
            for comp, (r, reps) in recorded.items() if comp is not None},
    }
    live = [(r, results[c.key]) for r, c in zip(runs, configs) if c.tag == "live"]
    if live:
        r, reps = live[0]
        cost["live_view"] = {
            "period_p50_with_s": r["period_s"]["p50"],
            "ratio": r["period_s"]["p50"] / rec_off["period_s"]["p50"],
            "viewer_messages": statistics.median(x.get("viewer_messages", 0) for x in reps),
            "cycles": statistics.median(x.get("cycles", 0) for x in reps)}
    # the default (zstd) stands for "with --record"
    cost["period_p50_with_s"] = cost["compressions"]["zstd"]["period_p50_with_s"]
    cost["ratio"] = cost["compressions"]["zstd"]["ratio"]
    return cost
