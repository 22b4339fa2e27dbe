"""The unit's own CPU time per CPU (runtime/host/unit_load.py): what the busy guard and
the admission judge under SCHED_FIFO, since the kernel throttles real-time time only."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from types import SimpleNamespace

import pytest
from ctrlunit.runtime.host import sched
from ctrlunit.runtime.host.busy_guard import BusyGuard
from ctrlunit.runtime.host.unit_load import UnitLoad, thread_cpus


def scripted(readings: list[dict[int, tuple[int, int]]], cpus: int = 2) -> UnitLoad:
    clock = iter(float(i) for i in range(100))
    it = iter(readings)
    return UnitLoad(lambda: [1], cpus=cpus, read=lambda pids: next(it),
                    clock=lambda: next(clock))


ZERO, ONE, BOTH = frozenset({0}), frozenset({1}), frozenset({0, 1})


def test_a_pinned_threads_time_goes_to_its_cpu_and_any_others_is_spread():
    load = scripted([{10: (ZERO, 5_000_000_000), 11: (BOTH, 0)},  # the first: a baseline
                     {10: (ZERO, 5_600_000_000), 11: (BOTH, 200_000_000)},
                     {10: (ZERO, 5_900_000_000), 11: (BOTH, 400_000_000),
                      12: (ONE, 100_000_000)}])  # 12 started after the last reading
    first = load.sample()
    assert first == [(0.0, 0.0), (0.0, 0.0)]
    second = load.sample()
    assert second == [(pytest.approx(0.7), 1.0), (pytest.approx(0.1), 1.0)]
    third = load.sample()
    assert third == [(pytest.approx(1.1), 2.0), (pytest.approx(0.3), 2.0)]
    assert load.cpu_times() is third
    # the busiest CPU's share of the unit's time between two readings
    assert sched.busy_share(second, third) == pytest.approx(0.4)


def test_a_thread_on_cpus_out_of_range_or_gone_is_not_charged():
    load = scripted([{10: (frozenset({7}), 0)}, {10: (frozenset({7}), 10**9)}, {}])
    load.sample()
    assert load.sample() == [(0.0, 1.0), (0.0, 1.0)]
    assert load.sample() == [(0.0, 2.0), (0.0, 2.0)]


def newer(load: UnitLoad, than: list | None = None) -> list:
    """The reading process's next reading after ``than`` (bounded: 5 s)."""
    end = time.monotonic() + 5
    while time.monotonic() < end:
        got = load.cpu_times()
        if got and (than is None or got[0][1] > than[0][1]):
            return got
        time.sleep(0.02)
    raise AssertionError("no reading from the reading process")


def test_other_programs_time_is_not_the_units():
    """A process spinning beside this one keeps a CPU busy: the machine's busy share sees
    it; the unit's own (this process, asleep) does not."""
    spin = subprocess.Popen([sys.executable, "-c", "import time\nt=time.time()\n"
                             "while time.time() - t < 3: pass"])
    try:
        time.sleep(0.3)
        with UnitLoad(lambda: [os.getpid()], every_s=0.05) as load:
            newer(load)
            machine0, unit0 = sched.cpu_times(), newer(load)
            time.sleep(1.0)
            machine, unit = sched.busy_share(machine0, sched.cpu_times()), \
                sched.busy_share(unit0, newer(load, unit0))
        assert machine is not None and machine > 0.8
        assert unit is not None and unit < 0.2
    finally:
        spin.kill()
        spin.wait(timeout=5)


def test_the_unit_spinning_is_the_units():
    """A role pinned to one CPU and spinning: that CPU is the unit's, all of it."""
    cpu = min(os.sched_getaffinity(0))
    spin = subprocess.Popen([sys.executable, "-c", "import time\nt=time.time()\n"
                             "while time.time() - t < 3: pass"],
                            preexec_fn=lambda: os.sched_setaffinity(0, {cpu}))
    try:
        with UnitLoad(lambda: [spin.pid], every_s=0.05) as load:
            unit0 = newer(load, newer(load))  # the spinner's threads adopted, then a reading
            time.sleep(1.0)
            unit = sched.busy_share(unit0, newer(load, unit0))
        assert unit is not None and unit > 0.6  # one CPU, less what the host took
        assert thread_cpus([spin.pid])  # its one thread is read
    finally:
        spin.kill()
        spin.wait(timeout=5)
    assert thread_cpus([spin.pid]) == {}  # gone: nothing, no error


def test_the_guard_reading_the_units_time_leaves_fifo_alone_on_a_busy_machine():
    """The guard, fed the unit's readings (0.2 of a CPU) while the machine's CPUs are full,
    never falls back; fed the machine's, it would."""
    times = iter(float(i) * 0.5 for i in range(100))
    unit = iter([[(0.1 * i, 0.5 * i), (0.0, 0.5 * i)] for i in range(100)])
    guard = BusyGuard(lambda: [], 0.95, read=lambda: next(unit), clock=lambda: next(times))
    for cycle in range(20):
        guard(SimpleNamespace(cycle=cycle), {})
    assert guard.report() is None and guard.fifo
    full = iter([[(0.5 * i, 0.5 * i)] for i in range(100)])
    times = iter(float(i) * 0.5 for i in range(100))
    demoted: list[int] = []
    busy = BusyGuard(lambda: demoted, 0.95, read=lambda: next(full),
                     clock=lambda: next(times))
    for cycle in range(5):
        busy(None, cycle)
    assert busy.report() is not None


def test_every_s_must_be_positive():
    with pytest.raises(ValueError, match="every_s = 0: allowed more than 0 s"):
        UnitLoad(lambda: [], every_s=0)


def test_the_reading_process_adopts_a_process_without_its_past_and_ends_with_the_unit():
    """A process the reader learns of late is taken as it is then: its run time before
    is not charged to one reading (a guard would read it as a CPU over its budget)."""
    busy = subprocess.Popen([sys.executable, "-c", "import time\nt=time.time()\n"
                             "while time.time() - t < 0.8: pass\ntime.sleep(5)"])
    try:
        time.sleep(1.0)  # 0.8 s of CPU before the reader knows it
        with UnitLoad(lambda: [busy.pid], every_s=0.05) as load:
            first = newer(load)
            second = newer(load, newer(load, first))
            assert sum(b for b, _ in second) < 0.1, second  # asleep since it was adopted
            child = load._child
        assert child is not None and child.poll() is not None  # ended with the unit
    finally:
        busy.kill()
        busy.wait(timeout=5)
