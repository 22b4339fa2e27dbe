"""The guard of a unit under SCHED_FIFO (:mod:`.sched`): back to the default policy
before the kernel's real-time throttling can freeze the unit, and under FIFO again once
the load has fallen (docs/architecture.md, scheduling policy)."""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Callable, Iterable
from typing import Any

from .sched import busy_share, cpu_times, default_threads, demote
from .unit_load import UnitLoad

DEMOTE_BUSY_SHARE = 0.95
"""Under FIFO, a run that keeps a CPU busier than this share of the real-time budget over
the last :data:`DEMOTE_WINDOWS` windows (a second, the kernel's own accounting period) goes
back to the default policy (:class:`BusyGuard`); so does one window busier than the budget
itself."""

GUARD_WINDOW_S = 0.5
"""The window over which :class:`BusyGuard` measures the busiest CPU's busy share."""

DEMOTE_WINDOWS = 2
"""How many of the newest windows the sustained-load rule of :class:`BusyGuard` reads
together. The kernel throttles only real-time time beyond its budget within one second;
one busy half-second cannot reach that alone."""

RESTORE_BUSY_SHARE = 0.85
"""After a fall-back, :data:`RESTORE_WINDOWS` consecutive windows with every CPU at most
this share of the budget busy put the unit back under SCHED_FIFO. Below the demotion's
limit, so that the load that made it fall back does not bring FIFO straight back, and
above the unit's own load at 1 ms on the reference machine (0.72-0.80 of a CPU by
:func:`busy_share`, 0.86 in a busy window), so that FIFO does come back once a busy spell
has passed."""

RESTORE_WINDOWS = 4
"""See :data:`RESTORE_BUSY_SHARE`."""

ADMIT_BUSY_SHARE = 0.75
"""Under FIFO, a trial that kept a CPU busier than this share of the kernel's real-time
budget does not hold (runtime/launch/admission.py). A tenth below the share at which
:class:`BusyGuard` puts a run back under FIFO (:data:`RESTORE_BUSY_SHARE`): the run's
motion costs more than the trial's robot at rest, and one trial of 0.3 s reads up to
0.1 more or less than the next at the same period. At the restore share itself, 3 of 10
runs of README's first command beside two busy loops missed more than the main job's
bound, at periods whose trials had read 0.68-0.78; at this share 0 of 10, 1.6-2 ms
instead of 1.25-2 ms (docs/measurements/2026-11-28-admission-margin.md)."""

MAX_RESTORES = 3
"""How many times a run goes back to SCHED_FIFO after falling back; after that it stays
under the default policy (a load that keeps coming back would otherwise flap)."""


class BusyGuard:
    """Under FIFO, puts the unit back under the default policy before the kernel's
    real-time throttling can freeze it, and under FIFO again once the load has fallen.

    Called every interval (``on_cycle``): once per :data:`GUARD_WINDOW_S` it reads the
    busiest CPU's busy share since the last reading (:func:`busy_share`, about 30 us).
    Every process of ``pids()`` goes to the default policy, and :attr:`event` says when
    and why (the report's ``scheduling_fallback``), when a CPU was busier than ``share``
    of the real-time budget over the newest ``sustain`` windows together (a sustained
    load near the budget), or busier than the budget itself in the newest window alone (a
    load that throttles within the second if it lasts). Under the default policy a period
    that needed FIFO does not hold (a 60 s run at 1 ms that fell back at interval 47 000
    lost the robot's tracking within 0.2 s), so once
    ``restore_windows`` windows in a row kept every CPU at most ``restore_share`` of the
    budget busy, the processes go back under FIFO at ``priority``; at most
    ``max_restores`` times a run, every change listed in :attr:`changes`.

    Parameters
    ----------
    pids : the unit's processes on this machine (this one and its children).
    budget : :func:`rt_budget`.
    priority : the FIFO priority the unit runs at (0: never go back to FIFO).
    share, window_s, sustain : the sustained-load threshold, the window and how many
        windows it reads together (module constants by default).
    restore_share, restore_windows, max_restores : the way back (module constants).
    read, clock : the busy counters and the clock (tests give their own).
    load : the unit's own CPU time, read by a thread of its own (the kernel throttles
        real-time time only: other programs' time is not the unit's); it replaces ``read``.
    """

    def __init__(self, pids: Callable[[], Iterable[int]], budget: float, *,
                 priority: int = 0, share: float = DEMOTE_BUSY_SHARE,
                 window_s: float = GUARD_WINDOW_S, sustain: int = DEMOTE_WINDOWS,
                 restore_share: float = RESTORE_BUSY_SHARE,
                 restore_windows: int = RESTORE_WINDOWS, max_restores: int = MAX_RESTORES,
                 read: Callable[[], list[tuple[float, float]]] = cpu_times,
                 clock: Callable[[], float] = time.monotonic,
                 say: Callable[[str], None] | None = None,
                 load: UnitLoad | None = None) -> None:
        if sustain < 1:
            raise ValueError(f"sustain = {sustain}: allowed 1 or more windows")
        self.pids, self.limit, self.window_s = pids, share * budget, window_s
        self.budget, self.sustain = budget, sustain
        self.priority = priority
        self.restore_limit = restore_share * budget
        self.restore_windows, self.max_restores = restore_windows, max_restores
        self.load = load
        """The unit's own CPU time (runtime/host/unit_load.py), which the guard reads
        instead of ``read`` where given, and ends at :meth:`close`."""
        self.read = load.cpu_times if load is not None else read
        self.clock, self.say = clock, say
        self.event: dict[str, Any] | None = None
        self.changes: list[dict[str, Any]] = []
        """Every change of policy: ``{cycle, busy_share, policy}``, ``policy`` the one
        taken (``default`` or ``fifo``)."""
        self.fifo = True
        self.recent: deque[float] = deque(maxlen=6)
        """The busiest CPU's share in the newest windows (the fall-back's event keeps them:
        how the load came to the limit)."""
        self._calm = 0  # consecutive windows under the restore limit, under the default
        self._kept_default: set[int] = set()
        """Threads under the default policy when the guard fell back (an observer's, the
        recording's writer, a library's server): the return to FIFO leaves them there."""
        self._t = 0.0
        self._last: list[tuple[float, float]] | None = None  # the first call starts the window
        # the readings that began the newest windows: the sustained share
        self._starts: deque[list[tuple[float, float]]] = deque(maxlen=sustain)

    @property
    def restores(self) -> int:
        return sum(1 for c in self.changes if c["policy"] == "fifo")

    def __call__(self, progress: Any = None, *_: Any) -> None:
        """``on_cycle``: once per window, read the busy share and act on it (the class's
        notes); ``progress`` is the interval just finished (its ``cycle`` is noted)."""
        cycle = getattr(progress, "cycle", None)
        now = self.clock()
        if self._last is not None and now - self._t < self.window_s:
            return
        cur = self.read()
        if self._last is None:
            self._t, self._last = now, cur
            return
        share = busy_share(self._last, cur)
        if share is None:
            self._starts.clear()  # a window that is no measurement breaks the sequence
            self._t, self._last = now, cur
            return
        self._starts.append(self._last)
        self._t, self._last = now, cur
        self.recent.append(round(share, 3))
        if self.fifo:
            if share > self.budget:
                self._fall_back(share, cycle, why="budget")
            elif len(self._starts) == self.sustain:
                sustained = busy_share(self._starts[0], cur)
                if sustained is not None and sustained > self.limit:
                    self._fall_back(sustained, cycle, why="sustained")
            return
        self._calm = self._calm + 1 if share <= self.restore_limit else 0
        if (self._calm >= self.restore_windows and self.priority
                and self.restores < self.max_restores):
            demote(self.pids(), priority=self.priority, skip=self._kept_default)
            self.fifo, self._calm = True, 0
            self.changes.append({"cycle": cycle, "busy_share": share, "policy": "fifo"})
            if self.say is not None:
                self.say(f"ctrlunit: every CPU at most {self.restore_limit:.0%} busy over "
                         f"{self.restore_windows * self.window_s:g} s: every role under "
                         f"SCHED_FIFO {self.priority} again at interval {cycle}")

    def _fall_back(self, share: float, cycle: int | None, *, why: str) -> None:
        """Every role under the default policy: ``why`` is ``budget`` (the newest window
        alone over the budget) or ``sustained`` (``share`` is the newest ``sustain``
        windows' together, over the limit)."""
        pids = self.pids()
        self._kept_default = default_threads(pids)  # an observer's: they stay there
        demoted = demote(pids)
        self._starts.clear()
        self.fifo, self._calm = False, 0
        self.changes.append({"cycle": cycle, "busy_share": share, "policy": "default"})
        over = self.window_s * (1 if why == "budget" else self.sustain)
        limit = self.budget if why == "budget" else self.limit
        if self.event is None:
            self.event = {"cycle": cycle, "busy_share": share, "limit": limit, "rule": why,
                          "window_s": self.window_s, "over_s": over,
                          "processes": len(demoted), "windows": list(self.recent)}
        if self.say is not None:
            self.say(f"ctrlunit: a CPU was {share:.0%} busy over {over:g} s under SCHED_FIFO "
                     f"(limit {limit:.0%}, near the kernel's real-time throttling): every "
                     f"role back under the default policy at interval {cycle}")

    def close(self) -> None:
        """End the reading of the unit's CPU time, if the guard reads it."""
        if self.load is not None:
            self.load.close()

    def report(self) -> dict[str, Any] | None:
        """The report's ``scheduling_fallback``: the first fall-back (None if none), with
        every change of policy and how many times FIFO came back."""
        if self.event is None:
            return None
        return {**self.event, "changes": list(self.changes), "restored": self.restores,
                "fifo_at_end": self.fifo}


__all__ = ["ADMIT_BUSY_SHARE", "DEMOTE_BUSY_SHARE", "DEMOTE_WINDOWS", "GUARD_WINDOW_S",
           "MAX_RESTORES", "RESTORE_BUSY_SHARE", "RESTORE_WINDOWS", "BusyGuard"]
