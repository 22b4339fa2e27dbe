"""The sections of a run's configuration, each frozen: what the unit computes, how it is
scheduled, the plant's options, the transport, and the run's length and outputs.

A :class:`~ctrlunit.runtime.config.RunConfig` holds one of each; it is built and validated
once from the options of ``ctrlunit start`` (their flat names, e.g. ``--plant-lag`` is
``plant.lag``) and never changed: a derived configuration (``--period auto``, a replay) is
a new one. Every role derives its plan and engine from ``control`` and ``schedule``;
beyond that the peripheral reads ``transport`` and ``run.trace``, the plant ``plant``,
``schedule`` (clock, period, delay) and ``transport``; the central every section.
"""

from __future__ import annotations

import secrets
from dataclasses import dataclass, field


@dataclass(frozen=True)
class ControlConfig:
    """What the unit computes: the task, the law and its model (Ch. V, § IV.7), the
    robot's parameters and the cost model of the blocks."""

    task: str = "pick-place"
    law: str = "resolved-acceleration"
    model: str = "complete"
    observer: str = "predict"
    model_state: str = "auto"
    """Where resolved acceleration evaluates its model (topology/graph.py, MODEL_STATES),
    or ``auto`` (config.RunConfig.resolved_model_state)."""
    bandwidth_hz: float | None = None
    params: str | None = None
    max_error: float = 0.02
    cost_model: str = "native"
    cost_scale: float = 1.0


@dataclass(frozen=True)
class ScheduleConfig:
    """How the work is spread and timed: peripherals, pipeline depth, clock and period,
    placement, the pipeline's rules (topology/pipeline.py), late data, admission, and the
    operating system's scheduling of the processes."""

    peripherals: int = 3
    pipeline: int = 1
    clock: str = "realtime"
    period: float = 1e-3
    period_auto: bool = False
    """``--period auto``: realtime runs at the shortest period of the admission ladder that
    holds (runtime/launch/admission.py); ``period`` is where the ladder starts."""
    command_delay: str = "full"
    """When the plant applies a command (config.COMMAND_DELAYS)."""
    placement: str | None = None
    """A placement file (``--placement FILE``); None: the placement of
    ``central_blocks``."""
    placement_auto: bool = False
    """``--placement auto``: the warm-up chooses which rounds the central runs itself
    (topology/balance.py, ``auto_central_blocks``); the central then tells the
    peripherals (a ``place`` order) and runs with them in ``central_blocks``."""
    central_blocks: list[str] | None = None
    """Per-axis blocks the central runs for every axis, with the default spread of the axes
    (the placement's ``central_blocks``); None: none, or not chosen yet (auto)."""
    replies: str = "auto"
    hold_rounds: str = "auto"
    """``--hold-rounds`` (topology/pipeline.py, ``HOLD_RULES``)."""
    late_policy: str = "compute"
    """``--late-policy`` (config.LATE_POLICIES)."""
    missed_command: str = "extrapolate"
    """``--missed-command`` (config.MISSED_COMMANDS)."""
    late: dict[str, str] = field(default_factory=dict)
    fault_periods: float = 3.0
    overload: str = "auto"
    """``--overload`` (config.OVERLOAD_ACTIONS)."""
    admission: bool = True
    """Realtime: run the admission trial before the first command (runtime/launch/admission.py)."""
    trial_only: bool = False
    """Run the admission trial and stop before the first command (``ctrlunit latency
    --unit``)."""
    rt_priority: int | str = "auto"
    """``--rt-priority``: ``auto`` (runtime/host/sched.py, ``choose``), 0 or a FIFO priority."""
    idle: str = "auto"
    """``--idle``: whether idle CPUs poll during the run (runtime/host/idle.py, ``choose``)."""
    pin: str | None = None
    cpus: str | None = None


@dataclass(frozen=True)
class PlantOptions:
    """The simulated robot's options (plant/simulator.py)."""

    substeps: int | None = None
    lag: float = 0.0
    friction: float = 0.0
    belt: bool = False


@dataclass(frozen=True)
class TransportConfig:
    """The unit's Zenoh session: its id, endpoints and time-outs."""

    unit: str = field(default_factory=lambda: "u" + secrets.token_hex(4))
    listen: list[str] | None = None
    connect: list[str] | None = None
    zenoh_config: str | None = None
    keys: str | None = None
    """``--keys DIR``: the unit's credentials (runtime/transport/security.py): every link but the
    local socket is mutual TLS, and access control holds each role to its keys."""
    insecure: bool = False
    """``--insecure``: allow links beyond the host without keys (a lab bench)."""
    timeout: float = 2.0
    startup_timeout: float = 30.0


@dataclass(frozen=True)
class RunOptions:
    """How long the run lasts and what it writes."""

    cycles: int | None = None
    duration: float | None = None
    t1_cycles: int = 500
    record: str | None = None
    record_compression: str = "zstd"
    """Chunk compression of ``--record`` (runtime/recording/mcap_writer.py, ``COMPRESSIONS``)."""
    trace: bool = False
    report: str | None = None
    progress: bool = False
    status_file: str | None = None
    foxglove: str | None = None
    """``[HOST:]PORT`` of the live view's Foxglove WebSocket server (runtime/observe/viewer.py)."""
    foxglove_rate: float = 200.0
    """``/signals/state`` messages per second of the live view (0: every interval)."""


SECTIONS: dict[str, type] = {"control": ControlConfig, "schedule": ScheduleConfig,
                             "plant": PlantOptions, "transport": TransportConfig,
                             "run": RunOptions}
"""The sections of a RunConfig, by attribute name."""

RENAMED = {"plant_substeps": "substeps", "plant_lag": "lag", "plant_friction": "friction"}
"""Options whose flat name (``--plant-lag``) differs from their field in the section."""


__all__ = [
    "RENAMED",
    "SECTIONS",
    "ControlConfig",
    "PlantOptions",
    "RunOptions",
    "ScheduleConfig",
    "TransportConfig",
]
