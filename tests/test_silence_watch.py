"""The silence watch's bookkeeping (runtime/central/silence.py), driven directly: when a
plant's silence counts as a gap, when a request starts a peripheral's silence, and the
edge of a limit, each at its exact figure."""

from __future__ import annotations

from ctrlunit.runtime.central.silence import SilenceWatch

MS = 1_000_000


def watch(*, stride: int = 1, realtime: bool = True) -> SilenceWatch:
    return SilenceWatch(peripherals=3, realtime=realtime, period_s=1e-3, fault_periods=3,
                        timeout_s=2.0, stride=lambda: stride)


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
