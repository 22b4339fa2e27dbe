"""The central's guard (runtime/central/: late.py, state_check.py; silence.py:
tests/test_guard_silence.py) in this process: a real central on the loopback bus
(tests/loopback.py), its peripherals' replies held back or let through one by one, the
plant's samples and the replies received when the test says, the guard's clock set by
the test. Each check states what the guard must do at the edge of its limit: nothing one
nanosecond before, the named fault at it or just after."""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import msgpack
import pytest
from ctrlunit.kernels.dynamics import gravity_torques
from ctrlunit.runtime.central import Fault, exits, scheduler
from ctrlunit.runtime.central.late import LateData
from ctrlunit.runtime.central.pace import pace_of
from ctrlunit.runtime.central.records import InFlight
from ctrlunit.runtime.central.settings import LoopSettings
from ctrlunit.runtime.central.state_check import check_state, hold_torques, lengths
from ctrlunit.runtime.config import (
    EXIT_OBSERVER,
    EXIT_PERIPHERAL,
    EXIT_PLANT,
    RunConfig,
)
from ctrlunit.runtime.transport.codec import decode
from ctrlunit.runtime.transport.node import Event
from loopback import LoopbackUnit, realtime_unit, take_sample
from runner import unit_id

MS = 1_000_000
T0 = 10**12
"""A moment of the guard's clock (ns) about which a test has the plant's samples and the
peripherals' replies received (``at`` of :func:`settle` and :func:`sample`)."""


class Clock:
    """The guard's clock (``time`` in runtime/central/scheduler.py and exits.py), moved
    by the test."""

    def __init__(self, now_ns: int) -> None:
        self.now = now_ns

    def monotonic_ns(self) -> int:
        return self.now

    def monotonic(self) -> float:
        return self.now / 1e9

    def perf_counter_ns(self) -> int:
        return self.now

    def process_time(self) -> float:
        return 0.0

    def install(self, monkeypatch: Any) -> Clock:
        """The central's checks read this clock."""
        for module in (scheduler, exits):
            monkeypatch.setattr(module, "time", self)
        return self


def fault_just_past(c: Any, clock: Clock, limit: int) -> Fault:
    """The guard at ``limit`` (nothing) and one nanosecond past it: the fault raised."""
    c.check_silence(limit)
    clock.now += 1
    with pytest.raises(Fault) as info:
        c.check_silence(limit)
    return info.value


def received_at(ev: Event, at: int | None) -> Event:
    """``ev`` as received at ``at`` on the guard's clock (as it came where None)."""
    return ev if at is None else Event(ev.kind, ev.index, ev.data, at)


def settle(u: LoopbackUnit, *, muted: frozenset[int] = frozenset(),
           at: int | None = None) -> None:
    """Start what may start, send, let the peripherals not in ``muted`` answer, handle
    the replies (received at ``at`` where given); until nothing moves (bounded)."""
    c = u.central
    u.muted = set(muted)
    for _ in range(50):
        c.start_ready()
        c.send_ready(0)  # asked at 0: a round's deadline is the limit
        u.pump()
        if not u.node.events.pending():
            return
        while u.node.events.pending():
            c.handle(received_at(u.node.events.get_nowait(), at))
    raise AssertionError("the exchange did not settle")


def sample(u: LoopbackUnit, k: int, *, at: int | None = None) -> None:
    """Realtime by hand: the plant's sample ``k``, taken by the central (received at
    ``at`` on the guard's clock where given)."""
    if at is None:
        take_sample(u, k)
        return
    assert u.server is not None
    u.server.sample_no = k
    u.server.publish_sample((0, 0))
    u.central.handle(received_at(u.node.events.get_nowait(), at))


class PlantSamples:
    """The plant's samples as the central receives them, numbered from 0, each when the
    test says (:meth:`at`), or one a period up to a moment (:meth:`until`)."""

    def __init__(self, u: LoopbackUnit) -> None:
        self.u = u
        self.period_ns = int(u.rc.schedule.period * 1e9)
        self.next = 0
        self.last = 0

    def at(self, t: int) -> None:
        """The next sample, received at ``t``."""
        sample(self.u, self.next, at=t)
        self.next, self.last = self.next + 1, t

    def until(self, t: int) -> None:
        """The plant samples on, a sample every period, the newest received at ``t``."""
        while self.last + self.period_ns < t:
            self.at(self.last + self.period_ns)
        if self.last < t:
            self.at(t)


def let_through(u: LoopbackUnit, k: int, *, at: int) -> None:
    """Peripheral ``k``'s replies held back so far (``u.muted``), received at ``at``."""
    for j, reply in [w for w in u.withheld if w[0] == k]:
        u.withheld.remove((j, reply))
        u.central.handle(Event("reply", j, reply, at))


def first_interval(u: LoopbackUnit) -> None:
    sample(u, 0)
    settle(u)
    assert u.central.done == 1


def second_interval_late(tag: str, *, muted: set[int], **kw: Any) -> tuple[Any, Any, Any]:
    """A realtime unit whose first interval is done and whose second waits for the
    ``muted`` peripherals' replies to round 0: ``(unit, central, that interval)``."""
    u = realtime_unit(tag, **kw)
    first_interval(u)
    sample(u, 1)
    settle(u, muted=frozenset(muted))
    return u, u.central, u.central.inflight[1]


def reply_vals(u: LoopbackUnit, peripheral: int, cycle: int, stage: int) -> dict:
    key = u.node.keys.reply(peripheral + 1)
    for k, data in u.bus.log:
        if k != key:
            continue
        for part in decode(data, u.rc.transport.unit)["parts"]:
            if (part["cycle"], part["stage"]) == (cycle, stage):
                return part["vals"]
    raise AssertionError(f"no reply of peripheral {peripheral + 1} to {cycle}/{stage}")


def requests_for(u: LoopbackUnit, cycle: int, stage: int) -> list[bytes]:
    """The requests on the bus that carry round ``stage`` of ``cycle``."""
    return [data for k, data in u.bus.log if k == u.node.keys.request and any(
        (p["cycle"], p["stage"]) == (cycle, stage)
        for p in decode(data, u.rc.transport.unit)["parts"])]


def request_of(u: LoopbackUnit, cycle: int, stage: int) -> bytes:
    found = requests_for(u, cycle, stage)
    if not found:
        raise AssertionError(f"no request for {cycle}/{stage}")
    return found[0]


def plain(v: Any) -> Any:
    return [plain(x) for x in v] if isinstance(v, tuple | list) else v


def held(seen: list[tuple]) -> list[tuple]:
    """The rounds held, as the recording heard of them (``on_message``'s ``held``)."""
    return [a for a in seen if a[0] == "held"]


def held_rounds(seen: list[tuple]) -> set[tuple[int, int, int]]:
    """(cycle, round, peripheral) of each round held (:func:`held`)."""
    return {(m["cycle"], m["stage"], m["peripheral"])
            for m in (msgpack.unpackb(a[4]) for a in held(seen))}


# -- late data ---------------------------------------------------------------------------


def test_hold_takes_the_last_accepted_values_of_the_late_peripheral_only_at_its_time():
    seen: list[tuple] = []
    u = realtime_unit("hold", late_policy="hold",
                      on_message=lambda *a: seen.append(a))
    c = u.central
    first_interval(u)
    sample(u, 1)
    settle(u, muted=frozenset({1}))
    f = c.inflight[1]
    assert f.waiting == {1} and f.round is not None and f.round.index == 0
    before = {n: plain(f.ctx[n]) for n in f.round.recv}
    c.check_late(f.late_ns - 1)
    assert f.waiting == {1} and not f.dropped and not held(seen)
    c.check_late(f.late_ns)
    assert f.waiting == set() and f.dropped == {1}
    assert held_rounds(seen) == {(1, 0, 1)}  # (cycle, round, peripheral)
    last = reply_vals(u, 1, 0, 0)
    for name in last:
        assert plain(f.ctx[name])[1] == plain(last[name])[0]  # axis 1: peripheral 2's
        for axis in (0, 2):
            assert plain(f.ctx[name])[axis] == before[name][axis]
    assert c.snapshot().late.per_axis == (0, 1, 0)
    assert len(held(seen)) == 1
    _direction, key, cycle, stage, payload, t_ns = held(seen)[0]
    assert key == f"{u.node.keys.root}/faults/held" and (cycle, stage) == (1, 0)
    assert t_ns == f.late_ns
    msg = msgpack.unpackb(payload)
    assert msg == {"cycle": 1, "stage": 0, "peripheral": 1,
                   "vals": {n: [plain(v)[0]] for n, v in last.items()}}
    # the interval went on without peripheral 2's reply: its next round is ready, and
    # goes out with the next request
    assert f.round is not None and f.round.index == 1 and not requests_for(u, 1, 1)
    c.send_ready(0)
    assert requests_for(u, 1, 1)


def test_a_held_replys_late_arrival_is_counted_and_marks_the_peripheral_alive(monkeypatch):
    """The held reply comes at last: counted as late, and its peripheral's silence counts
    from it (a fault a limit later, not sooner); a second copy moves nothing."""
    u = realtime_unit("holdlate", late_policy="hold")
    c = u.central
    plant = PlantSamples(u)
    plant.at(T0)
    settle(u, at=T0)
    plant.at(T0 + MS)
    settle(u, muted=frozenset({1}), at=T0 + MS)
    f = c.inflight[1]
    c.check_late(f.late_ns)
    limit = c.limit_ns()
    at = T0 + 5 * MS  # when the late reply comes
    clock = Clock(at + limit).install(monkeypatch)
    plant.until(clock.now)
    late = request_of(u, 1, 0)
    u.muted = set()
    for reply in u.peripherals[1][1].on_request(late):
        c.handle(Event("reply", 1, reply, at))
    assert c.node.rejected["late_reply"] == 1
    for reply in u.peripherals[1][1].on_request(late):  # a second copy: not held any more
        c.handle(Event("reply", 1, reply, at + MS))
    assert c.node.rejected["unexpected_reply"] == 1
    # peripheral 2's values are held (judged by its silence): silent since the late reply
    exc = fault_just_past(c, clock, limit)
    assert exc.process == "peripheral-2" and str(exc).startswith(
        f"peripheral 2 has not answered for {limit / 1e6:.1f} ms "
        f"(limit {limit / 1e6:.1f} ms)"), str(exc)


def test_a_reply_to_a_throw_away_interval_is_counted_as_a_straggler():
    """A reply part for a warm-up's or a trial's cycle (from ``WARMUP_BASE`` up) that no
    interval waits for is a straggler of the unit's own; any other is unexpected. Both
    are counted, neither as malformed (runtime/central/flood.py)."""
    from ctrlunit.runtime.central.warmup import WARMUP_BASE
    from ctrlunit.runtime.transport.codec import encode

    _, c, _ = second_interval_late("straggle", late_policy="hold", muted={1})
    for cycle in (WARMUP_BASE + 7, (1 << 41) + 3, 999_999):
        part = {"cycle": cycle, "stage": 0, "vals": {}, "span": [0, 1]}
        c.handle(("reply", 1, encode(c.node.unit, cycle, 0, parts=[part]), 123))
    assert c.node.rejected["straggler"] == 2 and c.node.rejected["unexpected_reply"] == 1


def test_hold_waits_when_there_is_nothing_to_hold_yet():
    seen: list[tuple] = []
    u = realtime_unit("holdnone", late_policy="hold", on_message=lambda *a: seen.append(a))
    c = u.central
    sample(u, 0)
    settle(u, muted=frozenset({2}))
    f = c.inflight[0]
    c.check_late(f.late_ns + 5 * MS)
    assert f.waiting == {2} and f.late_ns == 0 and not f.dropped and not held(seen)
    assert c.snapshot().late.per_axis == (0, 0, 0)


def test_wait_policy_keeps_waiting_and_looks_no_more():
    _u, c, f = second_interval_late("wait", late_policy="wait", muted={0})
    c.check_late(f.late_ns)
    assert f.waiting == {0} and f.late_ns == 0 and not f.dropped


def test_fault_policy_names_the_peripheral_round_blocks_and_cycle():
    _u, c, f = second_interval_late("fault", late_policy="fault", muted={0, 2})
    c.check_late(f.late_ns - 1)
    with pytest.raises(Fault) as info:
        c.check_late(f.late_ns)
    exc = info.value
    assert exc.process == "peripheral-1" and exc.code == EXIT_PERIPHERAL
    assert str(exc) == ("late data: peripheral 1 missed the deadline of round 0 "
                              "(ik_obs0, jinv_obs0, residual0) of cycle 1")


def test_late_data_is_not_judged_outside_realtime():
    u = LoopbackUnit(RunConfig.of(unit=unit_id("lslate"), clock="lockstep", peripherals=3,
                               late_policy="fault"))
    c = u.central
    u.start_plant()
    c.handle(u.node.events.get_nowait())
    settle(u, muted=frozenset({0}))
    f = c.inflight[0]
    assert f.waiting == {0} and f.late_ns == 0  # no late-data time in virtual time
    c.check_late(10**18)
    assert f.waiting == {0}


def late_data(u: LoopbackUnit) -> tuple[LateData, list[InFlight]]:
    """The late data of ``u``'s run on its own (runtime/central/late.py: its plan and
    its policies), and the intervals it goes on with."""
    sch, advanced = u.rc.schedule, []
    return LateData(u.setup.engine(), late=sch.late, late_policy=sch.late_policy,
                    faults_key=f"{u.node.keys.root}/faults", pending=lambda: False,
                    advance=advanced.append, span=lambda *a: None), advanced


def test_a_rounds_policy_is_the_strictest_of_its_blocks():
    u = realtime_unit("pol", late_policy="wait", late={"jdot": "hold"})
    assert late_data(u)[0].policy == {0: "wait", 1: "hold"}
    u = realtime_unit("pol2", late_policy="hold", late={"ik": "fault", "jdot": "wait"})
    assert late_data(u)[0].policy == {0: "hold", 1: "fault"}
    u = realtime_unit("pol3", late_policy="fault", late={"residual0": "wait"})
    assert late_data(u)[0].policy == {0: "fault", 1: "fault"}


# -- the robot's state ---------------------------------------------------------------------


def check(u: LoopbackUnit, cycle: int, p: Any, pc: Any) -> None:
    """The central's check of the robot's state at ``cycle`` (estimate ``p``, reference
    ``pc``), with the unit's parameters, limit and hint."""
    check_state(cycle, p, pc, params=u.setup.params, max_error=u.rc.control.max_error,
                hint=u.central.overload_hint)


def test_tracking_error_beyond_max_error_stops_with_the_observers_code():
    u = realtime_unit("track", max_error=0.005)
    p0 = tuple(u.setup.task.start())
    check(u, 3, p0, p0)
    check(u, 3, (p0[0] + 0.004999, p0[1], p0[2]), p0)  # within
    with pytest.raises(Fault) as info:
        check(u, 3, (p0[0] + 0.0051, p0[1], p0[2]), p0)
    exc = info.value
    assert (exc.process, exc.code) == ("central", EXIT_OBSERVER)
    assert str(exc) == ("cycle 3: tracking error 5.1 mm exceeds --max-error 5.0 mm")
    check(u, 3, None, p0)
    check(u, 3, p0, None)


def test_leaving_the_usable_workspace_is_checked_every_tenth_interval():
    u = realtime_unit("ws", max_error=1.0)
    out = (0.0, 0.0, -2.0)  # far below the reach of the arms
    check(u, 11, out, out)
    with pytest.raises(Fault) as info:
        check(u, 20, out, out)
    exc = info.value
    assert (exc.process, exc.code) == ("central", EXIT_OBSERVER)
    assert str(exc).startswith("cycle 20: the robot left the usable workspace: ")


def test_the_overload_hint_appears_in_realtime_when_most_deadlines_are_missed():
    """The realtime pace's rule (runtime/central/pace.py, on its own), then the central's
    hint from what the plant reports and the samples it skipped."""
    rc = RunConfig.of(unit=unit_id("hint-pace"), clock="realtime", period=2e-3, peripherals=3)
    pace = pace_of(LoopSettings.of(rc, peripherals=3, cycles=100, first_cycle=0,
                                   trial=False))
    assert pace.overload_hint(misses=6, skipped=4, periods=100) == ""  # not above a tenth
    assert pace.overload_hint(misses=6, skipped=5, periods=100) == (
        "; 6 commands missed their deadline and 5 samples were skipped in 100 periods: "
        "this machine does not sustain a 2 ms period with 3 peripheral(s) (try a longer "
        "--period or --fault-periods, or --clock lockstep)")
    # few periods: at least 5 misses before it says so
    assert pace.overload_hint(misses=5, skipped=0, periods=10) == ""
    assert pace.overload_hint(misses=6, skipped=0, periods=10).startswith(
        "; 6 commands missed their deadline")
    assert "in 1 periods" in pace.overload_hint(misses=6, skipped=0, periods=0)
    u = realtime_unit("hint", period=2e-3)
    c = u.central
    assert c.overload_hint() == ""
    assert u.server is not None
    u.server.misses = 6  # the plant's count of late commands, in its samples
    for k in range(3):
        sample(u, k)
    settle(u)  # from the newest sample: two skipped
    assert c.overload_hint().startswith(
        "; 6 commands missed their deadline and 2 samples were skipped in 3 periods: "
        "this machine does not sustain a 2 ms period with 3 peripheral(s)"), c.overload_hint()
    u = LoopbackUnit(RunConfig.of(unit=unit_id("hintls"), clock="lockstep"))
    assert u.server is not None
    u.server.misses = 10**6
    u.start_plant()
    u.central.handle(u.node.events.get_nowait())
    assert u.central.overload_hint() == ""


def test_hold_torques_hold_the_last_estimate_against_gravity_or_are_zero():
    u = realtime_unit("holdtau")
    p = tuple(u.setup.task.start())
    want = [float(x) for x in gravity_torques(u.setup.params, p)]
    got = u.central.hold_torques()  # the estimate before any interval: the task's start
    assert got == want and all(type(x) is float for x in got)
    assert max(abs(x) for x in got) > 0.1
    # after 1.5 s of pick-place the platform has moved (the start's torques are 0.016 N m
    # off): the torques hold the observer's latest estimate, within 1e-4 N m of the
    # plant's true last position (6e-6 on 2026-11-28), not the start's
    true_p: list[Any] = []
    u = LoopbackUnit(RunConfig.of(unit=unit_id("holdtau2"), clock="lockstep", cycles=1500),
                     on_cycle=lambda progress, ctx: true_p.append(progress.true_p))
    u.run()
    got = u.central.hold_torques()
    at_last = [float(x) for x in gravity_torques(u.setup.params, true_p[-1])]
    assert max(abs(a - b) for a, b in zip(got, at_last, strict=True)) < 1e-4
    assert max(abs(a - b) for a, b in zip(got, want, strict=True)) > 1e-2
    assert hold_torques(u.setup.params, (0.0, 0.0, -2.0)) == [0.0, 0.0, 0.0]
    assert hold_torques(u.setup.params, (math.nan, 0.0, 0.0)) == [0.0, 0.0, 0.0]


def test_a_fault_carries_its_process_and_code():
    f = Fault("why", process="plant", code=EXIT_PLANT)
    assert (str(f), f.process, f.code) == ("why", "plant", EXIT_PLANT)


# -- edges that only a wrong guard would cross ----------------------------------------------


def twin(f: Any, **changes: Any) -> Any:
    """Another interval like ``f`` (its own sets), e.g. at another round or cycle."""
    return dataclasses.replace(f, waiting=set(changes.pop("waiting", f.waiting)),
                               dropped=set(), **changes)


def test_every_interval_in_flight_is_judged_not_only_the_first():
    u = realtime_unit("many", late_policy="fault", late={
        "ik_obs0": "wait", "jinv_obs0": "wait", "residual0": "wait"})
    c = u.central
    first_interval(u)
    sample(u, 1)
    settle(u, muted=frozenset({0}))
    f = c.inflight[1]  # round 0 (wait), late
    done = twin(f, cycle=0, waiting=set())  # answered: nothing to judge
    later = twin(f, cycle=2, round=u.setup.plan.rounds[1])  # round 1 (fault), late
    c.inflight.clear()
    c.inflight.update({0: done, 1: f, 2: later})
    with pytest.raises(Fault, match="round 1 .* of cycle 2"):
        c.check_late(f.late_ns)
    assert f.late_ns == 0  # the waiting one was looked at too


def test_an_interval_without_late_time_or_without_waiting_is_left_alone():
    _u, c, f = second_interval_late("alone", late_policy="fault", muted={0})
    late = f.late_ns
    f.late_ns = 0  # already judged (wait) or not realtime-timed
    c.check_late(10**18)
    f.late_ns, f.waiting = late, set()  # every reply in, not yet advanced
    c.check_late(10**18)
    f.waiting = {0}
    with pytest.raises(Fault):
        c.check_late(late)


def test_hold_waits_while_no_peripheral_has_answered_at_all():
    seen: list[tuple] = []
    u = realtime_unit("holdnone2", late_policy="hold", on_message=lambda *a: seen.append(a))
    c = u.central
    sample(u, 0)
    settle(u, muted=frozenset({0, 1, 2}))
    f = c.inflight[0]
    replies = {u.node.keys.reply(k + 1) for k in range(3)}
    assert not any(k in replies for k, _ in u.bus.log)  # no values taken: none to hold
    c.check_late(f.late_ns)
    assert f.waiting == {0, 1, 2} and f.late_ns == 0 and not held(seen)


def round_0(cycle: int, u: LoopbackUnit, waiting: set[int]) -> InFlight:
    """Interval ``cycle`` of ``u``'s plan waiting for round 0 of ``waiting``, late."""
    return InFlight(cycle=cycle, gen=iter(()), ctx={}, sample_ns=0, start_ns=0,
                    round=u.setup.plan.rounds[0], waiting=set(waiting), late_ns=1)


def answered(late: LateData, u: LoopbackUnit, axes: tuple[int, ...]) -> None:
    """Round 0's values of ``axes`` accepted (their peripherals answered it)."""
    for axis in axes:
        late.remember({name: [float(axis)] for name in u.setup.plan.rounds[0].recv}, (axis,))


def test_hold_goes_on_to_the_next_interval_past_one_it_cannot_hold():
    """The late data on its own (runtime/central/late.py): an interval that cannot be
    held (a peripheral it waits for never answered) waits, and the one behind it, which
    can, is held."""
    u = realtime_unit("holdnext", late_policy="hold")
    late, advanced = late_data(u)
    answered(late, u, (1, 2))  # peripheral 1's axis has nothing to hold
    blank, f = round_0(0, u, {0, 1, 2}), round_0(1, u, {1})
    late.check(1, [blank, f])
    assert blank.waiting == {0, 1, 2} and blank.late_ns == 0
    assert f.dropped == {1} and late.held == {(1, 0, 1)} and advanced == [f]


def test_late_counts_add_up_per_axis():
    seen: list[tuple] = []
    u = realtime_unit("count", late_policy="hold", on_message=lambda *a: seen.append(a))
    c = u.central
    first_interval(u)
    for k in (1, 2):
        sample(u, k)
        settle(u, muted=frozenset({1}))
        c.check_late(c.inflight[k].late_ns)
        settle(u)
    assert c.snapshot().late.per_axis == (0, 2, 0) and c.done == 3
    assert held_rounds(seen) == {(1, 0, 1), (2, 0, 1)}


def test_the_held_set_stays_bounded():
    """The late data on its own (runtime/central/late.py): the rounds held are
    remembered up to 1024, the oldest forgotten first."""
    u = realtime_unit("count-bound", late_policy="hold")
    late, _ = late_data(u)
    answered(late, u, (0, 1, 2))
    for k in range(1, 1023):
        late.expect_late(-k, 0, 0)
    late.expect_late(2, 0, 1)  # 1023 held
    late.check(1, [round_0(3, u, {2})])
    assert len(late.held) == 1024 and (-1022, 0, 0) in late.held  # at the bound: all kept
    late.check(1, [round_0(4, u, {2})])
    assert len(late.held) == 1024 and (-1022, 0, 0) not in late.held  # past it: oldest out
    assert (4, 0, 2) in late.held


def test_a_rounds_policy_is_the_strictest_whatever_the_order_of_its_blocks():
    u = realtime_unit("order", late_policy="hold", late={"dyn_axis": "fault"})
    assert late_data(u)[0].policy == {0: "hold", 1: "fault"}


def test_tracking_error_at_exactly_max_error_is_allowed_and_reported_in_mm():
    u = realtime_unit("exact", max_error=0.005)
    pc = (0.0, 0.0, -0.35)
    check(u, 3, (0.005, 0.0, -0.35), pc)
    u = realtime_unit("mm", max_error=0.5)
    with pytest.raises(Fault, match=r"tracking error 750\.0 mm exceeds --max-error 500\.0 mm"):
        check(u, 3, (0.75, 0.0, -0.35), pc)




@pytest.mark.parametrize("err, limit, said", [
    (0.0051, 0.005, ("5.1 mm", "5.0 mm")),
    (0.005004, 0.005, ("5.004 mm", "5.000 mm")),  # the decimals that tell them apart
    (14.2e-6, 1e-5, ("14.2 um", "10.0 um")),  # under a millimetre: um, not "0.0 mm"
    (0.75, 0.5, ("750.0 mm", "500.0 mm")),
    (0.5, 1e-5, ("500000.0 um", "10.0 um")),  # the limit's unit, as the user gave it
    (0.0200000001, 0.02, ("20.000000099999998 mm", "20.0 mm")),  # every digit past three
])
def test_a_tracking_fault_gives_figures_a_reader_can_tell_apart(err, limit, said):
    """``--max-error 0.00001`` faulted with "tracking error 0.0 mm exceeds --max-error
    0.0 mm" (a new user's try, 2026-11-28)."""
    assert lengths(err, limit) == said
