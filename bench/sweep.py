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
import math
import os
import platform
import random
import statistics
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..runtime.config import RunConfig
from ..runtime.launcher import start
from ..runtime.report import gantt_window
from ..runtime.sched import fifo_permitted
from ..runtime.stopping import raise_if_stopped
from ..runtime.timing import warm_intervals
from .floor import floor
from .realtime import realtime_stage, stage_steps
from .thesis import THESIS, thesis_stage

STAGES = ("floor", "sweep", "recording", "thesis", "balance", "target", "realtime")
"""The bench's stages, in the order they run (``ctrlunit bench --stages``)."""

@dataclass
class Config:
    peripherals: int
    pipeline: int
    cost_model: str
    clock: str = "freerun"
    period: float = 1e-3
    cost_scale: float = 1.0
    law: str = "resolved-acceleration"
    tag: str = "sweep"
    record: str | None = None  # --record-compression of a recorded run; None: not recorded
    placement: str | None = None  # a placement file (the balance stage)
    rt_priority: int = 0  # SCHED_FIFO for every role (the target stage)
    foxglove: bool = False  # --foxglove, with a viewer reading everything
    model_state: str = "acting"  # sample: the thesis's graph (no block ``ahead``)

    @property
    def key(self) -> str:
        return (f"{self.tag}:{self.law}:n{self.peripherals}:d{self.pipeline}:"
                f"{self.cost_model}x{self.cost_scale:g}:{self.clock}:{self.period:g}"
                f"{f':record-{self.record}' if self.record else ''}"
                f"{':placed' if self.placement else ''}"
                f"{f':fifo{self.rt_priority}' if self.rt_priority else ''}"
                f"{':foxglove' if self.foxglove else ''}"
                f"{f':model-{self.model_state}' if self.model_state != 'acting' else ''}")


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


def thesis_cycles(quick: bool) -> int:
    """Intervals of each thesis run: at T-800 x 30 an interval takes 12-50 ms."""
    return 40 if quick else 80


def thesis_pairs(quick: bool, repeats: int | None) -> int:
    """Alternated pairs of the thesis stage: at least two, so that its figures are medians
    no single slow run decides."""
    return max(2, repeats or (2 if quick else 3))


def cycles_for(cfg: Config, quick: bool) -> int:
    if cfg.clock == "realtime":
        return 300 if quick else 1500
    if cfg.cost_model == "t800":
        per = 1.6e-3 * cfg.cost_scale
        budget = 0.5 if quick else 3.0
        return int(min(1500, max(20 if quick else 40, budget / per)))
    return 300 if quick else 2000


def run_one(cfg: Config, cycles: int, tmp: Path | None = None) -> tuple[dict[str, Any], Any]:
    record = str(tmp / f"rec-{random.randrange(1 << 30)}.mcap") if cfg.record and tmp else None
    rc = RunConfig.of(record=record, record_compression=cfg.record or "zstd",
                   peripherals=cfg.peripherals, pipeline=cfg.pipeline,
                   clock=cfg.clock,
                   period=cfg.period, cost_model=cfg.cost_model, cost_scale=cfg.cost_scale,
                   law=cfg.law, cycles=cycles, max_error=1.0, t1_cycles=200,
                   placement=cfg.placement, rt_priority=cfg.rt_priority,
                   model_state=cfg.model_state,
                   unit=f"bench-{os.getpid()}-{random.randrange(1 << 30)}")
    viewer = None
    if cfg.foxglove:
        from .viewer_client import ViewerClient

        port = _free_port()
        rc = rc.replace(foxglove=f"127.0.0.1:{port}")
        viewer = ViewerClient(port)
    inspect: dict[str, Any] = {}
    try:
        code, rep = start(rc, echo=lambda m: None, inspect=inspect)
        raise_if_stopped(code, rep)  # Ctrl-C or a stop signal ends the bench, not one run
    finally:
        if viewer is not None:
            viewer.stop()
    rep["exit_code"] = code
    if viewer is not None:
        rep["viewer_messages"] = viewer.messages
        rep["viewer_error"] = viewer.error
    if record:
        rep["record_bytes_per_interval"] = Path(record).stat().st_size / cycles
        Path(record).unlink(missing_ok=True)
    return rep, inspect.get("central")


def _free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _balance_stage(results: dict[str, list[dict]], configs: list[Config], out: Path, *,
                   quick: bool, repeats: int, progress: Callable[[str, int, int], None] | None,
                   done: int, total: int) -> dict[str, Any]:
    """§ IV.7.2 in the report: balance's recommendation for n = 3 (native, freerun, depth 1
    and 2), re-run against the default placement alternately, predicted against measured
    (the model calibrated on the thesis's depth-1 t800 run is judged in :mod:`.thesis`).

    The placement comes from the sweep's run; the prediction it is judged by comes from the
    model calibrated again on the median default-placement re-run, made alternately with
    the balanced ones, so that both sides of the comparison see the same machine (this
    VM's speed drifts by up to 2x between the sweep and the re-runs)."""
    from ..topology.balance import (
        analyse,
        asked_replies,
        calibrate,
        placement_of,
        predict,
        write_placement,
    )

    stage: dict[str, Any] = {"native": []}
    for d in (1, 2):
        base = next(c for c in configs if c.tag == "sweep" and c.peripherals == 3
                    and c.pipeline == d and c.cost_model == "native")
        first = results[base.key][0]
        a = analyse(first)
        path = out / f"placement-depth{d}.json"
        write_placement(a, path)
        # the placement says how many peripherals it needs (balance may group them)
        placed = Config(int(a["placement"]["peripherals"]), d, "native", tag="balance",
                        placement=str(path))
        before_cfg = Config(3, d, "native", tag="balance")
        before, after = [], []
        for _ in range(repeats):
            for cfg, acc in ((before_cfg, before), (placed, after)):
                if progress:
                    progress(cfg.key, done, total)
                rep, _central = run_one(cfg, cycles_for(cfg, quick), out)
                acc.append(rep)
                done += 1
        ok_b = sorted((r for r in before if r.get("exit_code") == 0),
                      key=lambda r: r["period_mean_s"])
        ok_a = sorted((r for r in after if r.get("exit_code") == 0),
                      key=lambda r: r["period_mean_s"])
        entry: dict[str, Any] = {"depth": d, "recommendations": a["recommendations"],
                                 "placement": a["placement"],
                                 "predicted_from_sweep_s": a["predicted"][f"depth{d}"]["period_s"],
                                 "predicted_period_s": math.nan,  # from the re-runs, below
                                 "model_now_s": a["current"][f"depth{d}"]["period_s"]}
        if ok_b and ok_a:
            mid_b, mid = ok_b[len(ok_b) // 2], ok_a[len(ok_a) // 2]
            graph, costs, _cal = calibrate(mid_b)
            pred = predict(graph, placement_of(a), costs, depth=d,
                           replies=asked_replies(mid_b))[0].period_mean_s
            before_s = statistics.median(r["period_mean_s"] for r in ok_b)
            after_s = mid["period_mean_s"]
            entry.update(predicted_period_s=pred, measured_before_s=before_s,
                         measured_after_s=after_s, error=after_s / pred - 1.0,
                         gain=1.0 - after_s / before_s)
            if d == 2:
                stage["gantt"] = {
                    "n = 3, depth 2, default placement (measured)": first.get("gantt_ms") or [],
                    "balance's placement (predicted)": a["predicted"]["gantt_ms"],
                    "balance's placement, re-run (measured)": mid.get("gantt_ms") or []}
        stage["native"].append(entry)
    return stage


TARGET_PERIOD_S = 0.5e-3
"""Issue 4's benchmark target: the freerun period at n = 3, depth 2."""
TARGET_RT_PRIORITY = 10


def _target_stage(out: Path, *, quick: bool, repeats: int,
                  progress: Callable[[str, int, int], None] | None, done: int,
                  total: int) -> dict[str, Any]:
    """The freerun period at n = 3, depth 2 against the 0.5 ms target: the default
    placement and balance's depth-2 placement, each under the default scheduling policy
    and under SCHED_FIFO for every role (``--rt-priority``), run one after the other in
    each repeat so that the four see the same machine."""
    placement = out / "placement-depth2.json"
    permitted = fifo_permitted()
    variants = []
    for placed in [None] + ([str(placement)] if placement.exists() else []):
        n = int(json.loads(placement.read_text())["peripherals"]) if placed else 3
        for rt in (0, TARGET_RT_PRIORITY) if permitted else (0,):
            variants.append(Config(n, 2, "native", tag="target", placement=placed,
                                   rt_priority=rt))
    runs: dict[str, list[dict]] = {v.key: [] for v in variants}
    for _ in range(repeats):
        for cfg in variants:
            if progress:
                progress(cfg.key, done, total)
            rep, _central = run_one(cfg, cycles_for(cfg, quick) * 3, out)
            runs[cfg.key].append(rep)
            done += 1
    rows = []
    for cfg in variants:
        ok = [r for r in runs[cfg.key] if r.get("exit_code") == 0]
        means = [r["period_mean_s"] for r in ok]
        cpu = [(r.get("cpu_per_interval_s") or {}).get("total") for r in ok]
        cpu = [c for c in cpu if c]
        rows.append({
            "placement": "balance's (depth 2)" if cfg.placement else "default",
            "scheduling": f"SCHED_FIFO {cfg.rt_priority}" if cfg.rt_priority else "default",
            "period_mean_s": statistics.median(means) if means else math.nan,
            "period_mean_spread_s": [min(means), max(means)] if means else [],
            "cpu_per_interval_s": statistics.median(cpu) if cpu else math.nan,
            "exchanges_per_interval": ok[0].get("exchanges_per_interval") if ok else None,
            "runs": len(runs[cfg.key]), "ok": len(ok)})
    return {"target_s": TARGET_PERIOD_S, "fifo_permitted": permitted,
            "config": "freerun, n = 3, depth 2, native; the variants alternate in each "
                      "repeat", "variants": rows}


def machine_info() -> dict[str, Any]:
    import zenoh

    return {
        "host": platform.node(), "platform": platform.platform(),
        "python": platform.python_version(), "cores": os.cpu_count(),
        "zenoh": getattr(zenoh, "__version__", "1.x"),
        "affinity": sorted(os.sched_getaffinity(0)),
    }


def summarise(reps: list[dict[str, Any]], cfg: Config) -> dict[str, Any]:
    """Median over repeats, with the spread (min..max) of the key figures."""
    ok = [r for r in reps if "period_s" in r]

    def med(path: Callable[[dict], float]) -> float:
        vals = [path(r) for r in ok if path(r) is not None and math.isfinite(path(r))]
        return statistics.median(vals) if vals else math.nan

    def spread(path: Callable[[dict], float]) -> list[float]:
        vals = [path(r) for r in ok if path(r) is not None and math.isfinite(path(r))]
        return [min(vals), max(vals)] if vals else [math.nan, math.nan]

    first = ok[0] if ok else {}
    busy_keys = first.get("business", {}).keys()
    return {
        "peripherals": cfg.peripherals, "pipeline": cfg.pipeline,
        "cost_model": cfg.cost_model, "cost_scale": cfg.cost_scale, "clock": cfg.clock,
        "law": cfg.law, "tag": cfg.tag, "nominal_period_s": cfg.period,
        "processors": first.get("processors"), "round_trips": first.get("round_trips"),
        "repeats": len(ok),
        "period_s": {k: med(lambda r, k=k: r["period_s"][k]) for k in ("p50", "p99", "max")},
        "period_mean_s": med(lambda r: r.get("period_mean_s", math.nan)),
        "traversal_s": {k: med(lambda r, k=k: r["traversal_s"][k])
                        for k in ("p50", "p99", "max")},
        "t1_s": med(lambda r: r["t1_s"]),
        "efficiency": med(lambda r: r["efficiency"]),
        "efficiency_spread": spread(lambda r: r["efficiency"]),
        "speedup": med(lambda r: r["speedup"]),
        "deadline_misses": med(lambda r: r["deadline_misses"]),
        "business": {k: med(lambda r, k=k: r["business"].get(k, math.nan))
                     for k in busy_keys},
        "cpu_per_interval_s": med(lambda r: (r.get("cpu_per_interval_s") or {}).get("total")),
        "cpu_bound_period_s": med(lambda r: r.get("cpu_bound_period_s")),
        "t_s_model_s": med(lambda r: r["t_s_model_s"]),
        "t_p_model_s": med(lambda r: r["t_p_model_s"]),
        "tracking_error_m": {"max": med(lambda r: r["tracking_error_m"]["max"])},
        "cost_model_error_s": first.get("cost_model_error_s"),
        "exit_codes": [r.get("exit_code") for r in reps],
    }


def bench(out_dir: str | Path, *, stages: tuple[str, ...] = STAGES, quick: bool = False,
          repeats: int | None = None, realtime_periods: list[float] | None = None,
          scale: float = 30.0, realtime_runs: int | None = None,
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
             "realtime": stage_steps(rt_runs, rt_long)}
    total = len(configs) * repeats + sum(steps[s] for s in stages)
    done = 0
    t_start = time.monotonic()
    rng = random.Random(1994)
    report: dict[str, Any] = {"machine": machine_info(), "stages": list(stages),
                              "thesis_1994": THESIS, "quick": quick, "repeats": repeats,
                              "cost_scale_thesis_runs": scale}
    if "floor" in stages:
        if progress:
            progress("floor (pipes and Zenoh)", done, total)
        report["floor"] = floor((1, 2, 3), rounds=500 if quick else 3000,
                                paced_rounds=300 if quick else 3000)
        done += 1
    for rep_i in range(repeats if configs else 0):
        order = list(configs)
        rng.shuffle(order)  # interleave: no configuration always runs first or last
        for cfg in order:
            if progress:
                progress(cfg.key, done, total)
            rep, central = run_one(cfg, cycles_for(cfg, quick)
                                   * (3 if cfg.tag in ("record", "live") else 1), out)
            results[cfg.key].append(rep)
            done += 1
            if central is not None and rep_i == 0:
                log = central.log
                c = np.asarray(log.cmd_ns.recent, dtype=np.int64)
                s = np.asarray(log.sample_ns, dtype=np.int64)
                warm = warm_intervals(len(c))
                samples[cfg.key] = {"period_s": (np.diff(c[warm:]) / 1e9).tolist(),
                                    "traversal_s": ((c[warm:] - s[warm:]) / 1e9).tolist()}
    report["runs"] = [summarise(results[c.key], c) for c in configs]
    if "thesis" in stages:
        th = thesis_stage(scale=scale, repeats=pairs, cycles=thesis_cycles(quick),
                          run=lambda cfg, n: _run_kept(cfg, n, out, gantt), config=Config,
                          progress=progress, done=done, total=total)
        done += 3 * pairs
        report["runs"] += [summarise(th["reports"][c.key], c)
                           for c in _thesis_configs(scale)]
        report["thesis"] = {k: v for k, v in th.items() if k != "reports"}
    if "balance" in stages:
        report["balance"] = _balance_stage(results, configs, out, quick=quick,
                                           repeats=repeats, progress=progress, done=done,
                                           total=total)
        done += 2 * 2 * repeats
    if "target" in stages:
        report["target"] = _target_stage(out, quick=quick, repeats=repeats,
                                         progress=progress, done=done, total=total)
        done += 4 * repeats
    if "realtime" in stages:
        report["realtime"] = realtime_stage(runs=rt_runs, long_s=rt_long, progress=progress,
                                            done=done, total=total)
    if "recording" in stages:
        report["recording_cost"] = _recording_cost(report["runs"], configs, results)
    report["wall_s"] = time.monotonic() - t_start
    report["method"] = METHOD
    from .figures import write_figures
    from .markdown import write_markdown

    report["figures"] = write_figures(out, report, samples, gantt)
    (out / "report.json").write_text(json.dumps(_safe(report), indent=2))
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
        gantt[key] = gantt_window(central.meters.spans)
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


def _safe(x: Any) -> Any:
    if isinstance(x, dict):
        return {str(k): _safe(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [_safe(v) for v in x]
    if isinstance(x, float) and not math.isfinite(x):
        return None
    if isinstance(x, np.generic):
        return _safe(x.item())
    return x
