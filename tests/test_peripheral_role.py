"""The peripheral's contract, through what it exposes (runtime/roles/peripheral.py).

``Peripheral`` (bytes in, bytes out) and its loop ``serve`` on a loopback node: which
replies leave and in which order, what is kept between rounds and for how long, what is
counted when a request cannot be answered, what a recording's trace holds, what the role
reports at its end, and which orders it obeys. Requests are the real ones of a
resolved-acceleration unit's first interval (two rounds), renumbered where a test needs
other cycles.
"""

from __future__ import annotations

from collections import Counter
from typing import Any

import pytest
from ctrlunit.runtime.compute.engine import Engine
from ctrlunit.runtime.config import ConfigError
from ctrlunit.runtime.roles import peripheral as peripheral_module
from ctrlunit.runtime.roles.peripheral import MAX_KEPT_CYCLES, Peripheral, declare, serve
from ctrlunit.runtime.transport.codec import decode, encode
from ctrlunit.runtime.transport.node import WARM_RSS_AT
from loopback import Bus, LoopbackNode
from runner import unit_id
from test_validation import ENGINE_BY_LAW, UNIT

ENGINE, PARTS = ENGINE_BY_LAW["resolved-acceleration"]
R0, R1 = PARTS[0], PARTS[1]


def part(p: dict[str, Any], cycle: int) -> dict[str, Any]:
    return {**p, "cycle": cycle}


def request(*parts: dict[str, Any], **envelope: Any) -> bytes:
    return encode(UNIT, parts[0]["cycle"], parts[0]["stage"], parts=list(parts), **envelope)


def answered(payloads: Any) -> list[tuple[int, int]]:
    """(cycle, stage) of each part of each reply, in order."""
    return [(p["cycle"], p["stage"]) for b in payloads for p in decode(b, UNIT)["parts"]]


class Tick:
    def __init__(self) -> None:
        self.now = 0

    def __call__(self) -> int:
        self.now += 1
        return self.now


def test_the_two_rounds_are_answered_and_the_first_rounds_context_is_kept_until_the_last():
    per = Peripheral(ENGINE, 0, UNIT)
    assert answered(per.on_request(request(part(R0, 5)))) == [(5, 0)]
    assert answered(per.on_request(request(part(R1, 5)))) == [(5, 1)]
    # the last round drops the interval's context: its round 1 again is an unknown cycle
    assert list(per.on_request(request(part(R1, 5)))) == []
    assert per.rejected == Counter({"unknown_cycle": 1})
    assert per.served == 2


def test_with_each_the_first_round_leaves_first_and_alone():
    per = Peripheral(ENGINE, 1, UNIT)
    list(per.on_request(request(part(R0, 3))))
    out = list(per.on_request(request(part(R1, 3), part(R0, 4), each=True)))
    assert answered(out) == [(4, 0), (3, 1)]  # one reply each, first rounds first
    per2 = Peripheral(ENGINE, 1, UNIT)
    list(per2.on_request(request(part(R0, 3))))
    out = list(per2.on_request(request(part(R1, 3), part(R0, 4))))
    assert len(out) == 1 and answered(out) == [(3, 1), (4, 0)]  # fused: one, in order


def test_a_later_round_of_an_unseen_cycle_is_counted_and_the_rest_is_answered():
    per = Peripheral(ENGINE, 0, UNIT)
    out = list(per.on_request(request(part(R1, 7), part(R0, 8))))
    assert answered(out) == [(8, 0)]
    assert per.rejected == Counter({"unknown_cycle": 1})
    list(per.on_request(request(part(R1, 9))))
    assert per.rejected == Counter({"unknown_cycle": 2})


def test_eight_intervals_are_kept_and_the_oldest_goes_first():
    assert MAX_KEPT_CYCLES == 8
    per = Peripheral(ENGINE, 0, UNIT)
    for c in range(8):
        list(per.on_request(request(part(R0, c))))
    assert answered(per.on_request(request(part(R1, 0)))) == [(0, 1)]  # all eight kept
    for c in range(8, 17):
        list(per.on_request(request(part(R0, c))))
    # 9..16 are the newest eight after 16 opened: 1..8 went, oldest first
    assert list(per.on_request(request(part(R1, 8)))) == []
    assert answered(per.on_request(request(part(R1, 9)))) == [(9, 1)]
    assert per.rejected == Counter({"unknown_cycle": 1})


def test_a_kernel_that_raises_is_counted_by_its_type_and_the_rest_is_answered(monkeypatch):
    per = Peripheral(ENGINE, 0, UNIT)
    run_round = Engine.run_round
    calls = Counter()

    def flaky(self: Engine, rnd: Any, ctx: dict, axes: Any) -> None:
        calls[rnd.index] += 1
        if rnd.index == 0 and calls[0] == 1:
            raise ZeroDivisionError("kernel")
        run_round(self, rnd, ctx, axes)

    monkeypatch.setattr(Engine, "run_round", flaky)
    out = list(per.on_request(request(part(R0, 1), part(R0, 2))))
    assert answered(out) == [(2, 0)]
    assert per.rejected == Counter({"kernel_error:ZeroDivisionError": 1})
    calls.clear()
    list(per.on_request(request(part(R0, 3))))
    assert per.rejected == Counter({"kernel_error:ZeroDivisionError": 2})


def test_a_validation_gap_is_counted_as_invalid_by_type_and_never_raised(monkeypatch):
    def gap(*_: Any) -> Any:
        raise TypeError("a check that let something through")

    monkeypatch.setattr(peripheral_module, "check_vals", gap)
    per = Peripheral(ENGINE, 0, UNIT)
    assert list(per.on_request(request(part(R0, 1)))) == []
    assert list(per.on_request(request(part(R0, 2)))) == []
    assert per.rejected == Counter({"invalid:TypeError": 2})
    assert per.served == 0


@pytest.mark.parametrize("each, reason", [(1, "bad_value"), ("yes", "bad_value"),
                                          (None, "bad_value")])
def test_each_must_be_a_bool(each, reason):
    per = Peripheral(ENGINE, 0, UNIT)
    assert list(per.on_request(request(part(R0, 1), each=each))) == []
    assert list(per.on_request(request(part(R0, 1), each=each))) == []
    assert per.rejected == Counter({reason: 2})


def test_a_round_the_plan_does_not_have_is_a_bad_stage():
    per = Peripheral(ENGINE, 0, UNIT)
    assert list(per.on_request(request({**R0, "stage": 7}))) == []
    assert per.rejected == Counter({"bad_stage": 1})


def test_the_rejections_go_to_the_counter_given():
    shared: Counter[str] = Counter({"earlier": 3})
    per = Peripheral(ENGINE, 0, UNIT, rejected=shared)
    list(per.on_request(b"\x00"))
    assert per.rejected is shared and shared["earlier"] == 3 and sum(shared.values()) == 4


def test_the_trace_holds_each_rounds_own_outputs_for_the_peripherals_axes_only_if_asked():
    plain = Peripheral(ENGINE, 2, UNIT)
    traced = Peripheral(ENGINE, 2, UNIT, trace=True)
    for per in (plain, traced):
        for r in (R0, R1):
            (reply,) = list(per.on_request(request(part(r, 1))))
            p = decode(reply, UNIT)["parts"][0]
            if per is plain:
                assert "trace" not in p
                continue
            rnd = ENGINE.plan.rounds[r["stage"]]
            outputs = [o for b in rnd.blocks for o in b.outputs if o not in rnd.recv]
            assert list(p["trace"]) == outputs and outputs
            assert all(len(v) == 1 for v in p["trace"].values())  # axis 2 only
            assert set(p["vals"]) <= set(outputs) | set(rnd.recv)


def test_busy_time_is_the_sum_of_the_compute_spans():
    per = Peripheral(ENGINE, 0, UNIT, clock=Tick())
    assert per.busy_ns == 0 and per.rss_warm == -1
    spans = []
    for c in range(3):
        for r in (R0, R1):
            for b in per.on_request(request(part(r, c))):
                spans += [p["span"] for p in decode(b, UNIT)["parts"]]
    assert per.busy_ns == sum(t1 - t0 for t0, t1 in spans) == 6
    assert all(t1 == t0 + 1 for t0, t1 in spans)


def test_memory_counts_as_warm_after_twice_the_warm_up_in_parts():
    per = Peripheral(ENGINE, 0, UNIT)
    n = 2 * WARM_RSS_AT
    for c in range(n // 2):
        list(per.on_request(request(part(R0, c))))
        list(per.on_request(request(part(R1, c))))
        if per.served == n - 2:
            assert per.rss_warm == -1
    assert per.served == n and per.rss_warm > 0


def place_to(blocks: Any) -> Engine:
    if blocks != ["ik_obs0"]:
        raise ConfigError("not a per-axis block list")
    return ENGINE


def test_a_place_order_before_the_start_switches_the_plan_and_is_acknowledged():
    per = Peripheral(ENGINE, 0, UNIT, place=place_to)
    ack = per.on_place({"central_blocks": ["ik_obs0"]}, "peripheral-1", started=False)
    msg = decode(ack, UNIT)
    assert (msg["cycle"], msg["stage"], msg["role"]) == (0, "placed", "peripheral-1")
    assert msg["central_blocks"] == sorted(ENGINE.plan.placement.central_blocks)
    assert per.on_place({"central_blocks": ["nope"]}, "peripheral-1", started=False) is None
    assert per.rejected == Counter({"bad_value": 1})
    for _ in range(2):
        assert per.on_place({"central_blocks": ["ik_obs0"]}, "p", started=True) is None
    assert Peripheral(ENGINE, 0, UNIT).on_place({}, "p", started=False) is None
    assert per.rejected == Counter({"bad_value": 1, "bad_stage": 2})


# -- serve, on a node the test drives ----------------------------------------------------

class Published:
    def __init__(self) -> None:
        self.items: list[bytes] = []

    def put(self, data: bytes) -> None:
        self.items.append(bytes(data))


def served(requests: list[bytes], *, orders: list[dict] = (), index: int = 0,
           **kw: Any) -> tuple[dict[str, Any], LoopbackNode, Published, list[tuple[str, bytes]]]:
    """Run :func:`serve` on a loopback node holding ``requests`` then ``orders``; it
    returns at the first stop order or, with nothing left, at its watchdog."""
    bus = Bus()
    node = LoopbackNode(bus, UNIT, f"peripheral-{index + 1}")
    declare(node, index)
    control = node.keys.control("peripheral")
    node.route(control, "control")
    for data in requests:
        bus.put(node.keys.request, data)
    for o in orders:
        o = dict(o)
        bus.put(control, encode(UNIT, 0, o.pop("stage"), **o))
    out = Published()
    res = serve(node, ENGINE, index, out, watchdog=0.0, **kw)
    return res, node, out, bus.log


def test_declare_routes_requests_and_publishes_on_the_peripherals_own_reply_key():
    bus = Bus()
    node = LoopbackNode(bus, UNIT, "peripheral-3")
    pub = declare(node, 2)
    assert pub.key == node.keys.reply(3)
    bus.put(node.keys.request, request(part(R0, 1)))
    ev = node.events.get_nowait()
    assert ev.kind == "request" and ev.data == request(part(R0, 1))


def test_serve_answers_until_a_stop_and_reports_what_it_did():
    res, node, out, _ = served([request(part(R0, 1)), request(part(R1, 1)), b"junk"],
                               orders=[{"stage": "stop"}, {"stage": "start"}])
    assert res["exit"] == "stop"
    assert answered(out.items) == [(1, 0), (1, 1)]
    assert res["served"] == 2 and res["busy_ns"] > 0
    assert 0 < res["wall_ns"] < 60e9
    assert res["rejected"] == dict(node.rejected) and sum(res["rejected"].values()) == 1
    assert set(res["rss_kb"]) == {"warm", "end"} and res["rss_kb"]["warm"] == -1
    assert res["rss_kb"]["end"] > 0 and "cpu_s" in res


def test_serve_passes_trace_and_its_place_to_the_role_and_acknowledges_on_hello():
    res, node, out, log = served([request(part(R0, 1))], trace=True, place=place_to,
                                 orders=[{"stage": "place", "central_blocks": ["ik_obs0"]},
                                         {"stage": "stop"}])
    assert res["exit"] == "stop"
    assert "trace" in decode(out.items[0], UNIT)["parts"][0]
    acks = [decode(d, UNIT) for k, d in log if k == node.keys.hello("peripheral-1")]
    assert [(a["stage"], a["role"]) for a in acks] == [("placed", "peripheral-1")]


def test_serve_ends_at_its_watchdog_when_the_central_is_silent():
    res, _, out, _ = served([])
    assert res["exit"] == "watchdog" and res["served"] == 0 and out.items == []


def test_a_valid_request_marks_the_central_alive_and_junk_does_not():
    for data, alive in ((b"junk", False), (request(part(R0, 1)), True)):
        bus = Bus()
        node = LoopbackNode(bus, UNIT, "peripheral-1")
        reply = declare(node, 0)
        node.last_heard_ns = 0
        bus.put(node.keys.request, data)
        serve(node, ENGINE, 0, reply, watchdog=0.0)
        assert (node.last_heard_ns > 0) == alive


def test_the_watchdog_waits_its_seconds_from_the_last_word_of_the_central():
    import time

    bus = Bus()
    node = LoopbackNode(bus, UNIT, "peripheral-1")
    reply = declare(node, 0)
    t0 = time.monotonic()
    node.last_heard_ns = time.monotonic_ns()
    assert serve(node, ENGINE, 0, reply, watchdog=0.3)["exit"] == "watchdog"
    assert time.monotonic() - t0 >= 0.3  # a lower bound only: never a wall-time window


# -- run_peripheral: the role's whole life over a real Zenoh session, in this process ----


@pytest.mark.zenoh
def test_run_peripheral_says_hello_serves_after_go_and_says_bye_at_stop(tmp_path):
    """A scripted central on a unix socket: the role says hello until ``go``, answers a
    request on its own reply key, and at ``stop`` ends with exit 0 and a bye carrying its
    report (served, its scheduling policy). A role that hears no go ends with exit 6."""
    import threading
    import time

    import zenoh
    from ctrlunit.runtime.compute.setup import make_setup
    from ctrlunit.runtime.config import EXIT_LINK, EXIT_OK, RunConfig
    from ctrlunit.runtime.roles.peripheral import run_peripheral
    from ctrlunit.runtime.transport.zsession import Keys, make_config

    endpoint = f"unixsock-stream/{tmp_path / 'c.sock'}"
    rc = RunConfig.of(unit=UNIT + "-life", peripherals=3, clock="lockstep",
                      startup_timeout=5.0, timeout=1.0)
    setup = make_setup(rc)
    keys = Keys(rc.transport.unit)
    heard: list[dict] = []
    replies: list[dict] = []
    with zenoh.open(make_config(listen=[endpoint])) as central:
        central.declare_subscriber(keys.hello("peripheral-2"), lambda s: heard.append(
            decode(bytes(s.payload.to_bytes()), rc.transport.unit)))
        central.declare_subscriber(keys.reply(2), lambda s: replies.append(
            decode(bytes(s.payload.to_bytes()), rc.transport.unit)))
        control = central.declare_publisher(keys.control("peripheral"))
        requests = central.declare_publisher(keys.request)
        result: list[int] = []
        role = threading.Thread(target=lambda: result.append(run_peripheral(
            setup, 2, make_config(connect=[endpoint]))), daemon=True)
        role.start()
        deadline = time.monotonic() + 10
        while not heard and time.monotonic() < deadline:
            time.sleep(0.02)
        assert heard and heard[0]["stage"] == "hello" and heard[0]["role"] == "peripheral-2"
        control.put(encode(rc.transport.unit, 0, "go"))
        while not replies and time.monotonic() < deadline:
            requests.put(encode(rc.transport.unit, 1, 0,
                                parts=[part(ENGINE_BY_LAW["resolved-acceleration"][1][0],
                                            1)]))
            time.sleep(0.05)
        control.put(encode(rc.transport.unit, 0, "stop"))
        role.join(timeout=10)
        time.sleep(0.1)
    assert not role.is_alive() and result == [EXIT_OK]
    assert replies and replies[0]["parts"][0]["cycle"] == 1
    bye = [m for m in heard if m["stage"] == "bye"]
    assert bye and bye[0]["role"] == "peripheral-2"
    assert bye[0]["report"]["exit"] == "stop" and bye[0]["report"]["served"] >= 1
    assert bye[0]["report"]["sched"].startswith("SCHED_")
    lonely = RunConfig.of(unit=UNIT + "-alone", peripherals=3, clock="lockstep",
                          startup_timeout=0.3)
    code = run_peripheral(make_setup(lonely), 1,
                          make_config(connect=[f"unixsock-stream/{tmp_path / 'none.sock'}"]))
    assert code == EXIT_LINK


def test_the_centrals_warm_up_occupies_no_modelled_time_and_the_runs_cycles_do():
    """Under the T-800 cost model a warm-up round (cycles from ``WARMUP_BASE``) is computed
    without occupying its modelled time; a round of the run is (its settle waits for the
    debt and keeps its error). At ``--cost-scale 1000`` the warm-up's 30 intervals took so
    long that the plant, hearing nothing, ended on its watchdog (exit 4)."""
    from ctrlunit.runtime.compute.engine import CostModel
    from ctrlunit.runtime.transport.codec import WARMUP_BASE

    cost = CostModel("t800", scale=0.01)
    per = Peripheral(Engine(ENGINE.plan, ENGINE.cfg, cost=cost), 0, UNIT)
    assert answered(per.on_request(request(part(R0, WARMUP_BASE)))) == [(WARMUP_BASE, 0)]
    assert cost.errors_ns == [] and cost.deadline == 0 and not cost.waive
    assert answered(per.on_request(request(part(R0, 5)))) == [(5, 0)]
    assert len(cost.errors_ns) == 1  # the run's round settled its modelled time


def test_the_whole_warm_up_occupies_no_modelled_time_on_any_process():
    """The central's warm-up under the T-800 cost model, every role's engine watched: no
    modelled time is settled during it, on the central nor on a peripheral; the run's
    first interval then settles on both."""
    from loopback import LoopbackUnit, lockstep_config

    unit = LoopbackUnit(lockstep_config(unit_id("warm"), peripherals=3, pipeline=2, cycles=2,
                                        cost_model="t800", cost_scale=0.01))
    costs = [unit.central.engine.cost] + [p.engine.cost for _, p in unit.peripherals]
    assert all(c.name == "t800" for c in costs)
    unit.plant_muted = True  # the plant's samples begin with the run
    unit.central.warm_up()
    unit.plant_muted = False
    assert [len(c.errors_ns) for c in costs] == [0, 0, 0, 0]
    unit.run()
    assert all(c.errors_ns for c in costs)
