"""One bench run and what the bench's stages share: the configuration of a run
(:class:`Config`), its length, the run itself through ``ctrlunit start``'s launcher, and
the median of repeated runs (:func:`summarise`)."""

from __future__ import annotations

import math
import os
import platform
import random
import statistics
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..runtime.config import RunConfig
from ..runtime.launch.launcher import start
from ..runtime.roles.stopping import raise_if_stopped


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


def thesis_cycles(quick: bool) -> int:
    """Intervals of each thesis run: at T-800 x 60 an interval takes 25-100 ms."""
    return 24 if quick else 60


def thesis_pairs(quick: bool, repeats: int | None) -> int:
    """Alternated pairs of the thesis stage: at least three, so that its figures are
    medians no single slow pair decides (of two, the median is their mean: beside the
    test suite one slow pair failed 4 of 10 quick stages, docs/measurements/
    2026-11-27-newcomer.md)."""
    return max(3, repeats or 3)


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

    def med(path: Callable[[dict], Any]) -> float:
        vals = [path(r) for r in ok if path(r) is not None and math.isfinite(path(r))]
        return statistics.median(vals) if vals else math.nan

    def spread(path: Callable[[dict], Any]) -> list[float]:
        vals = [path(r) for r in ok if path(r) is not None and math.isfinite(path(r))]
        return [min(vals), max(vals)] if vals else [math.nan, math.nan]

    def at(name: str, key: str, default: Any = None) -> Callable[[dict], Any]:
        """The figure ``r[name][key]`` of a run's report ``r`` (``default`` if absent,
        where one is given)."""
        if default is None:
            return lambda r: r[name][key]
        return lambda r: r[name].get(key, default)

    first = ok[0] if ok else {}
    busy_keys = first.get("business", {}).keys()
    return {
        "peripherals": cfg.peripherals, "pipeline": cfg.pipeline,
        "cost_model": cfg.cost_model, "cost_scale": cfg.cost_scale, "clock": cfg.clock,
        "law": cfg.law, "tag": cfg.tag, "nominal_period_s": cfg.period,
        "processors": first.get("processors"), "round_trips": first.get("round_trips"),
        "repeats": len(ok),
        "period_s": {k: med(at("period_s", k)) for k in ("p50", "p99", "max")},
        "period_mean_s": med(lambda r: r.get("period_mean_s", math.nan)),
        "traversal_s": {k: med(at("traversal_s", k)) for k in ("p50", "p99", "max")},
        "t1_s": med(lambda r: r["t1_s"]),
        "efficiency": med(lambda r: r["efficiency"]),
        "efficiency_spread": spread(lambda r: r["efficiency"]),
        "speedup": med(lambda r: r["speedup"]),
        "deadline_misses": med(lambda r: r["deadline_misses"]),
        "business": {k: med(at("business", k, math.nan)) for k in busy_keys},
        "cpu_per_interval_s": med(lambda r: (r.get("cpu_per_interval_s") or {}).get("total")),
        "cpu_bound_period_s": med(lambda r: r.get("cpu_bound_period_s")),
        "t_s_model_s": med(lambda r: r["t_s_model_s"]),
        "t_p_model_s": med(lambda r: r["t_p_model_s"]),
        "tracking_error_m": {"max": med(lambda r: r["tracking_error_m"]["max"])},
        "cost_model_error_s": first.get("cost_model_error_s"),
        "exit_codes": [r.get("exit_code") for r in reps],
    }


def json_safe(x: Any) -> Any:
    """``x`` as JSON can hold it: keys as text, numpy scalars as numbers, NaN and
    infinities as null."""
    if isinstance(x, dict):
        return {str(k): json_safe(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [json_safe(v) for v in x]
    if isinstance(x, float) and not math.isfinite(x):
        return None
    if isinstance(x, np.generic):
        return json_safe(x.item())
    return x


__all__ = ["Config", "cycles_for", "json_safe", "machine_info", "run_one", "summarise",
           "thesis_cycles", "thesis_pairs"]
