"""Supervision of the roles ``ctrlunit start`` runs as child processes: how they are
started (their CPUs, the signals left to the launcher, death with the parent: taken by
each child itself, runtime/host/launched.py) and ended."""

from __future__ import annotations

import contextlib
import json
import os
import re
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import NamedTuple

from ..config import RunConfig
from ..host import launched, sched

LEFT_TO_THE_LAUNCHER = launched.LEFT_TO_THE_LAUNCHER


def spawn_role(spec: Path, role: str, index: int | None, endpoint: str, log: Path, *,
               cpus: set[int] | None = None) -> subprocess.Popen:
    """Start one role as a child process (``ctrlunit plant|peripheral --spec``), on
    ``cpus`` (see :func:`role_cpus`) if given. The child takes them itself, ignores the
    terminal's signals and dies with this process (runtime/host/launched.py): no code runs
    between fork and exec, so Python starts it with ``vfork`` rather than copying this
    process (a peripheral started again mid-run stalled the unit 4-12 ms that way)."""
    run = json.loads(spec.read_text())["run"]
    args = [sys.executable, "-m", "ctrlunit.runtime.host.launched", role, "--spec", str(spec),
            "--connect", endpoint, "--unit", run["unit"]]  # the unit id names it in ps
    if index is not None:
        args += ["--index", str(index)]
    env = os.environ | {launched.PARENT_ENV: str(os.getpid())}
    if cpus:
        env[launched.CPUS_ENV] = ",".join(str(c) for c in sorted(cpus))
    with open(log, "ab") as out:  # the child has its own copy
        return subprocess.Popen(args, stdout=out, stderr=subprocess.STDOUT,
                                stdin=subprocess.DEVNULL, env=env)


def role_cpus(rc: RunConfig) -> tuple[set[int] | None, set[int] | None]:
    """``(central, others)``: the CPUs the launcher pins itself (the central) and the roles
    it starts to, or None to leave an affinity alone.

    ``--cpus same``: every role on CPU 0; ``--cpus split``: the central on 0, the others
    on 1; ``--pin`` alone pins the central only. Read before the central pins itself: the
    children are given their CPUs explicitly, since they would otherwise inherit the
    central's. A CPU this process may not use is replaced by every CPU it may use.
    """
    pin = {int(c) for c in rc.schedule.pin.split(",") if c.strip()} if rc.schedule.pin else None
    try:
        mine = set(os.sched_getaffinity(0))
    except OSError:
        return pin, None

    def only(cpu: int) -> set[int]:
        return {cpu} if cpu in mine else mine

    if rc.schedule.cpus == "same":
        return pin or only(0), only(0)
    if rc.schedule.cpus == "split":
        return pin or only(0), only(1)
    return pin, (mine if pin else None)


def end_children(children: list[subprocess.Popen], *, grace: float = 1.0) -> None:
    """Wait up to ``grace`` s for children to exit, then terminate, then kill."""
    deadline = time.monotonic() + grace
    for p in children:
        with contextlib.suppress(subprocess.TimeoutExpired):
            p.wait(timeout=max(0.0, deadline - time.monotonic()))
    for p in children:
        if p.poll() is None:
            p.terminate()
    for p in children:
        try:
            p.wait(timeout=0.3)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait(timeout=1.0)


ZENOH_THREADS = re.compile(r"(app|rx|tx|net|acc)-\d+")
"""The names Zenoh gives its runtimes' worker threads."""


def process_state(pid: int, *, threads: re.Pattern[str] | None = None) -> str:
    """What the threads of process ``pid`` (those whose name matches ``threads``, if
    given) are doing now, from ``/proc``: ``runnable`` (a thread is running or waiting for
    a CPU), ``stopped`` (by a signal or a tracer), ``blocked`` (in uninterruptible
    sleep), ``sleeping`` (every thread waits for an event: a message, a timer),
    ``exited``, or ``unknown`` where ``/proc`` does not say. Reads one small file per
    thread (about 10 us each)."""
    states = set()
    try:
        for tid in os.listdir(f"/proc/{pid}/task"):
            with contextlib.suppress(OSError):
                with open(f"/proc/{pid}/task/{tid}/stat") as fh:
                    stat = fh.read()
                name = stat[stat.index("(") + 1:stat.rindex(")")]
                if threads is None or threads.fullmatch(name):
                    states.add(stat[stat.rindex(")") + 2])
    except OSError:
        return "exited"
    if not states:
        return "unknown"
    if "R" in states:
        return "runnable"
    if states & {"T", "t"}:
        return "stopped"
    if states & {"Z", "X"}:
        return "exited"
    if "D" in states:
        return "blocked"
    return "sleeping"


def process_cpus(pid: int) -> set[int]:
    """The CPUs the threads of process ``pid`` last ran on (``/proc/<pid>/task/<tid>/stat``,
    field 39); empty where the process is gone. A thread asleep on a timer waits for that
    CPU's: where the hypervisor holds the CPU, the thread neither runs nor waits."""
    cpus: set[int] = set()
    with contextlib.suppress(OSError):
        for tid in os.listdir(f"/proc/{pid}/task"):
            with contextlib.suppress(OSError, ValueError, IndexError):
                with open(f"/proc/{pid}/task/{tid}/stat") as fh:
                    stat = fh.read()
                cpus.add(int(stat[stat.rindex(")") + 2:].split()[36]))
    return cpus


ThreadTimes = dict[int, tuple[int, int]]
"""Per thread id: nanoseconds run on a CPU, nanoseconds waited on a runqueue for one."""


def thread_times(pid: int, *, threads: re.Pattern[str] | None = None) -> ThreadTimes:
    """The CPU time and the runqueue wait of each thread of process ``pid`` (those whose
    name matches ``threads``, if given) since it started, from
    ``/proc/<pid>/task/<tid>/schedstat`` (the kernel's scheduler accounting; on a guest
    with paravirtual time accounting a thread's CPU time leaves out what the hypervisor
    took). Empty where the process is gone or the kernel does not keep them."""
    out: ThreadTimes = {}
    try:
        tids = os.listdir(f"/proc/{pid}/task")
    except OSError:
        return out
    for tid in tids:
        with contextlib.suppress(OSError, ValueError, IndexError):
            if threads is not None:
                with open(f"/proc/{pid}/task/{tid}/comm") as fh:
                    if not threads.fullmatch(fh.read().strip()):
                        continue
            with open(f"/proc/{pid}/task/{tid}/schedstat") as fh:
                run, wait = fh.read().split()[:2]
            out[int(tid)] = (int(run), int(wait))
    return out


def cpu_denied(before: ThreadTimes, after: ThreadTimes, *, window_ns: int,
               runnable: bool) -> tuple[int, int]:
    """Of a window of ``window_ns`` between two :func:`thread_times` readings of one
    process, how long the machine kept it from running, and how much CPU it got.

    Kept from running: the longest any one thread waited on a runqueue in the window, or,
    where the process was runnable at both ends (``runnable``), the window less the CPU
    time its threads got, if more (a thread left on a CPU the hypervisor took neither
    runs nor waits in the guest's accounting). Threads started in the window count from
    zero. A reading that is empty (the process gone, the accounting unreadable) is no
    evidence: nothing denied.

    Returns
    -------
    (denied_ns, ran_ns) : both at least 0; ``ran_ns`` summed over the threads.
    """
    if not before or not after:
        return 0, 0
    waited = ran = 0
    for tid, (run, wait) in after.items():
        run0, wait0 = before.get(tid, (0, 0))
        waited = max(waited, wait - wait0)
        ran += max(0, run - run0)
    denied = max(waited, window_ns - ran if runnable else 0)
    return max(0, min(denied, window_ns)), ran


class MachineLoad(NamedTuple):
    """How short of CPUs this machine is (:func:`machine_load`)."""

    pressure_ns: int | None
    """How long, in all, at least one task has waited for a CPU since boot (the
    kernel's pressure stall information, ``some`` line of ``/proc/pressure/cpu``), in ns;
    unlike a thread's own runqueue wait, which the kernel adds up only once the thread
    runs again, it counts a wait still going on. None where the kernel does not keep it
    (before Linux 4.20, or PSI disabled)."""
    waiting: int | None
    """Tasks runnable now beyond the machine's CPUs (``/proc/loadavg``), the reader
    included; None where unknown."""
    stolen_s: list[float] | None = None
    """Each CPU's time taken by the hypervisor since boot
    (:func:`~ctrlunit.runtime.host.sched.stolen_s`: counted in whole ticks of 10 ms);
    None where the kernel does not count it."""


_pressure_fd: int | None = None
"""``/proc/pressure/cpu``, opened once per process and read from its start each time."""
_pressure_open = threading.Lock()


def cpu_pressure_ns() -> int | None:
    """:attr:`MachineLoad.pressure_ns` alone. The file stays open: a read from its start
    costs about 5 us of CPU on the reference machine, against 27-39 us for an open, a read
    and a close (the central reads it as it sends requests: runtime/central/excuse.py)."""
    global _pressure_fd
    with contextlib.suppress(OSError, IndexError, ValueError):
        fd = _pressure_fd
        if fd is None:
            with _pressure_open:  # one descriptor, whichever thread asks first
                if _pressure_fd is None:
                    _pressure_fd = os.open("/proc/pressure/cpu", os.O_RDONLY | os.O_CLOEXEC)
                fd = _pressure_fd
        try:
            first = os.pread(fd, 256, 0).split(b"\n", 1)[0]
        except OSError:
            _pressure_fd = None  # closed under it: opened again at the next reading
            raise
        return int(first.rsplit(b"total=", 1)[1]) * 1000
    return None


def machine_load() -> MachineLoad:
    """Read :class:`MachineLoad` (three files, about 0.2 ms on the reference machine, most
    of it ``/proc/stat``): at a silence's excuse and its renewals only."""
    pressure, waiting = cpu_pressure_ns(), None
    with contextlib.suppress(OSError, IndexError, ValueError):
        with open("/proc/loadavg") as fh:
            running = int(fh.read().split()[3].split("/")[0])
        waiting = max(0, running - (os.cpu_count() or 1))
    return MachineLoad(pressure, waiting, sched.stolen_s())


def unit_cores(central: set[int] | None, others: set[int] | None) -> int:
    """How many CPUs the roles started on this host can use together, given
    :func:`role_cpus` (read before the central pins itself)."""
    try:
        mine = set(os.sched_getaffinity(0))
    except OSError:
        return os.cpu_count() or 1
    return len((central or mine) | (others or mine))
