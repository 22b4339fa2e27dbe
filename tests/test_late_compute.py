"""``--late-policy compute``: the central runs a late peripheral's round itself, with the
kernels the peripheral runs, on the values it sent; the commands are those the reply would
have given, bit for bit. A real central on the loopback bus (tests/loopback.py), its
peripherals' replies held back or let through, the clock set by the test."""

from __future__ import annotations

from typing import Any

import msgpack
import pytest
from ctrlunit.runtime.central import Central, Fault, silence_limits
from ctrlunit.runtime.central.late import HELD_KEPT
from ctrlunit.runtime.compute.blocks import ObserverDiverged
from ctrlunit.runtime.compute.engine import Engine
from ctrlunit.runtime.compute.setup import make_setup
from ctrlunit.runtime.config import EXIT_OBSERVER, EXIT_PERIPHERAL, RunConfig
from ctrlunit.runtime.transport.codec import decode
from loopback import LoopbackUnit, turn
from loopback import take_sample as sample
from runner import unit_id

ON_THE_PATH = ["accel", "dyn_axis", "residual0"]


def unit(tag: str, *, on_message: Any = None, **kw: Any) -> LoopbackUnit:
    kw.setdefault("peripherals", 3)
    kw.setdefault("pipeline", 2)
    return LoopbackUnit(RunConfig.of(unit=unit_id(tag), clock="realtime", **kw),
                        on_message=on_message)


def commands(u: LoopbackUnit) -> dict[int, list[float]]:
    key = u.node.keys.command
    return {m["cycle"]: m["tau"] for m in (decode(d, u.rc.transport.unit)
                                           for k, d in u.bus.log if k == key)}


def computed(c: Central) -> int:
    """Late peripherals' rounds the central has run itself so far (its snapshot's)."""
    return c.snapshot().late.computed


def foreseen(tag: str, state: str = "foreseen", **kw: Any) -> LoopbackUnit:
    return unit(tag, model_state=state, central_blocks=ON_THE_PATH, **kw)


@pytest.mark.parametrize("state", ["foreseen", "foreseen2"])
def test_a_late_round_run_ahead_is_computed_at_its_sample_with_the_same_commands(state):
    """Peripheral 2 never answers from interval 2 on: under ``compute`` each interval's
    round is computed by the central once its sample is here, and every command equals
    that of the same run where every reply came (``foreseen2``: rounds of two intervals
    in each request)."""
    seen: list[tuple] = []
    ref, u = foreseen("cmpref", state), foreseen("cmp", state, late_policy="compute",
                                                 on_message=lambda *a: seen.append(a))
    for x in (ref, u):
        turn(x)
    for k in range(6):
        for x in (ref, u):
            if x is u and k == 1:
                u.muted = {1}  # from interval 2's round on (sent at interval 1's end)
            sample(x, k)
            turn(x)
        c = u.central
        if k >= 2:
            assert k in c.inflight
            f = c.inflight[k]
            assert f.waiting == {1} and f.late_ns  # late at its sample
            c.check_late(f.late_ns - 1)
            assert f.waiting == {1} and k not in commands(u)
            c.check_late(f.late_ns)
            assert not f.waiting and f.dropped == {1}
            turn(u)
    assert commands(u) == commands(ref) and len(commands(u)) == 6
    c = u.central
    late = c.snapshot().late
    assert late.computed == 4 and late.per_axis == (0, 4, 0)
    rec = [a for a in seen if a[0] == "computed"]
    assert [msgpack.unpackb(a[4]) for a in rec] == [
        {"cycle": k, "stage": 0, "peripheral": 1} for k in range(2, 6)]
    assert all(a[1] == f"{u.node.keys.root}/faults/computed" for a in rec)
    assert [(a[2], a[3]) for a in rec] == [(k, 0) for k in range(2, 6)]  # cycle, round
    for a in rec:  # each computed round is the central's compute, from its record's time
        t0 = a[5]
        assert isinstance(t0, int) and t0 > 0
        assert any(s[:3] == ("central", a[2], t0) and s[3] >= t0
                   for s in c.snapshot().times.spans)
    # a late reply is counted as such (each of its parts), never merged
    for k, reply in u.withheld[:1]:
        c.handle(("reply", k, reply, 1))
    assert c.node.rejected == {"late_reply": 1 if state == "foreseen" else 2}
    # the replies of every computed round (2 to 5) are late when they come: one a part
    for k, reply in u.withheld[1:(4 if state == "foreseen" else 2)]:
        c.handle(("reply", k, reply, 1))
    assert c.node.rejected == {"late_reply": 4}


def test_computed_rounds_keep_the_memory_of_late_rounds_at_its_bound():
    """The late data on its own, with a foreseen unit's plan: four rounds computed for a
    late peripheral are remembered (their replies will be late) and the memory stays at
    its bound, the oldest four going for the new four."""
    from ctrlunit.runtime.central.late import LateData
    from ctrlunit.runtime.central.records import InFlight
    from ctrlunit.runtime.compute.controller import Controller

    setup = make_setup(foreseen("cmpheld", late_policy="compute").rc)
    engine = setup.engine()
    ctl = Controller(engine, setup.rc.schedule.period, setup.params.increment,
                     tuple(setup.task.start()))
    advanced: list[InFlight] = []
    ld = LateData(engine, late={}, late_policy="compute", faults_key="ctrlunit/u/faults",
                  pending=lambda: False, advance=advanced.append, span=lambda *a: None)
    old = {(-i, 0, 0) for i in range(1, HELD_KEPT + 1)}  # a full memory of late rounds
    ld.held |= old
    for k in range(2, 6):  # each interval's round run ahead, peripheral 2 late at 1 ns
        ctx = ctl.context(k)
        gen = engine.cycle(ctx, gate=True)
        ld.check(1, [InFlight(k, gen, ctx, 0, 0, round=next(gen), waiting={1}, late_ns=1)])
    assert [f.cycle for f in advanced] == [2, 3, 4, 5] and ld.computed == 4
    assert {(k, 0, 1) for k in range(2, 6)} <= ld.held  # their replies: late when they come
    assert len(ld.held) == HELD_KEPT and old - ld.held == {
        (-i, 0, 0) for i in range(HELD_KEPT - 3, HELD_KEPT + 1)}


def test_a_computed_round_reads_the_replies_already_waiting_first():
    u = foreseen("cmpwait", late_policy="compute")
    c = u.central
    u.muted = {0}
    turn(u)
    sample(u, 0)
    turn(u)
    f = c.inflight[0]
    assert f.waiting == {0}
    for k, reply in u.withheld:  # the reply is in the inbox, not yet read
        u.bus.put(u.node.keys.reply(k + 1), reply)
    u.withheld.clear()
    c.check_late(f.late_ns)
    assert f.waiting == {0} and computed(c) == 0  # read it first
    c.handle(u.node.events.get_nowait())
    assert not f.waiting and computed(c) == 0 and 0 in commands(u)


def test_a_round_that_needs_values_the_peripherals_kept_waits():
    """The thesis's placement of the foreseen graph: round 1 (residual0) reads the IK the
    peripheral kept from round 0, which the central never received: it cannot be computed
    here, so the central waits, as under ``wait``."""
    u = unit("cmpkept", model_state="foreseen", late_policy="compute")
    c = u.central
    turn(u)
    sample(u, 0)
    u.muted = {2}
    turn(u)
    f = c.inflight[0]
    assert f.round is not None and f.round.index == 1 and f.waiting == {2}
    c.check_late(f.late_ns)
    assert f.waiting == {2} and f.late_ns == 0 and computed(c) == 0


def test_the_acting_graph_computes_its_late_rounds_at_their_share_of_the_deadline():
    """Any plan: a round is late at its share of the deadline and computed then; the
    interval's next round leaves, and the command equals the one with every reply."""
    ref, u = unit("cmparef", pipeline=1), unit("cmpa", pipeline=1, late_policy="compute")
    sample(ref, 0)
    turn(ref)
    turn(ref)  # its second round
    assert ref.central.done == 1
    u.muted = {0}
    sample(u, 0)
    turn(u)
    c = u.central
    f = c.inflight[0]
    assert f.round is not None and f.round.index == 0 and f.waiting == {0}
    c.check_late(f.late_ns)
    turn(u)  # round 1: peripheral 1 still muted
    assert f.round.index == 1 and f.waiting == {0}
    c.check_late(f.late_ns)
    assert c.done == 1 and commands(u) == commands(ref) and computed(c) == 2


def test_a_peripheral_that_stays_silent_is_still_a_fault(monkeypatch):
    """Computing its late rounds keeps the commands on time, not a dead peripheral alive:
    under ``--peripheral-loss fault`` its silence past the limit is the named fault, as
    under every late-data policy (the default takes it over: tests/test_takeover.py)."""
    # past the start-up's longer limit: this test judges the limit of a run under way
    monkeypatch.setattr(silence_limits, "STARTUP_INTERVALS", 0)
    u = foreseen("cmpdead", late_policy="compute", peripheral_loss="fault")
    c = u.central
    turn(u)
    sample(u, 0)
    c.start_ready()  # a turn (loopback.turn) whose replies of peripheral 3 are received,
    c.send_ready(0)  # as its last ones, as if at t = 1 ns (long ago)
    c.prime()
    c.send_ready(0)
    u.pump()
    while u.node.events.pending():
        ev = u.node.events.get_nowait()
        c.handle(ev._replace(rx_ns=1) if ev.kind == "reply" and ev.index == 2 else ev)
    u.muted = {2}
    for k in range(1, 3):
        sample(u, k)
        turn(u)
        f = c.inflight[k] if k in c.inflight else None
        if f is not None and f.waiting:
            c.check_late(f.late_ns)
            turn(u)
    limit = c.limit_ns()  # the unit is unsupervised (unit()): no process state excuses it
    with pytest.raises(Fault) as info:
        c.check_silence(limit)  # peripheral 3 last answered at t = 1 ns
    assert info.value.process == "peripheral-3" and info.value.code == EXIT_PERIPHERAL


def test_the_summary_tells_late_replies_from_rejected_messages():
    """A late reply is no malformed message: the summary says so on a line of its own."""
    from ctrlunit.runtime.observe.report import finish_report
    from ctrlunit.runtime.observe.summary import summary
    from loopback import lockstep_config

    u = LoopbackUnit(lockstep_config(unit_id("cmpsum"), peripherals=3, pipeline=2,
                                     cycles=20, max_error=1.0))
    u.run()
    r = finish_report(u.setup, u.central.snapshot(), None)
    r["rejected_messages"] = {"late_reply": 3, "bad_value": 1}
    lines = summary(r).splitlines()
    assert "  late replies 3 (dropped: their rounds were held or computed by the central)" \
        in lines
    assert "  rejected messages bad_value: 1" in lines
    r["rejected_messages"] = {"late_reply": 2}
    assert not any("rejected" in x for x in summary(r).splitlines())
    # the warm-up's and the trials' stragglers: the unit's own, late, not malformed
    r["rejected_messages"] = {"straggler": 3}
    lines = summary(r).splitlines()
    assert ("  stragglers  3 replies to the warm-up's or the admission trials' throw-away "
            "intervals came after them (dropped)") in lines
    assert not any("rejected" in x for x in lines)


def test_a_late_round_whose_point_is_out_of_reach_is_the_observers_fault(monkeypatch):
    """A round the central computes for a late peripheral raises as the central's own steps
    do: a point out of reach is a fault by name (exit 5), never a traceback (a new user's
    ``bench --quick`` once ended in ``ObserverDiverged`` during an admission trial)."""
    u = foreseen("cmpdiv", late_policy="compute")
    turn(u)
    u.muted = {1}
    sample(u, 0)
    turn(u)
    sample(u, 1)
    turn(u)
    c = u.central
    assert 1 in c.inflight
    f = c.inflight[1]
    assert f.waiting == {1} and f.late_ns

    def out_of_reach(*_a: Any, **_k: Any) -> None:
        raise ObserverDiverged("point (0.06, 0, -0.17) m is out of reach of chain 1")

    monkeypatch.setattr(Engine, "run_round", out_of_reach)  # the central's compute only
    with pytest.raises(Fault) as exc:
        c.check_late(f.late_ns)
    assert exc.value.code == EXIT_OBSERVER and "out of reach" in str(exc.value)
