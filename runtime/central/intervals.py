"""The central's intervals in flight through the pipeline (§ IV.7.2, Fig. 24): when one
starts (from its sample, or ahead of it), when its sample-free steps run, how its rounds
go out (fused into one request, or held for the next interval's first round), and how it
finishes (the command, its logs). The rules are the pure functions of
:mod:`ctrlunit.topology.pipeline`; :class:`Intervals` applies them to its state."""

from __future__ import annotations

import time
from collections import OrderedDict
from collections.abc import Callable
from typing import Any

from ...topology.pipeline import holds_lone_round, may_prime, may_start, prime_cycles
from ...topology.plan import Round
from ..compute.blocks import ObserverDiverged
from ..compute.controller import Controller
from ..compute.engine import AWAIT_SAMPLE, Engine
from ..config import EXIT_OBSERVER
from ..transport.codec import encode
from ..transport.node import WARM_RSS_AT, Node, rss_kb
from .fault import Fault
from .intake import Intake, synthetic_counts
from .meters import Meters
from .outgoing import Outgoing
from .overload import Overload
from .pace import pace_of
from .records import CycleLog, InFlight
from .samples import sample_source
from .settings import NO_HOLD, LoopSettings, PlanShape, t1_input
from .silence import SilenceWatch
from .state_check import check_state


class Intervals:
    """The intervals of one central between their samples and their commands.

    Parameters
    ----------
    node, settings : the central's node and settings.
    outgoing : what the central sends (:class:`~.outgoing.Outgoing`).
    engine, controller : the plan and its sources (:meth:`use` when they change).
    intake : the samples taken (each interval starts from one).
    silence : told when requests go out; gives the silence limit.
    overload : told of late intervals and of each finished one.
    expect_late : ``expect_late(cycle, stage, peripheral)``: a reply will come late.
    meters, log : the central's accounting and its log of finished intervals.
    hint : ends a fault's message.
    on_cycle, on_message : after each interval ``on_cycle(cycle, ctx)``; the recording's
        hook (None: none).
    """

    def __init__(self, node: Node, settings: LoopSettings, engine: Engine,
                 controller: Controller, *, outgoing: Outgoing, intake: Intake,
                 silence: SilenceWatch,
                 overload: Overload, expect_late: Callable[[int, int, int], None],
                 meters: Meters, log: CycleLog, hint: Callable[[], str],
                 on_cycle: Callable[[int, dict], None] | None = None,
                 on_message: Callable[..., None] | None = None) -> None:
        self.node = node
        self.settings = settings
        self.silence = silence
        self.overload = overload
        self.expect_late = expect_late
        self.meters = meters
        self.log = log
        self.hint = hint
        self.on_cycle = on_cycle
        self.on_message = on_message
        self.out = outgoing
        self.inflight: OrderedDict[int, InFlight] = OrderedDict()
        self.outbox: list[InFlight] = []
        """Intervals whose next round waits to be sent."""
        self.primed: list[tuple[int, dict]] = []
        """Next intervals whose sample-free steps ran."""
        self.next_cycle = controller.first_cycle
        self.done = 0
        self.hold_from = NO_HOLD  # none from this cycle on starts or is primed (re-placing)
        self.pace = pace_of(settings)
        self.samples = sample_source(
            settings.clock, intake, synthetic=self._synthetic_sample, trial=settings.trial,
            on_skip=self._skipped, note=None if on_message is None else self._note_synthetic)
        self.use(engine, controller)

    def use(self, engine: Engine, controller: Controller) -> None:
        """Run ``engine``'s plan with ``controller``."""
        self.engine = engine
        self.ctl = controller
        self.shape = PlanShape.of(engine.plan, self.settings.peripherals)

    def _newest_handed_off(self) -> bool | None:
        """Whether the newest interval started from its sample has handed off (None: none
        in flight); an interval run ahead of its sample does not count yet."""
        for f in reversed(self.inflight.values()):
            if not f.awaiting_sample:
                return f.handed_off
        return None

    def _may_start(self) -> bool:
        if self.next_cycle >= self.hold_from:
            return False
        live = sum(1 for f in self.inflight.values()
                   if not f.finishing and not f.awaiting_sample)
        return may_start(depth=self.settings.depth, live=live, next_cycle=self.next_cycle,
                         cycles=self.settings.end, newest_handed_off=self._newest_handed_off())

    def start_ready(self) -> None:
        """Start every interval that may start (:func:`~ctrlunit.topology.pipeline.may_start`)
        and has its sample (freerun: a synthetic one), up to its first round."""
        while self._may_start():
            t_in = time.perf_counter_ns()
            taken = self.samples.take(self.next_cycle)
            if taken is None:
                return
            k, counts, t_ns = taken  # realtime and behind: the newest sample's
            self.next_cycle = k + self.ctl.hold_of(k)
            t0 = time.monotonic_ns()
            primed = self._take_primed(k)
            ahead = self.inflight.get(k) if primed is not None else None
            if ahead is not None and ahead.awaiting_sample:  # its rounds ran ahead
                self._sample_came(ahead, k, counts, t_ns, t0, t_in)
                continue
            if primed is not None:  # its sample-free steps are done
                ctx = primed
                self.ctl.measure(ctx, k, counts)
                gen = self.engine.cycle(ctx, skip_prefix=True)
            else:
                ctx = self.ctl.sources(k, counts)
                gen = self.engine.cycle(ctx)
            if len(self.meters.t1_inputs) < self.settings.t1_cycles:
                self.meters.t1_inputs.append(t1_input(ctx))
            f = InFlight(k, gen, ctx, t_ns, t0)
            self.inflight[k] = f
            self.meters.admit_ns += time.perf_counter_ns() - t_in
            self.advance(f)

    def _skipped(self, k: int, newest: int) -> None:
        """Realtime and behind the plant's clock: interval ``k`` starts from the newest
        sample, ``newest``'s; count the samples skipped (on the control rate's grid where
        it is halved) as one late mark, however long the stall."""
        if self.ctl.stride > 1:  # the rate is halved: the grid's samples only
            skipped = sum(1 for c in range(k, newest) if self.ctl.on_grid(c))
        else:
            skipped = newest - k
        self.meters.skipped += skipped
        self.overload.mark_late(self.done, self.ctl.stride)
        if self.settings.trial:
            self.meters.skip_marks.append((len(self.log.traversal_ns), skipped))
        self.next_cycle = newest

    def _note_synthetic(self, k: int, counts: list[int], t_ns: int) -> None:
        assert self.on_message is not None
        self.on_message("in", self.node.keys.sample, k, "sample", encode(
            self.node.unit, k, "sample", counts=counts, t_ns=t_ns, synthetic=True), t_ns)

    def _sample_came(self, f: InFlight, k: int, counts: list[int], t_ns: int, t0: int,
                     t_in: int) -> None:
        """The sample of ``f``, an interval whose rounds ran ahead of it: measure, and go
        on from the sample's steps if its rounds are back."""
        self.ctl.measure(f.ctx, k, counts)
        if len(self.meters.t1_inputs) < self.settings.t1_cycles:
            self.meters.t1_inputs.append(t1_input(f.ctx))
        gated = f.sampled(t_ns, t0)
        if f.waiting:  # a round run ahead is late once its sample is here (realtime)
            f.late_at(self.pace.sample_late_at(f, t_ns))
        self.meters.admit_ns += time.perf_counter_ns() - t_in
        if gated:  # its rounds are back: on from the sample's steps
            self.advance(f)

    def _take_primed(self, k: int) -> dict | None:
        """The context of interval ``k`` if its sample-free steps ran (it was primed),
        else None, with the previous interval's estimate, final now (with foresight 2 it
        was not when ``k`` was primed). Intervals primed before ``k`` are dropped (their
        samples were skipped); those after it stay (foresight 2: primed with ``k``)."""
        ctx = None
        while self.primed and self.primed[0][0] <= k:
            cycle, c = self.primed.pop(0)
            if cycle == k:
                ctx = c
                ctx["est"] = self.ctl.est
                continue
            self._drop_ahead(cycle)
            if self.on_message is not None:  # its primed steps ran, its interval did not:
                # the reference they computed stays in the task's cache, which a later
                # loop of the task reads, so replay runs them too (runtime/recording/replay.py)
                self.on_message("in", self.node.keys.inbox("central") + "/primed", cycle,
                                "primed", encode(self.node.unit, cycle, "primed"),
                                time.monotonic_ns())
        return ctx

    def _drop_ahead(self, cycle: int) -> None:
        """Forget an interval started ahead of a skipped sample: its replies are late ones."""
        f = self.inflight.get(cycle)
        if f is None or not f.awaiting_sample:
            return
        del self.inflight[cycle]
        if f in self.outbox:
            self.outbox.remove(f)
        elif f.round is not None:
            for k in f.waiting:
                self.expect_late(cycle, f.round.index, k)

    def prime(self) -> bool:
        """Depth 2: run the next interval's sample-free leading steps (the plan's
        ``presample_steps``: for resolved acceleration the reference and the observer's
        prediction) as soon as the newest interval has handed off its estimate, before
        the next interval has a slot or its sample. They would otherwise sit between one
        interval's last reply and the next request, with the peripherals idle. Same
        arithmetic: the estimate they use is final at the hand-off. Returns whether it
        ran them."""
        if not may_prime(primed=bool(self.primed) or self.hold_from != NO_HOLD,
                         depth=self.settings.depth, next_cycle=self.next_cycle,
                         cycles=self.settings.end, newest_handed_off=self._newest_handed_off()):
            return False
        k0 = self.next_cycle
        for k in prime_cycles(next_cycle=k0, cycles=self.settings.end,
                              foresight=self.engine.plan.graph.foresight,
                              next_is_one=self.ctl.hold_of(k0) == 1,
                              after_on_grid=self.ctl.on_grid(k0 + 1)):
            t0 = time.monotonic_ns()
            ctx = self.ctl.context(k)
            if self.shape.ahead_rounds:  # its rounds run ahead of the sample too
                f = InFlight(k, self.engine.cycle(ctx, gate=True), ctx, 0, t0,
                             awaiting_sample=True)
                self.inflight[k] = f
                self.primed.append((k, ctx))
                self.advance(f)
                continue
            try:
                self.engine.prefix(ctx)
            except ObserverDiverged as exc:
                raise Fault(f"cycle {k}: {exc}", process="central",
                            code=EXIT_OBSERVER) from None
            self.primed.append((k, ctx))
            self.meters.span("central", k, t0, time.monotonic_ns())
        return True

    def _synthetic_sample(self, k: int) -> list[int]:
        task = self.engine.cfg.task
        assert task is not None
        return synthetic_counts(self.engine.cfg.params, task.sample(self.ctl.time_of(k))[0])

    def advance(self, f: InFlight) -> None:
        """Run the interval's central steps up to its next round (or its end)."""
        f.start_ns = time.monotonic_ns()  # the central's span starts here, not at a send
        rnd = self._step(f)
        while rnd is AWAIT_SAMPLE:  # run ahead: its sample-free steps and rounds are done
            if f.awaiting_sample:
                f.gate()
                self.meters.span("central", f.cycle, f.start_ns, time.monotonic_ns())
                return
            rnd = self._step(f)  # the sample came while its rounds were out
        if not f.handed_off and (rnd is None or self.shape.round_step[rnd.index]
                                 > self.shape.handoff):
            self.ctl.handoff(f.ctx)
            f.handed()
        if rnd is None:
            self._finish(f)
            return
        f.at_round(rnd)
        self.outbox.append(f)
        self.meters.span("central", f.cycle, f.start_ns, time.monotonic_ns())

    @staticmethod
    def _step(f: InFlight) -> Round | None:
        """Run the steps of ``f`` up to its next round (None: to its end)."""
        try:
            rnd = f.gen.send(None) if f.started else next(f.gen)
        except StopIteration:
            rnd = None
        except ObserverDiverged as exc:
            raise Fault(f"cycle {f.cycle}: {exc}", process="central",
                        code=EXIT_OBSERVER) from None
        f.stepped()
        return rnd

    # -- messages out -----------------------------------------------------------------

    def flush(self, now: int) -> int:
        """Send every queued round as the parts of one request; returns, when a round is
        held back to be fused with the next interval's first round (realtime, depth 2),
        the time until which it is held, else 0."""
        if not self.outbox:
            return 0
        hold_until = self._hold_until()
        if hold_until and now < hold_until:
            return hold_until
        t_in = time.perf_counter_ns()
        limit_ns = self.silence.limit_ns(self.done)
        sch = self.settings
        round_trips = self.engine.plan.round_trips
        parts: list[dict[str, Any]] = []
        for f in self.outbox:
            rnd = f.round
            assert rnd is not None
            f.sent(sch.peripherals, deadline_ns=now + limit_ns,
                   late_ns=self.pace.round_late_at(f, rnd.index, round_trips))
            parts.append({"cycle": f.cycle, "stage": rnd.index,
                          "vals": Engine.request_vals(rnd, f.ctx, (0, 1, 2))})
        self.outbox.clear()
        self.silence.asked(now)
        self.out.request(parts, since_ns=t_in)
        return 0

    def _hold_until(self) -> int:
        """Depth 2 with a plant: a lone round of an interval past its hand-off waits for
        the next interval's first round, so that both go in one exchange. In realtime the
        next sample is due one period after this interval's; the round waits at most a
        quarter period past that (a late or lost sample). In lockstep the next sample
        follows the command just sent; the plant's silence is a fault after
        ``--timeout``."""
        f = self.outbox[0]
        sch = self.settings
        if not holds_lone_round(depth=sch.depth, ready=len(self.outbox), hold=sch.hold,
                                handed_off=f.handed_off, cycle=f.cycle,
                                next_cycle=self.next_cycle, cycles=min(sch.end, self.hold_from)):
            return 0
        return self.pace.hold_until(f, self.silence.limit_ns(self.done))

    def _finish(self, f: InFlight) -> None:
        t_in = time.perf_counter_ns()
        sch = self.settings
        # here, after the next request is out: off the critical path
        check_state(f.cycle, f.ctx.get("p"), f.ctx.get("pc"), params=self.engine.cfg.params,
                    max_error=sch.max_error, hint=self.hint)
        cmd = f.ctx["cmd"]
        now = self.out.command(f.cycle, cmd, grid=self.ctl)
        self.meters.span("central", f.cycle, f.start_ns, now)
        del self.inflight[f.cycle]
        self._log(f, cmd, now)
        if self.on_cycle is not None:
            self.on_cycle(f.cycle, f.ctx)
            self.meters.finished(f.cycle)
        self.meters.finish_ns += time.perf_counter_ns() - t_in

    def _log(self, f: InFlight, cmd: Any, now: int) -> None:
        """Log a finished interval (:meth:`CycleLog.record`), tell the overload rule, and
        sample the memory at its marks."""
        if self.log.record(f, cmd, now, deadline_ns=self.settings.deadline_ns):
            self.overload.mark_late(self.done, self.ctl.stride)
        self.overload.after_interval(self.done, self.ctl.stride)
        self.done += 1
        if self.done == WARM_RSS_AT:
            self.meters.rss_warm = rss_kb()
        if self.done % 10_000 == 0:
            self.meters.rss_series.append((self.done, rss_kb()))


__all__ = ["Intervals"]
