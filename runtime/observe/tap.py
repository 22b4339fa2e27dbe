"""The central's side of an observer: intervals noted at a rate into a bounded queue,
handled later on the observer's own thread.

The live view (:mod:`.viewer`, ``--foxglove`` and the observers' keys) and the live
ROS 2 topics (runtime/recording/ros2_live.py) watch the run the same way: in ``on_cycle``
the central's thread takes an interval apart into a tuple (:func:`.signals.capture`) when
one is due at the observer's rate, and appends it to a deque that drops its oldest item
when full; nothing there waits. The observer's thread empties the deque with
:meth:`IntervalTap.drain`, which gives the GIL back regularly. An observer that falls
behind skips intervals, counted in :attr:`IntervalTap.dropped`.
"""

from __future__ import annotations

import collections
import time
from collections.abc import Callable
from typing import TYPE_CHECKING

from .signals import Interval, capture

if TYPE_CHECKING:
    from ..central.snapshot import Progress

QUEUE_INTERVALS = 4096
"""Intervals the central may be ahead of an observer's thread before the oldest are
dropped (4 s at 1 kHz)."""
YIELD_EVERY_S = 100e-6
"""An observer's thread gives up the GIL after this much work: the longest it can make the
central's thread wait (docs/measurements/2026-11-23-live-view.md)."""


class IntervalTap:
    """Intervals of a run, at most ``rate_hz`` a second of command time (0: every one).

    :meth:`offer` is called on the central's thread, :meth:`drain` and :meth:`clear` on
    the observer's (under its own lock where it also restarts)."""

    def __init__(self, *, rate_hz: float, capacity: int = QUEUE_INTERVALS) -> None:
        self.queue: collections.deque[Interval] = collections.deque(maxlen=capacity)
        self.appended = 0
        """Intervals noted."""
        self.handled = 0
        """Intervals the observer's thread took from the queue."""
        self._every_ns = round(1e9 / rate_hz) if rate_hz > 0 else 0
        self._due_ns: int | None = None

    def offer(self, progress: Progress, ctx: dict) -> None:
        """On the central's thread, after an interval: note it if it is due (its command
        left at least ``1 / rate_hz`` after the last one noted)."""
        t = progress.cmd_ns
        if self._due_ns is not None and t < self._due_ns:
            return
        self._due_ns = t + self._every_ns
        self.queue.append(capture(progress, ctx))
        self.appended += 1

    def drain(self, handle: Callable[[Interval], None]) -> None:
        """On the observer's thread: ``handle`` each interval queued until none is left,
        giving the GIL back after every :data:`YIELD_EVERY_S` of work: the central's
        thread, returning from a wait in Zenoh, would otherwise wait for it up to the
        switch interval (5 ms); a yield costs ~50 us, so once per :data:`YIELD_EVERY_S`,
        not per item."""
        queue = self.queue
        held_since = time.perf_counter()
        while queue:
            try:
                item = queue.popleft()
            except IndexError:
                break
            self.handled += 1
            handle(item)
            if time.perf_counter() - held_since >= YIELD_EVERY_S:
                time.sleep(0)
                held_since = time.perf_counter()

    @property
    def dropped(self) -> int:
        """Intervals noted that the deque let go before the observer took them."""
        return max(0, self.appended - self.handled - len(self.queue))

    def clear(self) -> None:
        """Forget everything (a new run)."""
        self.queue.clear()
        self.appended = self.handled = 0
        self._due_ns = None
