"""The silence watch's bookkeeping (runtime/central/silence.py), driven directly: when a
plant's silence counts as a gap, when a request starts a peripheral's silence, and the
edge of a limit, each at its exact figure."""

from __future__ import annotations

from ctrlunit.runtime.central.excuse import UNSUPERVISED, Supervision
from ctrlunit.runtime.central.silence import SilenceWatch

MS = 1_000_000


def watch(*, stride: int = 1, realtime: bool = True,
          supervision: Supervision = UNSUPERVISED) -> SilenceWatch:
    """A watch of 3 peripherals at 1 ms, its ``supervision`` given at construction as the
    launcher gives the central's."""
    return SilenceWatch(peripherals=3, realtime=realtime, period_s=1e-3, fault_periods=3,
                        timeout_s=2.0, stride=lambda: stride, supervision=supervision)


def test_a_gap_in_the_samples_counts_past_two_sample_intervals_and_not_at_them():
    w = watch()
    w.heard_sample(5 * MS)  # the first: no gap before it
    assert w.last_sample_ns == 5 * MS and not w.plant_gaps
    w.heard_sample(7 * MS)  # two periods: the plant's own rhythm
    assert not w.plant_gaps and w.last_sample_ns == 7 * MS
    w.heard_sample(9 * MS + 1)  # one nanosecond more: a gap, from the last sample
    assert list(w.plant_gaps) == [(7 * MS, 9 * MS + 1)] and w.last_sample_ns == 9 * MS + 1


def test_at_the_halved_rate_a_gap_counts_past_two_of_its_sample_intervals():
    w = watch(stride=2)
    w.heard_sample(10 * MS)
    w.heard_sample(13 * MS)  # three periods: shorter than two intervals of two periods
    w.heard_sample(17 * MS)  # four: not more than two intervals
    assert not w.plant_gaps
    w.heard_sample(21 * MS + 1)
    assert list(w.plant_gaps) == [(17 * MS, 21 * MS + 1)]


def test_a_request_starts_the_silence_of_each_peripheral_that_has_answered_since():
    w = watch()
    w.asked(4 * MS)  # nothing heard yet: asked now
    assert w.asked_ns == [4 * MS] * 3
    w.heard_reply(1, 5 * MS)
    w.asked(6 * MS)  # peripheral 2 answered after it was asked: asked anew; the others not
    assert w.asked_ns == [4 * MS, 6 * MS, 4 * MS]
    assert [w.silent_since(k) for k in range(3)] == [4 * MS, 6 * MS, 4 * MS]
    w.heard_reply(0, 4 * MS)  # a reply at the very time of the request: asked again
    w.asked(8 * MS)
    assert w.asked_ns[0] == 8 * MS


def test_the_limit_ends_at_its_nanosecond_and_lockstep_adds_nothing():
    w = watch()
    w.heard_sample(100 * MS)  # the plant talks: nothing shared
    assert w.fault_at(90 * MS, 93 * MS, 3 * MS) == 93 * MS  # due now, not later
    assert w.fault_at(90 * MS, 93 * MS - 1, 3 * MS) == 93 * MS
    w.own_gaps.append((91 * MS, 92 * MS))  # the central itself stalled a millisecond
    assert w.fault_at(90 * MS, 95 * MS, 3 * MS) == 94 * MS
    quiet = watch()
    quiet.heard_sample(85 * MS)  # the plant silent since 85 ms: a silence it shares
    assert quiet.fault_at(90 * MS, 93 * MS, 3 * MS) == 93 * MS  # at the limit: no more yet
    assert quiet.fault_at(90 * MS, 95 * MS, 3 * MS) == 96 * MS  # past it: 4 ms shared, <= 3
    assert quiet.silence_ends("plant", 90 * MS, 95 * MS, 3 * MS) == 93 * MS  # its own
    lock = watch(realtime=False)
    lock.own_gaps.append((91 * MS, 92 * MS))  # no stall counts outside realtime
    assert lock.fault_at(90 * MS, 95 * MS, 3 * MS) == 93 * MS
    assert lock.silence_ends("plant", 90 * MS, 95 * MS, 3 * MS) == 93 * MS
    assert w.silence_ends("plant", 90 * MS, 95 * MS, 3 * MS) == 94 * MS


def _interval(cycle: int, waiting: set[int], deadline_ns: int):
    from types import SimpleNamespace

    from ctrlunit.runtime.central.records import InFlight

    return InFlight(cycle=cycle, gen=iter(()), ctx={}, sample_ns=0, start_ns=0,
                    round=SimpleNamespace(index=1), waiting=set(waiting),
                    deadline_ns=deadline_ns)


def _fault(w: SilenceWatch, now: int, intervals, *, limit: int = 3 * MS, **kw):
    from ctrlunit.runtime.central.fault import Fault

    args = dict(done=100, plant_awaited=None, newest_sample=0, started_ns=0) | kw
    try:
        w.check(now, limit, intervals, **args)
    except Fault as exc:
        return str(exc)
    return None


def test_a_peripheral_that_never_answered_is_judged_by_its_rounds_not_as_fallen_silent():
    w = watch()
    w.heard_sample(9 * MS)
    w.asked(1 * MS)  # asked 9 ms ago, never answered: not yet the alive check's business
    assert _fault(w, 10 * MS, [_interval(5, {0}, deadline_ns=12 * MS)]) is None
    w.heard_reply(0, 2 * MS)  # once it has answered, its silence since is watched
    w.asked(3 * MS)
    assert "peripheral 1 has not answered for 7.0 ms" in _fault(
        w, 10 * MS, [_interval(5, {0}, deadline_ns=12 * MS)])


def test_every_interval_and_every_waiting_peripheral_is_looked_at():
    """An interval with nothing to wait for, or still within its limit, does not end the
    look at the ones after it; nor does an excused peripheral at the next one."""
    w = watch(realtime=False)
    overdue = _interval(7, {1}, deadline_ns=2 * MS)
    for first in (_interval(6, set(), deadline_ns=1 * MS),
                  _interval(6, {2}, deadline_ns=20 * MS)):
        assert "peripheral 2 did not answer round 1 of cycle 7: silent for 9.0 ms" in \
            _fault(w, 8 * MS, [first, overdue])


class _Roles:
    """Scripted process states and accounting (runtime/central/excuse.py, Supervision)."""

    def __init__(self, states: dict[str, str]) -> None:
        self.states = states | {"central": "sleeping"}

    def supervision(self) -> Supervision:
        from ctrlunit.runtime.roles.supervise import MachineLoad

        return Supervision(role_state=self.states.__getitem__,
                           role_times=lambda role: {1: (0, 0)},
                           machine_load=lambda: MachineLoad(0, 0))


def test_an_excused_peripheral_does_not_hide_the_next_one_and_keeps_its_silence_s_start():
    w = watch(supervision=_Roles({"peripheral-1": "runnable", "peripheral-2": "stopped",
                                  "peripheral-3": "runnable"}).supervision())
    w.heard_sample(7 * MS)
    message = _fault(w, 8 * MS, [_interval(7, {0, 1}, deadline_ns=3 * MS)])
    assert message.startswith("peripheral 2 did not answer round 1 of cycle 7")
    assert "its process was stopped" in message
    excused = w.excuse_of("peripheral-1")
    assert excused is not None and excused.since == 0 and excused.until == 2 * 3 * MS
    # the excuse renewed against its own start: 8 limits from 0, not from elsewhere
    assert _fault(w, 9 * MS, [_interval(7, {0}, deadline_ns=3 * MS)]) is None


def test_the_plant_s_silence_names_the_central_s_own_stall():
    w = watch()
    w.heard_sample(10 * MS)
    w.woke(11 * MS, 13_050_001)  # the central did not run for 2.05 ms + 1 ns
    message = _fault(w, 15_100_000, [], plant_awaited=12, newest_sample=11)
    assert message == ("no sample from the plant for 5.1 ms (cycle 12 awaited, newest seen "
                       "11, plus 2.1 ms the central itself did not run)")
    brief = watch()
    brief.heard_sample(10 * MS)
    brief.woke(8 * MS, 10 * MS + 1)  # a stall that overlaps the silence by 1 ns
    assert _fault(brief, 14 * MS, [], plant_awaited=12, newest_sample=11).endswith(
        "plus 0.0 ms the central itself did not run)")


def test_the_watch_keeps_the_eight_newest_gaps_of_each_kind():
    w = watch()
    for k in range(1, 11):  # ten gaps of the plant, ten stalls of the central
        w.heard_sample(10 * k * MS)
        w.woke(10 * k * MS, 10 * k * MS + 2 * MS)
    assert list(w.plant_gaps) == [(10 * k * MS, 10 * (k + 1) * MS) for k in range(2, 10)]
    assert list(w.own_gaps) == [(10 * k * MS, 10 * k * MS + 2 * MS) for k in range(3, 11)]


def test_a_one_second_period_is_a_billion_nanoseconds():
    w = SilenceWatch(peripherals=1, realtime=True, period_s=1.0, fault_periods=3,
                     timeout_s=2.0, stride=lambda: 1)
    w.woke(0, 1_000_000_000)  # exactly a period late: not a stall
    w.woke(5_000_000_000, 6_000_000_001)
    assert list(w.own_gaps) == [(5_000_000_000, 6_000_000_001)]


def test_a_plant_silent_from_the_start_can_be_excused_and_judged_again():
    w = watch(supervision=_Roles({"plant": "runnable"}).supervision())  # and denied its CPU
    assert _fault(w, 8 * MS, [], plant_awaited=0, started_ns=1 * MS) is None  # excused
    assert w.excuse_of("plant") is not None
    assert _fault(w, 9 * MS, [], plant_awaited=0, started_ns=1 * MS) is None  # renewed


def test_the_wake_up_for_the_plant_s_silence_counts_the_central_s_stalls():
    w = watch()
    w.heard_sample(10 * MS)
    w.woke(11 * MS, 13 * MS)  # 2 ms the central did not run, 1 ms of it before 12 ms
    assert w.wake_at(12 * MS, 3 * MS, []) == 10 * MS + 3 * MS + 1 * MS


def test_the_note_of_a_silence_the_plant_shared_states_the_part_not_counted():
    w = watch()
    for rx in (9 * MS, 13_050_001, 14 * MS):  # the plant silent 4.05 ms + 1 ns
        w.heard_sample(rx)
    message = _fault(w, 15_100_000, [_interval(7, {0}, deadline_ns=13 * MS)])
    assert message == ("peripheral 1 did not answer round 1 of cycle 7: silent for 5.1 ms "
                       "(limit 3.0 ms, plus 2.1 ms the plant was silent too)")
    brief = watch()
    for rx in (9 * MS, 11 * MS + 1, 12 * MS, 13 * MS, 14 * MS, 15 * MS):  # 1 ns shared
        brief.heard_sample(rx)
    assert _fault(brief, 15_100_000, [_interval(7, {0}, deadline_ns=13 * MS)]).endswith(
        "(limit 3.0 ms, plus 0.0 ms the plant was silent too)")


def test_a_look_at_the_inbox_without_waiting_is_no_stall_of_the_central():
    """Where something was already due, the loop looks at its inbox without sleeping: the
    time since it was due is not time the machine kept the central from running."""
    w = watch()
    w.woke(10 * MS, 15 * MS, slept_from=15 * MS - 1000)  # asked at 15 ms - 1 us, to 10 ms
    assert not w.own_gaps
    w.woke(20 * MS, 25 * MS, slept_from=19 * MS)  # slept from 19 ms, meant to wake at 20
    assert list(w.own_gaps) == [(20 * MS, 25 * MS)]
    w.woke(30 * MS, 35 * MS, slept_from=32 * MS)  # began to wait 2 ms late: 3 ms of its own
    assert list(w.own_gaps) == [(20 * MS, 25 * MS), (32 * MS, 35 * MS)]


def test_the_same_stall_is_never_counted_twice():
    """Looks again and again at the same past moment count each nanosecond once: summed,
    overlapping gaps made the silence they were waiting out longer at every look."""
    w = watch()
    w.woke(10 * MS, 13 * MS)
    w.woke(10 * MS, 14 * MS)  # the same moment meant: 1 ms past the last, not a stall
    w.woke(10 * MS, 16 * MS + 1)  # counted from where the last one ended
    assert list(w.own_gaps) == [(10 * MS, 13 * MS), (13 * MS, 16 * MS + 1)]
    # the plant's silence since 0 ends later by them: from 10 ms to 16 ms, not 3 + 6 ms
    assert w.silence_ends("plant", 0, 20 * MS, 3 * MS) == 3 * MS + 6 * MS + 1


def plant_samples_on(w: SilenceWatch, until: int) -> None:
    """The plant samples every period after its last sample, the newest at ``until``."""
    t = w.last_sample_ns + MS
    while t < until:
        w.heard_sample(t)
        t += MS
    w.heard_sample(until)


def test_an_answer_ends_the_excuse_and_the_next_silence_starts_afresh():
    """The peripheral answers during its extension: its excuse is gone (and dropped, so
    that the loop's next looks do not weigh it), and a later silence is judged from its
    own limit, with a first extension of its own."""
    # runnable, and no renewal's evidence
    w = watch(supervision=_Roles({"peripheral-2": "runnable"}).supervision())
    w.heard_sample(9 * MS)
    w.heard_reply(1, 10 * MS)  # peripheral 2, waited for since
    waiting = [_interval(1, {1}, deadline_ns=10**18)]
    now = 10 * MS + 3 * MS + 1
    plant_samples_on(w, now)
    assert _fault(w, now, waiting) is None  # past its limit, runnable: excused
    assert w.excuses == 1 and "peripheral-2" in w.excuse.granted
    w.heard_reply(1, now + 1)  # it answers
    assert w.excuse_of("peripheral-2") is None
    assert "peripheral-2" not in w.excuse.granted
    now += 1 + 3 * MS + 1
    plant_samples_on(w, now)
    assert _fault(w, now, waiting) is None  # silent again past its limit: excused anew
    assert w.excuses == 2


def test_the_messages_keep_their_units_at_large_values():
    """A period of a second, 1000 of them the limit: the figures stay in milliseconds,
    to a tenth (the limits themselves: tests/test_guard.py)."""
    limit = 123_456_789_000  # 123456.789 ms

    def long_watch() -> SilenceWatch:
        return SilenceWatch(peripherals=3, realtime=True, period_s=1.0, fault_periods=1000,
                            timeout_s=600.0, stride=lambda: 1)

    w = long_watch()
    w.heard_reply(1, 5 * 10**9)
    now = 5 * 10**9 + limit + 1
    w.heard_sample(now)  # the plant goes on sampling: the peripheral alone is silent
    f = _interval(1, {1}, deadline_ns=now + 1)
    assert "for 123456.8 ms (limit 123456.8 ms)" in _fault(w, now, [f], limit=limit)
    never = long_watch()  # peripheral 2 never answered: judged by its round alone
    now = f.deadline_ns + 1
    never.heard_sample(now)
    assert "silent for 123456.8 ms (limit 123456.8 ms)" in _fault(never, now, [f], limit=limit)
    plant = long_watch()
    plant.heard_sample(1)
    assert "no sample from the plant for 123456.8 ms" in _fault(
        plant, 1 + limit + 1, [], limit=limit, plant_awaited=1)


def test_the_wake_up_is_the_end_of_a_silence_waited_for_the_plant_s_or_the_rounds():
    """Of the peripherals, those waited for count (not the others, whose silences end
    sooner), and among them only those that have spoken; then the plant's silence, the
    round's deadline, or a limit from now (the central's other reasons to wake:
    tests/test_guard.py)."""
    w = watch()
    now = 10**12
    for k, at in enumerate((now - 500, now - 300, now - 400)):
        w.heard_reply(k, at)
    w.heard_sample(now - 100)
    f = _interval(1, {1}, deadline_ns=now + 990)  # peripheral 2 is the one waited for
    timeout = 1000
    assert w.wake_at(now, timeout, [f]) == now - 300 + timeout
    w.heard_reply(1, now)
    assert w.wake_at(now, timeout, [f]) == now - 100 + timeout  # the plant
    w.heard_sample(now)
    assert w.wake_at(now, timeout, [f]) == now + 990  # the round's deadline
    f.waiting.clear()
    assert w.wake_at(now, timeout, [f]) == now + timeout
    quiet = watch()  # no process has spoken: none watched between its rounds
    f = _interval(1, {1}, deadline_ns=now + 5000)
    assert quiet.wake_at(now, timeout, [f]) == now + timeout
