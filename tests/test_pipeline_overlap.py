"""The two-stage pipeline's overlap, structurally (§ IV.7.2, Fig. 24).

At depth 2 one request carries interval k's second round and interval k+1's first. With a
reply per round (``each``) the peripheral must publish the first part's reply before it
starts computing the second part: the central then goes on with that interval while the
peripheral computes the other one. A peripheral that computes every part before it
publishes anything still gives the same values, so only the order of events can tell:
these tests read it off a clock and a publish hook that they control, never wall time.
"""

from __future__ import annotations

import itertools
from typing import Any

import pytest
from ctrlunit.runtime.config import RunConfig
from ctrlunit.runtime.roles.peripheral import declare, serve
from ctrlunit.runtime.transport.codec import decode
from loopback import Bus, LoopbackNode, LoopbackUnit


class TickClock:
    """A monotonic clock that moves one tick per reading, and logs who read it."""

    def __init__(self, log: list[tuple[str, int]]) -> None:
        self.now = 0
        self.reads = log

    def __call__(self) -> int:
        self.now += 1
        self.reads.append(("clock", self.now))
        return self.now


def overlap_unit(unit: str, **kw: Any) -> LoopbackUnit:
    rc = RunConfig.of(unit=unit, clock="freerun", peripherals=3, pipeline=2, cycles=12,
                      model_state="sample", replies="each", **kw)
    u = LoopbackUnit(rc)
    assert u.central.choose_replies()["mode"] == "each"  # as the launcher does at warm-up
    return u


def requests_of(u: LoopbackUnit) -> list[bytes]:
    """Every request the central sent (one key for every peripheral), in order."""
    key = u.node.keys.request
    return [data for k, data in u.bus.log if k == key]


def two_part_each(data: bytes, unit: str) -> bool:
    msg = decode(data, unit)
    return bool(msg.get("each")) and len(msg.get("parts", [])) >= 2


def test_the_first_parts_reply_leaves_before_the_second_part_is_computed():
    """Through the real central's scheduling: one tick clock for every peripheral, and a
    publish hook on the bus that reads it. Each peripheral's reply must be published
    before its next part's compute span starts."""
    u = overlap_unit("overlap-role")
    unit = u.rc.transport.unit
    log: list[tuple[str, int]] = []
    clock = TickClock(log)
    for _, per in u.peripherals:
        per.clock = clock
    published: list[tuple[str, bytes, int]] = []  # (key, reply, tick it left at)
    put = u.bus.put

    def publish_hook(key: str, data: bytes) -> None:
        if "/reply/" in key:
            published.append((key, data, clock()))
        put(key, data)

    u.bus.put = publish_hook  # type: ignore[method-assign]
    u.run()

    assert sum(two_part_each(d, unit) for d in requests_of(u)) >= 5, \
        "depth 2 with each sends interval k's second round and k+1's first together"
    by_periph: dict[str, list[tuple[int, int, int]]] = {}
    for key, data, tick in published:
        parts = decode(data, unit)["parts"]
        assert len(parts) == 1, "with each, a reply holds one round"
        t0, t1 = parts[0]["span"]
        assert t0 < t1 < tick
        by_periph.setdefault(key, []).append((t0, t1, tick))
    assert len(by_periph) == 3
    for key, seq in by_periph.items():
        for (_, _, left), (t0_next, _, _) in itertools.pairwise(seq):
            assert left < t0_next, f"{key}: a reply left only after the next part began"


@pytest.mark.parametrize("law", ["resolved-acceleration", "computed-torque"])
def test_serve_publishes_each_reply_before_computing_the_next_part(law):
    """The role's loop (:func:`serve`) on a node the test drives: the requests of a real
    depth-2 run are fed to a fresh peripheral; the engine's rounds and the publisher's
    puts are logged in one sequence. Every two-part request must log compute, publish,
    compute, publish, never compute, compute, publish, publish."""
    u = overlap_unit(f"overlap-serve-{law}", law=law)
    u.run()
    unit = u.rc.transport.unit
    requests = requests_of(u)
    assert any(two_part_each(d, unit) for d in requests)

    bus = Bus()
    node = LoopbackNode(bus, unit, "peripheral-1")
    events: list[str] = []

    class Publisher:
        def put(self, data: bytes) -> None:
            events.append("publish")

    declare(node, 0)
    engine = u.setup.engine()
    run_round = engine.run_round

    def logged_round(rnd: Any, ctx: dict, axes: Any) -> None:
        events.append("compute")
        run_round(rnd, ctx, axes)

    engine.run_round = logged_round  # type: ignore[method-assign]
    for data in requests:
        bus.put(node.keys.request, data)
    res = serve(node, engine, 0, Publisher(), watchdog=0.0)
    assert res["exit"] == "watchdog"
    assert not node.rejected, dict(node.rejected)
    assert events.count("compute") == events.count("publish") == res["served"]
    # with each, every compute is followed by its publish before the next compute
    assert events == ["compute", "publish"] * res["served"], "".join(e[0] for e in events)
