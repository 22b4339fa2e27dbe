"""The central's guard (runtime/central/: silence.py, late.py, state_check.py) in this
process: a real central on the loopback bus (tests/loopback.py), its peripherals' replies
held back or let through one by one, the guard's clock set by the test. Each check states
what the guard must do at the edge of its limit: nothing one nanosecond before, the named
fault at it or just after."""

from __future__ import annotations

import math
from typing import Any

import msgpack
import pytest
from ctrlunit.kernels.dynamics import gravity_torques
from ctrlunit.runtime.central import Fault, exits, scheduler, silence
from ctrlunit.runtime.central.state_check import check_state
from ctrlunit.runtime.compute.controller import Estimate
from ctrlunit.runtime.config import (
    EXIT_OBSERVER,
    EXIT_PERIPHERAL,
    EXIT_PLANT,
    RunConfig,
)
from ctrlunit.runtime.roles.supervise import MachineLoad
from ctrlunit.runtime.transport.codec import decode
from loopback import LoopbackUnit, realtime_unit, supervise
from loopback import take_sample as sample
from runner import unit_id

MS = 1_000_000


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


def settle(u: LoopbackUnit, *, muted: frozenset[int] = frozenset()) -> None:
    """Start what may start, send, let the peripherals not in ``muted`` answer, handle
    the replies; until nothing moves (bounded)."""
    c = u.central
    u.muted = set(muted)
    for _ in range(50):
        c.intervals.start_ready()
        c.intervals.flush(c.meters.t_start_ns or 0)
        u.pump()
        if not u.node.events.pending():
            return
        while u.node.events.pending():
            c.handle(u.node.events.get_nowait())
    raise AssertionError("the exchange did not settle")


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


def request_of(u: LoopbackUnit, cycle: int, stage: int) -> bytes:
    for k, data in u.bus.log:
        if k == u.node.keys.request and any(
                (p["cycle"], p["stage"]) == (cycle, stage)
                for p in decode(data, u.rc.transport.unit)["parts"]):
            return data
    raise AssertionError(f"no request for {cycle}/{stage}")


def plain(v: Any) -> Any:
    return [plain(x) for x in v] if isinstance(v, tuple | list) else v


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
    assert f.waiting == {1} and not f.dropped and not c.late.held
    c.check_late(f.late_ns)
    assert f.waiting == set() and f.dropped == {1}
    assert c.late.held == {(1, 0, 1)}  # (cycle, round, peripheral)
    last = reply_vals(u, 1, 0, 0)
    for name in last:
        assert plain(f.ctx[name])[1] == plain(last[name])[0]  # axis 1: peripheral 2's
        for axis in (0, 2):
            assert plain(f.ctx[name])[axis] == before[name][axis]
    assert c.late.late_per_axis == [0, 1, 0]
    held = [a for a in seen if a[0] == "held"]
    assert len(held) == 1
    _direction, key, cycle, stage, payload, t_ns = held[0]
    assert key == f"{u.node.keys.root}/faults/held" and (cycle, stage) == (1, 0)
    assert t_ns == f.late_ns
    msg = msgpack.unpackb(payload)
    assert msg == {"cycle": 1, "stage": 0, "peripheral": 1,
                   "vals": {n: [plain(v)[0]] for n, v in last.items()}}
    # the interval went on without peripheral 2's reply: its next round is out
    assert f.round is not None and f.round.index == 1 and f in c.intervals.outbox


def test_a_held_replys_late_arrival_is_counted_and_marks_the_peripheral_alive():
    u, c, f = second_interval_late("holdlate", late_policy="hold", muted={1})
    c.check_late(f.late_ns)
    c.silence.last_reply_ns[1] = 0
    late = request_of(u, 1, 0)
    u.muted = set()
    for reply in u.peripherals[1][1].on_request(late):
        c.handle(("reply", 1, reply, 123))
    assert c.node.rejected["late_reply"] == 1
    assert (1, 0, 1) not in c.late.held
    assert c.silence.last_reply_ns[1] == 123
    for reply in u.peripherals[1][1].on_request(late):  # a second copy: not held any more
        c.handle(("reply", 1, reply, 456))
    assert c.node.rejected["unexpected_reply"] == 1 and c.silence.last_reply_ns[1] == 123


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
    u = realtime_unit("holdnone", late_policy="hold")
    c = u.central
    sample(u, 0)
    settle(u, muted=frozenset({2}))
    f = c.inflight[0]
    c.check_late(f.late_ns + 5 * MS)
    assert f.waiting == {2} and f.late_ns == 0 and not f.dropped and not c.late.held
    assert c.late.late_per_axis == [0, 0, 0]


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


def test_a_rounds_policy_is_the_strictest_of_its_blocks():
    u = realtime_unit("pol", late_policy="wait", late={"jdot": "hold"})
    assert u.central.late.policy == {0: "wait", 1: "hold"}
    u = realtime_unit("pol2", late_policy="hold", late={"ik": "fault", "jdot": "wait"})
    assert u.central.late.policy == {0: "hold", 1: "fault"}
    u = realtime_unit("pol3", late_policy="fault", late={"residual0": "wait"})
    assert u.central.late.policy == {0: "fault", 1: "fault"}


# -- limits and silence --------------------------------------------------------------------


def test_the_silence_limit_is_fault_periods_after_start_up_and_the_timeout_elsewhere():
    u = realtime_unit("limit", period=2e-3, fault_periods=4.0)
    c = u.central
    assert c.limit_ns() == 20 * MS  # start-up: at least 20 ms
    c.intervals.done = silence.STARTUP_INTERVALS - 1
    assert c.limit_ns() == 20 * MS
    c.intervals.done = silence.STARTUP_INTERVALS
    assert c.limit_ns() == 8 * MS
    u = realtime_unit("limit2", period=10e-3, fault_periods=3.0)
    assert u.central.limit_ns() == 30 * MS  # longer than start-up's floor: kept
    u = LoopbackUnit(RunConfig.of(unit=unit_id("limit3"), clock="lockstep", timeout=0.75))
    assert u.central.limit_ns() == 750 * MS


def test_a_silent_peripheral_is_a_fault_just_after_its_limit(monkeypatch):
    u = realtime_unit("silent", late_policy="hold")
    c = u.central
    first_interval(u)
    sample(u, 1)
    settle(u, muted=frozenset({1}))
    c.intervals.done = 100  # past start-up
    limit = c.limit_ns()
    assert limit == 3 * MS
    f = c.inflight[1]
    f.deadline_ns = 10**18  # the round's own deadline out of the way
    clock = Clock(c.silence.last_reply_ns[1] + limit)
    clock.install(monkeypatch)
    c.silence.plant_gaps.clear()  # the plant goes on sampling: the peripheral alone is silent
    c.silence.last_sample_ns = clock.now
    exc = fault_just_past(c, clock, limit)
    assert exc.process == "peripheral-2" and exc.code == EXIT_PERIPHERAL
    assert str(exc).startswith("peripheral 2 has not answered for 3.0 ms (limit 3.0 ms)")
    c.check_late(f.late_ns)  # held: still judged by its silence
    assert f.dropped == {1} and not f.waiting
    with pytest.raises(Fault, match="peripheral 2 has not answered"):
        c.check_silence(limit)
    f.dropped.clear()  # neither waited for nor held: its silence is no fault
    c.check_silence(limit)


def silent_peripheral_2(tag: str, monkeypatch) -> tuple[Any, Clock, int]:
    """A unit past start-up whose peripheral 2 alone went silent (the plant samples on),
    the guard's clock at its limit."""
    u = realtime_unit(tag, late_policy="hold")
    c = u.central
    first_interval(u)
    sample(u, 1)
    settle(u, muted=frozenset({1}))
    c.intervals.done = 100
    limit = c.limit_ns()
    c.inflight[1].deadline_ns = 10**18  # the round's own deadline and late time out of
    c.inflight[1].late_ns = 0  # the way: its silence alone is judged
    c.silence.plant_gaps.clear()
    clock = Clock(c.silence.last_reply_ns[1] + limit)
    clock.install(monkeypatch)
    c.silence.last_sample_ns = clock.now
    return c, clock, limit


def test_a_silence_the_plant_shared_is_not_counted_up_to_one_more_limit(monkeypatch):
    """The machine stalled every process: the plant's last sample is as old as the
    peripheral's last reply, so the silence counts only past twice the limit."""
    c, clock, limit = silent_peripheral_2("shared", monkeypatch)
    c.silence.last_sample_ns = c.silence.last_reply_ns[1] - 2 * MS  # silent since before the reply
    clock.now += 1
    c.check_silence(limit)  # past the limit, but the plant was silent too
    clock.now = c.silence.last_reply_ns[1] + 2 * limit
    exc = fault_just_past(c, clock, limit)
    assert exc.process == "peripheral-2"
    assert str(exc).startswith("peripheral 2 has not answered for 6.0 ms (limit 3.0 ms, "
                               "plus 3.0 ms the plant was silent too)"), str(exc)


def test_a_runnable_silent_process_has_one_more_limit_and_is_then_a_fault(monkeypatch):
    """The silent peripheral's process is runnable (waiting for a CPU): the machine is
    slow, not the process; its silence counts only past twice the limit, once."""
    c, clock, limit = silent_peripheral_2("runnable", monkeypatch)
    asked: list[str] = []
    supervise(c, role_state=lambda role: asked.append(role) or "runnable")
    since = c.silence.last_reply_ns[1]
    clock.now += 1
    c.check_silence(limit)  # past the limit, but runnable: excused
    assert asked == ["peripheral-2"] and c.silence.excuses == 1
    assert c.next_check(clock.now, limit, 0) == since + 2 * limit  # no busy wait
    clock.now = c.silence.last_sample_ns = since + 2 * limit  # the plant samples on
    c.check_silence(limit)
    clock.now += 1
    with pytest.raises(Fault) as info:  # still runnable, still silent: now a fault
        c.check_silence(limit)
    assert info.value.process == "peripheral-2" and c.silence.excuses == 1
    assert str(info.value).startswith(
        "peripheral 2 has not answered for 6.0 ms (limit 3.0 ms); its process was runnable "
        "(after one extension of its limit)"), str(info.value)


def test_a_silence_is_excused_once_while_the_centrals_own_zenoh_thread_is_runnable(
        monkeypatch):
    """The peripheral sleeps (it waits for the request, or has answered) while the
    central's own Zenoh thread has yet to send or read: the central was the slow one."""
    c, clock, limit = silent_peripheral_2("central-busy", monkeypatch)
    supervise(c, role_state=lambda role: "runnable" if role == "central" else "sleeping")
    clock.now += 1
    c.check_silence(limit)
    assert c.silence.excuses == 1
    clock.now = c.silence.last_sample_ns = c.silence.last_reply_ns[1] + 2 * limit + 1
    with pytest.raises(Fault, match="its process was sleeping"):
        c.check_silence(limit)


class Accounting:
    """Fake scheduler accounting: each role's one thread gains ``run`` and ``wait`` ns
    per ns of the guard's clock from ``gains[role]`` (default nothing); the machine's CPU
    pressure gains ``pressure`` ns per ns."""

    def __init__(self, clock: Clock, gains: dict[str, tuple[float, float]], *,
                 pressure: float = 0.0, waiting: int = 0) -> None:
        self.clock, self.gains, self.pressure, self.waiting = clock, gains, pressure, waiting

    def __call__(self, role: str) -> dict[int, tuple[int, int]]:
        run, wait = self.gains.get(role, (0.0, 0.0))
        return {7: (int(run * self.clock.now), int(wait * self.clock.now))}

    def install(self, c: Any) -> None:
        supervise(c, role_times=self)
        supervise(c, machine_load=lambda: MachineLoad(int(self.pressure * self.clock.now),
                                                      self.waiting))


def renewals_until_fault(c: Any, clock: Clock, limit: int, *, plant_samples: bool = True
                         ) -> tuple[Fault, list[int]]:
    """Judge the silence just after each moment the guard would look again, the plant
    sampling on (unless ``plant_samples`` is false: the plant is the silent one), until it
    is a fault (bounded by 20 looks); the moments looked at."""
    looks = []
    for _ in range(20):
        clock.now = c.next_check(clock.now, limit, 0) + 1
        if plant_samples:
            c.silence.last_sample_ns = clock.now
        looks.append(clock.now)
        try:
            c.check_silence(limit)
        except Fault as exc:
            return exc, looks
    raise AssertionError("no fault after 20 looks")


def test_a_process_the_machine_keeps_from_a_cpu_is_excused_a_limit_at_a_time_up_to_a_cap(
        monkeypatch):
    """Runnable, waiting on a runqueue all along: each limit is renewed while the kernel's
    accounting shows the process denied a CPU for half of it or more, until the silence
    has lasted 8 limits (README: "up to 8 limits (24 ms at 1 ms)")."""
    c, clock, limit = silent_peripheral_2("starved", monkeypatch)
    supervise(c, role_state=lambda role: "runnable")
    Accounting(clock, {"peripheral-2": (0.0, 1.0)}).install(c)
    since = c.silence.last_reply_ns[1]
    exc, looks = renewals_until_fault(c, clock, limit)
    cap = 8
    assert looks[-1] == since + cap * limit + 1  # no look wasted, none missed
    assert c.silence.excuses == cap - 1  # the first excuse and its renewals
    assert limit == 3_000_000  # three periods of 1 ms: the cap is 24 ms
    assert exc.process == "peripheral-2" and str(exc).startswith(
        "peripheral 2 has not answered for 24.0 ms (limit 3.0 ms); its "
        f"process was runnable (after {cap - 1} extensions of its limit"), str(exc)


def first_then(first: str, then: str) -> Any:
    """The silent peripheral 2's state: ``first`` at the first look, ``then`` at every
    later one; the central's Zenoh threads asleep."""
    looks: list[str] = []

    def state(role: str) -> str:
        if role != "peripheral-2":
            return "sleeping"
        looks.append(role)
        return first if len(looks) == 1 else then
    return state


@pytest.mark.parametrize("gains, then", [
    ((1.0, 0.0), "runnable"),  # it ran the whole extension: an endless loop, with CPU
    # to spare for the machine's other tasks (they waited 0.4 of it)
    ((0.1, 0.3), "sleeping"),  # it ran a little, waited a little, sleeps: it was served
])
def test_a_process_that_had_its_cpu_and_stayed_silent_is_a_fault_after_one_extension(
        monkeypatch, gains, then):
    """Runnable at its limit, but over its extension the machine let it run, or kept it
    waiting for less than half of it: the process, not the machine, is at fault."""
    c, clock, limit = silent_peripheral_2(f"served-{then}", monkeypatch)
    supervise(c, role_state=first_then("runnable", then))
    Accounting(clock, {"peripheral-2": gains}, pressure=0.4).install(c)
    since = c.silence.last_reply_ns[1]
    exc, looks = renewals_until_fault(c, clock, limit)
    assert looks[-1] == since + 2 * limit + 1 and c.silence.excuses == 1
    window = limit  # from the first look, a nanosecond past the limit, to the second
    assert str(exc).endswith(
        f"its process was {then} (after one extension of its limit; in the last "
        f"{window / 1e6:.1f} ms it was kept from a CPU {gains[1] * window / 1e6:.1f} ms "
        f"and ran {gains[0] * window / 1e6:.1f} ms, and tasks waited for a CPU "
        f"{0.4 * window / 1e6:.1f} ms)"), str(exc)


def test_a_sleeping_peripheral_is_excused_while_the_centrals_zenoh_threads_wait_for_a_cpu(
        monkeypatch):
    """The request or the reply is in transit at the central, whose Zenoh threads the
    machine does not run: renewed as long as they wait (up to the cap), whatever the
    peripheral itself does meanwhile (asleep: nothing to do)."""
    c, clock, limit = silent_peripheral_2("central-starved", monkeypatch)
    supervise(c, role_state=lambda role: "runnable" if role == "central" else "sleeping")
    Accounting(clock, {"central": (0.0, 0.9)}).install(c)
    exc, looks = renewals_until_fault(c, clock, limit)
    assert looks[-1] == c.silence.last_reply_ns[1] + 8 * limit + 1
    assert c.silence.excuses == 8 - 1
    assert "its process was sleeping" in str(exc)


def test_a_sleeping_plant_is_excused_while_the_machines_tasks_wait_for_a_cpu(monkeypatch):
    """The plant's timer fired and its thread waits on a CPU another task holds: the
    thread's own wait is added up only once it runs, the CPU pressure counts it now."""
    c, clock = silent_plant("plant-pressure", monkeypatch, lambda role: "sleeping")
    Accounting(clock, {"plant": (0.05, 0.0)}, pressure=0.6).install(c)
    exc, looks = renewals_until_fault(c, clock, 3 * MS, plant_samples=False)
    assert c.silence.excuses == 8 - 1
    assert looks[-1] == 5 * MS + 8 * 3 * MS + 1
    assert "tasks waited for a CPU 1.8 ms)" in str(exc), str(exc)


def test_a_sleeping_peripheral_is_excused_once_while_more_tasks_are_runnable_than_cpus(
        monkeypatch):
    """What is in transit may wait for a CPU in a thread the central does not look at
    (the peripheral's, the plant's): the machine short of CPUs excuses the first limit;
    the accounting decides the next."""
    c, clock, limit = silent_peripheral_2("machine-short", monkeypatch)
    supervise(c, role_state=lambda role: "sleeping")
    Accounting(clock, {}, waiting=2).install(c)
    since = c.silence.last_reply_ns[1]
    exc, looks = renewals_until_fault(c, clock, limit)
    assert looks[-1] == since + 2 * limit + 1 and c.silence.excuses == 1
    assert exc.process == "peripheral-2"
    c, clock, limit = silent_peripheral_2("machine-idle", monkeypatch)
    supervise(c, role_state=lambda role: "sleeping")
    Accounting(clock, {}, waiting=0).install(c)
    assert fault_just_past(c, clock, limit).process == "peripheral-2"
    assert c.silence.excuses == 0


def test_without_the_accounting_a_silence_is_excused_once(monkeypatch):
    """A kernel or a process whose accounting cannot be read gives no evidence: one
    extension, as for any runnable silent process."""
    c, clock, limit = silent_peripheral_2("no-accounting", monkeypatch)
    supervise(c, role_state=lambda role: "runnable")
    supervise(c, role_times=lambda role: {})
    supervise(c, machine_load=lambda: MachineLoad(None, None))
    since = c.silence.last_reply_ns[1]
    exc, looks = renewals_until_fault(c, clock, limit)
    assert looks[-1] == since + 2 * limit + 1 and c.silence.excuses == 1
    assert exc.process == "peripheral-2"


def test_the_rounds_check_does_not_excuse_again_what_the_peripherals_check_excused(
        monkeypatch):
    """A peripheral's silence is judged from its last reply and from its round's sending,
    two starts of one silence: an excuse holds for that silence until it answers, so the
    two checks cannot grant each other's extensions in turn (each keyed by its own start,
    they did, for as long as the process stayed runnable)."""
    c, clock, limit = silent_peripheral_2("two-starts", monkeypatch)
    since = c.silence.last_reply_ns[1]
    c.inflight[1].deadline_ns = since + MS + limit  # its round went out 1 ms later
    supervise(c, role_state=lambda role: "runnable")  # no accounting: one extension
    exc, looks = renewals_until_fault(c, clock, limit)
    assert c.silence.excuses == 1 and looks[-1] <= since + MS + 2 * limit + 1
    assert "after one extension" in str(exc)


def test_an_answer_ends_the_excuse_and_the_next_silence_starts_afresh(monkeypatch):
    """The peripheral answers during its extension: its excuse is gone (and dropped, so
    that the loop's next looks do not weigh it), and a later silence is judged from its
    own limit, with a first extension of its own."""
    c, clock, limit = silent_peripheral_2("answered", monkeypatch)
    supervise(c, role_state=lambda role: "runnable")
    clock.now += 1
    c.check_silence(limit)
    assert c.silence.excuses == 1 and "peripheral-2" in c.silence.excuse.granted
    c.silence.last_reply_ns[1] = clock.now + 1  # it answers
    assert c.silence.excuse_of("peripheral-2") is None
    assert "peripheral-2" not in c.silence.excuse.granted
    clock.now = c.silence.last_sample_ns = c.silence.last_reply_ns[1] + limit + 1
    c.check_silence(limit)  # silent again past its limit: excused anew
    assert c.silence.excuses == 2


def test_a_process_stopped_during_its_extension_is_a_fault_at_its_end(monkeypatch):
    c, clock, limit = silent_peripheral_2("stopped-later", monkeypatch)
    supervise(c, role_state=first_then("runnable", "stopped"))
    Accounting(clock, {"peripheral-2": (0.0, 1.0)}).install(c)  # starved, yet stopped
    since = c.silence.last_reply_ns[1]
    exc, looks = renewals_until_fault(c, clock, limit)
    assert looks[-1] == since + 2 * limit + 1 and c.silence.excuses == 1
    assert "its process was stopped (after one extension of its limit)" in str(exc)


def test_a_starved_plant_is_excused_a_limit_at_a_time_too(monkeypatch):
    c, clock = silent_plant("plant-starved", monkeypatch, lambda role: "runnable")
    Accounting(clock, {"plant": (0.0, 1.0)}).install(c)
    exc, looks = renewals_until_fault(c, clock, 3 * MS, plant_samples=False)
    assert exc.process == "plant" and c.silence.excuses == 8 - 1
    assert looks[-1] == 5 * MS + 8 * 3 * MS + 1


@pytest.mark.parametrize("state", ["stopped", "exited", "blocked"])
def test_a_frozen_or_exited_process_is_a_fault_whatever_the_central_is_doing(monkeypatch,
                                                                              state):
    """A process stopped by a signal cannot answer, whatever is in transit: the frozen-role
    tests' case (tests/test_faults.py)."""
    c, clock, limit = silent_peripheral_2(f"frozen-{state}", monkeypatch)
    supervise(c, role_state=lambda role: "runnable" if role == "central" else state)
    exc = fault_just_past(c, clock, limit)
    assert exc.process == "peripheral-2" and c.silence.excuses == 0


@pytest.mark.parametrize("state", ["sleeping", "stopped", "exited", "blocked"])
def test_a_silent_process_that_is_not_runnable_is_a_fault_at_its_limit(monkeypatch, state):
    """Nothing in transit at the central either (a sleeping process is excused while the
    central's own Zenoh thread is runnable: the next test)."""
    c, clock, limit = silent_peripheral_2(f"not-{state}", monkeypatch)
    supervise(c, role_state=lambda role: "sleeping" if role == "central" else state)
    exc = fault_just_past(c, clock, limit)
    assert exc.process == "peripheral-2" and c.silence.excuses == 0
    assert str(exc) == (f"peripheral 2 has not answered for 3.0 ms (limit 3.0 ms); "
                        f"its process was {state}"), str(exc)


def silent_plant(tag: str, monkeypatch, state) -> tuple[Any, Clock]:
    """A central whose plant's last sample came at 5 ms, the clock at its 3 ms limit
    plus one nanosecond, ``state(role)`` what the processes are doing."""
    u = realtime_unit(tag)
    c = u.central
    first_interval(u)
    c.intervals.done = 100
    c.silence.last_sample_ns = 5 * MS
    clock = Clock(5 * MS + 3 * MS + 1)
    clock.install(monkeypatch)
    supervise(c, role_state=state)
    return c, clock


def test_a_silent_plant_that_is_runnable_is_excused_once(monkeypatch):
    c, clock = silent_plant("plant-runnable", monkeypatch,
                            lambda role: "runnable" if role == "plant" else "sleeping")
    c.check_silence(3 * MS)
    assert c.silence.excuses == 1
    clock.now = 5 * MS + 6 * MS
    exc = fault_just_past(c, clock, 3 * MS)
    assert exc.process == "plant" and str(exc).startswith(
        "no sample from the plant for 6.0 ms (cycle 1 awaited, newest seen 0); its process "
        "was runnable"), str(exc)


def test_a_silent_plant_asleep_past_its_tick_is_excused_once(monkeypatch):
    """The plant samples on its own clock: asleep with its sample overdue, it waits for a
    timer the machine has not served, not for a message; a stopped plant is a fault at
    its limit."""
    # asleep, and the central's Zenoh threads too: nothing in transit
    c, clock = silent_plant("plant-asleep", monkeypatch, lambda role: "sleeping")
    c.check_silence(3 * MS)
    assert c.silence.excuses == 1
    clock.now = 5 * MS + 6 * MS
    exc = fault_just_past(c, clock, 3 * MS)
    assert exc.process == "plant" and str(exc).endswith(
        "its process was sleeping (after one extension of its limit)"), str(exc)
    c, clock = silent_plant("plant-stopped", monkeypatch,
                            lambda role: "stopped" if role == "plant" else "runnable")
    clock.now -= 1
    exc = fault_just_past(c, clock, 3 * MS)
    assert exc.process == "plant" and c.silence.excuses == 0


def test_no_silence_is_excused_outside_realtime_or_where_the_process_is_unknown(monkeypatch):
    c, clock, limit = silent_peripheral_2("unknown", monkeypatch)
    supervise(c, role_state=None)  # a role started by hand, maybe on another host
    exc = fault_just_past(c, clock, limit)
    assert exc.process == "peripheral-2" and "its process" not in str(exc)
    assert c.silence.excuses == 0


def test_the_first_interval_is_judged_by_its_rounds_deadline_only(monkeypatch):
    u = realtime_unit("first")
    c = u.central
    sample(u, 0)
    settle(u, muted=frozenset({0, 1}))
    f = c.inflight[0]
    c.silence.last_reply_ns = [1, 1, 1]  # long ago, but nothing is done yet
    clock = Clock(f.deadline_ns)
    clock.install(monkeypatch)
    exc = fault_just_past(c, clock, 3 * MS)
    assert exc.process == "peripheral-1" and exc.code == EXIT_PERIPHERAL
    assert str(exc).startswith("peripheral 1 did not answer round 0 of cycle 0: "
                                     "silent for 3.0 ms (limit 3.0 ms)")


def test_a_silent_plant_is_a_fault_after_the_limit_unless_messages_wait(monkeypatch):
    u = realtime_unit("plant")
    c = u.central
    first_interval(u)
    c.intervals.done = 100
    assert not c.intake.samples and not c.inflight
    c.silence.last_sample_ns = 5 * MS
    clock = Clock(5 * MS + 3 * MS)
    clock.install(monkeypatch)
    exc = fault_just_past(c, clock, 3 * MS)
    assert exc.process == "plant" and exc.code == EXIT_PLANT
    assert str(exc) == ("no sample from the plant for 3.0 ms (cycle 1 awaited, newest "
                              "seen 0)")
    u.node.events.deliver(u.node.keys.sample, b"unread")  # the central may be the slow one
    c.check_silence(3 * MS)
    u.node.events.get_nowait()
    c.intake.samples[1] = ([0, 0, 0], 0)  # a sample not started yet: not the plant's silence
    c.check_silence(3 * MS)
    del c.intake.samples[1]
    c.intervals.next_cycle = c.cycles  # every interval started: nothing more is awaited
    c.check_silence(3 * MS)


def test_a_silence_is_not_even_looked_at_while_a_message_waits(monkeypatch):
    """Past the limit with a reply unread: no process state read (0.25-0.3 ms each from
    /proc), no excuse spent; once the inbox is empty the silence is judged as before."""
    c, clock, limit = silent_peripheral_2("unread", monkeypatch)
    asked: list[str] = []
    supervise(c, role_state=lambda role: asked.append(role) or "sleeping")
    clock.now += 1
    c.node.events.deliver(c.node.keys.sample, b"unread")
    for _ in range(3):  # every turn of the central's loop while it waits
        c.check_silence(limit)
    assert asked == [] and c.silence.excuses == 0
    c.node.events.get_nowait()
    with pytest.raises(Fault, match="its process was sleeping"):
        c.check_silence(limit)
    assert asked and c.silence.excuses == 0


def test_the_plants_silence_counts_from_the_start_before_any_sample(monkeypatch):
    u = LoopbackUnit(RunConfig.of(unit=unit_id("plant0"), clock="lockstep", timeout=0.5))
    c = u.central
    c.meters.t_start_ns = 7 * MS
    clock = Clock(7 * MS + 500 * MS)
    clock.install(monkeypatch)
    c.check_silence(500 * MS)
    clock.now += 1
    with pytest.raises(Fault, match="no sample from the plant for 500.0 ms"):
        c.check_silence(500 * MS)
    u = LoopbackUnit(RunConfig.of(unit=unit_id("plant1"), clock="freerun", timeout=0.5))
    u.central.meters.t_start_ns = 7 * MS
    u.central.check_silence(500 * MS)  # freerun: no plant


def test_next_check_is_the_earliest_moment_something_could_fail():
    _u, c, f = second_interval_late("next", late_policy="hold", muted={1})
    now = 10**12
    f.deadline_ns, f.late_ns = now + 990, now + 950
    # peripheral 2 is the one waited for
    c.silence.last_reply_ns = [now - 500, now - 300, now - 400]
    c.silence.last_sample_ns = now - 100
    timeout = 1000
    assert c.next_check(now, timeout, 0) == now - 300 + timeout
    c.silence.last_reply_ns[1] = now
    assert c.next_check(now, timeout, 0) == now - 100 + timeout  # the plant
    c.silence.last_sample_ns = now
    assert c.next_check(now, timeout, 0) == now + 950  # late data
    assert c.next_check(now, timeout, now + 700) == now + 700  # a held round's release
    f.late_ns = 0
    assert c.next_check(now, timeout, 0) == now + 990  # the round's deadline
    f.waiting.clear()
    assert c.next_check(now, timeout, 0) == now + timeout
    c.silence.last_sample_ns = 0
    c.silence.last_reply_ns = [0, 0, 0]
    f.waiting.add(1)
    f.deadline_ns = now + 5000
    assert c.next_check(now, timeout, 0) == now + timeout


def test_next_check_outside_realtime_ignores_silence():
    u = LoopbackUnit(RunConfig.of(unit=unit_id("nextls"), clock="lockstep", peripherals=2))
    c = u.central
    u.start_plant()
    c.handle(u.node.events.get_nowait())
    settle(u, muted=frozenset({0}))
    f = c.inflight[0]
    now = f.deadline_ns - 10_000
    c.silence.last_reply_ns = [now - 900, now - 900]
    c.silence.last_sample_ns = now - 900
    assert c.next_check(now, 50_000, 0) == f.deadline_ns


def test_a_dead_child_is_a_fault_of_its_kind_looked_at_every_50_ms(monkeypatch):
    u = realtime_unit("child")
    c = u.central
    c.silence.check_children()  # none started: nothing to look at
    calls = []
    dead: list[tuple[str, int] | None] = [None]
    supervise(c, child_check=lambda **_: calls.append(1) or dead[0])
    clock = Clock(10**12)
    clock.install(monkeypatch)
    c.silence.check_children()
    assert len(calls) == 1
    dead[0] = ("plant", -9)
    clock.now += 50 * MS - 1000
    c.silence.check_children()  # not yet looked at again
    assert len(calls) == 1
    clock.now += 1000
    with pytest.raises(Fault) as info:
        c.silence.check_children()
    exc = info.value
    assert (exc.process, exc.code) == ("plant", EXIT_PLANT)
    assert str(exc) == "plant exited (status -9)"
    dead[0] = ("peripheral-2", 1)
    clock.now += 50 * MS
    with pytest.raises(Fault) as info:
        c.silence.check_children()
    exc = info.value
    assert (exc.process, exc.code) == ("peripheral-2", EXIT_PERIPHERAL)


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
    u = realtime_unit("hint", period=2e-3)
    c = u.central
    c.intervals.next_cycle = 100
    c.meters.plant_misses, c.meters.skipped = 6, 4  # 10 of 100: not more than a tenth
    assert c.overload_hint() == ""
    c.meters.skipped = 5
    assert c.overload_hint() == (
        "; 6 commands missed their deadline and 5 samples were skipped in 100 periods: "
        "this machine does not sustain a 2 ms period with 3 peripheral(s) (try a longer "
        "--period or --fault-periods, or --clock lockstep)")
    c.intervals.next_cycle = 10
    # few periods: at least 5 misses before it says so
    c.meters.plant_misses, c.meters.skipped = 5, 0
    assert c.overload_hint() == ""
    c.meters.plant_misses = 6
    assert c.overload_hint().startswith("; 6 commands missed their deadline")
    c.intervals.next_cycle = 0
    assert "in 1 periods" in c.overload_hint()
    u = LoopbackUnit(RunConfig.of(unit=unit_id("hintls"), clock="lockstep"))
    u.central.meters.plant_misses = 10**6
    assert u.central.overload_hint() == ""


def test_hold_torques_hold_the_last_estimate_against_gravity_or_are_zero():
    u = realtime_unit("holdtau")
    c = u.central
    p = tuple(u.setup.task.start())
    c.ctl.est = Estimate(p, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    want = [float(x) for x in gravity_torques(u.setup.params, p)]
    got = c.hold_torques()
    assert got == want and all(type(x) is float for x in got)
    assert max(abs(x) for x in got) > 0.1
    c.ctl.est = Estimate((0.0, 0.0, -2.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    assert c.hold_torques() == [0.0, 0.0, 0.0]
    c.ctl.est = Estimate((math.nan, 0.0, 0.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    assert c.hold_torques() == [0.0, 0.0, 0.0]


def test_a_fault_carries_its_process_and_code():
    f = Fault("why", process="plant", code=EXIT_PLANT)
    assert (str(f), f.process, f.code) == ("why", "plant", EXIT_PLANT)


# -- edges that only a wrong guard would cross ----------------------------------------------


def twin(f: Any, **changes: Any) -> Any:
    """Another interval like ``f`` (its own sets), e.g. at another round or cycle."""
    import dataclasses

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
    later = twin(f, cycle=2, round=u.central.engine.plan.rounds[1])  # round 1 (fault), late
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


def test_hold_waits_while_no_peripheral_has_answered_at_all_and_goes_on_to_the_next():
    u = realtime_unit("holdnone2", late_policy="hold")
    c = u.central
    sample(u, 0)
    settle(u, muted=frozenset({0, 1, 2}))
    f = c.inflight[0]
    assert c.late.last_vals == {}
    c.check_late(f.late_ns)
    assert f.waiting == {0, 1, 2} and f.late_ns == 0 and not c.late.held
    # with an interval that can be held behind it, that one is held
    u, c, f = second_interval_late("holdnext", late_policy="hold", muted={1})
    blank = twin(f, cycle=0, ctx={}, waiting={0, 1, 2})
    c.late.last_vals["rowo0_i"][0] = None  # peripheral 1's axis has nothing to hold
    c.inflight.clear()
    c.inflight.update({0: blank, 1: f})
    c.check_late(f.late_ns)
    assert blank.waiting == {0, 1, 2} and blank.late_ns == 0
    assert f.dropped == {1} and c.late.held == {(1, 0, 1)}


def test_late_counts_add_up_per_axis_and_the_held_set_stays_bounded():
    u = realtime_unit("count", late_policy="hold")
    c = u.central
    first_interval(u)
    for k in (1, 2):
        sample(u, k)
        settle(u, muted=frozenset({1}))
        c.check_late(c.inflight[k].late_ns)
        settle(u)
    assert c.late.late_per_axis == [0, 2, 0] and c.done == 3
    assert c.late.held == {(1, 0, 1), (2, 0, 1)}
    sample(u, 3)
    settle(u, muted=frozenset({2}))
    c.late.held = {(-k, 0, 0) for k in range(1, 1023)} | {(2, 0, 1)}  # 1023 held
    c.check_late(c.inflight[3].late_ns)
    assert len(c.late.held) == 1024 and (-1022, 0, 0) in c.late.held  # at the bound: all kept
    settle(u)
    sample(u, 4)
    settle(u, muted=frozenset({2}))
    c.check_late(c.inflight[4].late_ns)
    assert len(c.late.held) == 1024 and (-1022, 0, 0) not in c.late.held  # past it: oldest out
    assert (4, 0, 2) in c.late.held


def test_a_rounds_policy_is_the_strictest_whatever_the_order_of_its_blocks():
    u = realtime_unit("order", late_policy="hold", late={"dyn_axis": "fault"})
    assert u.central.late.policy == {0: "hold", 1: "fault"}


def test_limits_and_messages_keep_their_units_at_large_values(monkeypatch):
    u = realtime_unit("units", period=1.0, fault_periods=1000.0, cycles=50)
    c = u.central
    first_interval(u)
    c.intervals.done = 100
    assert c.limit_ns() == 1000 * 10**9
    u2 = LoopbackUnit(RunConfig.of(unit=unit_id("units2"), clock="lockstep", timeout=600.0))
    assert u2.central.limit_ns() == 600 * 10**9
    sample(u, 1)
    settle(u, muted=frozenset({1}))
    limit = 123_456_789_000  # 123456.789 ms
    f = c.inflight[1]
    clock = Clock(c.silence.last_reply_ns[1] + limit + 1)
    f.deadline_ns = clock.now + 1
    clock.install(monkeypatch)
    c.silence.plant_gaps.clear()  # the plant goes on sampling: the peripheral alone is silent
    c.silence.last_sample_ns = clock.now
    with pytest.raises(Fault, match=r"for 123456\.8 ms \(limit 123456\.8 ms\)"):
        c.check_silence(limit)
    c.silence.last_reply_ns[1] = 0
    clock.now = f.deadline_ns + 1
    with pytest.raises(Fault, match=r"silent for 123456\.8 ms \(limit 123456\.8 ms\)"):
        c.check_silence(limit)
    c.inflight.clear()
    c.silence.last_sample_ns = 1
    clock.now = 1 + limit + 1
    with pytest.raises(Fault, match=r"no sample from the plant for 123456\.8 ms"):
        c.check_silence(limit)


def test_tracking_error_at_exactly_max_error_is_allowed_and_reported_in_mm():
    u = realtime_unit("exact", max_error=0.005)
    pc = (0.0, 0.0, -0.35)
    check(u, 3, (0.005, 0.0, -0.35), pc)
    u = realtime_unit("mm", max_error=0.5)
    with pytest.raises(Fault, match=r"tracking error 750\.0 mm exceeds --max-error 500\.0 mm"):
        check(u, 3, (0.75, 0.0, -0.35), pc)


def test_at_the_halved_rate_the_silence_limit_is_three_halved_periods(monkeypatch):
    """The plant samples every second period at the halved rate: three of its periods,
    6 ms at 1 ms."""
    u = realtime_unit("halved-limit")
    c = u.central
    c.intervals.done = 100
    assert c.limit_ns() == 3 * MS
    c.ctl.halve(c.next_cycle)
    assert c.ctl.stride == 2 and c.limit_ns() == 6 * MS


def test_an_excused_peripheral_does_not_hide_another_ones_fault(monkeypatch):
    """Peripherals 1 and 3 silent past their limit: peripheral 1 is runnable (excused),
    peripheral 3 asleep with nothing in transit: the fault names peripheral 3."""
    u = realtime_unit("two-silent", late_policy="hold")
    c = u.central
    first_interval(u)
    sample(u, 1)
    settle(u, muted=frozenset({0, 2}))
    c.intervals.done = 100
    limit = c.limit_ns()
    c.inflight[1].deadline_ns = 10**18
    c.inflight[1].late_ns = 0
    c.silence.plant_gaps.clear()
    clock = Clock(max(c.silence.last_reply_ns[0], c.silence.last_reply_ns[2]) + limit + 1)
    clock.install(monkeypatch)
    c.silence.last_sample_ns = clock.now
    supervise(c, role_state=lambda role: "runnable" if role == "peripheral-1" else "sleeping")
    with pytest.raises(Fault) as info:
        c.check_silence(limit)
    assert info.value.process == "peripheral-3", str(info.value)
    assert c.silence.excuses == 1
