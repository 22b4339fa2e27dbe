"""The central's guard: faults, silence, deadlines, late data and the robot's state.

Every wait of the scheduler is bounded: a peripheral or the plant silent beyond its limit
is a :class:`Fault` naming the process; in realtime a round's late replies follow the
late-data policy (wait, hold the last values, fault); the observed state must track the
reference within ``--max-error`` and stay in the usable workspace (Eq. V.33). A fault ends
the run with its exit code, and :meth:`CentralGuard.hold_torques` gives the plant the
torques to hold while it stops (docs/faults-and-errors.md).

:class:`CentralGuard` is a part of :class:`~.central.Central` (a mixin): it reads the
scheduler's state (``inflight``, ``last_reply_ns``, ``samples``, ...) and never changes
the schedule except to hold a late round's values.
"""

from __future__ import annotations

import math
import time
from typing import TYPE_CHECKING, Any, NamedTuple

import msgpack

from ..kernels.workspace import check_point
from . import silence_rule
from .config import EXIT_OBSERVER, EXIT_PERIPHERAL, EXIT_PLANT, LATE_POLICIES
from .engine import Engine
from .supervise import MachineLoad, ThreadTimes, cpu_denied

if TYPE_CHECKING:
    from .central_state import InFlight


class Fault(RuntimeError):
    """A detected fault: ``process`` names the failed process, ``code`` the exit code."""

    def __init__(self, message: str, *, process: str, code: int) -> None:
        super().__init__(message)
        self.process = process
        self.code = code


class Excuse(NamedTuple):
    """A silence past its limit that is not a fault yet (:meth:`CentralGuard._excuse`)."""

    since: int
    """When the silence it excuses began."""
    until: int
    """No fault before this."""
    at: int
    """When it was granted or last renewed."""
    times: tuple[ThreadTimes, ThreadTimes, int | None] | None
    """The silent process's and the central's Zenoh threads' scheduler accounting then,
    and the machine's CPU pressure (:attr:`~.supervise.MachineLoad.pressure_ns`)."""
    runnable: bool
    """Whether the silent process was runnable then."""
    renewals: int = 0
    seen: tuple[int, int, int, int] | None = None
    """Of the last window looked at: its length, how long the machine kept the process
    (or the central's Zenoh threads) from a CPU, how much CPU it got, how long tasks
    waited for a CPU in it (ns); for the fault's message."""


class CentralGuard:
    """Faults, deadlines and late data of :class:`~.central.Central`."""

    def _timeout_ns(self) -> int:
        """How long a reply or a sample may be missing before it is a fault: the
        ``--timeout`` in lockstep and freerun; in realtime ``--fault-periods`` periods
        (default 3; during the first 20 intervals at least 20 ms). A reply later than its
        deadline but within that is lateness (a miss at the plant, or the late-data
        policy); silence for that long is a failed process or link."""
        if self.rc.schedule.clock == "realtime":  # samples every stride periods
            limit = self.rc.schedule.fault_periods * self.rc.schedule.period * self.ctl.stride
            if self.done < self.STARTUP_INTERVALS:  # first real intervals: start-up
                limit = max(limit, self.STARTUP_LIMIT_S)
            return int(limit * 1e9)
        return int(self.rc.transport.timeout * 1e9)

    STARTUP_INTERVALS = 20

    STARTUP_LIMIT_S = 0.020
    """Realtime: until this many intervals are done the silence limit is at least
    ``STARTUP_LIMIT_S`` (first samples, first real values through every process)."""

    def _own_stall(self, since: int, now: int) -> int:
        """Realtime: how much of ``[since, now]`` the central itself did not run (it woke
        more than a period after it meant to: ``own_gaps``). No silence can be judged
        while the judge is stopped; a process that failed in that time is named within
        the limit after the central runs again."""
        if self.rc.schedule.clock != "realtime":
            return 0
        return silence_rule.overlap(self.own_gaps, since, now)

    def _plant_shared(self, since: int, now: int, timeout_ns: int) -> int:
        """The part of a silence since ``since`` that the plant's samples shared (gaps in
        them longer than two periods, less the period a sample takes anyway) beyond the
        central's own stalls (:meth:`_own_stall`), up to one limit."""
        return silence_rule.plant_shared(
            self.plant_gaps, self.last_sample_ns, since, now,
            every_ns=self.period_ns * self.ctl.stride,  # how often the plant samples
            own_ns=self._own_stall(since, now), limit_ns=timeout_ns)

    def _fault_at(self, since: int, now: int, timeout_ns: int) -> int:
        """When a process silent since ``since`` becomes a fault: ``since + timeout_ns``;
        in realtime, later by the part of the silence in which the central itself did not
        run (:meth:`_own_stall`), and once that has passed, by the part the plant's
        samples shared, up to one more limit (:meth:`_plant_shared`). A silence the whole
        unit shares is a stall of the machine (all five processes stopped: a busy host's
        stalls run 6-26 ms), not a failed process; a frozen process is still named while
        the plant goes on talking.
        """
        realtime = self.rc.schedule.clock == "realtime"
        end = silence_rule.fault_at(since, now, timeout_ns,
                                    own_ns=self._own_stall(since, now), realtime=realtime)
        if end >= now or not realtime:
            return end
        return end + self._plant_shared(since, now, timeout_ns)

    def _silence_ends(self, role: str, since: int, now: int, timeout_ns: int) -> int:
        """When the silence of ``role`` (silent since ``since``) becomes a fault: after
        ``timeout_ns`` for the plant, :meth:`_fault_at` for a peripheral, or later while
        it is excused (:meth:`_excuse`)."""
        return self._excused_end(role, self._limit_end(role, since, now, timeout_ns))

    def _excused_end(self, role: str, end: int) -> int:
        """``end`` (the limit's end of a silence of ``role``), or later while excused."""
        excused = self._excuse_of(role)
        return max(end, excused.until) if excused is not None else end

    def _excuse_of(self, role: str) -> Excuse | None:
        """The excuse of the silence ``role`` is in: one granted or renewed since it last
        answered (a reply, a sample), whichever of its silence's starts (its last reply,
        the request after it, a round's sending) the check that granted it looked at."""
        excused = self.excused.get(role)
        if excused is None:
            return None
        answered = self.last_sample_ns if role == "plant" \
            else self.last_reply_ns[int(role.rsplit("-", 1)[1]) - 1]
        if excused.at > answered:
            return excused
        del self.excused[role]  # that silence ended: the loop's next looks find nothing
        return None

    def _limit_end(self, role: str, since: int, now: int, timeout_ns: int) -> int:
        if role == "plant":  # its silence is the one the others' may share
            return since + timeout_ns + self._own_stall(since, now)
        return self._fault_at(since, now, timeout_ns)

    def _silent(self, role: str, since: int, now: int, timeout_ns: int,
                end: int | None = None) -> bool:
        """Whether the silence of ``role`` since ``since`` is a fault now (``end``: its
        limit's end, when the caller has it)."""
        if end is None:
            end = self._limit_end(role, since, now, timeout_ns)
        return now > self._excused_end(role, end) \
            and not self._excuse(role, since, now, timeout_ns)

    EXCUSED_LIMITS = 8
    """Realtime: however long the machine keeps a silent process (or the central's own
    Zenoh threads) from a CPU, its silence is a fault once it lasts this many limits
    (24 ms at 1 ms and ``--fault-periods 3``; the reference machine's stalls ran 6-26
    ms). The robot's tracking is watched all along (``--max-error``)."""

    def _excuse(self, role: str, since: int, now: int, timeout_ns: int) -> bool:
        """Realtime, a role this central started: a silence past its limit is not yet a
        fault while the machine, not the process, is slow. The first time, for one more
        limit, while the silent process is runnable (running or waiting for a CPU), or
        while it sleeps and one of the central's own Zenoh threads is runnable or the
        machine has more runnable tasks than CPUs (the silent process is working through
        what it was sent, or what is in transit waits for a CPU: on 2026-11-24 a 60 s
        run at 1 ms ended 30 intervals before its end on a peripheral silent 3.3 ms
        against a 3 ms limit). The plant is excused while it sleeps too: it samples on
        its own clock and waits for nothing in transit, so a plant asleep past its tick
        is a timer the machine has not served yet (on 2026-11-25 a 60 s run at 1 ms
        stopped after 4202 periods on the plant silent 3.1 ms, asleep when looked at and
        runnable a moment later). Then, a limit at a time, while the kernel's accounting
        shows that over the last limit the machine kept the silent process or the
        central's Zenoh threads from a CPU, or kept its own tasks waiting for one, for at
        least half of it (:meth:`_renew`), up to :attr:`EXCUSED_LIMITS` in all. A stopped or exited
        process is a fault at once, a sleeping peripheral with nothing in transit too,
        and one that ran but did not answer while the machine let everything run (e.g.
        a deadlock) at the end of its extension."""
        if self.rc.schedule.clock != "realtime" or self.role_state is None:
            return False
        prev = self._excuse_of(role)
        if prev is not None:
            return self._renew(role, prev, now, timeout_ns)
        state = self.role_state(role)
        load = self._machine()
        if not (state == "runnable" or (state == "sleeping" and (
                role == "plant" or self.role_state("central") == "runnable"
                or load.waiting))):
            return False
        self.excused[role] = Excuse(since, self._limit_end(role, since, now, timeout_ns)
                                    + timeout_ns, now, self._times(role, load),
                                    state == "runnable")
        self.excuses += 1
        return True

    def _times(self, role: str, load: MachineLoad | None = None
               ) -> tuple[ThreadTimes, ThreadTimes, int | None] | None:
        """The scheduler accounting of ``role``'s threads and of the central's Zenoh
        threads, and the machine's CPU pressure (from ``load`` where the caller has just
        read it); None where this central cannot read them."""
        if self.role_times is None:
            return None
        load = load or self._machine()
        return self.role_times(role), self.role_times("central"), load.pressure_ns

    def _machine(self) -> MachineLoad:
        """How short of CPUs the machine is, where this central can read it."""
        return self.machine_load() if self.machine_load is not None \
            else MachineLoad(None, None)

    def _renew(self, role: str, prev: Excuse, now: int, timeout_ns: int) -> bool:
        """Extend an excused silence by one more limit if, in the window since it was
        granted or last renewed, the machine kept the silent process or the central's
        Zenoh threads from a CPU (:func:`~.supervise.cpu_denied`), or kept some task
        waiting for one (the CPU pressure, which counts a wait still going on: a thread's
        own wait is added up only when it runs again), for at least half the window, and
        the silence is shorter than :attr:`EXCUSED_LIMITS` limits (plus the central's
        own stalls). A process that was not denied its CPU and did not answer is a
        fault, as is one stopped or exited meanwhile."""
        times = self._times(role)
        last = silence_rule.renewal_cap(prev.since, timeout_ns, self.EXCUSED_LIMITS,
                                        self._own_stall(prev.since, now))
        if prev.times is None or times is None or now >= last:
            return False
        state = self.role_state(role) if self.role_state is not None else "unknown"
        if state not in ("runnable", "sleeping"):
            return False
        window = now - prev.at
        denied, ran = cpu_denied(prev.times[0], times[0], window_ns=window,
                                 runnable=prev.runnable and state == "runnable")
        ours, _ = cpu_denied(prev.times[1], times[1], window_ns=window, runnable=False)
        waited = 0 if prev.times[2] is None or times[2] is None \
            else min(window, max(0, times[2] - prev.times[2]))
        seen = (window, max(denied, ours), ran, waited)
        if not silence_rule.renewal_holds(window, denied, ours, waited):
            self.excused[role] = prev._replace(seen=seen)
            return False
        self.excused[role] = Excuse(prev.since, min(now + timeout_ns, last), now, times,
                                    state == "runnable", prev.renewals + 1, seen)
        self.excuses += 1
        return True

    def _state_note(self, role: str) -> str:
        """For a silence fault's message: what the silent process was doing, where known,
        whether this silence was excused (:meth:`_excuse`) and, where its last extension
        was looked at, how long the machine kept it from a CPU in it, how much CPU it
        got and how long the machine's tasks waited for one."""
        if self.role_state is None:
            return ""
        excused = self._excuse_of(role)
        note = ""
        if excused is not None:
            n = excused.renewals + 1
            note = (" (after one extension of its limit" if n == 1
                    else f" (after {n} extensions of its limit")
            if excused.seen is not None:
                window, denied, ran, waited = excused.seen
                note += (f"; in the last {window / 1e6:.1f} ms it was kept from a CPU "
                         f"{denied / 1e6:.1f} ms and ran {ran / 1e6:.1f} ms, and tasks "
                         f"waited for a CPU {waited / 1e6:.1f} ms")
            note += ")"
        return f"; its process was {self.role_state(role)}{note}"

    def _shared_note(self, since: int, now: int, timeout_ns: int, *,
                     plant: bool = False) -> str:
        """For a fault's message: how much of a silence was not counted (:meth:`_fault_at`;
        ``plant``: the plant's own silence, where only the central's stalls count)."""
        own = self._own_stall(since, now)
        shared = 0 if plant else self._fault_at(since, now, timeout_ns) - since - timeout_ns - own
        return (f", plus {own / 1e6:.1f} ms the central itself did not run" if own > 0
                else "") + (f", plus {shared / 1e6:.1f} ms the plant was silent too"
                            if shared > 0 else "")

    def _next_check(self, now: int, timeout_ns: int, hold_until: int) -> int:
        """When the loop must look at the clock again, however quiet the inbox: a held
        round's release, a round's deadline, its late-data time where the round's policy
        acts on it (``hold`` or ``fault``: under ``wait``, the default, lateness changes
        nothing, and each such wake cost the central a wake-up of its inbox's ticker
        thread), and in realtime the moment a silent peripheral or plant would become a
        fault."""
        wake = now + timeout_ns
        if hold_until:
            wake = min(wake, hold_until)
        for f in self.inflight.values():
            if f.waiting:
                since = f.deadline_ns - timeout_ns
                end = self._fault_at(since, now, timeout_ns)  # the same for each peripheral
                for k in f.waiting:
                    wake = min(wake, self._excused_end(f"peripheral-{k + 1}", end))
                if f.late_ns and f.round is not None \
                        and self.late_policy[f.round.index] != "wait":
                    wake = min(wake, f.late_ns)
                if self.rc.schedule.clock == "realtime":  # liveness: wake when it would fail
                    for k in f.waiting:
                        if self.last_reply_ns[k]:
                            wake = min(wake, self._silence_ends(
                                f"peripheral-{k + 1}", self._silent_since(k), now,
                                timeout_ns))
        if self.rc.schedule.clock == "realtime" and self.last_sample_ns:
            wake = min(wake, self._silence_ends("plant", self.last_sample_ns, now,
                                                timeout_ns))
        return wake

    def _silent_since(self, k: int) -> int:
        """Since when peripheral ``k`` has been silent: its last reply, or the first request
        sent to it after that reply if one was. Time in which nothing was asked of it is
        not silence: with two intervals' rounds in one request (``foreseen2``) a
        peripheral is asked every second period, and counted from its last reply the
        silence limit would lose a period of its margin. A peripheral whose rounds the
        central computes is still asked, so a hung one is caught within the limit of the
        first request it did not answer (one that exits, within 50 ms:
        :meth:`_check_children`)."""
        return max(self.last_reply_ns[k], self.asked_ns[k])

    def _check_deadlines(self, timeout_ns: int) -> None:
        """Raise the fault of a silent peripheral or plant, unless messages are still
        waiting in the inbox (the central may have been the slow one: a reply it has not
        read yet is not silence). Those are read first, and the silence is looked at only
        once none waits: looking costs a late central most (the excuse reads ``/proc``,
        0.25-0.3 ms a process on the reference machine, and the fault's message again),
        and until 2026-11-24 it was done at every turn of the loop and the fault dropped
        when a message waited."""
        if self.node.events.pending():
            return  # the check runs again after each event
        self._find_silence(timeout_ns)

    def _find_silence(self, timeout_ns: int) -> None:
        now = time.monotonic_ns()
        if self.rc.schedule.clock == "realtime" and self.done:
            for k, last in enumerate(self.last_reply_ns):  # alive, even when its data is held
                t = self._silent_since(k) if last else 0
                role = f"peripheral-{k + 1}"
                if t and any(k in f.dropped or k in f.waiting for f in self.inflight.values()) \
                        and self._silent(role, t, now, timeout_ns):
                    raise Fault(f"peripheral {k + 1} has not answered for "
                                f"{(now - t) / 1e6:.1f} ms (limit {timeout_ns / 1e6:.1f} ms"
                                f"{self._shared_note(t, now, timeout_ns)})"
                                f"{self._state_note(role)}{self._overload_hint()}",
                                process=role, code=EXIT_PERIPHERAL)
        for f in self.inflight.values():
            since = f.deadline_ns - timeout_ns
            if not f.waiting:
                continue
            end = self._fault_at(since, now, timeout_ns)
            if now <= end:
                continue  # within the limit: no excuse can make it a fault sooner
            for k in sorted(f.waiting):
                role = f"peripheral-{k + 1}"
                if not self._silent(role, since, now, timeout_ns, end):
                    continue
                raise Fault(
                    f"peripheral {k + 1} did not answer round {f.round.index if f.round else '?'}"
                    f" of cycle {f.cycle}: silent for {(now - since) / 1e6:.1f} ms (limit "
                    f"{timeout_ns / 1e6:.1f} ms{self._shared_note(since, now, timeout_ns)})"
                    f"{self._state_note(role)}{self._overload_hint()}",
                    process=role, code=EXIT_PERIPHERAL)
        if (self.rc.schedule.clock != "freerun" and not self.samples
                and self.next_cycle < self.cycles
                and not any(f.waiting for f in self.inflight.values())):
            last = self.last_sample_ns or self.t_start_ns
            if self._silent("plant", last, now, timeout_ns):
                raise Fault(f"no sample from the plant for {(now - last) / 1e6:.1f} ms "
                            f"(cycle {self.next_cycle} awaited, newest seen "
                            f"{self.newest_sample}"
                            f"{self._shared_note(last, now, timeout_ns, plant=True)})"
                            f"{self._state_note('plant')}"
                            f"{self._overload_hint()}", process="plant", code=EXIT_PLANT)

    def _check_children(self) -> None:
        """Fault at once when a role process this central started has died."""
        if self.child_check is None:
            return
        now = time.monotonic()
        if now < self._next_child_check:
            return
        self._next_child_check = now + 0.05
        dead = self.child_check()
        if dead is not None:
            name, rc = dead
            code = EXIT_PLANT if name == "plant" else EXIT_PERIPHERAL
            raise Fault(f"{name} exited (status {rc})", process=name, code=code)

    def _late_policies(self) -> dict[int, str]:
        """Policy per round: the strictest of its blocks' (fault > hold > compute > wait);
        every round has at least one block."""
        order = {p: k for k, p in enumerate(LATE_POLICIES)}
        sch = self.rc.schedule
        return {r.index: max((sch.late.get(b.name, sch.late_policy) for b in r.blocks),
                             key=order.__getitem__) for r in self.plan.rounds}

    def _check_late(self, now: int) -> None:
        if self.rc.schedule.clock != "realtime":
            return
        for f in list(self.inflight.values()):
            if not f.waiting or f.round is None or not f.late_ns or now < f.late_ns:
                continue
            policy = self.late_policy[f.round.index]
            if policy == "wait":
                f.late_ns = 0
                continue
            if policy == "compute":
                if self.node.events.pending():
                    continue  # a reply may be among them: read first, look again after
                if not self._compute_late(f):
                    f.late_ns = 0  # it needs values the peripherals kept: wait
                continue
            k = min(f.waiting)
            late = [b.name for b in f.round.blocks]
            if policy == "fault":
                raise Fault(f"late data: peripheral {k + 1} missed the deadline of round "
                            f"{f.round.index} ({', '.join(late)}) of cycle {f.cycle}",
                            process=f"peripheral-{k + 1}", code=EXIT_PERIPHERAL)
            # hold: the last values of the missing peripherals' axes; a peripheral that
            # never answered this round has none (its slots are None): wait for it
            if not all(self.last_vals.get(name, (None,) * 3)[a] is not None
                       for name in f.round.recv for p in f.waiting
                       for a in self.plan.placement.axes[p]):
                f.late_ns = 0  # nothing to hold yet: wait
                continue
            for p in sorted(f.waiting):
                axes = self.plan.placement.axes[p]
                held = {name: [self.last_vals[name][a] for a in axes] for name in f.round.recv}
                Engine.merge(f.ctx, held, axes)
                for a in axes:
                    self.late_per_axis[a] += 1
                f.dropped.add(p)
                self.held.add((f.cycle, f.round.index, p))
                if self.on_message is not None:  # the recording, so that replay holds too
                    self.on_message("held", f"{self.node.keys.root}/faults/held", f.cycle,
                                    f.round.index, msgpack.packb(
                                        {"cycle": f.cycle, "stage": f.round.index,
                                         "peripheral": p, "vals": held},
                                        use_single_float=False), now)
                if len(self.held) > 1024:
                    self.held.discard(min(self.held))
            f.waiting.clear()
            self._advance(f)

    def _compute_late(self, f: InFlight) -> bool:
        """``--late-policy compute``: run the round of ``f`` for the axes of the peripherals
        that have not answered, here, with the kernels they would have run on the values
        they were sent (bit for bit their reply's values), and go on with the interval.
        Their replies, when they come, are counted as late; their silence is still
        watched (a peripheral that stays silent is a fault as ever). False, and nothing
        done, where the round needs values only the peripherals hold."""
        rnd = f.round
        assert rnd is not None
        late = sorted(f.waiting)
        axes = [a for p in late for a in self.plan.placement.axes[p]]
        if not Engine.can_run(rnd, f.ctx, axes):
            return False
        t0 = time.monotonic_ns()
        self.engine.run_round(rnd, f.ctx, axes)
        for p in late:
            paxes = self.plan.placement.axes[p]
            Engine.merge(self.last_vals, Engine.reply_vals(rnd, f.ctx, paxes), paxes)
            for a in paxes:
                self.late_per_axis[a] += 1
            f.dropped.add(p)
            self.held.add((f.cycle, rnd.index, p))
            self.computed += 1
            if self.on_message is not None:  # the recording: replay knows the reply is missing
                self.on_message("computed", f"{self.node.keys.root}/faults/computed", f.cycle,
                                rnd.index, msgpack.packb({"cycle": f.cycle, "stage": rnd.index,
                                                          "peripheral": p}), t0)
        while len(self.held) > 1024:  # bounded: the oldest rounds' late replies forgotten
            self.held.discard(min(self.held))
        self._span("central", f.cycle, t0, time.monotonic_ns())
        f.waiting.clear()
        self._advance(f)
        return True

    def _check_state(self, f: InFlight) -> None:
        """The observed state must track the reference and stay in the usable workspace
        (Eq. V.33, checked every 10th interval); otherwise stop safely with a reason."""
        p, pc = f.ctx.get("p"), f.ctx.get("pc")
        if p is None or pc is None:
            return
        err = math.dist(p, pc)
        why = None
        if err > self.rc.control.max_error:
            why = (f"tracking error {err * 1e3:.1f} mm exceeds --max-error "
                   f"{self.rc.control.max_error * 1e3:.1f} mm")
        elif f.cycle % 10 == 0:
            chk = check_point(self.engine.cfg.params, p)
            if not chk.ok:
                why = f"the robot left the usable workspace: {chk.reason}"
        if why is None:
            return
        raise Fault(f"cycle {f.cycle}: {why}{self._overload_hint()}", process="central",
                    code=EXIT_OBSERVER)

    def _overload_hint(self) -> str:
        """In realtime, when most deadlines were missed: say that the machine, not a
        process, is the likely cause."""
        periods = max(1, self.next_cycle)
        late = self.plant_misses + self.skipped
        if self.rc.schedule.clock != "realtime" or late <= max(5, periods // 10):
            return ""
        return (f"; {self.plant_misses} commands missed their deadline and {self.skipped} "
                f"samples were skipped in {periods} periods: this machine does not sustain "
                f"a {self.rc.schedule.period * 1e3:g} ms period with {self.n} peripheral(s) (try a "
                "longer --period or --fault-periods, or --clock lockstep)")

    def hold_torques(self) -> list[float]:
        """Gravity-holding torques at the last estimated position (the first stage of the
        safe stop); zeros if that position is not usable."""
        from ..kernels.dynamics import gravity_torques

        p = self.ctl.est[0]
        try:
            if check_point(self.engine.cfg.params, p).ok:
                return [float(x) for x in gravity_torques(self.engine.cfg.params, p)]
        except (ValueError, ZeroDivisionError):
            pass
        return [0.0, 0.0, 0.0]


ROLE_REPORT_FIELDS: dict[str, tuple[type, ...]] = {
    "exit": (str,), "sched": (str,), "served": (int,), "samples": (int,), "misses": (int,),
    "busy_ns": (int,), "wall_ns": (int,), "cpu_s": (int, float), "rejected": (dict,),
    "rss_kb": (dict,), "safe_stop": (dict,), "commands": (int,), "spares": (int,),
}
"""What a role's ``bye`` report may hold, by field; anything else is left out."""


def role_report(report: dict[str, Any]) -> dict[str, Any]:
    """The fields of a role's final report that have the type the report reader expects
    (:data:`ROLE_REPORT_FIELDS`; ``rejected`` keeps only counts by text reason), so that
    a malformed or forged ``bye`` cannot break the run's report."""
    out: dict[str, Any] = {}
    for name, types in ROLE_REPORT_FIELDS.items():
        v = report.get(name)
        if isinstance(v, bool) or not isinstance(v, types):
            continue
        if name == "rejected":
            v = {k: n for k, n in v.items() if isinstance(k, str) and type(n) is int}
        out[name] = v
    return out
