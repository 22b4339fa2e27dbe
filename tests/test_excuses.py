"""The excuse of a silence, part by part (runtime/central/excuse.py): what ``Excuses.ask``
grants and records, when ``_renew`` extends it (through ``ask``), when an excuse ends
(``of``) and what a fault's message says of it (``note``), against a scripted machine
whose accounting the test sets to the nanosecond."""

from __future__ import annotations

import os

import pytest
from ctrlunit.runtime.central.excuse import EXCUSED_LIMITS, Excuses, Supervision
from ctrlunit.runtime.roles.supervise import MachineLoad

MS = 1_000_000
LIMIT = 3 * MS


class Machine:
    """What the central reads of its roles' processes, set by the test; every reading of
    the machine's load is counted, and its CPU pressure moves on by ``pressure_step`` at
    each."""

    def __init__(self) -> None:
        self.state = {"peripheral-1": "runnable", "plant": "sleeping", "central": "sleeping"}
        self.times = {"peripheral-1": {11: (0, 0)}, "plant": {21: (0, 0)},
                      "central": {31: (0, 0)}}
        self.pressure: int | None = 0
        self.pressure_step = 0
        self.waiting: int | None = 0
        self.stolen: list[float] | None = [0.0, 0.0]
        self.cpus: dict[str, set[int]] = {"plant": {1}}
        self.load_reads = 0
        self.stalls: list[tuple[int, int]] = []
        self.own = 0

    def load(self) -> MachineLoad:
        self.load_reads += 1
        if self.pressure is not None:
            self.pressure += self.pressure_step
        stolen = list(self.stolen) if self.stolen is not None else None
        return MachineLoad(self.pressure, self.waiting, stolen)

    def excuses(self, *, times: bool = True) -> Excuses:
        sup = Supervision(last_cpus=lambda r: self.cpus.get(r, set()),
                          role_state=lambda r: self.state[r],
                          role_times=(lambda r: dict(self.times[r])) if times else None,
                          machine_load=self.load)
        return Excuses(sup, own_stall=self.own_stall)

    def own_stall(self, since: int, now: int) -> int:
        self.stalls.append((since, now))
        return self.own


def grant(m: Machine, ex: Excuses, role: str = "peripheral-1", *, since: int = 0,
          now: int = 4 * MS) -> bool:
    return ex.ask(role, since, now, LIMIT, answered=since - 1, limit_end=lambda: since + LIMIT)


def test_a_grant_records_the_silence_its_end_and_the_accounting_read_once():
    m = Machine()
    m.pressure_step = 5
    ex = m.excuses()
    assert grant(m, ex, since=1000, now=4 * MS)
    e = ex.granted["peripheral-1"]
    assert (e.since, e.until, e.at, e.renewals, e.seen) == (1000, 1000 + 2 * LIMIT, 4 * MS,
                                                             0, None)
    # the machine's load read once: the pressure recorded is the one the grant judged by
    assert m.load_reads == 1 and e.times == ({11: (0, 0)}, {31: (0, 0)}, 5, [0.0, 0.0])
    assert e.runnable is True and ex.count == 1


@pytest.mark.parametrize("role, state, central, waiting, granted", [
    ("peripheral-1", "runnable", "sleeping", 0, True),
    ("peripheral-1", "sleeping", "runnable", 0, True),  # what it was sent waits for a CPU
    ("peripheral-1", "sleeping", "sleeping", 1, True),  # more runnable tasks than CPUs
    ("peripheral-1", "sleeping", "sleeping", 0, False),  # nothing in transit: no excuse
    ("plant", "sleeping", "sleeping", 0, True),  # a timer not served yet
    ("peripheral-1", "stopped", "runnable", 3, False),
    ("plant", "exited", "runnable", 3, False),
])
def test_a_grant_and_whether_the_process_was_runnable(role, state, central, waiting,
                                                      granted):
    m = Machine()
    m.state |= {role: state, "central": central}
    m.waiting = waiting
    ex = m.excuses()
    assert grant(m, ex, role) is granted
    if granted:
        assert ex.granted[role].runnable is (state == "runnable")
    else:
        assert role not in ex.granted and ex.count == 0


def test_an_excuse_lasts_while_the_role_has_not_answered_since():
    m = Machine()
    ex = m.excuses()
    assert grant(m, ex, since=0, now=4 * MS)
    at = ex.granted["peripheral-1"].at
    assert ex.of("peripheral-1", at - 1) is not None  # answered before it was granted
    assert ex.of("peripheral-1", at) is None  # an answer at its instant ends it
    assert "peripheral-1" not in ex.granted and ex.of("peripheral-1", 0) is None


def renew(m: Machine, ex: Excuses, now: int) -> bool:
    return ex.ask("peripheral-1", 0, now, LIMIT, answered=-1, limit_end=lambda: LIMIT)


def test_a_runnable_process_that_got_little_cpu_is_renewed_with_what_was_seen():
    m = Machine()
    ex = m.excuses()
    assert grant(m, ex, now=4 * MS)
    # runnable at both ends, 1 ms of CPU in a 3 ms window, no runqueue wait recorded: a
    # CPU the hypervisor took; 2 ms denied
    m.times["peripheral-1"] = {11: (1 * MS, 0)}
    m.pressure = 400
    assert renew(m, ex, 7 * MS)
    e = ex.granted["peripheral-1"]
    assert e.seen == (3 * MS, 2 * MS, 1 * MS, 400, 0)
    assert (e.at, e.until, e.renewals, e.runnable) == (7 * MS, 10 * MS, 1, True)
    assert e.times == ({11: (1 * MS, 0)}, {31: (0, 0)}, 400, [0.0, 0.0])
    assert m.stalls == [(0, 7 * MS)] and ex.count == 2


def test_a_process_asleep_now_is_judged_by_its_waits_alone():
    m = Machine()
    ex = m.excuses()
    assert grant(m, ex, now=4 * MS)
    m.state["peripheral-1"] = "sleeping"  # was runnable: CPU not got is no evidence now
    m.times["peripheral-1"] = {11: (1 * MS, 0)}
    assert not renew(m, ex, 7 * MS)
    assert ex.granted["peripheral-1"].seen == (3 * MS, 0, 1 * MS, 0, 0)
    m.times["peripheral-1"] = {11: (1 * MS, 2 * MS)}  # but a 2 ms runqueue wait is
    assert renew(m, ex, 7 * MS)
    assert ex.granted["peripheral-1"].runnable is False


def test_without_pressure_readings_nothing_waited():
    m = Machine()
    m.pressure = None
    ex = m.excuses()
    assert grant(m, ex, now=4 * MS)
    m.times["peripheral-1"] = {11: (1 * MS, 0)}
    assert renew(m, ex, 7 * MS)
    assert ex.granted["peripheral-1"].seen[3] == 0


def test_pressure_read_for_the_first_time_at_a_renewal_is_no_evidence():
    m = Machine()
    m.pressure = None
    ex = m.excuses()
    assert grant(m, ex, now=4 * MS)
    m.pressure = 10 * MS
    m.state["peripheral-1"] = "sleeping"
    assert not renew(m, ex, 7 * MS)
    assert ex.granted["peripheral-1"].seen == (3 * MS, 0, 0, 0, 0)


def test_an_unchanged_pressure_is_no_wait():
    m = Machine()
    m.pressure = 5 * MS
    ex = m.excuses()
    assert grant(m, ex, now=4 * MS)
    m.times["peripheral-1"] = {11: (3 * MS, 0)}  # ran the whole window
    assert not renew(m, ex, 7 * MS)
    assert ex.granted["peripheral-1"].seen == (3 * MS, 0, 3 * MS, 0, 0)


def test_the_renewals_stop_at_the_cap_which_the_central_s_own_stalls_extend():
    m = Machine()
    m.own = 2 * MS
    ex = m.excuses()
    assert grant(m, ex, now=4 * MS)
    cap = EXCUSED_LIMITS * LIMIT + m.own
    m.times["peripheral-1"] = {11: (0, 0)}  # runnable, no CPU at all: denied all along
    assert renew(m, ex, cap - 1)
    assert ex.granted["peripheral-1"].until == cap  # no later than the cap
    assert not renew(m, ex, cap)  # at the cap exactly: a fault
    assert m.stalls[-1] == (0, cap)


def test_the_fault_s_note_states_the_last_window_to_a_tenth_of_a_millisecond():
    m = Machine()
    ex = m.excuses()
    assert grant(m, ex, now=4 * MS)
    assert ex.note("peripheral-1", -1) == ("; its process was runnable (after one "
                                           "extension of its limit)")
    # every figure 1 ns past a twentieth of a millisecond: a 1 ppm error in a unit would
    # round it down
    window = 12_350_001
    m.times["peripheral-1"] = {11: (2_350_001, 10_050_001)}  # waited past window - ran
    m.times["central"] = {31: (0, 0)}
    m.pressure = 4_350_001
    assert renew(m, ex, 4 * MS + window)
    assert ex.note("peripheral-1", -1) == (
        "; its process was runnable (after 2 extensions of its limit; in the last 12.4 ms "
        "it was kept from a CPU 10.1 ms and ran 2.4 ms, and tasks waited for a CPU 4.4 ms)")
    m.state["peripheral-1"] = "stopped"
    assert ex.note("peripheral-1", 4 * MS + window) == "; its process was stopped"


def test_a_central_that_cannot_read_its_roles_grants_nothing_and_notes_nothing():
    ex = Excuses(Supervision(), own_stall=lambda since, now: 0)
    assert not ex.ask("plant", 0, 4 * MS, LIMIT, answered=-1, limit_end=lambda: LIMIT)
    assert ex.note("plant", -1) == ""
    m = Machine()
    ex = m.excuses(times=False)  # states readable, accounting not: one limit, no more
    assert grant(m, ex, now=4 * MS)
    assert ex.granted["peripheral-1"].times is None
    assert not renew(m, ex, 7 * MS)


# -- the first excuse from the pressure since the silence began ------------------------


def test_a_sleeping_peripheral_is_excused_when_tasks_waited_since_its_silence_began():
    """A burst of another real-time task held what was in transit and ended before the
    central looked: at that instant nothing is runnable, but the machine's pressure since
    the last note before the silence shows the wait (docs/measurements/
    2026-11-27-starvation.md)."""
    from ctrlunit.runtime.central.excuse import FIRST_PRESSURE_SHARE, MARK_EVERY_NS

    m = Machine()
    m.state |= {"peripheral-1": "sleeping", "central": "sleeping"}
    ex = m.excuses()
    ex.mark(0, read=lambda: 1_000 * MS)
    ex.mark(MARK_EVERY_NS - 1, read=lambda: 0)  # too soon after the last note: not noted
    assert ex.marks == type(ex.marks)([(0, 1_000 * MS)])
    since, now = MS, 9 * MS
    m.pressure = 1_000 * MS + int(FIRST_PRESSURE_SHARE * now) - 1  # a hair under the share
    assert not grant(m, ex, since=since, now=now)
    m.pressure += 1
    assert grant(m, ex, since=since, now=now)
    assert ex.granted["peripheral-1"].runnable is False


def test_no_note_before_the_silence_or_no_pressure_is_no_evidence():
    m = Machine()
    m.state |= {"peripheral-1": "sleeping", "central": "sleeping"}
    ex = m.excuses()
    ex.mark(5 * MS, read=lambda: 0)  # noted after the silence began
    m.pressure = 100 * MS
    assert not grant(m, ex, since=MS, now=9 * MS)
    ex.mark(8 * MS, read=lambda: None)  # the kernel keeps no pressure: nothing noted
    assert list(ex.marks) == [(5 * MS, 0)]
    unsupervised = Excuses(Supervision(), own_stall=lambda since, now: 0)
    unsupervised.mark(0, read=lambda: 0)
    assert not unsupervised.marks  # roles not started here: nothing read


def test_a_tick_of_steal_on_the_silent_process_s_cpu_renews_its_excuse():
    """The plant asleep at its excuse, runnable at its end, had run nothing and waited
    0.7 ms in it (CI, 2026-11-28: a fault): a tick of steal counted on the CPU it last ran
    on is the machine's doing. A tick on another CPU, steal the kernel does not count, or
    readings that do not match are no evidence."""
    tick = 1 / os.sysconf("SC_CLK_TCK")
    for stolen_then, stolen_now, renewed in (([0.5, 0.5], [0.5, 0.5 + tick], True),
                                             ([0.5, 0.5], [0.5 + 3 * tick, 0.5], False),
                                             ([0.5, 0.5], [0.5, 0.5], False),
                                             (None, [0.0, 0.51], False),
                                             ([0.5], [0.0, 0.51], False)):
        m = Machine()
        m.stolen = stolen_then
        ex = m.excuses()
        assert ex.ask("plant", 0, 4 * MS, LIMIT, answered=-1, limit_end=lambda: LIMIT)
        m.state["plant"] = "runnable"
        m.times["plant"] = {21: (0, 7 * MS // 10)}
        m.stolen = stolen_now
        assert ex.ask("plant", 0, 7 * MS, LIMIT, answered=-1,
                      limit_end=lambda: LIMIT) is renewed
        seen = ex.granted["plant"].seen
        assert seen is not None and seen[4] == (1 if renewed else 0)
        note = ex.note("plant", -1)
        assert ("the hypervisor's steal counter moved 1 tick(s) of 10 ms on the CPU it "
                "last ran on" in note) is renewed, note
