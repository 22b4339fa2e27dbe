"""What every role shares: a Zenoh session with one inbox, the start-up handshake,
rejection counters and a watchdog on the central's silence.

Inbox: every key a role receives lies under its prefix (:class:`~.zsession.Keys`), so one
FIFO subscriber carries all of it and the role's own thread reads it: no callback thread
and no second queue between Zenoh and the role (docs/message-costs.md: a callback handler feeding
a queue costs a thread hop per message; measured here 236 against 302-344 us p50 per
scatter/gather round of 3, and 165 against 215 us of the central's CPU).

Handshake: a role publishes ``hello`` every 50 ms until the central answers ``go`` on the
role's control key; the central starts once every expected role has said hello (so both
directions of every link carry traffic). ``stop`` on the control key ends every role; a
role that hears nothing from the central for ``watchdog`` seconds exits on its own, so no
process outlives a central that died.
"""

from __future__ import annotations

import gc
import os
import queue
import threading
import time
from collections import Counter
from collections.abc import Callable
from typing import Any, NamedTuple

import zenoh

from .codec import BadMessage, decode, encode
from .zsession import Keys


class Event(NamedTuple):
    """One received message: what its key was routed as, and when it arrived."""

    kind: str
    """The kind its key was routed as (``reply``, ``sample``, ``request``, ...)."""
    index: int  # type: ignore[assignment]  # a field named as tuple's method, by design
    """The index routed with the key (the peripheral of a reply, 0 otherwise)."""
    data: bytes
    """The payload, not yet decoded."""
    rx_ns: int
    """Receive time on the monotonic clock (ns)."""

TICK_MAX_S = 0.1
"""Longest a wait blocks inside Zenoh before it looks at the clock again (and Python sees
a pending Ctrl-C)."""


class _Ticker:
    """Wakes a blocked :meth:`Inbox.get` at its deadline.

    Zenoh's channel receive has no timeout, so a daemon thread publishes a session-local
    tick on the inbox when the armed deadline passes. It sleeps until the armed deadline
    (at most ``TICK_MAX_S``); arming a later deadline than it sleeps for costs no wake-up.
    """

    def __init__(self, tick: Callable[[], None]) -> None:
        self._tick = tick
        self._cond = threading.Condition()
        self._deadline = 0  # ns on the monotonic clock; 0: nothing armed
        self._target = 0  # when the thread wakes next
        self._closed = False
        self._thread = threading.Thread(target=self._run, name="ctrlunit-ticker", daemon=True)
        self._thread.start()

    def arm(self, deadline_ns: int) -> None:
        with self._cond:
            self._deadline = deadline_ns
            if deadline_ns < self._target:
                self._cond.notify()

    def disarm(self) -> None:
        self._deadline = 0  # a plain store: a late tick only makes get() look again

    def close(self) -> None:
        with self._cond:
            self._closed = True
            self._cond.notify()
        self._thread.join(timeout=1.0)

    def _run(self) -> None:
        idle_ns = int(TICK_MAX_S * 1e9)
        with self._cond:
            while not self._closed:
                now = time.monotonic_ns()
                d = self._deadline
                if d and now >= d:
                    self._deadline = 0
                    try:
                        self._tick()
                    except Exception:  # the session is closing
                        return
                    continue
                wait = (d - now) if d else idle_ns
                self._target = now + wait
                self._cond.wait(wait / 1e9)


class Inbox:
    """The events of one role, read by the role's own thread.

    Parameters
    ----------
    session : the role's Zenoh session.
    prefix : the role's inbox prefix; everything under it is received.
    on_unknown : called with a reason for a message on a key nobody routed.
    capacity : FIFO capacity (Zenoh's receive thread waits when it is full).

    :meth:`get` has the contract of :meth:`queue.SimpleQueue.get`: it returns an
    :data:`Event` ``(kind, index, payload, receive time)`` for a routed key, or raises
    :class:`queue.Empty` once ``timeout`` seconds have passed.
    """

    def __init__(self, session: zenoh.Session, prefix: str, *,
                 on_unknown: Callable[[str], None], capacity: int = 4096) -> None:
        self._routes: dict[str, tuple[str, int]] = {}
        self._on_unknown = on_unknown
        self._held: zenoh.Sample | None = None  # taken by pending(), given by get()
        self._sub = session.declare_subscriber(f"{prefix}/**",
                                               zenoh.handlers.FifoChannel(capacity))
        self._tick_key = f"{prefix}/tick"
        self._token = os.urandom(8)
        tick_pub = session.declare_publisher(self._tick_key,
                                             allowed_destination=zenoh.Locality.SESSION_LOCAL)
        token = self._token
        self._ticker = _Ticker(lambda: tick_pub.put(token))

    def route(self, key: str, kind: str, index: int = 0) -> None:
        """Deliver messages on ``key`` as events of ``kind`` (with ``index``)."""
        self._routes[key] = (kind, index)

    def _event(self, sample: zenoh.Sample) -> Event | None:
        key = str(sample.key_expr)
        r = self._routes.get(key)
        data = sample.payload.to_bytes()
        if r is not None:
            return Event(r[0], r[1], data, time.monotonic_ns())
        if key != self._tick_key or data != self._token:
            self._on_unknown("unexpected_key")
        return None  # a tick: look at the clock again

    def pending(self) -> bool:
        """Whether a message is waiting (it stays for the next :meth:`get`)."""
        if self._held is None:
            self._held = self._sub.try_recv()
        return self._held is not None

    @staticmethod
    def checkpoint() -> None:
        """Called by :meth:`get` before it returns or waits, and after each wake-up: a
        place where the caller's state is whole (a stop signal held meanwhile is raised
        here: runtime/roles/stopping.py, ``held_stops``). Does nothing by default."""

    def get(self, timeout: float | None = None) -> Event:
        self.checkpoint()
        s, self._held = self._held, None
        if s is None:
            s = self._sub.try_recv()
        end = None
        while True:
            if s is not None:
                ev = self._event(s)
                if ev is not None:
                    return ev
                s = self._sub.try_recv()
                continue
            now = time.monotonic_ns()
            if end is None:
                end = now + int(timeout * 1e9) if timeout is not None else 1 << 62
            if now >= end:
                raise queue.Empty
            self._ticker.arm(min(end, now + int(TICK_MAX_S * 1e9)))
            s = self._sub.recv()
            self._ticker.disarm()
            self.checkpoint()

    def get_nowait(self) -> Event:
        return self.get(timeout=0.0)

    def close(self) -> None:
        self._ticker.close()
        try:
            self._sub.undeclare()
        except Exception:
            pass


class Node:
    """A Zenoh session with one inbox.

    Parameters
    ----------
    conf : Zenoh configuration.
    unit : unit id.
    role : this role's name (``plant``, ``peripheral-1``, ``central``).
    inbox : the inbox this role reads (``central``, ``peripheral``, ``plant``); by
        default the role's name up to its first ``-``.
    """

    def __init__(self, conf: zenoh.Config, unit: str, role: str, *,
                 inbox: str | None = None) -> None:
        self.unit = unit
        self.role = role
        self.keys = Keys(unit)
        self.rejected: Counter[str] = Counter()
        self.session = zenoh.open(conf)
        self.inbox_name = inbox or role.split("-")[0]
        self.events = Inbox(self.session, self.keys.inbox(self.inbox_name),
                            on_unknown=self.reject)
        self.last_heard_ns = time.monotonic_ns()
        self.stop_msg: dict[str, Any] | None = None
        self.cpu_start_s: float | None = None
        """This process's CPU time (every thread) when the central said ``start``."""

    def route(self, key: str, kind: str, index: int = 0) -> None:
        """Deliver messages on ``key`` (under this role's inbox) as ``(kind, index, ...)``
        events."""
        if not key.startswith(self.keys.inbox(self.inbox_name) + "/"):
            raise ValueError(f"{key!r} is not in the inbox of {self.role}")
        self.events.route(key, kind, index)

    def publisher(self, key: str) -> zenoh.Publisher:
        """A publisher that never waits for a reader that stops reading: under DROP
        congestion control a peer whose transmit queue is full loses the message, the
        others get it (runtime/transport/zsession.py, ``closed_links``). The unit's roles
        read as fast as they are sent to: a role whose queue fills is silent past its
        limit long before (the silence watch names it)."""
        return self.session.declare_publisher(
            key, congestion_control=zenoh.CongestionControl.DROP)

    def decode(self, data: bytes) -> dict[str, Any] | None:
        """Decode a message for this unit, or count and drop it."""
        try:
            return decode(data, self.unit)
        except BadMessage as exc:
            self.reject(exc.reason, str(exc))
            return None

    def reject(self, reason: str, detail: str = "") -> None:
        """Count a message dropped for ``reason`` (``detail``: the reason with what was
        wrong, kept as :attr:`last_reject`)."""
        self.rejected[reason] += 1
        self.rejects += 1
        self.last_reject = detail or reason

    def close(self) -> None:
        """End the inbox and the session. A session that cannot close (Zenoh gives up after
        its own time-out, e.g. while a peer that stopped reading holds a link) is left to
        the process's end: what the run measured is written all the same; the reason is
        kept in :attr:`close_error`."""
        self.events.close()
        try:
            self.session.close()
        except Exception as exc:  # zenoh.ZError
            self.close_error = str(exc).splitlines()[0] if str(exc) else type(exc).__name__

    close_error: str | None = None
    """Why the session did not close, if it did not."""

    rejects: int = 0
    """Every rejection counted so far (the central's flood rule looks at its change)."""
    last_reject: str = ""
    """The last rejection's reason and detail (``too_large: 1048590 bytes``)."""

    def __enter__(self) -> Node:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- handshake (non-central roles) ----------------------------------------------------

    def wait_for_go(self, *, timeout: float, on_event: Callable[[Event], None] | None = None
                    ) -> dict[str, Any]:
        """Say hello until the central says go; returns the go message.

        Raises
        ------
        TimeoutError
            If no go arrives within ``timeout`` seconds.
        """
        return self._hello_until("go", timeout=timeout, on_event=on_event)

    def ask_config(self, *, timeout: float) -> dict[str, Any]:
        """Say hello asking for the unit's configuration until the central sends it (a
        role started by hand, runtime/config/handed.py); returns the ``config`` message.
        The central does not count this hello as the role's: the role says hello again
        once it is set up (:meth:`wait_for_go`).

        Raises
        ------
        TimeoutError
            If no configuration arrives within ``timeout`` seconds.
        """
        return self._hello_until("config", timeout=timeout, want="config")

    def _hello_until(self, stage: str, *, timeout: float,
                     on_event: Callable[[Event], None] | None = None,
                     **hello_fields: Any) -> dict[str, Any]:
        """Say hello every 50 ms until the central's order ``stage`` comes on this role's
        control key; other events go to ``on_event``."""
        hello = self.publisher(self.keys.hello(self.role))
        self.route(self.keys.control(self.inbox_name), "control")
        deadline = time.monotonic() + timeout
        next_hello = 0.0
        while True:
            now = time.monotonic()
            if now > deadline:
                raise TimeoutError(f"{self.role}: no {stage} from the central within "
                                   f"{timeout} s")
            if now >= next_hello:
                hello.put(encode(self.unit, 0, "hello", role=self.role, **hello_fields))
                next_hello = now + 0.05
            try:
                ev = self.events.get(timeout=0.05)
            except queue.Empty:
                continue
            if ev.kind == "control":
                msg = self.decode(ev.data)
                if msg is not None and msg["stage"] == stage:
                    self.last_heard_ns = time.monotonic_ns()
                    return msg
            elif on_event is not None:
                on_event(ev)


def rss_kb() -> int:
    """Resident memory of this process (kB), from /proc."""
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1])
    except OSError:
        pass
    return -1


WARM_RSS_AT = 1000  # intervals after which memory counts as warmed up


def freeze_heap(*, collect: bool = False) -> None:
    """Move every object alive now (the role's set-up and warm-up) out of the cyclic
    collector's reach, so that a collection during the run scans only what the run
    made: the collections that scanned the whole heap took about 1.4 ms in the central,
    more than a period at 1 ms. Costs microseconds (``collect``: a full collection first,
    milliseconds, for a process that hosts many runs); call it when the run starts."""
    if collect:
        gc.collect()
    gc.freeze()


CONTROL_STAGES = frozenset({"config", "go", "place", "probe", "start", "stop", "stride"})
"""The orders the central sends on the roles' control keys (``Central.say``)."""


def control_order(node: Node, ev: Event) -> dict[str, Any] | None:
    """The central's order in a control event (None if ``ev`` is none, does not decode or
    is no order: :data:`CONTROL_STAGES`; counted as ``bad_stage`` then), noting that the
    central spoke, when it said ``start`` (see :func:`cpu_used`) and the ``stop`` order
    (:attr:`Node.stop_msg`)."""
    if ev.kind != "control":
        return None
    msg = node.decode(ev.data)
    if msg is None:
        return None
    if msg["stage"] not in CONTROL_STAGES:
        node.reject("bad_stage")
        return None
    node.last_heard_ns = time.monotonic_ns()
    if msg["stage"] == "start" and node.cpu_start_s is None:
        node.cpu_start_s = time.process_time()
        freeze_heap()
    if msg["stage"] == "stop":
        node.stop_msg = msg
    return msg


def is_stop(node: Node, ev: Event) -> bool:
    """True if ``ev`` is a stop order from the central (:func:`control_order` noted it)."""
    order = control_order(node, ev)
    return order is not None and order["stage"] == "stop"


def cpu_used(node: Node) -> float | None:
    """CPU seconds this process (all its threads: Zenoh's too) spent since the central's
    ``start`` order, or None if it never came."""
    return None if node.cpu_start_s is None else time.process_time() - node.cpu_start_s


def say_bye(node: Node, report: dict[str, Any]) -> None:
    """A role's last word: its final report, sent a few times (the central collects it
    while it waits for every role after its stop order)."""
    pub = node.publisher(node.keys.hello(node.role))
    for _ in range(3):
        pub.put(encode(node.unit, 0, "bye", role=node.role, report=report))
        time.sleep(0.02)
