"""Live balance (``--balance live``): the central re-places per-axis blocks while it runs.

The central judges a window of :data:`EVERY` intervals with the model and the rules of
``ctrlunit balance`` (:func:`ctrlunit.topology.live_choice.live_choice`: the schedule model
calibrated on the window's figures, the thesis's rules of § IV.7.2 for the candidates, a
move only when it is predicted :data:`~ctrlunit.topology.balance.MARGIN` faster): the
first after :data:`SETTLE` intervals, again :data:`SETTLE` intervals after each move, and
after a judgement that called for none only when a window's mean period has moved by more
than that margin from the judged one; never more often than :data:`COST_SHARE` of the
central's time allows. A running unit keeps its processes, so only the central's blocks move: to the
central, or back to the peripherals that own their axes.

A move happens at an interval boundary (:meth:`LiveBalance.turn`): no interval past those
begun starts, the pipeline empties, every peripheral is told the blocks the central now
runs and the first interval of the new plan (a ``place`` order with ``from_cycle``, each
acknowledged by ``placed``: :meth:`~.orders.Orders.place`), and the intervals go on from
there with the new plan. The controller's state (the estimate, the observer's) is the
central's and stays; a block keeps nothing from one interval to the next, so the commands
are bit for bit those of a run that never moved (lockstep). The drain costs the overlap
of the intervals around the boundary, once per move.

Each move is recorded (``/central/placement``: the interval it starts at, the blocks, why,
the figures that justified it), so that ``replay --verify`` re-executes the run with the
plan each interval had, and listed in the report's ``rebalanced``.

Not in realtime: a judgement costs the central about 0.1 s of its own time
(docs/measurements/2026-11-28-live-balance.md), and the drain the deadlines around it (the
setting is refused there). Not while a peripheral is taken over (:mod:`.takeover`), whose
rounds the central computes with the plan it lost them with.
"""

from __future__ import annotations

import multiprocessing
import time
from collections.abc import Callable, Collection
from concurrent.futures import Future, ProcessPoolExecutor
from dataclasses import dataclass
from typing import Any

import msgpack

from ...topology.balance import MARGIN
from ...topology.live_choice import judge_ready, live_verdict
from ..compute.controller import Controller
from ..compute.engine import Engine
from ..config import RunConfig
from ..host.background import in_background
from .intervals import Intervals
from .meters import Meters
from .orders import Orders
from .outgoing import Outgoing
from .settings import NO_HOLD
from .warmup import WarmUp

EVERY = 40
"""Intervals in a judged window, and so at most one move per this many intervals."""
SETTLE = 8
"""Intervals left out after the start and after each move before a window begins: the
first rounds of a plan are slower (caches, the drain's empty pipeline)."""
COST_SHARE = 0.05
"""The largest share of the central's time judgements may take: after one that took t,
the next waits 19 t. A judgement costs about 0.1 s (the model's plays); at native costs
and a 1 ms period that is 100 intervals, once per 2 s at most."""
JUDGE_READY_S = 10.0
"""How long :meth:`LiveBalance.prepare` waits for the judge's process to start."""


@dataclass(frozen=True)
class _Window:
    """The central's counters where a window began."""

    done: int
    t_ns: int
    counts: tuple[int, ...]
    busy: tuple[int, ...]

    @staticmethod
    def of(m: Meters, done: int) -> _Window:
        return _Window(done, time.monotonic_ns(), _counts(m), tuple(m.periph_busy_ns))


def _counts(m: Meters) -> tuple[int, ...]:
    return (m.wait_ns, m.admit_ns, m.finish_ns, m.send_ns, m.exchanges, m.reply_ns,
            m.reply_msgs)


class LiveBalance:
    """The central's live re-placement.

    Parameters
    ----------
    rc : the run's configuration (``--balance``, the clock, the cost model, the replies
        asked).
    intervals : the intervals' part (its boundary, its plan and controller, the central's
        accounting, whether the run is an admission trial, which never moves).
    orders : tells the peripherals the new plan.
    warmup : each block's time for one interval (:meth:`~.warmup.WarmUp.block_costs_s`).
    outgoing : how the peripherals answer (the replies' mode the model plays).
    use : ``use(engine, controller)`` makes the central run an engine's plan (every part
        that follows the plan).
    lost : the peripherals taken over, kept up to date (no move while there is one).
    on_message : the recording's hook, or None.
    """

    def __init__(self, rc: RunConfig, *, intervals: Intervals, orders: Orders,
                 warmup: WarmUp, outgoing: Outgoing, use: Callable[[Engine, Controller], None],
                 lost: Collection[int], on_message: Callable[..., None] | None = None) -> None:
        sch = rc.schedule
        self.asked = sch.balance == "live" and not intervals.settings.trial
        self.enabled = self.asked and intervals.engine.plan.placement.peripherals > 0
        self.intervals = intervals
        self.meters = intervals.meters
        self.orders = orders
        self.warmup = warmup
        self.run = {"clock": sch.clock, "cost_model": rc.control.cost_model,
                    "cost_scale": rc.control.cost_scale, "asked": sch.replies}
        self.outgoing = outgoing
        self.use = use
        self.lost = lost
        self.on_message = on_message
        self.key = f"{orders.node.keys.root}/central/placement"
        self.window: _Window | None = None
        self.begin_at = SETTLE
        """Intervals done when the next window begins."""
        self.move: dict[str, Any] | None = None
        """The move chosen, until its boundary is reached."""
        self.moves: list[dict[str, Any]] = []
        """Every move made (the report's ``rebalanced``)."""
        self.judged = 0
        self.judge_ns = 0
        """Judgements made, and the central's time they took."""
        self.judged_period_s: float | None = None
        """The mean period of the last window judged that called for no move."""
        self.next_judge_ns = 0
        """No judgement before this time (:data:`COST_SHARE`)."""
        self.ended = ""
        """Why live balance stopped during the run, if it did."""
        self.pool: ProcessPoolExecutor | None = None
        self.pending: tuple[Future, dict[str, Any]] | None = None
        """The judgement under way in the judge's process, and the window it judges."""

    def prepare(self) -> None:
        """Start the judge's process and wait until it has imported the judge (at most
        :data:`JUDGE_READY_S`), before the warm-up: a new interpreter's start-up runs at
        the unit's priority (the pool's initializer lowers it only after), so started at
        the first judgement it took the CPUs from the run's intervals around it."""
        if not self.enabled or self.pool is not None:
            return
        self.pool = ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn"),
                                        initializer=in_background)
        try:
            self.pool.submit(judge_ready).result(timeout=JUDGE_READY_S)
        except Exception:
            pass  # at its first judgement, named in the report (:meth:`turn`)

    def turn(self, done: int) -> None:
        """Once per turn of the central's loop: begin or judge a window, or, the boundary
        reached, make the move."""
        if not self.enabled:
            return
        if self.move is not None:
            if self._drained():
                self._place(self.move)
            return
        if self.pending is not None:
            if self.pending[0].done():
                try:
                    choice, spent = self.pending[0].result()
                except Exception as exc:  # the judge's process died (killed, out of memory)
                    self.enabled, self.pending = False, None
                    self.ended = f"the judge's process ended ({type(exc).__name__})"
                    return  # the run goes on with the placement it has
                self._judged(done, choice, self.pending[1], spent)
            return
        if self.window is None:
            if done >= self.begin_at:
                self.window = _Window.of(self.meters, done)
            return
        if done - self.window.done < EVERY:
            return
        period = (time.monotonic_ns() - self.window.t_ns) / (done - self.window.done) / 1e9
        last = self.judged_period_s
        if ((last is None or abs(period / last - 1.0) > MARGIN)
                and time.monotonic_ns() >= self.next_judge_ns):
            self._judge(done)
        else:  # nothing changed since the last judgement, or too soon: a new window
            self.window = _Window.of(self.meters, done)

    def _drained(self) -> bool:
        iv = self.intervals
        return not (iv.inflight or iv.primed or iv.outbox)

    def figures(self, done: int) -> dict[str, Any]:
        """The window as a run's report, the fields ``ctrlunit balance`` reads."""
        w = self.window
        assert w is not None
        m = self.meters
        wall = max(1, time.monotonic_ns() - w.t_ns)
        n = max(1, done - w.done)
        wait, admit, finish, send, exch, reply, msgs = (
            a - b for a, b in zip(_counts(m), w.counts, strict=True))
        plan = self.intervals.engine.plan
        graph = plan.graph
        business = {"central": max(0.0, 1.0 - wait / wall)} | {
            f"peripheral_{k + 1}": (b - b0) / wall
            for k, (b, b0) in enumerate(zip(m.periph_busy_ns, w.busy, strict=True))}
        run = self.run
        return {
            "clock": run["clock"], "cost_model": run["cost_model"],
            "cost_scale": run["cost_scale"],
            "replies": {"asked": run["asked"],
                        "mode": "each" if self.outgoing.reply_each else "fused"},
            "law": graph.law, "model": graph.model, "observer": graph.observer,
            "model_state": graph.model_state, "pipeline": self.intervals.settings.depth,
            "placement": plan.placement.to_dict(), "block_cost_s": self.warmup.block_costs_s(),
            "period_mean_s": wall / n / 1e9, "business": business,
            "exchanges_per_interval": exch / n,
            "central_costs_s": {"start": admit / n / 1e9, "finish": finish / n / 1e9,
                                "send": send / max(1, exch) / 1e9,
                                "reply": reply / max(1, msgs) / 1e9,
                                "replies_per_interval": msgs / n,
                                "busy_per_interval": (wall - wait) / n / 1e9}}

    def _judge(self, done: int) -> None:
        """Hand the window to the judge (:meth:`_judged` takes its verdict)."""
        self.prepare()  # a process: the model's plays take no time from this one
        assert self.pool is not None
        figures = self.figures(done)
        self.window = None
        self.pending = (self.pool.submit(live_verdict, figures), figures)

    def _judged(self, done: int, choice: dict[str, Any] | None, figures: dict[str, Any],
                spent_ns: int) -> None:
        """A verdict came (after ``done`` intervals): a move, if any, waits for its
        boundary; the next judgement waits for :data:`COST_SHARE`."""
        self.pending = None
        self.judged += 1
        self.judge_ns += spent_ns
        self.next_judge_ns = time.monotonic_ns() + int(spent_ns * (1.0 / COST_SHARE - 1.0))
        self.begin_at = done  # the next window begins now, unless a move comes first
        self.judged_period_s = None if choice else figures["period_mean_s"]
        if choice is None or self.lost:
            return
        since = self._boundary()
        if since >= self.intervals.settings.end:
            return  # no interval left to run with it
        self.move = choice | {"at_interval": done, "from_cycle": since, "window": {
            k: figures[k] for k in ("business", "central_costs_s", "exchanges_per_interval")}}
        self.intervals.hold_from = since

    def _boundary(self) -> int:
        """The first interval not yet begun nor primed: none from it starts until the
        move is made."""
        iv = self.intervals
        begun = [*iv.inflight, *(c for c, _ in iv.primed)]
        return max([iv.next_cycle, *(c + 1 for c in begun)])

    def _place(self, move: dict[str, Any]) -> None:
        """The pipeline is empty: every peripheral takes the new plan, then the central."""
        blocks, since = move["central_blocks"], move["from_cycle"]
        engine = self.intervals.engine.placed(blocks)
        self.orders.place(blocks, from_cycle=since)
        rtt = self.warmup.warm_rtt_s  # the link's round trips, whatever the plan
        self.use(engine, self.intervals.ctl)
        self.warmup.warm_rtt_s = rtt
        # whether the peripherals answer each round at once depends on the central's work
        # between two rounds, which the move changed (:meth:`~.warmup.WarmUp.choose_replies`)
        move["replies"] = self.warmup.choose_replies()["mode"]
        self.outgoing.reply_each = move["replies"] == "each"
        self.moves.append(move)
        if self.on_message is not None:
            self.on_message("placed", self.key, since, "placed", msgpack.packb(move),
                            time.monotonic_ns())
        self.move = None
        self.intervals.hold_from = NO_HOLD
        self.begin_at = self.intervals.done + SETTLE

    def close(self) -> None:
        """End the judge's process (at the end of the run; a judgement under way is left
        to finish, its verdict unread)."""
        if self.pool is not None:
            self.pool.shutdown(wait=False, cancel_futures=True)

    def summary(self) -> dict[str, Any] | None:
        """What the report says of live balance where it was asked (``live_balance``):
        judgements made and the judge's CPU, whether one was under way at the end, the
        interval of the first judgement, the central blocks now, and why it stopped or
        never ran, if so."""
        if not self.asked:
            return None
        ended = self.ended or ("" if self.enabled else "no peripheral: nothing to move")
        return {"judged": self.judged, "judge_cpu_s": self.judge_ns / 1e9,
                "under_way": self.pending is not None,
                "first_judged_after": SETTLE + EVERY, "ended": ended,
                "central_blocks": sorted(self.intervals.engine.plan.placement.central_blocks)}

    def report(self) -> list[dict[str, Any]]:
        """Every move so far, in order (the report's ``rebalanced``)."""
        return [dict(m) for m in self.moves]


__all__ = ["EVERY", "SETTLE", "LiveBalance"]
