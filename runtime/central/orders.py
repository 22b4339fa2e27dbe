"""The central's orders to the other roles and what it hears back outside the cycle: the
handshake (every role's ``hello``, then ``go``), the orders (``place``, ``start``,
``stop``, ...) and the roles' final reports (``bye``)."""

from __future__ import annotations

import queue
import re
import time
from collections.abc import Callable, Collection
from typing import Any

from ..config import EXIT_LINK
from ..transport.codec import encode, short_text
from ..transport.node import Event, Node
from .fault import Fault, plant_fault, role_report

ROLE_NAME = re.compile(r"plant|peripheral-[1-9]")
"""What a role that asks for the configuration may be called."""

HELLO_ROLES = ("plant", *(f"peripheral-{k}" for k in range(1, 10)))
"""The roles whose hello keys the central reads (:data:`ROLE_NAME`), each event's index
the role's place here."""

REPEAT_S = 0.1
"""An order not yet acknowledged (place, stop) is given again this often: a role may
have missed it (an order may race a route, or a signal of the role's own)."""


class Orders:
    """Orders and acknowledgements of one central.

    Parameters
    ----------
    node : the central's node.
    peripherals : how many peripherals the unit has.
    plant : whether the unit has a plant (not in freerun).
    startup_timeout_s : how long the roles may take to say hello or confirm an order.
    check_children : raises the fault of a role process that has exited.
    take_sample : takes a sample that arrives while an order waits (``place``).
    config : the fields of the ``config`` order, the run's configuration a role started by
        hand asks for at its handshake (runtime/config/handed.py, ``config_message``).
    may_join : whether a role that asks for the configuration once the run has begun may
        have it (a lost peripheral started again: .takeover); by default none may.
    """

    def __init__(self, node: Node, *, peripherals: int, plant: bool,
                 startup_timeout_s: float, check_children: Callable[[], None],
                 take_sample: Callable[[bytes, int], None],
                 config: dict[str, Any],
                 may_join: Callable[[str], bool] = lambda role: False) -> None:
        self.node = node
        self.peripherals = peripherals
        self.plant = plant
        self.startup_timeout_s = startup_timeout_s
        self.check_children = check_children
        self.take_sample = take_sample
        self.config = config
        self.may_join = may_join
        self.started = False
        """Whether the run has begun (``start`` said)."""
        self.central_blocks: list[str] | None = None
        """The blocks the central runs, once a ``place`` order moved any: a role that
        says hello after it gets them with ``go``."""
        self.pubs = [node.publisher(node.keys.control(r)) for r in ("peripheral", "plant")]
        for i, role in enumerate(HELLO_ROLES):
            node.route(node.keys.hello(role), "hello", i)
        self.role_reports: dict[str, dict] = {}
        """Each role's final report (:func:`~.fault.role_report`), by role name."""
        self.peers_seen: set[str] = set()
        self.stopping = False
        """Whether :meth:`stop` has begun: a report naming a plant fault is then only kept."""

    def expected_roles(self) -> set[str]:
        """The names of the roles of this unit, the central's aside."""
        roles = {f"peripheral-{k + 1}" for k in range(self.peripherals)}
        if self.plant:
            roles.add("plant")
        return roles

    def say(self, stage: str, *, peripherals_only: bool = False, plant_only: bool = False,
            **extra: Any) -> bytes:
        """Publish a control order (go, place, start, stop, ...) to every other role (or
        only to the peripherals, or only to the plant); returns its payload."""
        payload = encode(self.node.unit, 0, stage, **extra)
        self.started = self.started or stage == "start"
        pubs = self.pubs[:1] if peripherals_only else self.pubs[1:] if plant_only \
            else self.pubs
        for pub in pubs:
            pub.put(payload)
        return payload

    def hello_message(self, ev: Event) -> dict[str, Any] | None:
        """The message of an event on a role's hello key, decoded, if it names that role;
        else counted (``bad_value``) and None. With keys a role may publish on its own
        hello key alone, so a role that claims another's name there is refused: a
        peripheral's certificate once sent a ``bye`` as the plant naming a plant fault
        (the unit stopped) or a safe stop the plant never made (it was reported)."""
        msg = self.node.decode(ev.data)
        if msg is not None and msg.get("role") != HELLO_ROLES[ev.index]:
            self.node.reject("bad_value", f"a message on {HELLO_ROLES[ev.index]}'s hello key "
                             f"names the role {str(msg.get('role'))[:24]!r}")
            return None
        return msg

    def on_hello(self, ev: Event) -> None:
        """A message on the hello key outside the handshake: a role that missed ``go``
        asks again; a ``bye`` carries a role's final report; a late ``placed`` is no
        fault; anything else is rejected.

        Raises
        ------
        Fault
            The plant's, with exit code 4, when its report names a plant fault (an arm at
            its mechanical stop, a singular configuration, ...) before the stop; the
            report is kept only from its final ``bye``, after the stop order."""
        msg = self.hello_message(ev)
        if msg is None:
            return
        stage = msg.get("stage")
        if stage == "hello" and msg.get("want") == "config":
            if self.may_join(str(msg.get("role"))):
                self.hand_config(msg)  # a lost peripheral started again
            return  # else the run has begun: a role that asks now is too late to join it
        if stage == "hello":  # a role that missed go asks again, or one started again
            blocks: dict[str, Any] = ({} if self.central_blocks is None
                                      else {"central_blocks": self.central_blocks})
            self.say("go", **blocks)
            if self.started:  # its CPU is counted from now (a running one's stays)
                self.say("start", peripherals_only=True)
        elif stage == "bye":
            report = msg.get("report")
            if msg.get("role") not in self.expected_roles() or type(report) is not dict:
                self.node.reject("bad_value")
                return
            kept = role_report(report)
            if "fault" in kept and msg["role"] == "plant" and not self.stopping:
                raise plant_fault(kept)
            self.role_reports[msg["role"]] = kept
        elif stage != "placed":  # a late acknowledgement of a place order is no fault
            self.node.reject("bad_stage")

    def hand_config(self, hello: dict[str, Any]) -> None:
        """Send the run's configuration to the kind of role that asked for it in
        ``hello`` (a role started by hand). A peripheral this unit does not have gets it
        too, and says so itself (its index against the unit's peripherals); a name that
        is no role is rejected."""
        role = hello.get("role")
        if not isinstance(role, str) or not ROLE_NAME.fullmatch(role):
            self.node.reject("bad_value")
            return
        self.say("config", peripherals_only=role != "plant", plant_only=role == "plant",
                 **self.config)

    def handshake(self) -> None:
        """Wait for every role's hello, then say go.

        Raises
        ------
        Fault
            If a role has not said hello within the start-up timeout.
        """
        expected = self.expected_roles()
        seen: set[str] = set()
        deadline = time.monotonic() + self.startup_timeout_s
        while seen != expected:
            left = deadline - time.monotonic()
            if left <= 0:
                missing = ", ".join(sorted(expected - seen))
                raise Fault(f"no hello from {missing} within {self.startup_timeout_s} s",
                            process=missing, code=EXIT_LINK)
            self.check_children()
            try:
                ev = self.node.events.get(timeout=min(left, 0.1))
            except queue.Empty:
                continue
            if ev.kind == "hello":
                msg = self.hello_message(ev)
                if msg is not None and msg.get("want") == "config":
                    self.hand_config(msg)  # its hello comes once it is set up
                elif msg is not None and msg.get("role") in expected:
                    seen.add(msg["role"])
            # a sample now is no fault: the plant's first sample may only follow go
        self.say("go")

    def place(self, central_blocks: list[str], *, skip: Collection[str] = (),
              from_cycle: int | None = None) -> None:
        """Tell every peripheral the blocks the central now runs (``--placement auto``'s
        choice at warm-up, or once the run has begun a live re-placement from interval
        ``from_cycle`` on, none begun: :mod:`.rebalance`) until each has rebuilt its plan
        and said ``placed`` (those in ``skip``, taken over, aside: one started again gets
        the blocks with ``go``).

        Raises
        ------
        Fault
            If a peripheral does not confirm within the start-up timeout.
        """
        waiting = {f"peripheral-{k + 1}" for k in range(self.peripherals)} - set(skip)
        self.central_blocks = central_blocks
        live: dict[str, Any] = {} if from_cycle is None else {"from_cycle": from_cycle}
        when = "at warm-up" if from_cycle is None else f"from interval {from_cycle}"
        deadline = time.monotonic() + self.startup_timeout_s
        next_say = 0.0
        while waiting:
            now = time.monotonic()
            if now > deadline:
                missing = ", ".join(sorted(waiting))
                raise Fault(f"{missing} did not take the placement chosen {when} within "
                            f"{self.startup_timeout_s} s", process=missing, code=EXIT_LINK)
            if now >= next_say:  # again until each has it
                self.say("place", peripherals_only=True, central_blocks=central_blocks,
                         **live)
                next_say = now + REPEAT_S
            self.check_children()
            try:
                ev = self.node.events.get(timeout=0.05)
            except queue.Empty:
                continue
            if ev.kind == "hello":
                msg = self.hello_message(ev)
                if (msg is not None and msg.get("stage") == "placed"
                        and msg.get("central_blocks") == central_blocks):
                    waiting.discard(msg.get("role"))
                elif msg is not None:
                    self.on_hello(ev)
            elif ev.kind == "sample":
                self.take_sample(ev.data, ev.rx_ns)
            # a reply now is the warm-up's, of the old plan: dropped

    def drain(self, *, seconds: float) -> None:
        """For ``seconds``, drop what arrives (after an admission trial that stopped
        early: its stragglers, so that the run does not count them as rejected); a
        ``bye`` is still taken."""
        deadline = time.monotonic() + seconds
        while (left := deadline - time.monotonic()) > 0:
            try:
                ev = self.node.events.get(timeout=left)
            except queue.Empty:
                break
            if ev.kind == "hello":
                self.on_hello(ev)

    def stop(self, *, reason: str, hold: list[float], wait: float) -> None:
        """Tell every role to stop, the plant to hold ``hold`` while it makes its safe
        stop, and collect their reports for up to ``wait`` seconds."""
        expected = self.expected_roles()
        self.stopping = True
        deadline = time.monotonic() + wait
        # a fault's message is long; whole, it made the order undecodable (the roles then
        # ran on, and the plant made no safe stop, until the launcher ended them)
        reason = short_text(reason)
        self.say("stop", reason=reason, hold=hold)
        next_say = time.monotonic() + REPEAT_S
        while set(self.role_reports) < expected and time.monotonic() < deadline:
            try:
                ev: Event | None = self.node.events.get(timeout=0.05)
            except queue.Empty:
                ev = None
            if ev is not None and ev.kind == "hello":
                self.on_hello(ev)
            if time.monotonic() > next_say:
                self.say("stop", reason=reason, hold=hold)
                next_say = time.monotonic() + REPEAT_S

    def zenoh_identity(self) -> dict[str, Any]:
        """This central's Zenoh id and the ids of the peers and routers it has been
        connected to (another unit's observers' relay is a router)."""
        info = self.node.session.info
        self.peers_seen.update(str(z) for z in [*info.peers_zid(), *info.routers_zid()])
        return {"zid": str(info.zid()), "peers": sorted(self.peers_seen)}


__all__ = ["Orders"]
