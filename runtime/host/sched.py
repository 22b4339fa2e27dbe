"""The scheduling policy of a role's process: SCHED_FIFO for the unit (``--rt-priority``).

With ``--rt-priority N`` every role of a unit (central, plant, peripherals, and their
Zenoh threads) runs under ``SCHED_FIFO`` at priority N. At equal priority FIFO tasks do
not preempt each other: a woken peripheral waits until the central has sent its request
to all three and blocks, instead of taking its CPU at each wake-up as the default
scheduler's wake-up preemption does, and each process runs its message to completion.
Measured on this 2-core VM (n = 3, depth 2, side by side; README): freerun mean period
-22 to -27 %, CPU per interval -15 %. Roles at a lower FIFO priority than the central,
or under ``SCHED_BATCH``, were slower.

The risk: when the unit needs more CPU than the machine has (realtime at 1 ms here, or
``--no-admission`` at a period it cannot hold), the kernel's real-time throttling
(``/proc/sys/kernel/sched_rt_runtime_us``, 95 % of each second) freezes every FIFO task
for up to 50 ms a second: 33-35 ms periods were measured, where the default policy's
longest was 4 ms. Two guards keep the unit below that budget: the admission refuses a
period whose trial kept a CPU busier than :data:`ADMIT_BUSY_SHARE` of it
(runtime/launch/admission.py), and during the run :class:`BusyGuard` puts every role back under
the default policy when a CPU stays busier than :data:`DEMOTE_BUSY_SHARE` of it for a
second, or passes the budget itself in one window (the kernel throttles CPU by CPU).

``auto`` (the default, :func:`choose`) uses FIFO at :data:`AUTO_PRIORITY` only where both
guards stand: the realtime clock with the admission on, a kernel that throttles, and a
process permitted to use FIFO; otherwise the default policy, with the reason in the
report (``scheduling_choice``). ``0`` leaves the policy as it is (the default policy,
unless the unit was started under another, e.g. with ``chrt``); 1-99 needs root,
CAP_SYS_NICE or ``ulimit -r`` (an error names them otherwise). Roles started by
``ctrlunit start`` inherit the launcher's policy; the report names each role's.
"""

from __future__ import annotations

import contextlib
import os
import subprocess
import sys
import time
from collections.abc import Collection, Iterable, Iterator
from typing import Any

MAX_PRIORITY = 99

AUTO = "auto"
AUTO_PRIORITY = 10
"""The FIFO priority ``--rt-priority auto`` chooses (every role at one priority: none
preempts another on wake-up)."""

class RtPermissionError(PermissionError):
    """SCHED_FIFO was asked for with ``--rt-priority N`` and this process may not use it."""


def _threads() -> list[int]:
    try:
        return [int(t) for t in os.listdir("/proc/self/task")]
    except OSError:
        return [0]


def _set_all(policy: int, priority: int) -> None:
    """``policy`` for every thread of this process (``sched_setscheduler`` acts on one
    thread); the threads started later inherit their creator's."""
    param = os.sched_param(priority)
    os.sched_setscheduler(0, policy, param)  # this thread first: it raises if refused
    for tid in _threads():
        with contextlib.suppress(ProcessLookupError, PermissionError):
            os.sched_setscheduler(tid, policy, param)


def pin_all(cpus: set[int]) -> None:
    """Every thread of this process on ``cpus`` (``sched_setaffinity`` acts on one
    thread): those started later inherit their creator's, but a library's started at
    import (numpy's BLAS worker) would stay where it was."""
    os.sched_setaffinity(0, cpus)  # this thread first: it raises if refused
    for tid in _threads():
        with contextlib.suppress(ProcessLookupError, PermissionError, OSError):
            os.sched_setaffinity(tid, cpus)


def fifo_permitted() -> bool:
    """Whether a process started like this one may use SCHED_FIFO (tried in a child
    interpreter, so that this process's policy is left alone)."""
    code = ("import os\ntry:\n os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(1))"
            "\nexcept PermissionError:\n raise SystemExit(1)")
    return subprocess.run([sys.executable, "-c", code], timeout=30).returncode == 0


def policy_name(tid: int = 0) -> str:
    """``"SCHED_FIFO 10"``, ``"SCHED_OTHER"``, ... for thread ``tid`` (0: this one)."""
    policy = os.sched_getscheduler(tid)
    names = {os.SCHED_OTHER: "SCHED_OTHER", os.SCHED_FIFO: "SCHED_FIFO",
             os.SCHED_RR: "SCHED_RR", os.SCHED_BATCH: "SCHED_BATCH",
             os.SCHED_IDLE: "SCHED_IDLE"}
    name = names.get(policy, f"policy {policy}")
    if policy in (os.SCHED_FIFO, os.SCHED_RR):
        return f"{name} {os.sched_getparam(tid).sched_priority}"
    return name


def check_pin(pin: str | None) -> None:
    """``--pin``: CPUs of this machine, ``0`` or ``0,1``, else a ``ValueError`` naming them
    (the run would fail at ``sched_setaffinity`` after the check let it pass)."""
    n = os.cpu_count() or 1
    if pin is not None and not all(c.strip().isdigit() and int(c) < n for c in pin.split(",")):
        raise ValueError(f"--pin {pin!r}: allowed CPUs of this machine, 0 to {n - 1}, "
                         "separated by commas (e.g. 0 or 0,1)")


def check_priority(priority: int | str) -> None:
    """``auto`` or 0 to 99, else a ``ValueError`` naming the option and the range."""
    if priority == AUTO:
        return
    if isinstance(priority, bool) or not isinstance(priority, int) or not (
            0 <= priority <= MAX_PRIORITY):
        raise ValueError(f"--rt-priority = {priority!r}: allowed auto, 0 (leave the policy as "
                         f"it is) or 1 to {MAX_PRIORITY} (SCHED_FIFO priority)")


def rt_budget() -> float | None:
    """The share of each CPU's time the kernel lets real-time tasks use before it throttles
    them (``sched_rt_runtime_us / sched_rt_period_us``, 0.95 by default); None when it
    does not throttle (``-1``) or the files cannot be read."""
    try:
        with open("/proc/sys/kernel/sched_rt_runtime_us") as fh:
            runtime = int(fh.read())
        with open("/proc/sys/kernel/sched_rt_period_us") as fh:
            period = int(fh.read())
    except (OSError, ValueError):
        return None
    return runtime / period if 0 <= runtime < period and period > 0 else None


def cpu_counters(stat: str = "/proc/stat") -> list[list[int]] | None:
    """The counters of each ``cpuN`` line of ``/proc/stat``, CPU by CPU, in clock ticks
    (``SC_CLK_TCK``): user, nice, system, idle, iowait, irq, softirq, steal, ...; None
    where it cannot be read."""
    out: list[list[int]] = []
    try:
        with open(stat) as fh:
            for line in fh:
                name, *values = line.split()
                if not name.startswith("cpu"):
                    break
                if name != "cpu":
                    out.append([int(v) for v in values])
    except (OSError, ValueError):
        return None
    return out


def cpu_times() -> list[tuple[float, float]]:
    """``(busy, elapsed)`` of each CPU in clock ticks (``SC_CLK_TCK``): ``elapsed`` the
    monotonic clock, ``busy`` that less the CPU's idle, iowait and steal time from
    ``/proc/stat``; ``[]`` where it cannot be read. :func:`busy_share` of two readings is
    the busiest CPU's busy share between them.

    The kernel measures idle time exactly, at every entry to and exit from idle, but
    samples user and system time at its tick (250 Hz on the reference machine): a unit
    whose period divides the tick's is seen at one phase of its period at every tick, so
    the sampled busy time read from 0 to 100 % of a CPU that the unit kept 72-80 % busy
    (docs/measurements/2026-11-24-realtime.md). Busy time is therefore taken as the time
    a CPU was not idle. Stolen time is not busy: the kernel's real-time throttling does
    not count it either."""
    counters = cpu_counters() or []
    now = time.monotonic() * os.sysconf("SC_CLK_TCK")
    out: list[tuple[float, float]] = []
    for values in counters:
        fields = values[:8] + [0] * (8 - len(values[:8]))
        not_busy = fields[3] + fields[4] + fields[7]  # idle, iowait, steal
        out.append((now - not_busy, now))
    return out


def stolen_s(stat: str = "/proc/stat") -> list[float] | None:
    """CPU time the hypervisor gave to others while each of this machine's CPUs had work
    to run (``steal``, the eighth field of each ``cpuN`` line of ``/proc/stat``), in
    seconds since boot, CPU by CPU; None where the kernel does not count it. Meanwhile
    that CPU runs nothing of this machine, whatever the policy: :func:`most_stolen` of
    two readings is how long the CPU that lost the most stood still."""
    counters = cpu_counters(stat)
    if not counters or any(len(values) < 8 for values in counters):
        return None
    return [values[7] / os.sysconf("SC_CLK_TCK") for values in counters]


def most_stolen(before: list[float] | None, after: list[float] | None) -> float | None:
    """The most CPU time the hypervisor took from one CPU between two :func:`stolen_s`
    readings (s, at least 0); None where either is missing or they do not match (a CPU
    taken offline between them)."""
    if before is None or after is None or len(before) != len(after) or not before:
        return None
    return round(max(0.0, *(a - b for b, a in zip(before, after, strict=True))), 3)


def busy_share(before: list[tuple[float, float]],
               after: list[tuple[float, float]]) -> float | None:
    """The busiest CPU's share of busy time between two :func:`cpu_times` readings (the
    kernel throttles real-time tasks CPU by CPU), within 0 to 1 (the counters are whole
    ticks); None when the readings do not match or no time passed between them."""
    if len(before) != len(after) or not before:
        return None
    if any(a[1] - b[1] <= 0 for b, a in zip(before, after, strict=True)):
        return None
    return max(min(1.0, max(0.0, (a[0] - b[0]) / (a[1] - b[1])))
               for b, a in zip(before, after, strict=True))


def leave_rt() -> None:
    """This thread under the default policy if it runs under a real-time one. For a thread
    whose work can wait, such as the recording's writer: at one FIFO priority a thread
    runs until it blocks, so a chunk's compression (1-2 ms every 100 ms) held a CPU against
    the roles and made a burst of deadline misses at 1 ms at every chunk
    (docs/measurements/2026-11-24-realtime.md). Cheap when there is nothing to do (one
    system call), so it can run before each job: a thread starts under its creator's
    policy."""
    if fifo_in_force():
        os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))


@contextlib.contextmanager
def thread_at_default() -> Iterator[None]:
    """This thread under the default policy for the block, then back under its own: the
    processes it starts meanwhile begin under the default policy (a process starts under
    its creator thread's). The roles' start-up (an interpreter, numpy's and Zenoh's
    imports: about 0.3 s of CPU each) under SCHED_FIFO held both CPUs of the reference
    machine for 0.5 s at every start, against every other program
    (docs/measurements/2026-11-29-command-hold.md)."""
    saved = current()
    if saved[0] in (os.SCHED_FIFO, os.SCHED_RR):
        os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    try:
        yield
    finally:
        if saved[0] in (os.SCHED_FIFO, os.SCHED_RR):
            os.sched_setscheduler(0, saved[0], os.sched_param(saved[1]))


def fifo_in_force(tid: int = 0) -> bool:
    """Whether thread ``tid`` (0: this one) runs under a real-time policy."""
    return os.sched_getscheduler(tid) in (os.SCHED_FIFO, os.SCHED_RR)


def choose(asked: int | str, *, clock: str, admission: bool, budget: float | None,
           guarded: bool = True, pinned: bool = False) -> tuple[int, str | None]:
    """The FIFO priority to try for ``--rt-priority asked`` (0: the policy as it is) and,
    for ``auto``, why (module notes). A number is taken as it is (no reason).
    ``guarded``: the unit's processes are watched by a :class:`BusyGuard` (``ctrlunit
    start``; a role started on its own is not). ``pinned``: the roles are pinned to CPUs
    (``--cpus``, ``--pin``): there ``auto`` keeps the default policy, since at one FIFO
    priority the threads of a role pinned to one CPU (its own thread and Zenoh's) wait
    behind each other, and after a CPU was taken from them for 10 ms the unit faulted
    within one to three such stalls where the default policy rode out twenty
    (docs/measurements/2026-11-27-starvation.md)."""
    check_priority(asked)
    if asked != AUTO:
        return int(asked), None
    if not guarded:
        return 0, "a role started on its own: only ctrlunit start guards the unit's load"
    if pinned:
        return 0, ("the roles are pinned to CPUs (--cpus, --pin): under FIFO at one "
                   "priority a pinned role's threads wait behind each other")
    if clock != "realtime":
        return 0, f"the {clock} clock has no deadlines to keep"
    if not admission:
        return 0, ("without the admission nothing keeps the unit's load under the kernel's "
                   "real-time budget")
    if budget is None:
        return 0, ("the kernel does not throttle real-time tasks (sched_rt_runtime_us -1): "
                   "a unit under FIFO could hold the CPUs")
    return AUTO_PRIORITY, (f"the realtime clock with the admission, and the kernel throttles "
                           f"real-time tasks at {budget:.0%} of each second")


def apply_choice(asked: int | str, *, clock: str, admission: bool,
                 guarded: bool = True, pinned: bool = False) -> tuple[str, dict[str, Any]]:
    """:func:`choose`, then :func:`apply_rt`; ``auto`` falls back to the policy as it is
    where FIFO is not permitted. Returns the policy in force and the choice for the report
    (``asked``, ``priority``, ``why``, ``budget``).

    Raises
    ------
    RtPermissionError
        A number 1-99 was asked and this process may not use SCHED_FIFO.
    """
    budget = rt_budget()
    priority, why = choose(asked, clock=clock, admission=admission, budget=budget,
                           guarded=guarded, pinned=pinned)
    try:
        policy = apply_rt(priority)
    except RtPermissionError:
        if asked != AUTO:
            raise
        priority, why = 0, "this process may not use SCHED_FIFO (root, CAP_SYS_NICE, ulimit -r)"
        policy = apply_rt(0)
    if asked == AUTO:
        why = (f"{policy}: {why}" if priority else f"{policy} (no SCHED_FIFO): {why}")
    return policy, {"asked": asked, "priority": priority, "why": why, "budget": budget}


def demote(pids: Iterable[int], *, priority: int = 0,
           skip: Collection[int] = ()) -> list[int]:
    """Every thread of each process in ``pids`` under the default policy, or with
    ``priority`` 1-99 under SCHED_FIFO at it, but the threads ``skip`` names; the pids
    whose threads could be reached (a process that has exited is skipped)."""
    done = []
    policy = os.SCHED_FIFO if priority else os.SCHED_OTHER
    param = os.sched_param(priority)
    for pid in pids:
        tids = _tids_of(pid)
        if tids is None:
            continue
        for tid in tids:
            if tid in skip:
                continue
            with contextlib.suppress(ProcessLookupError, PermissionError):
                os.sched_setscheduler(tid, policy, param)
        done.append(pid)
    return done


def default_threads(pids: Iterable[int]) -> set[int]:
    """The threads of the processes in ``pids`` under the default policy (not real-time):
    those that chose it, such as an observer's or the recording's writer (:func:`leave_rt`),
    which a return to SCHED_FIFO leaves where they are."""
    out = set()
    for pid in pids:
        for tid in _tids_of(pid) or ():
            with contextlib.suppress(ProcessLookupError, PermissionError):
                if not fifo_in_force(tid):
                    out.add(tid)
    return out


def _tids_of(pid: int) -> list[int] | None:
    """The threads of process ``pid``; None once it has exited."""
    try:
        return [int(t) for t in os.listdir(f"/proc/{pid}/task")]
    except OSError:
        return None


def apply_rt(priority: int) -> str:
    """Put this process (every thread, and the threads and processes it starts later)
    under SCHED_FIFO at ``priority``; 0 leaves its policy as it is.

    Returns
    -------
    The policy now in force (:func:`policy_name`).

    Raises
    ------
    ValueError
        ``priority`` outside 0-99.
    RtPermissionError
        ``priority`` 1-99 and this process may not use SCHED_FIFO.
    """
    check_priority(priority)
    if priority == AUTO:
        raise ValueError("--rt-priority auto: choose() the priority before applying it")
    if priority == 0:
        return policy_name()
    try:
        _set_all(os.SCHED_FIFO, priority)
    except PermissionError:
        raise RtPermissionError(
            f"--rt-priority {priority}: this process may not use SCHED_FIFO (run as root, "
            "grant CAP_SYS_NICE, or raise the real-time limit with ulimit -r); "
            "--rt-priority 0 runs at the default policy") from None
    return policy_name()


def current() -> tuple[int, int]:
    """This thread's ``(policy, priority)``, for :func:`restore`."""
    return os.sched_getscheduler(0), os.sched_getparam(0).sched_priority


def restore(saved: tuple[int, int]) -> None:
    """Every thread of this process back to ``saved`` (after a unit ran inside a
    longer-lived process, such as ``ctrlunit bench``: Zenoh's threads outlive a session)."""
    if current() != saved or any(_policy(t) != saved[0] for t in _threads()):
        with contextlib.suppress(PermissionError):
            _set_all(*saved)


def _policy(tid: int) -> int | None:
    try:
        return os.sched_getscheduler(tid)
    except OSError:
        return None
