"""Excuses for a silence (realtime): a role this central started that is silent past its
limit is not a fault yet while the kernel's accounting shows that the machine, not the
process, is slow (docs/faults-and-errors.md, the silence rule's third step).

:class:`Supervision` is what the central can learn about the role processes it started;
:class:`Excuses` grants and renews the excuses from it.
"""

from __future__ import annotations

import os
from collections import deque
from collections.abc import Callable
from typing import NamedTuple

from ..roles.supervise import MachineLoad, ThreadTimes, cpu_denied, cpu_pressure_ns
from . import silence_rule


class Supervision(NamedTuple):
    """What the central can learn about the role processes it started, from the
    launcher at construction; each None where it cannot (roles started by hand, on
    other hosts)."""

    child_check: Callable[..., tuple[str, int] | None] | None = None
    """``child_check(skip=())``: the name and exit status of a role process that has
    exited, other than those named in ``skip``, else None."""
    role_state: Callable[[str], str] | None = None
    """What a role's process is doing (:func:`~ctrlunit.runtime.roles.supervise.process_state`);
    ``"central"``: the central's own Zenoh threads."""
    role_times: Callable[[str], ThreadTimes] | None = None
    """The scheduler accounting of a role's threads
    (:func:`~ctrlunit.runtime.roles.supervise.thread_times`)."""
    machine_load: Callable[[], MachineLoad] | None = None
    """How short of CPUs the machine is (:func:`~ctrlunit.runtime.roles.supervise.machine_load`)."""
    restart: Callable[[str], None] | None = None
    """``restart(role)``: start a role whose process exited anew, in the background and
    under the default policy (a lost peripheral: .takeover): its start-up, about a
    CPU-second of imports, takes no CPU from the unit's SCHED_FIFO threads."""
    promote: Callable[[str], None] | None = None
    """``promote(role)``: give a role started again, once it is set up, the scheduling
    policy the calling thread has (the unit's)."""
    last_cpus: Callable[[str], set[int]] | None = None
    """The CPUs a role's threads last ran on
    (:func:`~ctrlunit.runtime.roles.supervise.process_cpus`)."""


UNSUPERVISED = Supervision()
"""Roles this central did not start: nothing known of their processes."""

EXCUSED_LIMITS = 8
"""Realtime: however long the machine keeps a silent process (or the central's own Zenoh
threads) from a CPU, its silence is a fault once it lasts this many limits (24 ms at 1 ms
and ``--fault-periods 3``; the reference machine's stalls ran 6-26 ms). The robot's
tracking is watched all along (``--max-error``)."""


TICKS_PER_S = os.sysconf("SC_CLK_TCK")
TICK_NS = 1_000_000_000 // TICKS_PER_S
"""The kernel counts the hypervisor's steal in these ticks (10 ms at the usual 100 a
second, ``/proc/stat``): a renewal counts a tick moved on the silent process's CPU as
the window's length at most."""

MARK_EVERY_NS = 2_000_000
"""How often, at most, the central notes the machine's CPU pressure as it sends a request
(:meth:`Excuses.mark`, 10-40 us a reading): a silence's first excuse reads the pressure
since the last note before the silence began."""

FIRST_PRESSURE_SHARE = 0.25
"""A silent process asleep is excused the first time when tasks waited for a CPU for at
least this share of the time since the silence began: a burst of another real-time task
on one CPU of two shows as half its length in the machine's pressure when the other CPU
is busy (the kernel weighs each CPU's stalls by its busy time)."""


class Excuse(NamedTuple):
    """A silence past its limit that is not a fault yet (:meth:`Excuses.ask`)."""

    since: int
    """When the silence it excuses began."""
    until: int
    """No fault before this."""
    at: int
    """When it was granted or last renewed."""
    times: tuple[ThreadTimes, ThreadTimes, int | None, list[float] | None] | None
    """The silent process's and the central's Zenoh threads' scheduler accounting then,
    the machine's CPU pressure and what the hypervisor had taken from each CPU
    (:attr:`~ctrlunit.runtime.roles.supervise.MachineLoad.pressure_ns`, ``stolen_s``)."""
    runnable: bool
    """Whether the silent process was runnable then."""
    renewals: int = 0
    seen: tuple[int, int, int, int, int] | None = None
    """Of the last window looked at: its length, how long the machine kept the process
    (or the central's Zenoh threads) from a CPU, how much CPU it got, how long tasks
    waited for a CPU in it (ns), and the ticks of steal counted on a CPU the process last
    ran on (:meth:`Excuses._stolen_ticks`); for the fault's message."""


class Excuses:
    """The excuses of one central's silences.

    Parameters
    ----------
    supervision : what the central can learn of the roles' processes.
    own_stall : ``own_stall(since, now)``: how much of ``[since, now]`` the central itself
        did not run (not counted towards :data:`EXCUSED_LIMITS`).
    """

    def __init__(self, supervision: Supervision, *,
                 own_stall: Callable[[int, int], int]) -> None:
        self.supervision = supervision
        self.own_stall = own_stall
        self.granted: dict[str, Excuse] = {}
        """The excuse of each role's silence, by role (until it answers)."""
        self.count = 0
        """Excuses granted or renewed."""
        self.marks: deque[tuple[int, int]] = deque(maxlen=64)
        """``(when, CPU pressure ns)``, noted as requests are sent (:meth:`mark`)."""

    def mark(self, now: int, *, read: Callable[[], int | None] = cpu_pressure_ns) -> None:
        """Note the machine's CPU pressure at ``now`` (a request was sent), at most once per
        :data:`MARK_EVERY_NS`, where this central supervises its roles."""
        if self.supervision.role_state is None:
            return
        if self.marks and now - self.marks[-1][0] < MARK_EVERY_NS:
            return
        pressure = read()
        if pressure is not None:
            self.marks.append((now, pressure))

    def waited_since(self, since: int, now: int, pressure: int | None) -> bool:
        """Whether tasks waited for a CPU for :data:`FIRST_PRESSURE_SHARE` of the time from
        the last note at or before ``since`` to ``now`` (``pressure``: read at ``now``)."""
        if pressure is None:
            return False
        before = [m for m in self.marks if m[0] <= since]
        if not before:
            return False
        at, then = before[-1]
        return now > at and pressure - then >= FIRST_PRESSURE_SHARE * (now - at)

    def of(self, role: str, answered: int) -> Excuse | None:
        """The excuse of the silence ``role`` is in: one granted or renewed since it last
        answered (``answered``: its last reply or sample), whichever of its silence's
        starts (its last reply, the request after it, a round's sending) the check that
        granted it looked at."""
        excused = self.granted.get(role)
        if excused is None:
            return None
        if excused.at > answered:
            return excused
        del self.granted[role]  # that silence ended: the loop's next looks find nothing
        return None

    def ask(self, role: str, since: int, now: int, limit_ns: int, *, answered: int,
            limit_end: Callable[[], int]) -> bool:
        """Whether the silence of ``role`` since ``since``, past its limit (which ends at
        ``limit_end()``), is excused now. The first time, for one more limit, while the
        silent process is runnable (running or waiting for a CPU), or while it sleeps and
        one of the central's own Zenoh threads is runnable, the machine has more runnable
        tasks than CPUs, or tasks waited for a CPU for a quarter of the silence so far
        (:meth:`waited_since`: a burst of another task that held what is in transit and
        has ended by the time the central looks; the silent process is working through
        what it was sent, or what is in transit waits for a CPU). The plant is excused
        while it sleeps too: it samples on its own clock and waits for nothing in transit,
        so a plant asleep past its tick is a timer the machine has not served yet. Then, a
        limit at a time, while the kernel's accounting shows that the machine kept the
        silent process or the central's Zenoh threads from a CPU, or kept its own tasks
        waiting for one, for at least half of the last limit, or the hypervisor's steal
        counter moved on a CPU the silent process last ran on (:meth:`_renew`), up to
        :data:`EXCUSED_LIMITS` in all. A stopped or exited process is never excused, a
        sleeping peripheral with nothing in transit neither, and one that ran but did not
        answer while the machine let everything run and the hypervisor took none of its
        CPUs (e.g. a deadlock) is not excused again."""
        role_state = self.supervision.role_state
        if role_state is None:
            return False
        prev = self.of(role, answered)
        if prev is not None:
            return self._renew(role, prev, now, limit_ns)
        state = role_state(role)
        load = self._machine()
        if not (state == "runnable" or (state == "sleeping" and (
                role == "plant" or role_state("central") == "runnable"
                or load.waiting or self.waited_since(since, now, load.pressure_ns)))):
            return False
        self.granted[role] = Excuse(since, limit_end() + limit_ns, now,
                                    self._times(role, load), state == "runnable")
        self.count += 1
        return True

    def _times(self, role: str, load: MachineLoad | None = None
               ) -> tuple[ThreadTimes, ThreadTimes, int | None, list[float] | None] | None:
        """The scheduler accounting of ``role``'s threads and of the central's Zenoh
        threads, the machine's CPU pressure and the hypervisor's steal (from ``load``
        where the caller has just read it); None where this central cannot read them."""
        role_times = self.supervision.role_times
        if role_times is None:
            return None
        load = load or self._machine()
        return role_times(role), role_times("central"), load.pressure_ns, load.stolen_s

    def _machine(self) -> MachineLoad:
        """How short of CPUs the machine is, where this central can read it."""
        machine_load = self.supervision.machine_load
        return machine_load() if machine_load is not None else MachineLoad(None, None)

    def _renew(self, role: str, prev: Excuse, now: int, limit_ns: int) -> bool:
        """Extend an excused silence by one more limit if, in the window since it was
        granted or last renewed, the machine kept the silent process or the central's
        Zenoh threads from a CPU (:func:`~ctrlunit.runtime.roles.supervise.cpu_denied`),
        or kept some task waiting for one (the CPU pressure, which counts a wait still
        going on: a thread's own wait is added up only when it runs again), for at least
        half the window, or the hypervisor's steal counter moved a tick on a CPU the
        silent process last ran on (:meth:`_stolen_ticks`: a tick is 10 ms, counted as the
        window at most), and the silence is shorter than :data:`EXCUSED_LIMITS` limits
        (plus the central's own stalls). The plant is renewed too while it sleeps and ran
        less than a tenth of the window: it ticks on its own clock, so asleep through
        periods without running its timer was not served (a virtual CPU its hypervisor
        held: the steal counter's 10 ms ticks do not see a few milliseconds; seen in CI,
        docs/measurements/2026-11-29-frozen-observers-and-250us.md). A process that was not
        denied its CPU and did not answer is not excused again, nor one stopped or exited
        meanwhile."""
        times = self._times(role)
        last = silence_rule.renewal_cap(prev.since, limit_ns, EXCUSED_LIMITS,
                                        self.own_stall(prev.since, now))
        if prev.times is None or times is None or now >= last:
            return False
        role_state = self.supervision.role_state
        state = role_state(role) if role_state is not None else "unknown"
        if state not in ("runnable", "sleeping"):
            return False
        window = now - prev.at
        denied, ran = cpu_denied(prev.times[0], times[0], window_ns=window,
                                 runnable=prev.runnable and state == "runnable")
        ours, _ = cpu_denied(prev.times[1], times[1], window_ns=window, runnable=False)
        waited = 0 if prev.times[2] is None or times[2] is None \
            else min(window, max(0, times[2] - prev.times[2]))
        stolen = self._stolen_ticks(role, prev.times[3], times[3])
        seen = (window, max(denied, ours), ran, waited, stolen)
        unserved = role == "plant" and state == "sleeping" and 10 * ran < window
        if not (unserved or silence_rule.renewal_holds(
                window, denied, ours, waited, min(window, stolen * TICK_NS))):
            self.granted[role] = prev._replace(seen=seen)
            return False
        self.granted[role] = Excuse(prev.since, min(now + limit_ns, last), now, times,
                                    state == "runnable", prev.renewals + 1, seen)
        self.count += 1
        return True

    def _stolen_ticks(self, role: str, before: list[float] | None,
                      after: list[float] | None) -> int:
        """The most ticks of steal the hypervisor counted, between two readings, on a CPU
        a thread of ``role`` last ran on: it counts whole ticks (``SC_CLK_TCK``), so one
        tick moved in a window says that the CPU stood still at least a moment of it, on
        a CPU where the silent process waits; 0 where any of it is unknown."""
        last_cpus = self.supervision.last_cpus
        if last_cpus is None or before is None or after is None or len(before) != len(after):
            return 0
        return max((round((after[c] - before[c]) * TICKS_PER_S) for c in last_cpus(role)
                    if 0 <= c < len(after)), default=0)

    def note(self, role: str, answered: int) -> str:
        """For a silence fault's message: what the silent process was doing, where known,
        whether this silence was excused and, where its last extension was looked at,
        how long the machine kept it from a CPU in it, how much CPU it got and how long
        the machine's tasks waited for one."""
        role_state = self.supervision.role_state
        if role_state is None:
            return ""
        excused = self.of(role, answered)
        note = ""
        if excused is not None:
            n = excused.renewals + 1
            note = (" (after one extension of its limit" if n == 1
                    else f" (after {n} extensions of its limit")
            if excused.seen is not None:
                window, denied, ran, waited, stolen = excused.seen
                note += (f"; in the last {window / 1e6:.1f} ms it was kept from a CPU "
                         f"{denied / 1e6:.1f} ms and ran {ran / 1e6:.1f} ms, and tasks "
                         f"waited for a CPU {waited / 1e6:.1f} ms")
                if stolen:
                    note += (f", and the hypervisor's steal counter moved {stolen} tick(s) "
                             f"of {TICK_NS / 1e6:g} ms on the CPU it last ran on")
            note += ")"
        state = role_state(role)
        return f"; its process {'had exited' if state == 'exited' else 'was ' + state}{note}"


__all__ = ["EXCUSED_LIMITS", "UNSUPERVISED", "Excuse", "Excuses", "Supervision"]
