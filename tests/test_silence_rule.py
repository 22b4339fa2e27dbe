"""When silence is a fault (runtime/central/silence.py, ``SilenceWatch.fault_at``): a
process silent for the limit is failed while the plant goes on talking; the part of a
silence the plant's samples shared (a stall of the whole machine) is not counted, up to
one more limit; lockstep and freerun keep their plain timeout."""

from __future__ import annotations

import pytest
from ctrlunit.runtime.central.silence import SilenceWatch

MS = 1_000_000
PERIOD = 4 * MS
LIMIT = 3 * PERIOD


class Guard(SilenceWatch):
    """The silence watch of a unit at ``PERIOD``, ``LIMIT`` in lockstep and freerun;
    ``stride`` is the control rate's divisor (2 once the rate is halved)."""

    def __init__(self, clock: str = "realtime") -> None:
        self.divisor = 1
        super().__init__(peripherals=3, realtime=clock == "realtime", period_s=PERIOD / 1e9,
                         fault_periods=3, timeout_s=LIMIT / 1e9, stride=lambda: self.divisor)


def test_before_the_limit_and_without_a_plant_silence_the_limit_stands():
    g = Guard()
    g.last_sample_ns = 100 * MS
    assert g.fault_at(90 * MS, 95 * MS, LIMIT) == 90 * MS + LIMIT  # not yet due
    # the plant sampled a period ago: the peripheral alone was silent
    assert g.fault_at(90 * MS, 103 * MS, LIMIT) == 90 * MS + LIMIT


def test_the_plant_silent_too_moves_the_fault_by_the_shared_part_up_to_one_limit():
    g = Guard()
    g.last_sample_ns = 89 * MS  # the plant's last sample before the stall
    since, now = 90 * MS, 103 * MS
    # shared: 13 ms of the silence without a sample, less the period one takes anyway
    assert g.fault_at(since, now, LIMIT) == since + LIMIT + (now - since - PERIOD)
    # a long stall: at most one more limit
    assert g.fault_at(since, 200 * MS, LIMIT) == since + 2 * LIMIT
    # a gap of two periods or less is the plant's own jitter, not a stall
    g.last_sample_ns = 102 * MS - 2 * PERIOD + 1
    assert g.fault_at(since, 102 * MS, LIMIT) == since + LIMIT


def test_a_past_plant_gap_counts_only_where_it_overlaps_the_silence():
    g = Guard()
    g.plant_gaps.append((80 * MS, 97 * MS))  # the plant silent 80-97 ms, then talking
    g.last_sample_ns = 101 * MS
    since, now = 90 * MS, 103 * MS
    assert g.fault_at(since, now, LIMIT) == since + LIMIT + (97 - 90) * MS - PERIOD
    g.plant_gaps.clear()
    g.plant_gaps.append((60 * MS, 85 * MS))  # ended before the silence began
    assert g.fault_at(since, now, LIMIT) == since + LIMIT


@pytest.mark.parametrize("clock", ["lockstep", "freerun"])
def test_lockstep_and_freerun_keep_the_plain_timeout(clock):
    g = Guard(clock)
    g.last_sample_ns = 10 * MS
    assert g.fault_at(90 * MS, 500 * MS, LIMIT) == 90 * MS + LIMIT


def test_a_fault_message_says_what_was_not_counted():
    g = Guard()
    g.last_sample_ns = 89 * MS
    assert g.shared_note(90 * MS, 103 * MS, LIMIT) == ", plus 9.0 ms the plant was silent too"
    g.last_sample_ns = 102 * MS
    assert g.shared_note(90 * MS, 103 * MS, LIMIT) == ""


def test_at_the_halved_rate_the_plant_samples_every_two_periods_and_that_is_no_stall():
    """Once the control rate is halved the plant publishes every second sample: a gap of
    two periods is its rhythm, not a stall the central shares; the limit doubles too."""
    g = Guard()
    g.divisor = 2
    assert g.limit_ns(1000) == 2 * LIMIT
    # the plant's last sample 3 periods before now, the silence long past its limit
    g.last_sample_ns, since, now = 91 * MS, 60 * MS, 91 * MS + 3 * PERIOD
    assert g.fault_at(since, now, 2 * LIMIT) == since + 2 * LIMIT  # nothing shared
    g.divisor = 1  # at the full rate the same gap was a stall the plant shared
    assert g.fault_at(since, now, 2 * LIMIT) == since + 2 * LIMIT + 3 * PERIOD - PERIOD


def test_the_time_the_central_itself_did_not_run_is_not_counted_at_all():
    """A stall of the central (it woke long after it meant to) hides every other process:
    that part of a silence is not counted, however long, on top of the plant's shared
    part (beyond what the central's stall explains); a stall before the silence began
    does not count."""
    g = Guard()
    g.last_sample_ns = 130 * MS  # the plant samples again after the stall
    since, now = 90 * MS, 131 * MS
    g.own_gaps.append((95 * MS, 125 * MS))  # 30 ms without the central
    assert g.fault_at(since, now, LIMIT) == since + LIMIT + 30 * MS
    # the plant silent through the same stall: nothing more than the central's stall
    g.plant_gaps.append((94 * MS, 126 * MS))
    assert g.fault_at(since, now, LIMIT) == since + LIMIT + 30 * MS
    assert g.silence_ends("plant", since, now, LIMIT) == since + LIMIT + 30 * MS
    g.own_gaps.clear()
    g.own_gaps.append((50 * MS, 80 * MS))  # over before the silence began
    g.plant_gaps.clear()
    assert g.fault_at(since, now, LIMIT) == since + LIMIT
    note = Guard()
    note.own_gaps.append((95 * MS, 125 * MS))
    note.last_sample_ns = 130 * MS
    assert note.shared_note(since, 140 * MS, LIMIT) == (
        ", plus 30.0 ms the central itself did not run")
