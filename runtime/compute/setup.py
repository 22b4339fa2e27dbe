"""Everything a role derives from the run configuration, once: the robot's parameters,
the task (refused here if it leaves the usable workspace), the placement and the exchange
plan, and the engine each role runs."""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ...kernels.laws import Gains
from ...kernels.params import DELTA_IA, DeltaParams, load_params
from ...kernels.task_file import get_task
from ...kernels.trajectory import Task
from ...kernels.workspace import require_path
from ...topology.graph import StageGraph, stage_graph
from ...topology.placement import (
    Placement,
    PlacementError,
    default_placement,
    load_placement,
    placement_from_mapping,
)
from ...topology.plan import ExchangePlan, exchange_plan
from ..config import ConfigError, RunConfig
from .blocks import BlockConfig
from .controller import Controller
from .engine import CostModel, Engine


@dataclass
class Setup:
    """Everything a role derives from the run configuration."""

    rc: RunConfig
    params: DeltaParams
    task: Task
    placement: Placement
    plan: ExchangePlan
    cycles: int

    def engine(self, *, peripherals_plan: bool = True, cost: str | None = None) -> Engine:
        plan = self.plan if peripherals_plan else exchange_plan(self.plan.graph,
                                                                default_placement(0))
        cfg = BlockConfig.build(self.params, model=self.rc.control.model,
                                gains=Gains.from_bandwidth(self.rc.bandwidth),
                                task=self.task, period=self.rc.schedule.period,
                                observer=self.rc.control.observer,
                                delay=self.rc.lead_periods)
        return Engine(plan, cfg, cost=CostModel(cost or self.rc.control.cost_model,
                                                scale=self.rc.control.cost_scale))

    def controller(self, engine: Engine) -> Controller:
        """The sources and observer state of a run of ``engine`` (the central's, replay's)."""
        return Controller(engine, self.rc.schedule.period, self.params.increment,
                          tuple(self.task.start()))

    def with_central_blocks(self, blocks: Sequence[str]) -> Setup:
        """This set-up with the per-axis blocks ``blocks`` run on the central (``--placement
        auto``'s choice at warm-up, or a central's ``place`` order): same peripherals, axes,
        task and options, the plan derived again.

        Raises
        ------
        ConfigError
            If ``blocks`` is not a list of the law's per-axis block names.
        """
        placement = _placement_of(self.plan.graph, {
            "peripherals": self.placement.peripherals,
            "axes": [list(g) for g in self.placement.axes], "central_blocks": blocks})
        return dataclasses.replace(
            self, rc=self.rc.replace(central_blocks=sorted(placement.central_blocks)),
            placement=placement, plan=exchange_plan(self.plan.graph, placement))


def _placement_of(graph: StageGraph, mapping: dict[str, Any]) -> Placement:
    """A placement from its fields (``peripherals``, ``axes``, ``central_blocks``), its
    central blocks checked against ``graph``'s per-axis blocks."""
    try:
        return placement_from_mapping(mapping, block_names={b.name for b in graph.axis_blocks},
                                      source="central_blocks")
    except PlacementError as exc:
        raise ConfigError(str(exc)) from None


def make_setup(rc: RunConfig) -> Setup:
    """Validate a run configuration and derive the plan.

    Raises
    ------
    ConfigError
        Naming the field at fault; a task outside the usable workspace is refused here,
        before any motion.
    """
    rc.validate()
    params = DELTA_IA if rc.control.params is None else load_params(rc.control.params)
    try:
        task = get_task(rc.control.task).align(rc.schedule.period / 2.0)
    except ValueError as exc:
        raise ConfigError(f"--task: {exc}") from None
    pts = np.array([task.sample_path(t)[0] for t in np.linspace(0.0, task.duration, 400)])
    try:
        require_path(params, pts, what=f"task {task.name}")
    except ValueError as exc:
        raise ConfigError(str(exc)) from None
    graph = stage_graph(rc.control.law, rc.control.model, observer=rc.control.observer,
                        model_state=rc.resolved_model_state)
    axis_blocks = sorted(b.name for b in graph.axis_blocks)
    for block in sorted(set(rc.schedule.late) - set(axis_blocks)):
        raise ConfigError(f"--late {block}={rc.schedule.late[block]}: {rc.control.law} has no "
                          f"per-axis block {block!r} (a late policy is a peripheral's round's); "
                          f"allowed: {', '.join(axis_blocks)}")
    if rc.schedule.placement:
        placement = load_placement(rc.schedule.placement,
                                   block_names={b.name for b in graph.axis_blocks})
        if placement.peripherals != rc.schedule.peripherals:
            raise ConfigError(
                f"placement {rc.schedule.placement} has {placement.peripherals} peripherals but "
                f"--peripherals is {rc.schedule.peripherals}")
    else:
        placement = _placement_of(graph, {"peripherals": rc.schedule.peripherals,
                                          "central_blocks": rc.schedule.central_blocks or []})
    plan = exchange_plan(graph, placement)
    cycles = rc.total_cycles(task.period)
    if cycles > 10**9 and rc.run.cycles is None and rc.run.duration is None:
        # one loop of a task whose accelerations are all but zero: it never ends
        raise ConfigError(f"--task {task.name}: one loop lasts {task.period:.3g} s, "
                          f"{cycles:.3g} intervals: allowed at most 1e9 (give --cycles or "
                          "--duration, or larger accelerations)")
    return Setup(rc, params, task, placement, plan, cycles)


def load_spec(path: str) -> RunConfig:
    """The run options a launcher wrote for its roles (``--spec FILE``), checked."""
    try:
        doc = json.loads(Path(path).read_text())
    except (OSError, ValueError) as exc:
        raise ConfigError(f"--spec {path}: cannot read it: {exc}") from None
    if not isinstance(doc, dict) or "run" not in doc:
        raise ConfigError(f"--spec {path}: expected an object with the field 'run' (a spec "
                          "the launcher writes)")
    return RunConfig.from_dict(doc["run"], source=f"--spec {path}: run").validate()
