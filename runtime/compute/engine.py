"""Execution of an exchange plan: the same code on the central, the peripherals and in the
single-process reference.

The central runs :meth:`Engine.cycle`, a generator that executes central steps and yields
at every round; the caller scatters the round's request, gathers the replies, merges them
with :meth:`Engine.merge_reply` and resumes the generator. A peripheral runs
:meth:`Engine.run_round` for its axes. :meth:`Engine.run_local` runs a whole interval in one
process with no exchange (n = 0, and the ``t_1`` measurement).
"""

from __future__ import annotations

import math
import statistics
import time
from collections.abc import Callable, Generator, Iterable, Iterator
from contextlib import contextmanager
from typing import Any

from ...topology.graph import EST2
from ...topology.placement import Placement, PlacementError
from ...topology.plan import ExchangePlan, Round, exchange_plan
from .axis_blocks import AXIS_KERNELS
from .blocks import CENTRAL_KERNELS, BlockConfig, Ctx, ObserverDiverged, names_for


class CostModel:
    """Makes blocks occupy their process for a given time without burning CPU.

    ``t800``: each block, after computing its real result, adds its T-800 time (per axis
    for axis blocks) to the time the process owes; before the process sends anything
    (:meth:`settle`) it sleeps until the debt is paid, the last stretch by spinning so that
    the emulated time is exact to a few microseconds whatever the sleep granularity. The
    spun stretch adapts to how late this machine's sleeps wake (twice their running mean
    overshoot, 50 us to 1 ms). The measured error of every settle is kept (``errors_ns``).
    """

    SPIN_MIN_NS = 50_000
    SPIN_MAX_NS = 1_000_000

    def __init__(self, name: str = "native", *, scale: float = 1.0) -> None:
        if name not in ("native", "t800"):
            raise ValueError(f"cost model must be native or t800, got {name!r}")
        if not 0.01 <= scale <= 1000.0:
            raise ValueError(f"cost scale must be in [0.01, 1000], got {scale!r}")
        self.name = name
        self.scale = scale
        self.errors_ns: list[int] = []
        self.deadline = 0
        self.overshoot_ns = 40_000.0  # running mean of how late a sleep wakes
        self.waive = False

    @contextmanager
    def waived(self) -> Iterator[None]:
        """Blocks run inside occupy their process for no modelled time: the central's
        warm-up, whose throw-away intervals exercise the exchange and are not the run's
        work (at ``--cost-scale 1000`` its 30 intervals would take 30-50 s of T-800 time,
        and the plant, which hears nothing meanwhile, would end on its watchdog)."""
        was, self.waive = self.waive, True
        try:
            yield
        finally:
            self.waive = was

    @property
    def spin_ns(self) -> int:
        return int(min(self.SPIN_MAX_NS, max(self.SPIN_MIN_NS, 2.0 * self.overshoot_ns)))

    def occupy(self, t800_us: float, count: int, t0_ns: int) -> None:
        if self.name == "native" or self.waive:
            return
        start = max(self.deadline, t0_ns)
        self.deadline = start + int(t800_us * 1000.0 * count * self.scale)

    def settle(self) -> None:
        if self.name == "native" or not self.deadline:
            return
        target = self.deadline
        spin = self.spin_ns
        now = time.monotonic_ns()
        if target - now > spin:
            wake = target - spin
            time.sleep((wake - now) / 1e9)
            late = time.monotonic_ns() - wake
            self.overshoot_ns += 0.1 * (late - self.overshoot_ns)
        while time.monotonic_ns() < target:
            pass
        if len(self.errors_ns) < 100_000:
            self.errors_ns.append(time.monotonic_ns() - target)
        self.deadline = 0


SpanSink = Callable[[str, int, int], None]

AWAIT_SAMPLE = Round(index=-1)
"""Yielded by :meth:`Engine.cycle` with ``gate``: the interval's steps that need no sample
are done, and it waits for its sample."""


class Engine:
    """Runs the blocks of an exchange plan.

    Parameters
    ----------
    plan : the exchange plan.
    cfg : kernel configuration.
    cost : cost model (``native`` computes only).
    span : optional ``span(block, t0_ns, t1_ns)`` callback recording each block's time.
    """

    def __init__(
        self,
        plan: ExchangePlan,
        cfg: BlockConfig,
        *,
        cost: CostModel | None = None,
        span: SpanSink | None = None,
    ) -> None:
        self.plan = plan
        self.cfg = cfg
        self.cost = cost or CostModel()
        self.span = span
        names: set[str] = set(plan.graph.sources)
        for b in plan.graph.blocks:
            names.update(b.inputs)
            names.update(b.outputs)
        self.axis_names = sorted(n for n in names if n.endswith("_i"))
        self.has_est2 = EST2 in plan.graph.sources
        self.presample = plan.presample_steps
        # bind kernels once
        self._bound: dict[str, tuple[Any, dict[str, str], float, bool]] = {}
        for b in plan.graph.blocks:
            fn = AXIS_KERNELS[b.kernel] if b.per_axis else CENTRAL_KERNELS[b.kernel]
            self._bound[b.name] = (fn, names_for(b), b.t800_us, b.per_axis)

    def placed(self, central_blocks: Iterable[str]) -> Engine:
        """This engine with the per-axis blocks ``central_blocks`` run on the central, the
        peripherals and their axes kept: the same graph, kernel configuration (the task
        and its cache included) and cost model, so that the values do not change (a live
        re-placement, runtime/central/rebalance.py).

        Raises
        ------
        PlacementError
            If a name is not one of the graph's per-axis blocks.
        """
        wanted = frozenset(central_blocks)
        bad = sorted(wanted - {b.name for b in self.plan.graph.axis_blocks})
        if bad:
            raise PlacementError(f"central_blocks {bad} are not per-axis blocks of this graph")
        placement = Placement(self.plan.placement.axes, wanted)
        return Engine(exchange_plan(self.plan.graph, placement), self.cfg, cost=self.cost,
                      span=self.span)

    # -- contexts ---------------------------------------------------------------------

    def new_ctx(self, t: float, est: Any, qmeas: Iterable[float], qdmeas: Iterable[float],
                *, hold: int = 1, est2: Any = None) -> Ctx:
        """A fresh interval context from its sources (topology/graph.py, ``SOURCES``);
        ``hold``: the periods the interval's command acts for; ``est2``: where the graph
        has the source ``est2``, the estimate of two intervals back (default ``est``)."""
        c: Ctx = {n: [None, None, None] for n in self.axis_names}
        c["t"] = t
        c["hold"] = hold
        c["est"] = est
        if self.has_est2:
            c[EST2] = est if est2 is None else est2
        c["qmeas_i"] = list(qmeas)
        c["qdmeas_i"] = list(qdmeas)
        return c

    # -- running blocks ---------------------------------------------------------------

    def _run_block(self, name: str, c: Ctx, axes: Iterable[int]) -> None:
        fn, n, cost_us, per_axis = self._bound[name]
        timed = self.span is not None or self.cost.name != "native"
        t0 = time.monotonic_ns() if timed else 0
        if per_axis:
            count = 0
            for i in axes:
                fn(c, i, self.cfg, n)
                count += 1
        else:
            fn(c, self.cfg, n)
            count = 1
        if timed:
            self.cost.occupy(cost_us, count, t0)
            if self.span is not None:
                self.span(name, t0, time.monotonic_ns())

    def run_round(self, rnd: Round, c: Ctx, axes: Iterable[int]) -> None:
        """Run a round's per-axis blocks for ``axes`` on context ``c``."""
        axes = tuple(axes)
        for b in rnd.blocks:
            self._run_block(b.name, c, axes)
        self.cost.settle()

    @staticmethod
    def can_run(rnd: Round, c: Ctx, axes: Iterable[int]) -> bool:
        """Whether ``c`` holds every input of ``rnd``'s blocks for ``axes`` that the round
        does not make itself (a round a peripheral would run on values it kept from an
        earlier round of the interval cannot run where those were never returned)."""
        axes = tuple(axes)
        made: set[str] = set()
        for b in rnd.blocks:
            for v in b.inputs:
                if v in made:
                    continue
                if v.endswith("_i"):
                    slot = c.get(v)
                    if slot is None or any(slot[a] is None for a in axes):
                        return False
                elif v not in c:
                    return False
            made.update(b.outputs)
        return True

    def prefix(self, c: Ctx) -> None:
        """Run the interval's leading steps that need no sample
        (:attr:`~ctrlunit.topology.plan.ExchangePlan.presample_steps`), their rounds
        included, in this process; then ``cycle(c, skip_prefix=True)`` runs the rest."""
        for step in self.plan.steps[:self.presample]:
            if step.round is not None:
                self.run_round(step.round, c, (0, 1, 2))
            else:
                assert step.block is not None
                self._run_block(step.block.name, c, (0, 1, 2))
        self.cost.settle()

    def cycle(self, c: Ctx, *, skip_prefix: bool = False, gate: bool = False
              ) -> Generator[Round, None, Ctx]:
        """Run the interval on the central, yielding at each round (without the leading
        sample-free steps when ``skip_prefix``: :meth:`prefix` ran them). With ``gate``
        the generator also yields :data:`AWAIT_SAMPLE` once, after those steps and before
        the first that needs the sample: an interval started before its sample (rounds
        that run ahead, depth 2) resumes from there once the sample is in ``c``."""
        start = self.presample if skip_prefix else 0
        for k, step in enumerate(self.plan.steps[start:], start):
            if gate and k == self.presample:
                self.cost.settle()
                yield AWAIT_SAMPLE
            if step.round is not None:
                self.cost.settle()
                yield step.round
            else:
                assert step.block is not None
                self._run_block(step.block.name, c, (0, 1, 2))
        self.cost.settle()
        return c

    def run_local(self, c: Ctx, *, skip_prefix: bool = False) -> Ctx:
        """Run the whole interval in this process, rounds included (no exchange); without
        its leading sample-free steps when ``skip_prefix`` (:meth:`prefix` ran them)."""
        gen = self.cycle(c, skip_prefix=skip_prefix)
        try:
            rnd = next(gen)
            while True:
                self.run_round(rnd, c, (0, 1, 2))
                rnd = gen.send(None)
        except StopIteration:
            pass
        return c

    # -- messages ---------------------------------------------------------------------

    @staticmethod
    def request_vals(rnd: Round, c: Ctx, axes: tuple[int, ...]) -> dict[str, Any]:
        """The request payload of ``rnd`` for a peripheral owning ``axes``. Values go to
        msgpack as they are: it packs tuples and named tuples as arrays, the same bytes
        as lists (a conversion to lists here cost every message a recursive copy)."""
        vals: dict[str, Any] = {}
        for name in rnd.send:
            v = c[name]
            vals[name] = [v[i] for i in axes] if name.endswith("_i") else v
        return vals

    @staticmethod
    def reply_vals(rnd: Round, c: Ctx, axes: tuple[int, ...]) -> dict[str, Any]:
        """The reply payload of ``rnd`` from a peripheral owning ``axes``."""
        return {name: [c[name][i] for i in axes] for name in rnd.recv}

    @staticmethod
    def merge(c: Ctx, vals: dict[str, Any], axes: tuple[int, ...]) -> None:
        """Merge decoded values into a context (per-axis values by axis)."""
        for name, v in vals.items():
            if name.endswith("_i"):
                slot = c.setdefault(name, [None, None, None])
                for k, i in enumerate(axes):
                    slot[i] = v[k]
            else:
                c[name] = v


def measure_t1(engine_factory: Callable[[], Engine], inputs: list[tuple], *, repeat: int = 1
               ) -> tuple[float, dict[str, float]]:
    """``t_1``: the same intervals computed by one process with no exchange.

    Parameters
    ----------
    engine_factory : builds an n = 0 engine (same law, model, cost model).
    inputs : ``(t, est, qmeas, qdmeas)`` of recorded intervals, and ``est2`` after them
        where the graph reads it.

    Returns
    -------
    (median seconds per interval, mean seconds per block)
    """
    block_ns: dict[str, list[int]] = {}

    def span(name: str, t0: int, t1: int) -> None:
        block_ns.setdefault(name, []).append(t1 - t0)

    eng = engine_factory()
    eng.span = span
    times = []
    for _ in range(repeat):
        for t, est, q, qd, *est2 in inputs:
            ctx = eng.new_ctx(t, est, q, qd, est2=est2[0] if est2 else None)
            t0 = time.perf_counter_ns()
            try:
                eng.run_local(ctx)
            except ObserverDiverged:
                continue
            times.append(time.perf_counter_ns() - t0)
    if not times:
        return math.nan, {}
    per_block = {k: statistics.fmean(v) / 1e9 for k, v in block_ns.items()}
    return statistics.median(times) / 1e9, per_block
