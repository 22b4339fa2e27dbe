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

One reading of the unit's 50-60 threads takes 2-10 ms, too long for the control path:
a thread of its own reads every :data:`SAMPLE_S` under the default policy, and the guard
(:class:`.busy_guard.BusyGuard`) reads the newest figures, shaped as
:func:`.sched.cpu_times` gives the machine's, so that :func:`.sched.busy_share` of two of
them is the busiest CPU's share of the unit's own time between them.
"""

from __future__ import annotations

import contextlib
import os
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
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

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

    def cpu_times(self) -> list[tuple[float, float]]:
        """The newest reading (``[]`` before the first): cheap, for the control path."""
        return self._newest

    def _loop(self) -> None:
        leave_rt()  # the reading can wait; the unit's roles cannot
        while not self._stop.wait(self.every_s):
            self.sample()

    def __enter__(self) -> UnitLoad:
        self.sample()
        self._thread = threading.Thread(target=self._loop, name="unit-load", daemon=True)
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """Stop the reading thread (waits at most one reading)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None


__all__ = ["SAMPLE_S", "UnitLoad", "thread_cpus"]
