"""What the central sends: each request to the peripherals (the parts of the rounds ready,
in one exchange) and each command to the plant, with the recording's note of each. The
mirror of :mod:`.inbox`; when they are sent is the pipeline's (:mod:`.intervals`)."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import zenoh

from ..transport.codec import encode
from ..transport.node import Node
from .meters import Meters
from .settings import CommandAhead, LoopSettings


class Outgoing:
    """The central's publishers and what it puts on them.

    Parameters
    ----------
    node, settings : the central's node (its publishers are declared here) and settings.
    meters : counts the exchanges and the time spent sending them.
    reply_each : peripherals answer each part of a fused request at once.
    on_message : the recording's hook, or None.
    """

    def __init__(self, node: Node, settings: LoopSettings, *, meters: Meters,
                 reply_each: bool = False, on_message: Callable[..., Any] | None = None
                 ) -> None:
        self.node = node
        self.settings = settings
        self.meters = meters
        self.on_message = on_message
        self.pub_req = node.publisher(node.keys.request) if settings.peripherals else None
        self.pub_cmd = node.publisher(node.keys.command)
        self.reply_each = reply_each
        """Peripherals answer each part of a fused request as soon as it is computed."""
        self.requests_on = True
        """Requests are published (off once every peripheral is taken over: .takeover)."""
        self.ahead = CommandAhead(settings.extrapolate)

    @property
    def publishers(self) -> list[zenoh.Publisher]:
        """Every publisher declared here (the admission's trial undeclares them)."""
        return [p for p in (self.pub_req, self.pub_cmd) if p is not None]

    def publish_request(self, payload: bytes) -> None:
        """Put ``payload`` on the request key."""
        assert self.pub_req is not None
        self.pub_req.put(payload)

    def request(self, parts: list[dict[str, Any]], *, since_ns: int) -> None:
        """Send ``parts`` (each a round of one interval) as one request, unless requests
        are off; ``since_ns``: when sending began (``perf_counter_ns``, for the meters)."""
        extra = {"each": True} if self.reply_each and len(parts) > 1 else {}
        first = parts[0]
        payload = encode(self.node.unit, first["cycle"], first["stage"], parts=parts, **extra)
        if self.requests_on:
            self.publish_request(payload)
        self.meters.exchanges += 1
        self.meters.send_ns += time.perf_counter_ns() - since_ns
        if self.on_message is not None:
            self.on_message("out", self.node.keys.request, first["cycle"], first["stage"],
                            payload, time.monotonic_ns())

    def command(self, cycle: int, cmd: Any, *, grid: Any) -> int:
        """Send interval ``cycle``'s command ``cmd`` (with the next one extrapolated where
        the settings say so: :class:`~.settings.CommandAhead`; flagged ``probe`` in the
        admission's trial, whose commands are sent as the run's are, never applied).
        Returns when it was sent (``monotonic_ns``)."""
        tau = [float(x) for x in cmd]
        nxt = self.ahead.after(cycle, tau, grid=grid)
        extra: dict[str, Any] = {} if nxt is None else {"next": nxt}
        if self.settings.trial:
            extra["probe"] = True
        payload = encode(self.node.unit, cycle, "command", tau=tau, **extra)
        self.pub_cmd.put(payload)
        now = time.monotonic_ns()
        if self.on_message is not None:
            self.on_message("out", self.node.keys.command, cycle, "command", payload, now)
        return now


__all__ = ["Outgoing"]
