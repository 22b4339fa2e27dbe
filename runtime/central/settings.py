"""What the central's loop reads of a run's configuration and of its plan, fixed once
(:class:`LoopSettings`, :class:`PlanShape`), and two small rules of its intervals."""

from __future__ import annotations

import sys
from dataclasses import dataclass
from typing import Any, NamedTuple

from ...topology.graph import EST2
from ...topology.pipeline import handoff_step, hold_rule
from ...topology.plan import ExchangePlan as Plan
from ..config import RunConfig

NO_HOLD = sys.maxsize
"""The intervals' boundary when none is held (runtime/central/rebalance.py sets one: from
it on no interval starts until the unit is re-placed)."""


def t1_input(ctx: dict) -> tuple:
    """What ``t_1`` recomputes an interval from (runtime/compute/engine.py, :func:`measure_t1`):
    its sources ``t, est, qmeas, qdmeas`` and, where the graph has it, ``est2``."""
    base = (ctx["t"], ctx["est"], list(ctx["qmeas_i"]), list(ctx["qdmeas_i"]))
    return (*base, ctx[EST2]) if EST2 in ctx else base


def extrapolated_command(tau: list[float], prev: list[float]) -> list[float]:
    """The command expected one period after ``tau``, from the one before it (``prev``):
    ``2 tau - prev``, the torques carried on at their last change. Sent with ``tau`` as
    ``next`` for the plant to apply if the next command is late (``--missed-command``)."""
    return [2.0 * a - b for a, b in zip(tau, prev, strict=True)]


class CommandAhead:
    """``--missed-command extrapolate`` (realtime at the full rate): with each command,
    the one its sample's successor is expected to bring, extrapolated from the last two
    (:func:`extrapolated_command`), for the plant to apply if that command is late
    (runtime/roles/plant_node.py, ``PlantServer.apply``). None at the first command, across a
    gap or a change of rate, in the other clocks (no deadline) and with
    ``--missed-command hold``."""

    def __init__(self, enabled: bool) -> None:
        self.enabled = enabled
        self.last: tuple[int, list[float]] | None = None
        """The last command sent: (cycle, tau)."""

    def after(self, cycle: int, tau: list[float], *, grid: Any) -> list[float] | None:
        """The command to send with ``tau``, the command of ``cycle``, or None. ``grid``
        tells the control rate (``hold_of``, ``on_grid``: the controller's or a
        :class:`~ctrlunit.runtime.compute.stride.StrideSchedule`): one is sent only where
        ``cycle``'s command acts for one period and the next sample runs an interval."""
        last, self.last = self.last, (cycle, tau)
        if (not self.enabled or last is None or last[0] != cycle - 1
                or grid.hold_of(cycle) != 1 or not grid.on_grid(cycle + 1)):
            return None
        return extrapolated_command(tau, last[1])


@dataclass(frozen=True)
class LoopSettings:
    """What the loop's rules read of the run's configuration, fixed for a run."""

    peripherals: int
    depth: int
    """The pipeline depth: intervals in flight at most."""
    clock: str
    plant: bool
    """Samples come from the plant's process (in freerun there is none)."""
    period_ns: int
    end: int
    """The cycle number after the run's last."""
    trial: bool
    """The admission's trial: commands sent flagged ``probe``, which the plant drops."""
    hold: Any
    """When a lone round waits to be fused (:func:`~ctrlunit.topology.pipeline.hold_rule`)."""
    deadline_ns: int
    """Realtime with peripherals: an interval whose command leaves later than this after
    its sample is late (its work goes to :attr:`CycleLog.late_work_ns`); 0 otherwise."""
    extrapolate: bool
    """Realtime with ``--missed-command extrapolate``: each command carries the next."""
    max_error: float
    t1_cycles: int
    """Intervals whose sources are kept for measuring t_1."""

    @classmethod
    def of(cls, rc: RunConfig, *, peripherals: int, cycles: int, first_cycle: int,
           trial: bool) -> LoopSettings:
        """The settings of a run of ``cycles`` intervals from ``first_cycle``."""
        sch = rc.schedule
        period_ns = int(sch.period * 1e9)
        realtime = sch.clock == "realtime"
        return cls(peripherals=peripherals, depth=sch.pipeline, clock=sch.clock,
                   plant=sch.clock != "freerun", period_ns=period_ns,
                   end=cycles + first_cycle, trial=trial,
                   hold=hold_rule(sch.hold_rounds, clock=sch.clock),
                   deadline_ns=sch.pipeline * period_ns if realtime and peripherals else 0,
                   extrapolate=realtime and not trial and sch.missed_command == "extrapolate",
                   max_error=rc.control.max_error, t1_cycles=rc.run.t1_cycles)


class PlanShape(NamedTuple):
    """What the loop reads of a plan, derived once (the plan's properties walk the
    graph, and the loop asks per interval)."""

    handoff: int
    """The step after which an interval has handed off its estimate to the next one."""
    round_step: dict[int, int]
    """The step index of each round."""
    last_round: int
    ahead_rounds: int
    """Rounds that need no sample (sent ahead of it at depth 2)."""

    @classmethod
    def of(cls, plan: Plan, peripherals: int) -> PlanShape:
        return cls(handoff_step(plan),
                   {s.round.index: k for k, s in enumerate(plan.steps) if s.round is not None},
                   plan.rounds[-1].index if plan.rounds else -1,
                   plan.ahead_rounds if peripherals else 0)


__all__ = ["NO_HOLD", "CommandAhead", "LoopSettings", "PlanShape", "extrapolated_command",
           "t1_input"]
