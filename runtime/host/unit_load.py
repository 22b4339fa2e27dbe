"""The unit's own CPU time, CPU by CPU: what the kernel's real-time throttling counts.

Under SCHED_FIFO the kernel throttles real-time tasks that use more than its budget of a
CPU (``sched_rt_runtime_us``, 95 % of each second). Only real-time time counts: a program
at the default policy on the same CPU runs only when the unit does not want the CPU, so a
machine kept busy by a browser or a compiler throttles nothing. :class:`UnitLoad` measures
the unit's threads' time on each CPU from the kernel's scheduler accounting
(``/proc/<pid>/task/<tid>/schedstat``, in ns, exact, unlike the tick-sampled user and
system times: docs/architecture.md, scheduling policy). A process pinned to one CPU has
its threads' time charged to that CPU, exactly; any other thread's time is spread evenly
over the CPUs its process may use. Charging it to the CPU the thread last ran on
(``/proc/<pid>/task/<tid>/stat``, field 39) put the time of threads that moved within a
reading on one CPU: under a burst of another real-time task the unit's threads moved
away from its CPU, their time landed on the other, which read 100 % busy, and the guard
took the unit out of FIFO for a load it did not have (docs/measurements/
2026-11-27-busy-machine.md).

One reading of the unit's 50-60 threads takes 2-10 ms, too long for the control path,
and a thread of the central's process doing it at the default policy held the GIL while
the unit's real-time threads kept it from a CPU (the central then waited for the GIL): a
process of its own reads every :data:`SAMPLE_S` under the default policy and writes each
reading on a pipe, and the guard (:class:`.busy_guard.BusyGuard`) reads the newest one
(one non-blocking read), shaped as :func:`.sched.cpu_times` gives the machine's, so that
:func:`.sched.busy_share` of two of them is the busiest CPU's share of the unit's own
time between them. A reader starved of a CPU only makes the readings older.
"""

from __future__ import annotations

import contextlib
import os
import select
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterable

from .sched import leave_rt

SAMPLE_S = 0.25
"""How often the reading thread reads the unit's threads: half the guard's window, so
that each of the guard's windows sees a newer reading."""


def thread_cpus(pids: Iterable[int]) -> dict[int, tuple[frozenset[int], int]]:
    """``{tid: (cpus, run_ns)}`` for every thread of the processes ``pids``: the CPUs its
    process may run on and its run time since it started. Threads or processes gone
    meanwhile are left out."""
    out: dict[int, tuple[frozenset[int], int]] = {}
    for pid in pids:
        try:
            tids = os.listdir(f"/proc/{pid}/task")
            cpus = frozenset(os.sched_getaffinity(pid))
        except OSError:
            continue
        for tid in tids:
            with contextlib.suppress(OSError, ValueError, IndexError):
                with open(f"/proc/{pid}/task/{tid}/schedstat", "rb") as fh:
                    out[int(tid)] = (cpus, int(fh.read().split()[0]))
    return out


class UnitLoad:
    """The unit's cumulative run time per CPU, read by a thread of its own.

    Parameters
    ----------
    pids : the unit's processes on this machine (called at every reading).
    every_s : the reading thread's interval.
    cpus : how many CPUs the machine has.
    read, clock : the threads' figures (:func:`thread_cpus`) and the clock (tests give
        their own).

    :meth:`cpu_times` returns the newest reading as ``[(busy_s, at_s), ...]``, one pair per
    CPU: ``busy_s`` the unit's run time on that CPU since the first reading, ``at_s`` the
    monotonic time of the reading. Use as a context manager (the thread starts and ends
    with it) or call :meth:`sample` directly.
    """

    def __init__(self, pids: Callable[[], Iterable[int]], *, every_s: float = SAMPLE_S,
                 cpus: int | None = None,
                 read: Callable[[Iterable[int]], dict[int, tuple[frozenset[int], int]]]
                 = thread_cpus,
                 clock: Callable[[], float] = time.monotonic) -> None:
        if not every_s > 0:
            raise ValueError(f"every_s = {every_s!r}: allowed more than 0 s")
        self.pids, self.every_s, self.read, self.clock = pids, every_s, read, clock
        self._busy = [0.0] * (cpus or os.cpu_count() or 1)
        self._runs: dict[int, int] | None = None  # each thread's run time at the last reading
        self._newest: list[tuple[float, float]] = []
        self._lock = threading.Lock()
        self._child: subprocess.Popen[bytes] | None = None

    def sample(self) -> list[tuple[float, float]]:
        """Read the unit's threads now, charge each one's run time since the last reading
        to its CPUs (module notes), and return the new :meth:`cpu_times`."""
        with self._lock:
            threads = self.read(list(self.pids()))
            at = self.clock()
            if self._runs is not None:
                for tid, (cpus, run) in threads.items():
                    # a thread first seen now started after the last reading
                    ran = run - self._runs.get(tid, 0)
                    mine = [c for c in cpus if 0 <= c < len(self._busy)]
                    for cpu in mine if ran > 0 else ():
                        self._busy[cpu] += ran / 1e9 / len(mine)
            self._runs = {tid: run for tid, (_cpus, run) in threads.items()}
            self._newest = [(b, at) for b in self._busy]
            return self._newest

    def __enter__(self) -> UnitLoad:
        """Start the reading process (this process's own readings stay :meth:`sample`'s)."""
        self.sample()
        self._child = subprocess.Popen(
            [sys.executable, "-c", "from ctrlunit.runtime.host.unit_load import serve; "
             f"serve({self.every_s!r}, {len(self._busy)})"],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL)
        assert self._child.stdout is not None
        os.set_blocking(self._child.stdout.fileno(), False)
        self._sent: tuple[int, ...] = ()
        self._tail = b""
        self._from_child: list[tuple[float, float]] = []
        return self

    def adopt(self, pids: Iterable[int]) -> None:
        """Take the threads of ``pids`` as they are now, without charging their time so
        far (processes the reader learns of after they started)."""
        threads = self.read(list(pids))
        with self._lock:
            if self._runs is not None:
                self._runs.update({tid: run for tid, (_c, run) in threads.items()})

    def cpu_times(self) -> list[tuple[float, float]]:
        """The newest reading (``[]`` before the first): cheap, for the control path. With
        the reading process running, the newest line it wrote (and the unit's processes
        sent to it when they changed)."""
        child = self._child
        if child is None or child.stdout is None:
            return self._newest
        pids = tuple(self.pids())
        if pids != self._sent and child.stdin is not None:
            with contextlib.suppress(OSError):
                child.stdin.write((" ".join(map(str, pids)) + "\n").encode())
                child.stdin.flush()
                self._sent = pids
        with contextlib.suppress(OSError, BlockingIOError, TypeError):
            got = os.read(child.stdout.fileno(), 65536)
            lines = (self._tail + got).split(b"\n")
            self._tail = lines[-1]
            for line in reversed(lines[:-1]):
                values = [float(v) for v in line.split()]
                if len(values) == len(self._busy) + 1:
                    self._from_child = [(b, values[0]) for b in values[1:]]
                    break
        return self._from_child

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """End the reading process."""
        child = self._child
        if child is None:
            return
        self._child = None
        with contextlib.suppress(OSError):
            if child.stdin is not None:
                child.stdin.close()
        try:
            child.wait(timeout=2.0)
        except subprocess.TimeoutExpired:
            child.kill()
            child.wait(timeout=5.0)
        if child.stdout is not None:
            child.stdout.close()


def serve(every_s: float, cpus: int, *, most_s: float = 7 * 24 * 3600.0) -> None:
    """The reading process: the unit's processes from stdin (a line of pids whenever
    they change), a reading every ``every_s`` on stdout (``at busy_0 busy_1 ...``, s),
    until stdin closes (the unit ended) or ``most_s``, under the default policy."""
    leave_rt()
    pids: list[int] = []
    load = UnitLoad(lambda: pids, every_s=every_s, cpus=cpus)
    stdin = sys.stdin.buffer
    tail = b""
    end = time.monotonic() + most_s
    while time.monotonic() < end:
        ready, _, _ = select.select([stdin], [], [], every_s)
        if ready:
            got = os.read(stdin.fileno(), 65536)
            if not got:
                return  # the unit closed its end
            lines = (tail + got).split(b"\n")
            tail = lines[-1]
            if len(lines) > 1:
                now = [int(v) for v in lines[-2].split()]
                load.adopt([p for p in now if p not in pids])
                pids = now
        reading = load.sample()
        sys.stdout.write(" ".join([repr(reading[0][1])] + [repr(b) for b, _ in reading])
                         + "\n")
        sys.stdout.flush()


__all__ = ["SAMPLE_S", "UnitLoad", "serve", "thread_cpus"]
