"""The silence rule's arithmetic (runtime/central/silence_rule.py), each edge with its figures:
what the central's own stalls and the plant's shared silence add to a limit, and when an
excused silence gets one more limit. The rule's behaviour in a unit is
tests/test_guard.py's and tests/test_silence_rule.py's."""

from __future__ import annotations

from ctrlunit.runtime.central.silence_rule import (
    fault_at,
    overlap,
    plant_shared,
    renewal_cap,
    renewal_holds,
)

MS = 1_000_000


def test_overlap_counts_only_the_part_of_each_gap_inside_the_window():
    gaps = [(0, 10 * MS), (20 * MS, 25 * MS), (40 * MS, 60 * MS)]
    assert overlap(gaps, 5 * MS, 50 * MS) == 5 * MS + 5 * MS + 10 * MS
    assert overlap(gaps, 10 * MS, 20 * MS) == 0  # between gaps
    assert overlap(gaps, 0, 100 * MS) == 35 * MS
    assert overlap([], 0, 100 * MS) == 0
    assert overlap([(30 * MS, 35 * MS)], 40 * MS, 50 * MS) == 0  # before the window


def test_the_plant_shares_only_gaps_over_two_sample_intervals_less_one_interval():
    every = 1 * MS
    # a gap of exactly two intervals is the plant on time: nothing shared
    assert plant_shared([(10 * MS, 12 * MS)], 13 * MS, 0, 13 * MS, every_ns=every,
                        own_ns=0, limit_ns=3 * MS) == 0
    # 5 ms between samples inside the silence: 5 - 1 = 4 ms, capped at the 3 ms limit
    assert plant_shared([(10 * MS, 15 * MS)], 16 * MS, 0, 16 * MS, every_ns=every,
                        own_ns=0, limit_ns=3 * MS) == 3 * MS
    assert plant_shared([(10 * MS, 15 * MS)], 16 * MS, 0, 16 * MS, every_ns=every,
                        own_ns=0, limit_ns=10 * MS) == 4 * MS
    # only the part inside the silence: it started at 13 ms
    assert plant_shared([(10 * MS, 15 * MS)], 16 * MS, 13 * MS, 16 * MS, every_ns=every,
                        own_ns=0, limit_ns=10 * MS) == 1 * MS
    # the gap still open since the last sample counts up to now
    assert plant_shared([], 10 * MS, 0, 14 * MS, every_ns=every, own_ns=0,
                        limit_ns=10 * MS) == 3 * MS
    # the central's own stall is not counted twice; never below zero
    assert plant_shared([], 10 * MS, 0, 14 * MS, every_ns=every, own_ns=2 * MS,
                        limit_ns=10 * MS) == 1 * MS
    assert plant_shared([], 10 * MS, 0, 14 * MS, every_ns=every, own_ns=5 * MS,
                        limit_ns=10 * MS) == 0
    # no sample yet (0): that gap is not the plant's silence
    assert plant_shared([(0, 9 * MS)], 0, 0, 14 * MS, every_ns=every, own_ns=0,
                        limit_ns=10 * MS) == 0
    # at the halved rate the plant samples every 2 ms: a 4 ms gap is on time
    assert plant_shared([(10 * MS, 14 * MS)], 15 * MS, 0, 15 * MS, every_ns=2 * MS,
                        own_ns=0, limit_ns=10 * MS) == 0
    # two gaps add up
    assert plant_shared([(0 + 1, 4 * MS + 1), (10 * MS, 14 * MS)], 15 * MS, 0, 15 * MS,
                        every_ns=every, own_ns=0, limit_ns=10 * MS) == 6 * MS


def test_a_fault_comes_a_limit_after_the_silence_began_plus_what_is_not_counted():
    looked: list[int] = []

    def shared(ms: int):
        def at() -> int:
            looked.append(ms)
            return ms * MS
        return at

    assert fault_at(100 * MS, 101 * MS, 3 * MS, own_ns=0,
                    shared=shared(5)) == 103 * MS  # not yet past: the plant not looked at
    assert fault_at(100 * MS, 103 * MS, 3 * MS, own_ns=0,
                    shared=shared(5)) == 103 * MS  # at the limit exactly: not past it
    assert not looked
    assert fault_at(100 * MS, 104 * MS, 3 * MS, own_ns=0, shared=shared(5)) == 108 * MS
    assert fault_at(100 * MS, 104 * MS, 3 * MS, own_ns=2 * MS,
                    shared=shared(5)) == 105 * MS  # within limit + own stall
    assert fault_at(100 * MS, 106 * MS, 3 * MS, own_ns=2 * MS,
                    shared=shared(1)) == 106 * MS
    assert looked == [5, 1]


def test_an_excuse_is_renewed_when_half_the_window_or_more_was_kept_from_a_cpu():
    w = 3 * MS
    assert renewal_holds(w, w // 2, 0, 0, 0)  # exactly half
    assert not renewal_holds(w, w // 2 - 1, 0, 0, 0)
    assert renewal_holds(w, 0, 2 * MS, 0, 0)  # the central's Zenoh threads
    assert renewal_holds(w, 0, 0, 2 * MS, 0)  # the machine's tasks
    assert renewal_holds(w, 0, 0, 0, 2 * MS)  # a CPU the hypervisor took
    assert not renewal_holds(w, MS, MS, MS, MS)  # a third each: not half of any
    assert renewal_cap(100 * MS, 3 * MS, 8, 0) == 124 * MS  # 8 limits: 24 ms at 1 ms
    assert renewal_cap(100 * MS, 3 * MS, 8, 7 * MS) == 131 * MS
