"""The observers' view of a run over Zenoh: ``ctrlunit/<unit>/view/`` (a
:class:`~.viewer.LiveView`'s sink).

A unit's control path is for the roles an interval needs; anything that only watches (a
viewer, a recorder on another host, a bridge) reads the observers' keys instead:

``ctrlunit/<unit>/view/state``
    the ``/signals/state`` message of the recording and the Foxglove view (JSON, schema
    ``ctrlunit.Signals``), at ``--foxglove-rate`` states a second of command time;
``ctrlunit/<unit>/view/running``
    once a second, the run's figures so far (JSON, ``ctrlunit.Running``).

The view's own thread publishes them, under DROP congestion control at the lowest
priority; the central's thread only appends to a bounded deque, and builds nothing while
no one subscribes. With keys, a viewer's certificate may read these keys and nothing else
(runtime/transport/security.py): a reader that stops reading can stall at most this
thread, and the view then drops intervals (its ``dropped`` count), never a command.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Any

import zenoh

from ..transport.zsession import Keys

LISTENING_EVERY_S = 0.5
"""How often the sink asks Zenoh whether anyone subscribes."""


def _matching(publisher: zenoh.Publisher) -> bool:
    """Whether a subscriber matches ``publisher`` (Zenoh's ``MatchingStatus``; the stubs
    type it as a bool)."""
    return bool(getattr(publisher.matching_status, "matching", False))


class ZenohSink:
    """Publishers on ``ctrlunit/<unit>/view/state`` and ``view/running`` in ``session``.

    :attr:`listening` is whether a subscriber matches, asked at most every
    :data:`LISTENING_EVERY_S` (the central's thread reads a cached flag)."""

    def __init__(self, session: zenoh.Session, keys: Keys, *,
                 own: Callable[[], None] | None = None) -> None:
        opts: dict[str, Any] = {"congestion_control": zenoh.CongestionControl.DROP,
                                "priority": zenoh.Priority.DATA_LOW}
        self._state = session.declare_publisher(keys.view("state"), **opts)
        self._running = session.declare_publisher(keys.view("running"), **opts)
        self.url = keys.view("**")
        self.session = session if own else None
        """The session, where the sink was given it to own (the observers' relay's
        client): kept alive with the sink, closed with it, then ``own`` called (it ends
        the relay)."""
        self.own = own
        self._listening = False
        self._asked = 0.0
        self._lock = threading.Lock()

    @property
    def listening(self) -> bool:
        now = time.monotonic()
        if now - self._asked >= LISTENING_EVERY_S and self._lock.acquire(blocking=False):
            try:
                self._asked = now
                self._listening = any(_matching(p) for p in (self._state, self._running))
            except Exception:  # the session is closing
                self._listening = False
            finally:
                self._lock.release()
        return self._listening

    def state(self, payload: bytes, log_time: int) -> None:
        self._state.put(payload)

    def running(self, payload: bytes, log_time: int) -> None:
        self._running.put(payload)

    def close(self) -> None:
        for pub in (self._state, self._running):
            try:
                pub.undeclare()
            except Exception:  # the session closed first
                pass
        if self.session is not None:
            try:
                self.session.close()
            except Exception:  # a close that times out: the process ends it
                pass
        if self.own is not None:
            self.own()
