"""A whole unit in one process, without Zenoh: the real central, peripherals and plant
server exchange their real encoded messages over an in-process bus.

The central runs its own event loop; each time it waits on its inbox, the bus first lets
the other roles handle what they received (a peripheral answers a request, the plant in
lockstep applies its command and publishes the next sample). So the central's
scheduling, intake, guard and recording are exercised in the test's own process, where
mutation testing can see them, and a test can hold back any message to build a fault.

    unit = LoopbackUnit(RunConfig.of(clock="lockstep", peripherals=3, pipeline=2, cycles=50))
    unit.run()                     # the central's loop until every interval is done
    unit.central.log.digest        # the commands, as a live run reports them
"""

from __future__ import annotations

import collections
import queue
import time
from collections.abc import Callable
from typing import Any

from ctrlunit.plant.simulator import Plant, PlantConfig
from ctrlunit.runtime.central import Central, Supervision
from ctrlunit.runtime.central.excuse import UNSUPERVISED
from ctrlunit.runtime.central.snapshot import Progress
from ctrlunit.runtime.compute.controller import Controller, initial_angles, initial_command
from ctrlunit.runtime.compute.setup import make_setup
from ctrlunit.runtime.config import RunConfig
from ctrlunit.runtime.roles.peripheral import Peripheral
from ctrlunit.runtime.roles.plant_node import PlantServer
from ctrlunit.runtime.transport.node import Event, Node
from ctrlunit.runtime.transport.zsession import Keys
from runner import unit_id

PUMP_ROUNDS = 1000
"""Bound on the hand-offs between roles in one pump (each moves at least one message)."""


class Bus:
    """Delivers every put to the nodes that routed its key, in order."""

    def __init__(self) -> None:
        self.nodes: list[LoopbackNode] = []
        self.log: list[tuple[str, bytes]] = []  # every message put, in order
        self.drop: Callable[[str, bytes], bool] | None = None  # True: lose this message

    def put(self, key: str, data: bytes) -> None:
        self.log.append((key, data))
        if self.drop is not None and self.drop(key, data):
            return
        for node in self.nodes:
            node.events.deliver(key, data)


class LoopbackPublisher:
    def __init__(self, bus: Bus, key: str) -> None:
        self.bus = bus
        self.key = key

    def put(self, data: bytes) -> None:
        self.bus.put(self.key, bytes(data))


class LoopbackInbox:
    """:class:`ctrlunit.runtime.transport.node.Inbox`'s contract over the bus. ``pump`` (set by the
    unit) runs the other roles before the owner looks at its events."""

    def __init__(self, on_unknown: Callable[[str], None], prefix: str) -> None:
        self._routes: dict[str, tuple[str, int]] = {}
        self._queue: collections.deque[Event] = collections.deque()
        self._on_unknown = on_unknown
        self._prefix = prefix + "/"
        self.pump: Callable[[], None] | None = None

    def route(self, key: str, kind: str, index: int = 0) -> None:
        self._routes[key] = (kind, index)

    def deliver(self, key: str, data: bytes) -> None:
        if not key.startswith(self._prefix):
            return
        r = self._routes.get(key)
        if r is None:
            self._on_unknown("unexpected_key")
            return
        self._queue.append(Event(r[0], r[1], data, time.monotonic_ns()))

    def pending(self) -> bool:
        return bool(self._queue)

    def get(self, timeout: float | None = None) -> Event:
        if self.pump is not None:
            self.pump()
        if self._queue:
            return self._queue.popleft()
        time.sleep(min(timeout or 0.0, 0.002))  # nothing will come: let the clock move
        raise queue.Empty

    def get_nowait(self) -> Event:
        if self._queue:
            return self._queue.popleft()
        raise queue.Empty

    def close(self) -> None:
        self._queue.clear()


class LoopbackNode(Node):
    """A :class:`~ctrlunit.runtime.transport.node.Node` on the bus instead of a Zenoh session."""

    def __init__(self, bus: Bus, unit: str, role: str, *, inbox: str | None = None) -> None:
        self.unit = unit
        self.role = role
        self.keys = Keys(unit)
        self.rejected = collections.Counter()
        self.inbox_name = inbox or role.split("-")[0]
        self.events = LoopbackInbox(self.reject, self.keys.inbox(self.inbox_name))
        self.last_heard_ns = time.monotonic_ns()
        self.stop_msg = None
        self.cpu_start_s = None
        self.bus = bus
        bus.nodes.append(self)

    def publisher(self, key: str) -> LoopbackPublisher:  # type: ignore[override]
        return LoopbackPublisher(self.bus, key)

    def close(self) -> None:
        self.events.close()


class LoopbackUnit:
    """The unit of ``rc`` in this process.

    Parameters
    ----------
    rc : run configuration (lockstep or freerun for :meth:`run`; any clock when a test
        drives the central by hand).
    on_cycle, on_message : the central's callbacks (a recorder's).
    supervision : what a launcher would let the central know of the roles' processes
        (:class:`~ctrlunit.runtime.central.Supervision`), given at construction as the
        launcher gives it; none by default (roles started by hand).
    """

    def __init__(self, rc: RunConfig, *,
                 on_cycle: Callable[[Progress, dict], None] | None = None,
                 on_message: Callable[..., None] | None = None,
                 supervision: Supervision = UNSUPERVISED) -> None:
        self.rc = rc
        self.setup = setup = make_setup(rc)
        self.bus = Bus()
        self.node = LoopbackNode(self.bus, rc.transport.unit, "central")
        engine = setup.engine()
        ctl = Controller(engine, rc.schedule.period, setup.params.increment,
                         tuple(setup.task.start()))
        self.controller = ctl  # the sources and observer the central was given
        self.central = Central(self.node, rc, engine, ctl, setup.cycles, on_cycle=on_cycle,
                               on_message=on_message, supervision=supervision)
        self.peripherals: list[tuple[LoopbackNode, Peripheral]] = []
        for k in range(setup.placement.peripherals):
            pnode = LoopbackNode(self.bus, rc.transport.unit, f"peripheral-{k + 1}")
            pnode.route(pnode.keys.request, "request")
            pnode.route(pnode.keys.control("peripheral"), "control")
            self.peripherals.append((pnode, Peripheral(
                setup.engine(), k, rc.transport.unit, trace=rc.run.trace,
                rejected=pnode.rejected,
                place=lambda blocks: setup.with_central_blocks(blocks).engine(),
                live=rc.schedule.balance == "live")))
        self.server: PlantServer | None = None
        if rc.schedule.clock != "freerun":
            pnode = LoopbackNode(self.bus, rc.transport.unit, "plant")
            plant = Plant(setup.params, PlantConfig(period=rc.schedule.period,
                                                    substeps=rc.plant.substeps,
                                                    lag=rc.plant.lag,
                                                    friction=rc.plant.friction, belt=rc.plant.belt),
                          q0=initial_angles(setup.params, setup.task),
                          p_guess=tuple(setup.task.start()))
            self.server = PlantServer(pnode, plant, depth=rc.schedule.pipeline,
                                      initial=initial_command(setup.params, setup.task),
                                      period_s=rc.schedule.period)
        self.muted: set[int] = set()  # peripherals (0-based) whose replies are withheld
        self.withheld: list[tuple[int, bytes]] = []  # (peripheral, reply) not delivered
        self.plant_muted = False
        self.node.events.pump = self.pump

    def pump(self) -> None:
        """Let every other role handle what it received, until none has anything left."""
        for _ in range(PUMP_ROUNDS):
            moved = False
            for k, (pnode, periph) in enumerate(self.peripherals):
                while pnode.events.pending():
                    ev = pnode.events.get_nowait()
                    moved = True
                    if ev.kind == "control":  # a place order (live balance), as serve()
                        self._order(pnode, periph, ev.data)
                        continue
                    for reply in periph.on_request(ev.data):
                        if k in self.muted:  # computed, but not (yet) delivered
                            self.withheld.append((k, reply))
                        else:
                            self.bus.put(pnode.keys.reply(k + 1), reply)
            if self.server is not None and not self.plant_muted:
                moved |= self._plant_lockstep()
            if not moved:
                return

    def _order(self, pnode: LoopbackNode, periph: Peripheral, data: bytes) -> None:
        """A control order to a peripheral: a ``place`` is taken (the run has begun) and
        acknowledged on its hello key, as the role's loop does; the others change nothing
        here."""
        from ctrlunit.runtime.transport.codec import decode

        order = decode(data, self.rc.transport.unit)
        if order.get("stage") == "place":
            ack = periph.on_place(order, pnode.role, started=True)
            if ack is not None:
                self.bus.put(pnode.keys.hello(pnode.role), ack)

    def start_plant(self) -> None:
        """The plant's first sample (its state at rest), as its role sends at start."""
        assert self.server is not None
        t = time.monotonic_ns()
        self.server.publish_sample((t, t))

    def _plant_lockstep(self) -> bool:
        """The plant role's lockstep step (runtime/roles/plant_node.py ``serve``): take the
        commands, apply the due one, integrate a period, publish the next sample."""
        server = self.server
        assert server is not None
        pnode = server.node
        moved = False
        while pnode.events.pending():
            ev = pnode.events.get_nowait()
            if ev.kind == "command":
                server.take_command(ev.data)
            moved = True
        if self.rc.schedule.clock != "lockstep":
            return moved
        while server.sample_no < self.setup.cycles:
            due = server.sample_no - self.rc.delay_periods
            if due >= 0:
                if due not in server.commands:
                    break
                server.apply(due)
            span = server.simulate()
            server.sample_no += 1
            server.publish_sample(span)
            moved = True
        return moved

    def run(self) -> Central:
        """The central's own loop (lockstep or freerun) until every interval is done;
        raises the central's :class:`~ctrlunit.runtime.central.Fault`."""
        if self.server is not None:
            self.start_plant()
        self.central.run()
        return self.central

    def commands(self) -> list[list[float]]:
        """Every command the central published, in order."""
        from ctrlunit.runtime.transport.codec import decode

        key = self.node.keys.command
        return [decode(d, self.rc.transport.unit)["tau"] for k, d in self.bus.log if k == key]


def lockstep_config(unit: str, **kw: Any) -> RunConfig:
    """A lockstep run configuration for the loopback unit."""
    kw.setdefault("clock", "lockstep")
    return RunConfig.of(unit=unit, **kw)


def record_lockstep(path: str, unit: str, **kw: Any) -> LoopbackUnit:
    """A lockstep run of the loopback unit recorded to ``path`` as ``ctrlunit start
    --record`` writes it (the same recorder, the peripherals' traces on)."""
    from ctrlunit.runtime.recording.recorder import Recorder

    rc = lockstep_config(unit, record=str(path), trace=True, **kw)
    recorder = Recorder(str(path), make_setup(rc))
    recorder.begin(recorder.setup)
    unit_ = LoopbackUnit(rc, on_cycle=recorder.on_cycle, on_message=recorder.on_message)
    unit_.recorder = recorder  # type: ignore[attr-defined]  # what it made of the run
    try:
        unit_.run()
    finally:
        recorder.close(unit_.central.snapshot())
        recorder.write_report({})
    return unit_


def realtime_unit(tag: str, *, on_message: Any = None,
                  supervision: Supervision = UNSUPERVISED, **kw: Any) -> LoopbackUnit:
    """A realtime loopback unit (3 peripherals, depth 1 unless ``kw`` says otherwise)
    with a unit id of its own, for a test that drives its central by hand, its
    ``supervision`` given at construction (:class:`LoopbackUnit`). A peripheral's
    silence past the rule is a fault here (``peripheral_loss="fault"``) unless ``kw``
    says otherwise: the silence rule's tests see when it fires, the take-over's pass
    ``peripheral_loss="takeover"``."""
    kw.setdefault("peripherals", 3)
    kw.setdefault("pipeline", 1)
    kw.setdefault("peripheral_loss", "fault")
    return LoopbackUnit(RunConfig.of(unit=unit_id(tag), clock="realtime", **kw),
                        on_message=on_message, supervision=supervision)


def take_sample(u: LoopbackUnit, k: int) -> None:
    """Realtime by hand: the plant's sample ``k`` (the robot's present state), taken by the
    central."""
    assert u.server is not None
    u.server.sample_no = k
    u.server.publish_sample((0, 0))
    u.central.handle(u.node.events.get_nowait())


def turn(u: LoopbackUnit) -> None:
    """Realtime by hand, one turn of the central's loop without its wait: start what may
    start, send, run the next interval ahead, send; then the peripherals that are not
    muted answer and the central takes their replies."""
    c = u.central
    c.start_ready()
    c.send_ready(0)
    c.prime()
    c.send_ready(0)
    u.pump()
    while u.node.events.pending():
        c.handle(u.node.events.get_nowait())
