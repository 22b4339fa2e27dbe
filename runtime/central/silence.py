"""The central's silence watch: when a silent peripheral or plant is a fault.

Every wait of the scheduler is bounded: a peripheral or the plant silent beyond its limit
is a :class:`~.fault.Fault` naming the process. In realtime the limit is
``--fault-periods`` periods, lengthened by the central's own stalls, by a silence the
plant shared (a stall of the whole machine) and, for a role this central started, while
the kernel's accounting shows that the machine, not the process, is slow
(docs/faults-and-errors.md, the silence rule in three steps; its arithmetic is
:mod:`.silence_rule`). A role process that exits is a fault at once.

:class:`SilenceWatch` keeps when each role last spoke and was asked; the scheduler tells
it (:meth:`SilenceWatch.heard_sample`, :meth:`~SilenceWatch.heard_reply`,
:meth:`~SilenceWatch.asked`, :meth:`~SilenceWatch.woke`) and asks it
(:meth:`~SilenceWatch.check`, :meth:`~SilenceWatch.wake_at`).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Collection
from functools import partial

from ..config import EXIT_PERIPHERAL, EXIT_PLANT, RunConfig
from . import silence_rule
from .excuse import UNSUPERVISED, Excuse, Excuses, Supervision
from .exits import ExitWatch
from .fault import Fault, role_of
from .records import InFlight
from .silence_limits import STARTUP_INTERVALS, STARTUP_LIMIT_S, Paced, Timeout


class SilenceWatch:
    """When each role last spoke, and whether its silence is a fault.

    Parameters
    ----------
    peripherals : how many peripherals the unit has.
    realtime : the clock is ``realtime``: its limits are :class:`~.silence_limits.Paced`
        (else :class:`~.silence_limits.Timeout`, ``timeout_s``), chosen here once.
    period_s : the sampling period.
    fault_periods : realtime: the limit in periods (at the current control rate).
    timeout_s : the limit in the other clocks.
    stride : the control-rate divisor now: samples come every ``stride()`` periods.
    supervision : what the central can learn of the roles' processes.
    hint : appended to a fault's message (the overload hint of the scheduler).
    """

    def __init__(self, *, peripherals: int, realtime: bool, period_s: float,
                 fault_periods: float, timeout_s: float, stride: Callable[[], int],
                 supervision: Supervision = UNSUPERVISED,
                 hint: Callable[[], str] = str) -> None:
        self.period_ns = int(period_s * 1e9)
        self.supervision = supervision
        self.hint = hint
        self.stride = stride
        self.last_sample_ns = 0
        self.last_reply_ns = [0] * peripherals
        self.asked_ns = [0] * peripherals
        """The first request sent to each peripheral after its last reply."""
        self.plant_gaps: deque[tuple[int, int]] = deque(maxlen=8)
        """The plant's silences over two sample intervals (from, to), the newest."""
        self.own_gaps: deque[tuple[int, int]] = deque(maxlen=8)
        """The central's own stalls (from, to): it woke more than a period late."""
        self.excuse = Excuses(supervision, own_stall=partial(silence_rule.overlap, self.own_gaps))
        self.limits: Paced | Timeout = Paced(
            period_s=period_s, fault_periods=fault_periods, stride=stride,
            own_gaps=self.own_gaps, plant_gaps=self.plant_gaps,
            last_sample=lambda: self.last_sample_ns, excuse=self.excuse,
        ) if realtime else Timeout(timeout_s)
        """How long a silence may last, by the run's clock."""
        self.gone: set[int] = set()
        """Peripherals taken over (:meth:`forget`): their silence is no longer watched."""
        self.exits = ExitWatch(supervision)

    @classmethod
    def of(cls, rc: RunConfig, *, peripherals: int, stride: Callable[[], int],
           supervision: Supervision, hint: Callable[[], str]) -> SilenceWatch:
        """The watch of a run of ``rc`` (its clock, period, fault periods and time-out)."""
        sch = rc.schedule
        return cls(peripherals=peripherals, realtime=sch.clock == "realtime",
                   period_s=sch.period, fault_periods=sch.fault_periods,
                   timeout_s=rc.transport.timeout, stride=stride, supervision=supervision,
                   hint=hint)

    # -- what the scheduler tells it ------------------------------------------------------

    def heard_sample(self, rx: int) -> None:
        """A sample arrived at ``rx``."""
        if self.last_sample_ns and rx - self.last_sample_ns > 2 * self.period_ns * self.stride():
            self.plant_gaps.append((self.last_sample_ns, rx))  # the plant silent too
        self.last_sample_ns = rx

    def heard_reply(self, k: int, rx: int) -> None:
        """Peripheral ``k`` answered at ``rx`` (a late reply too: it is alive)."""
        self.last_reply_ns[k] = rx

    def asked(self, now: int) -> None:
        """A request went to every peripheral at ``now``."""
        for k in range(len(self.asked_ns)):
            if self.asked_ns[k] <= self.last_reply_ns[k]:
                self.asked_ns[k] = now
        self.limits.asked(now)

    def woke(self, meant_ns: int, now: int, *, slept_from: int | None = None) -> None:
        """The central meant to be awake again by ``meant_ns`` and woke at ``now``: more
        than a period later is a stall of its own (the machine did not run it), which the
        silence rule does not count (:meth:`_own_stall`).

        ``slept_from``: when the wait began. A wait that began after ``meant_ns`` (a look
        at the inbox without waiting, because something was already due) is late by
        nothing of its own: the stall is counted from the later of the two. Each stall
        starts no earlier than the last one ended, so that none is counted twice
        (silence_rule.overlap sums them): otherwise the loop's own looks would lengthen
        the silence they wait out (docs/measurements/2026-11-27-starvation.md)."""
        start = meant_ns if slept_from is None else max(meant_ns, slept_from)
        if self.own_gaps:
            start = max(start, self.own_gaps[-1][1])
        if now - start > self.period_ns:
            self.own_gaps.append((start, now))

    def forget(self, k: int) -> None:
        """Watch peripheral ``k`` no more: its rounds are taken over (.takeover). Its
        process, if this central started it, is let go for good."""
        self.gone.add(k)
        self.exits.let_go.add(role_of(k))

    def watch_again(self, k: int, now: int) -> None:
        """Peripheral ``k`` is back (.takeover): watch its silence again from ``now``."""
        self.gone.discard(k)
        self.exits.let_go.discard(role_of(k))
        self.last_reply_ns[k] = now
        self.asked_ns[k] = 0

    # -- the limit --------------------------------------------------------------------

    def limit_ns(self, done: int) -> int:
        """How long a reply or a sample may be missing before it is a fault, after
        ``done`` intervals (the clock's :meth:`~.silence_limits.Paced.limit_ns`). A reply
        later than its deadline but within that is lateness (a miss at the plant, or the
        late-data policy); silence for that long is a failed process or link."""
        return self.limits.limit_ns(done)

    def silent_since(self, k: int) -> int:
        """Since when peripheral ``k`` has been silent: its last reply, or the first
        request sent to it after that reply if one was. Time in which nothing was asked
        of it is not silence: with two intervals' rounds in one request (foresight 2) a
        peripheral is asked every second period, and counted from its last reply the
        silence limit would lose a period of its margin. A peripheral whose rounds the
        central computes is still asked, so a hung one is caught within the limit of the
        first request it did not answer (one that exits, within
        :data:`~.exits.CHILD_CHECK_S`: :meth:`check_children`)."""
        return max(self.last_reply_ns[k], self.asked_ns[k])

    def _own_stall(self, since: int, now: int) -> int:
        """How much of ``[since, now]`` the central itself did not run, where the clock
        counts it (:meth:`~.silence_limits.Paced.own_stall`)."""
        return self.limits.own_stall(since, now)

    def fault_at(self, since: int, now: int, limit_ns: int) -> int:
        """When a peripheral silent since ``since`` becomes a fault
        (:meth:`~.silence_limits.Paced.fault_at`: in realtime later by the central's own
        stalls and by a silence the plant shared)."""
        return self.limits.fault_at(since, now, limit_ns)

    def _limit_end(self, role: str, since: int, now: int, limit_ns: int) -> int:
        if role == "plant":  # its silence is the one the others' may share
            return since + limit_ns + self._own_stall(since, now)
        return self.fault_at(since, now, limit_ns)

    def silence_ends(self, role: str, since: int, now: int, limit_ns: int) -> int:
        """When the silence of ``role`` (silent since ``since``) becomes a fault: after
        ``limit_ns`` for the plant, :meth:`fault_at` for a peripheral, or later while it
        is excused (:meth:`Excuses.ask`)."""
        return self._excused_end(role, self._limit_end(role, since, now, limit_ns))

    def _excused_end(self, role: str, end: int) -> int:
        """``end`` (the limit's end of a silence of ``role``), or later while excused."""
        excused = self.excuse_of(role)
        return max(end, excused.until) if excused is not None else end

    @property
    def excuses(self) -> int:
        """Silences past their limit excused (:meth:`Excuses.ask`)."""
        return self.excuse.count

    def _answered(self, role: str) -> int:
        """When ``role`` last answered: its last sample or reply."""
        return self.last_sample_ns if role == "plant" \
            else self.last_reply_ns[int(role.rsplit("-", 1)[1]) - 1]

    def excuse_of(self, role: str) -> Excuse | None:
        """The excuse of the silence ``role`` is in (:meth:`Excuses.of`)."""
        return self.excuse.of(role, self._answered(role))

    def _silent(self, role: str, since: int, now: int, limit_ns: int,
                end: int | None = None) -> bool:
        """Whether the silence of ``role`` since ``since`` is a fault now (``end``: its
        limit's end, when the caller has it)."""
        if end is None:
            end = self._limit_end(role, since, now, limit_ns)
        return now > self._excused_end(role, end) and not self.limits.excused(
            role, since, now, limit_ns, answered=self._answered(role),
            limit_end=lambda: self._limit_end(role, since, now, limit_ns))

    # -- the faults' messages -----------------------------------------------------------

    def _how_lost(self, role: str) -> str:
        """How a silent peripheral was lost (:class:`~.fault.Fault`'s ``lost``): ``exited``
        where its process is known to have exited (killed, it falls silent within a few
        periods, before the exit check looks), else ``silent``."""
        state = self.supervision.role_state
        return "exited" if state is not None and state(role) == "exited" else "silent"

    def _state_note(self, role: str) -> str:
        """For a silence fault's message: what the silent process was doing, and its
        excuse (:meth:`Excuses.note`)."""
        return self.excuse.note(role, self._answered(role))

    def shared_note(self, since: int, now: int, limit_ns: int, *,
                    plant: bool = False) -> str:
        """For a fault's message: how much of a silence was not counted (:meth:`fault_at`;
        ``plant``: the plant's own silence, where only the central's stalls count)."""
        own = self._own_stall(since, now)
        shared = 0 if plant else self.fault_at(since, now, limit_ns) - since - limit_ns - own
        return (f", plus {own / 1e6:.1f} ms the central itself did not run" if own > 0
                else "") + (f", plus {shared / 1e6:.1f} ms the plant was silent too"
                            if shared > 0 else "")

    # -- what the scheduler asks --------------------------------------------------------

    def wake_at(self, now: int, limit_ns: int, intervals: Collection[InFlight]) -> int:
        """When the loop must look again for a silence, however quiet its inbox: a
        round's deadline, and in realtime the moment a silent peripheral or the plant
        would become a fault."""
        wake = now + limit_ns
        # asked on every turn of the loop: each silence's end and each excuse once a call
        # (the peripherals asked by one request share their silence's start)
        ends: dict[int, int] = {}
        until: dict[int, int] = {}

        def end_of(since: int) -> int:  # a peripheral's :meth:`silence_ends`, unexcused
            if since not in ends:
                ends[since] = self.fault_at(since, now, limit_ns)
            return ends[since]

        def excused_end(k: int, end: int) -> int:  # :meth:`_excused_end`
            if k not in until:
                excused = self.excuse_of(role_of(k))
                until[k] = 0 if excused is None else excused.until
            return max(end, until[k])

        live = self.limits.watched(self.last_reply_ns)
        for f in intervals:
            if f.waiting:
                end = end_of(f.deadline_ns - limit_ns)  # the same for each peripheral
                for k in f.waiting:
                    wake = min(wake, excused_end(k, end))
                    if k in live:  # between its rounds too: when it would fail
                        wake = min(wake, excused_end(k, end_of(self.silent_since(k))))
        if self.limits.watched([self.last_sample_ns]):  # the plant, between its samples
            wake = min(wake, self.silence_ends("plant", self.last_sample_ns, now, limit_ns))
        exit_check = self.exits.wake_at(now)  # an exit is seen within the check's time
        return wake if exit_check is None else min(wake, exit_check)

    def check(self, now: int, limit_ns: int, intervals: Collection[InFlight], *,
              done: int, plant_awaited: int | None, newest_sample: int,
              started_ns: int) -> None:
        """Raise the fault of a silent peripheral or plant at ``now``: in realtime (once
        an interval is ``done``) a peripheral silent past its limit while an interval
        waits for it or holds its values; a peripheral that has not answered a round past
        the round's limit; the plant silent past its limit while interval
        ``plant_awaited`` waits for its sample and no round waits for a reply (silent
        since its last sample, or since ``started_ns``)."""
        for k in self.limits.watched(self.last_reply_ns) if done else ():  # held data too
            if k not in self.gone:
                t = self.silent_since(k)
                role = role_of(k)
                if any(k in f.dropped or k in f.waiting for f in intervals) \
                        and self._silent(role, t, now, limit_ns):
                    raise Fault(f"peripheral {k + 1} has not answered for "
                                f"{(now - t) / 1e6:.1f} ms (limit {limit_ns / 1e6:.1f} ms"
                                f"{self.shared_note(t, now, limit_ns)})"
                                f"{self._state_note(role)}{self.hint()}",
                                process=role, code=EXIT_PERIPHERAL, lost=self._how_lost(role))
        for f in intervals:
            since = f.deadline_ns - limit_ns
            if not f.waiting:
                continue
            end = self.fault_at(since, now, limit_ns)
            if now <= end:
                continue  # within the limit: no excuse can make it a fault sooner
            for k in sorted(f.waiting - self.gone):
                role = role_of(k)
                if not self._silent(role, since, now, limit_ns, end):
                    continue
                raise Fault(
                    f"peripheral {k + 1} did not answer round {f.round.index if f.round else '?'}"
                    f" of cycle {f.cycle}: silent for {(now - since) / 1e6:.1f} ms (limit "
                    f"{limit_ns / 1e6:.1f} ms{self.shared_note(since, now, limit_ns)})"
                    f"{self._state_note(role)}{self.hint()}",
                    process=role, code=EXIT_PERIPHERAL, lost=self._how_lost(role))
        if plant_awaited is not None and not any(f.waiting for f in intervals):
            last = self.last_sample_ns or started_ns
            if self._silent("plant", last, now, limit_ns):
                raise Fault(f"no sample from the plant for {(now - last) / 1e6:.1f} ms "
                            f"(cycle {plant_awaited} awaited, newest seen "
                            f"{newest_sample}"
                            f"{self.shared_note(last, now, limit_ns, plant=True)})"
                            f"{self._state_note('plant')}"
                            f"{self.hint()}", process="plant", code=EXIT_PLANT)

    def check_children(self) -> None:
        """Fault at once when a role process this central started has exited
        (:meth:`ExitWatch.check`)."""
        self.exits.check()


__all__ = ["STARTUP_INTERVALS", "STARTUP_LIMIT_S", "SilenceWatch"]
