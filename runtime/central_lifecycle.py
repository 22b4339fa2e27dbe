"""The central's start and end: the handshake with every role, the orders it gives
(``go``, ``start``, ``stop``) and the collection of the roles' final reports.

:class:`CentralLifecycle` is a part of :class:`~.central.Central` (a mixin).
"""

from __future__ import annotations

import queue
import time
from typing import Any

from .central_guard import Fault
from .codec import (
    encode,
    short_text,
)
from .config import EXIT_LINK, RunConfig
from .controller import Controller
from .engine import Engine


class CentralLifecycle:
    """Start-up and stop of :class:`~.central.Central`."""

    def expected_roles(self) -> set[str]:
        roles = {f"peripheral-{k + 1}" for k in range(self.n)}
        if self.rc.schedule.clock != "freerun":
            roles.add("plant")
        return roles

    def handshake(self) -> None:
        """Wait for every role's hello, then say go."""
        expected = self.expected_roles()
        seen: set[str] = set()
        deadline = time.monotonic() + self.rc.transport.startup_timeout
        while seen != expected:
            left = deadline - time.monotonic()
            if left <= 0:
                missing = ", ".join(sorted(expected - seen))
                raise Fault(f"no hello from {missing} within {self.rc.transport.startup_timeout} s",
                            process=missing, code=EXIT_LINK)
            self._check_children()
            try:
                ev = self.node.events.get(timeout=min(left, 0.1))
            except queue.Empty:
                continue
            if ev.kind == "hello":
                msg = self.node.decode(ev.data)
                if msg is not None and msg.get("role") in expected:
                    seen.add(msg["role"])
            elif ev.kind == "sample":
                pass  # the plant's first sample may only follow go
        self.say("go")

    def say(self, stage: str, *, peripherals_only: bool = False, plant_only: bool = False,
            **extra: Any) -> bytes:
        """Publish a control order (go, place, start, stop, ...) to every other role (or
        only to the peripherals, or only to the plant); returns its payload."""
        payload = encode(self.node.unit, 0, stage, **extra)
        pubs = self.pub_ctl[:1] if peripherals_only else self.pub_ctl[1:] if plant_only \
            else self.pub_ctl
        for pub in pubs:
            pub.put(payload)
        return payload

    def place(self, rc: RunConfig, engine: Engine, controller: Controller) -> None:
        """Switch the unit to ``engine``'s placement before the run (``--placement auto``'s
        choice at warm-up), without starting it again: every peripheral is told the
        blocks the central now runs, rebuilds its plan and says ``placed``; this returns
        once each has, and then runs the new plan itself. Warm up again before measuring
        (the round trips kept were of the old plan).

        Raises
        ------
        Fault
            If a peripheral does not confirm within the start-up timeout.
        """
        blocks = sorted(engine.plan.placement.central_blocks)
        waiting = {f"peripheral-{k + 1}" for k in range(self.n)}
        deadline = time.monotonic() + self.rc.transport.startup_timeout
        next_say = 0.0
        while waiting:
            now = time.monotonic()
            if now > deadline:
                missing = ", ".join(sorted(waiting))
                raise Fault(f"{missing} did not take the placement chosen at warm-up within "
                            f"{self.rc.transport.startup_timeout} s", process=missing,
                            code=EXIT_LINK)
            if now >= next_say:  # again until each has it (an order may race a route)
                self.say("place", peripherals_only=True, central_blocks=blocks)
                next_say = now + 0.1
            self._check_children()
            try:
                ev = self.node.events.get(timeout=0.05)
            except queue.Empty:
                continue
            if ev.kind == "hello":
                msg = self.node.decode(ev.data)
                if (msg is not None and msg.get("stage") == "placed"
                        and msg.get("central_blocks") == blocks):
                    waiting.discard(msg.get("role"))
                elif msg is not None:
                    self._handle(ev)
            elif ev.kind == "sample":
                self._on_sample(ev.data, ev.rx_ns)
            # a reply now is the warm-up's, of the old plan: dropped
        self.rc = rc
        self.use(engine, controller)

    def zenoh_identity(self) -> dict[str, Any]:
        """This central's Zenoh id and the ids of the peers it is connected to."""
        info = self.node.session.info
        self.peers_seen.update(str(z) for z in info.peers_zid())
        return {"zid": str(info.zid()), "peers": sorted(self.peers_seen)}

    def stop(self, *, reason: str = "done", wait: float = 1.0) -> None:
        """Tell every role to stop (the plant runs its safe stop) and collect their
        reports for up to ``wait`` seconds."""
        expected = self.expected_roles()
        deadline = time.monotonic() + wait
        hold = self.hold_torques()
        # a fault's message is long; whole, it made the order undecodable (the roles then
        # ran on, and the plant made no safe stop, until the launcher ended them)
        reason = short_text(reason)
        self.say("stop", reason=reason, hold=hold)
        next_say = time.monotonic() + 0.1
        while set(self.role_reports) < expected and time.monotonic() < deadline:
            try:
                ev = self.node.events.get(timeout=0.05)
            except queue.Empty:
                ev = None
            if ev is not None and ev.kind == "hello":
                self._handle(ev)
            if time.monotonic() > next_say:
                self.say("stop", reason=reason, hold=hold)
                next_say = time.monotonic() + 0.1
