"""The control unit's state between intervals, and an in-process closed loop.

:class:`Controller` turns an encoder sample into the sources of an interval (measured
angles, backward-difference rates, time, the observer's previous estimate) and takes the
observer's estimate back at the interval's *hand-off point*: the step after which the next
interval may start (§ IV.7.2: interval k+1 starts while k is in its second half). The
hand-off point is where the last of ``p, pdot, pddot`` is produced, so that the next
interval always predicts from this one, whatever the timing: the arithmetic is the same
at depth 1 and 2 and in one process.

:func:`simulate` runs the loop with the plant in process: the reference for the
distributed runs (lockstep), and for tests.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import NamedTuple

from ...kernels.dynamics import gravity_torques
from ...kernels.kinematics import inverse_kinematics
from ...kernels.laws import Gains
from ...kernels.params import DeltaParams
from ...kernels.trajectory import Task
from ...plant.simulator import Plant, PlantConfig
from ...topology.graph import stage_graph
from ...topology.placement import default_placement
from ...topology.plan import exchange_plan
from .blocks import BlockConfig
from .engine import CostModel, Engine
from .stride import StrideSchedule


def initial_command(params: DeltaParams, task: Task) -> list[float]:
    """Gravity-holding torques at the task's start: applied until the first command."""
    return [float(x) for x in gravity_torques(params, task.start())]


def initial_angles(params: DeltaParams, task: Task) -> list[float]:
    """Arm angles at the task's start (the plant is placed there)."""
    return [float(x) for x in inverse_kinematics(params, task.start())]


class Estimate(NamedTuple):
    """The observer's estimate handed from one interval to the next (the source ``est``).

    ``p, pd, pdd`` : position, velocity and commanded acceleration, 3-tuples of floats;
    ``t`` : the time of the sample they were estimated from (s), ``None`` for the
    starting estimate (no sample yet);
    ``acc`` : the commanded accelerations of the latest intervals, ``(t, pdd)`` pairs oldest
    first, at most ``delay + 1`` of them: the commands acting from the period that ends at
    the next sample to the last one before the next interval's command acts
    (runtime/compute/blocks.py, :func:`acting_acceleration`).
    """

    p: tuple[float, float, float]
    pd: tuple[float, float, float]
    pdd: tuple[float, float, float]
    t: float | None = None
    acc: tuple[tuple[float, tuple[float, float, float]], ...] = ()


@dataclass
class Controller:
    """Sources and observer state of consecutive intervals."""

    engine: Engine
    period: float
    increment: float
    p0: tuple[float, float, float]
    est: Estimate = field(init=False)
    first_cycle: int = 0
    """The cycle at t = 0 (the admission's trial intervals count from a base of their own)."""
    q_prev: list[float] | None = field(default=None, init=False)
    k_prev: int = field(default=0, init=False)
    grid: StrideSchedule = field(default_factory=StrideSchedule, init=False)
    """Which samples run an interval (every one until the rate is halved: :meth:`halve`,
    runtime/compute/stride.py)."""
    older: tuple[Estimate, ...] = field(default=(), init=False)
    """The estimates handed off before :attr:`est`, newest last (two kept): the source
    ``est2`` (:meth:`est_before`)."""

    def __post_init__(self) -> None:
        # plain floats: a numpy scalar here would make every value computed from the
        # estimate a numpy scalar too, and the kernels several times slower (docs/message-costs.md)
        p0 = self.p0
        self.est = Estimate((float(p0[0]), float(p0[1]), float(p0[2])), (0.0, 0.0, 0.0),
                            (0.0, 0.0, 0.0))

    def sources(self, cycle: int, counts: list[int]) -> dict:
        """Context of interval ``cycle`` from its encoder counts."""
        ctx = self.context(cycle)
        self.measure(ctx, cycle, counts)
        return ctx

    def context(self, cycle: int) -> dict:
        """Context of interval ``cycle`` before its sample: time and the estimate handed
        off by the previous interval (enough for the plan's sample-free leading steps)."""
        return self.engine.new_ctx(self.time_of(cycle), self.est, (0.0,) * 3, (0.0,) * 3,
                                   hold=self.hold_of(cycle),
                                   est2=self.est_before(cycle) if self.engine.has_est2
                                   else None)

    def est_before(self, cycle: int) -> Estimate:
        """The source ``est2`` of interval ``cycle`` (topology/graph.py, ``EST2``): the
        newest estimate handed off by an interval whose sample is at least two periods
        before this one's (the starting estimate if none is). It is decided by the
        samples' times alone, so the central, which takes it before the previous
        interval has handed off, and a one-process run or a replay, which take it after,
        find the same one."""
        limit = self.time_of(cycle) - 1.5 * self.period  # two periods back, less rounding
        for e in (self.est, *reversed(self.older)):
            if e.t is None or e.t <= limit:
                return e
        return self.older[0] if self.older else self.est

    def halve(self, start: int) -> None:
        """Halve the control rate from cycle ``start`` on (a realtime run on overload):
        only the samples ``start, start + 2, ...`` run intervals, and each of their
        commands acts for two periods (the source ``hold``). ``start`` must lie past every
        interval already begun; ValueError if the rate is halved already."""
        self.grid.change(2, start)

    @property
    def stride(self) -> int:
        """1 at the full control rate, 2 once halved (the latest change)."""
        return self.grid.stride

    def on_grid(self, cycle: int) -> bool:
        """Whether sample ``cycle`` runs an interval (every one until :meth:`halve`)."""
        return self.grid.on_grid(cycle)

    def hold_of(self, cycle: int) -> int:
        """The periods the command of interval ``cycle`` acts for."""
        return self.grid.hold_of(cycle)

    def time_of(self, cycle: int) -> float:
        """The time of sample ``cycle`` on the task's clock (s): the unit's one timebase."""
        return (cycle - self.first_cycle) * self.period

    def measure(self, ctx: dict, cycle: int, counts: list[int]) -> None:
        """Put sample ``cycle``'s angles and backward-difference rates into ``ctx``
        (samples must come in increasing cycle order)."""
        q = [c * self.increment for c in counts]
        if self.q_prev is None or cycle <= self.k_prev:
            qd = [0.0, 0.0, 0.0]
        else:  # skipped samples (realtime, behind) widen the difference
            dt = self.period * (cycle - self.k_prev)
            qd = [(q[i] - self.q_prev[i]) / dt for i in range(3)]
        self.q_prev = q
        self.k_prev = cycle
        ctx["qmeas_i"] = q
        ctx["qdmeas_i"] = qd

    def handoff(self, ctx: dict) -> None:
        """Take the observer's estimate from an interval at its hand-off point."""
        pdd = tuple(ctx.get("pdd", (0.0, 0.0, 0.0)))
        keep = self.engine.cfg.delay + 1
        self.older = (*self.older, self.est)[-2:]
        self.est = Estimate(
            tuple(ctx.get("p", self.est[0])),
            tuple(ctx.get("pd", (0.0, 0.0, 0.0))),
            pdd,
            ctx["t"],
            (*self.est.acc, (ctx["t"], pdd))[-keep:],
        )


@dataclass
class SimResult:
    """Outcome of :func:`simulate` (lists per interval: one per cycle until the control
    rate is halved, one per second cycle after)."""

    commands: list[list[float]]
    positions: list[list[float]]
    references: list[list[float]]

    @property
    def tracking_error(self) -> list[float]:
        return [math.dist(p, r) for p, r in zip(self.positions, self.references)]


def build_engine(
    params: DeltaParams,
    task: Task,
    *,
    law: str,
    model: str,
    gains: Gains,
    period: float,
    observer: str = "predict",
    peripherals: int = 0,
    cost: str = "native",
    delay: int = 0,
    model_state: str = "acting",
) -> Engine:
    """The one-process engine of a law; ``delay``: periods from a sample to the start of
    the period in which its command acts (the feed-forward lead, :class:`BlockConfig`);
    ``model_state``: where the model is evaluated (topology/graph.py, ``MODEL_STATES``)."""
    graph = stage_graph(law, model, observer=observer, model_state=model_state)
    plan = exchange_plan(graph, default_placement(peripherals))
    cfg = BlockConfig.build(params, model=model, gains=gains, task=task, period=period,
                            observer=observer, delay=delay)
    return Engine(plan, cfg, cost=CostModel(cost))


def simulate(
    params: DeltaParams,
    task: Task,
    *,
    law: str = "resolved-acceleration",
    model: str = "complete",
    gains: Gains,
    cycles: int,
    period: float = 1e-3,
    delay: int = 0,
    observer: str = "predict",
    plant_config: PlantConfig | None = None,
    model_state: str = "acting",
    halve_at: int | None = None,
) -> SimResult:
    """Closed loop in one process: sample k -> interval k -> command applied from the
    start of period ``k + delay`` (the distributed unit's ``RunConfig.delay_periods``: the
    depth, or one less with ``--command-delay short``) until the next command is due.
    ``halve_at``: from that cycle on only every second sample runs an interval
    (:meth:`Controller.halve`, a realtime run's answer to overload)."""
    task.align(period / 2.0)  # as the distributed unit does
    engine = build_engine(params, task, law=law, model=model, gains=gains, period=period,
                          observer=observer, delay=delay, model_state=model_state)
    pc = plant_config or PlantConfig(period=period)
    plant = Plant(params, pc, q0=initial_angles(params, task), p_guess=tuple(task.start()))
    ctl = Controller(engine, period, params.increment, tuple(task.start()))
    if halve_at is not None:
        ctl.halve(halve_at)
    due: dict[int, list[float]] = {}  # cycle -> the command due at its period's start
    plant.set_command(initial_command(params, task))
    res = SimResult([], [], [])
    for k in range(cycles):
        if ctl.on_grid(k):
            counts = plant.encoder_counts()
            ctx = engine.run_local(ctl.sources(k, counts))
            ctl.handoff(ctx)  # sequential: the hand-off point is the end of the interval
            res.commands.append(list(ctx["cmd"]))
            res.references.append(list(ctx.get("pc", task.sample(k * period)[0])))
            res.positions.append(list(plant.state.p))
            due[k + delay] = ctx["cmd"]
        if k in due:
            plant.set_command(due.pop(k))
        plant.step()
    return res
