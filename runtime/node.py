"""What every role shares: a Zenoh session whose subscribers feed one queue, the
start-up handshake, rejection counters and a watchdog on the central's silence.

Handshake: a role publishes ``hello`` every 50 ms until the central answers ``go`` on the
control key; the central starts once every expected role has said hello (so both
directions of every link carry traffic). ``stop`` on the control key ends every role; a
role that hears nothing from the central for ``watchdog`` seconds exits on its own, so no
process outlives a central that died.
"""

from __future__ import annotations

import queue
import time
from collections import Counter
from collections.abc import Callable
from typing import Any

import zenoh

from .codec import BadMessage, decode, encode
from .zsession import Keys

Event = tuple[str, int, bytes, int]  # (kind, index, payload, receive time ns)


class Node:
    """A Zenoh session with one event queue.

    Parameters
    ----------
    conf : Zenoh configuration.
    unit : unit id.
    role : this role's name (``plant``, ``peripheral-1``, ``central``).
    """

    def __init__(self, conf: zenoh.Config, unit: str, role: str) -> None:
        self.unit = unit
        self.role = role
        self.keys = Keys(unit)
        self.events: queue.SimpleQueue[Event] = queue.SimpleQueue()
        self.rejected: Counter[str] = Counter()
        self.session = zenoh.open(conf)
        self._subs: list[Any] = []
        self.last_heard_ns = time.monotonic_ns()
        self.stop_msg: dict[str, Any] | None = None

    def subscribe(self, key: str, kind: str, index: int = 0) -> None:
        """Push every sample on ``key`` into the event queue as ``(kind, index, bytes, t)``."""
        put = self.events.put

        def cb(sample: zenoh.Sample) -> None:
            put((kind, index, sample.payload.to_bytes(), time.monotonic_ns()))

        self._subs.append(self.session.declare_subscriber(key, cb))

    def publisher(self, key: str) -> zenoh.Publisher:
        """A publisher that never drops: every exchange of the interval must arrive (Zenoh's
        default congestion control for publications is DROP)."""
        return self.session.declare_publisher(
            key, congestion_control=zenoh.CongestionControl.BLOCK)

    def decode(self, data: bytes) -> dict[str, Any] | None:
        """Decode a message for this unit, or count and drop it."""
        try:
            return decode(data, self.unit)
        except BadMessage as exc:
            self.rejected[exc.reason] += 1
            return None

    def reject(self, reason: str) -> None:
        self.rejected[reason] += 1

    def close(self) -> None:
        for s in self._subs:
            try:
                s.undeclare()
            except Exception:
                pass
        self.session.close()

    # -- handshake (non-central roles) ----------------------------------------------------

    def wait_for_go(self, *, timeout: float, on_event: Callable[[Event], None] | None = None
                    ) -> dict[str, Any]:
        """Say hello until the central says go; returns the go message.

        Raises
        ------
        TimeoutError
            If no go arrives within ``timeout`` seconds.
        """
        hello = self.publisher(self.keys.hello)
        self.subscribe(self.keys.control, "control")
        deadline = time.monotonic() + timeout
        next_hello = 0.0
        while True:
            now = time.monotonic()
            if now > deadline:
                raise TimeoutError(f"{self.role}: no go from the central within {timeout} s")
            if now >= next_hello:
                hello.put(encode(self.unit, 0, "hello", role=self.role))
                next_hello = now + 0.05
            try:
                ev = self.events.get(timeout=0.05)
            except queue.Empty:
                continue
            if ev[0] == "control":
                msg = self.decode(ev[2])
                if msg is not None and msg["stage"] == "go":
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


def is_stop(node: Node, ev: Event) -> bool:
    """True if ``ev`` is a stop order from the central (and note that it spoke)."""
    if ev[0] != "control":
        return False
    msg = node.decode(ev[2])
    if msg is None:
        return False
    node.last_heard_ns = time.monotonic_ns()
    if msg["stage"] == "stop":
        node.stop_msg = msg
        return True
    return False
