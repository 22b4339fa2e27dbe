"""What the central reads of the processes it started (runtime/roles/supervise.py): their state
and their threads' scheduler accounting, on which the silence rule's excuse rests."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import threading
import time

import pytest
from ctrlunit.runtime.roles.supervise import cpu_denied, machine_load, process_state, thread_times

MS = 1_000_000


@pytest.fixture
def child():
    """Start ``python -c CODE`` children; every one is killed at the end of the test."""
    started: list[subprocess.Popen] = []

    def start(code: str) -> subprocess.Popen:
        p = subprocess.Popen([sys.executable, "-c", code])
        started.append(p)
        return p

    yield start
    for p in started:
        if p.poll() is None:
            p.kill()
        p.wait(timeout=5)


def test_a_sleeping_stopped_and_exited_process_are_told_apart(child):
    p = child("import time; time.sleep(30)")
    deadline = time.monotonic() + 5
    while process_state(p.pid) != "sleeping" and time.monotonic() < deadline:
        time.sleep(0.01)  # the interpreter starts up first
    assert process_state(p.pid) == "sleeping"
    os.kill(p.pid, signal.SIGSTOP)
    deadline = time.monotonic() + 5
    while process_state(p.pid) != "stopped" and time.monotonic() < deadline:
        time.sleep(0.01)
    assert process_state(p.pid) == "stopped"
    p.kill()
    p.wait(timeout=5)
    assert process_state(p.pid) == "exited"
    assert thread_times(p.pid) == {}


def test_a_spinning_thread_gains_cpu_time_and_a_sleeping_one_none():
    stop = threading.Event()

    def spin() -> None:
        end = time.monotonic() + 5  # bounded, whatever happens to the test
        while not stop.is_set() and time.monotonic() < end:
            pass

    sleeper = threading.Thread(target=stop.wait, args=(5,), name="sleeper")
    spinner = threading.Thread(target=spin, name="spinner")
    sleeper.start()
    spinner.start()
    try:
        before = thread_times(os.getpid())
        time.sleep(0.2)
        after = thread_times(os.getpid())
    finally:
        stop.set()
        spinner.join()
        sleeper.join()
    assert spinner.native_id in after and sleeper.native_id in after
    spun = after[spinner.native_id][0] - before[spinner.native_id][0]
    slept = after[sleeper.native_id][0] - before[sleeper.native_id][0]
    assert spun > 20 * MS  # at least a tenth of the window on a busy 2-CPU machine
    assert slept < spun / 10
    assert all(run >= 0 and wait >= 0 for run, wait in after.values())


def test_thread_times_keeps_only_the_threads_named_as_asked():
    """The kernel's name of a thread (as Zenoh's runtimes name theirs), not Python's."""
    stop = threading.Event()
    named_ready = threading.Event()

    def run() -> None:
        with open(f"/proc/self/task/{threading.get_native_id()}/comm", "w") as fh:
            fh.write("rx-7")
        named_ready.set()
        stop.wait(5)

    t = threading.Thread(target=run)
    t.start()
    try:
        assert named_ready.wait(5)
        named = thread_times(os.getpid(), threads=re.compile(r"rx-\d+"))
    finally:
        stop.set()
        t.join()
    assert list(named) == [t.native_id]


def test_denied_is_the_longest_wait_of_one_thread_not_the_sum():
    before = {1: (0, 0), 2: (0, 0)}
    after = {1: (1 * MS, 2 * MS), 2: (1 * MS, 1 * MS), 3: (0, 1 * MS)}  # 3 started meanwhile
    assert cpu_denied(before, after, window_ns=3 * MS, runnable=False) == (2 * MS, 2 * MS)


def test_a_runnable_process_that_hardly_ran_was_denied_the_rest_of_the_window():
    """A thread left on a CPU the hypervisor took neither runs nor waits in the guest's
    accounting: runnable at both looks, it was denied what it did not run."""
    before = {1: (5 * MS, 0)}
    after = {1: (5 * MS + MS // 2, 0)}
    assert cpu_denied(before, after, window_ns=3 * MS, runnable=True) == (5 * MS // 2, MS // 2)
    assert cpu_denied(before, after, window_ns=3 * MS, runnable=False) == (0, MS // 2)


def test_a_process_that_ran_the_whole_window_was_denied_nothing():
    before = {1: (0, 0)}
    after = {1: (3 * MS, 0)}
    assert cpu_denied(before, after, window_ns=3 * MS, runnable=True) == (0, 3 * MS)


def test_denied_stays_within_the_window_and_counters_never_go_back():
    before = {1: (9 * MS, 9 * MS)}
    after = {1: (1 * MS, 50 * MS)}  # a reused thread id: its counters restarted
    denied, ran = cpu_denied(before, after, window_ns=3 * MS, runnable=True)
    assert denied == 3 * MS and ran == 0



def test_an_empty_reading_is_no_evidence_of_anything():
    """The process gone or its accounting unreadable: nothing denied, even runnable."""
    assert cpu_denied({}, {}, window_ns=3 * MS, runnable=True) == (0, 0)
    assert cpu_denied({1: (0, 0)}, {}, window_ns=3 * MS, runnable=True) == (0, 0)
    assert cpu_denied({}, {1: (0, 0)}, window_ns=3 * MS, runnable=True) == (0, 0)


def test_the_machines_load_is_a_growing_pressure_total_in_ns_and_a_count_or_unknown():
    first = machine_load()
    time.sleep(0.01)
    second = machine_load()
    assert first.waiting is None or first.waiting >= 0
    if first.pressure_ns is None:  # no PSI on this kernel: no evidence, never an error
        assert second.pressure_ns is None
        return
    assert second.pressure_ns is not None and second.pressure_ns >= first.pressure_ns
    assert first.pressure_ns % 1000 == 0  # the kernel counts microseconds


def test_the_kept_pressure_file_reads_what_the_kernel_counts_now(child):
    """The pressure file stays open and is read from its start each time: the total it
    gives grows when more tasks want a CPU than the machine has (three busy children per
    CPU for 0.6 s), as the file opened anew says."""
    from ctrlunit.runtime.roles.supervise import cpu_pressure_ns

    before = cpu_pressure_ns()
    if before is None:
        pytest.skip("no CPU pressure information on this kernel")
    busy = "import time\nt = time.monotonic()\nwhile time.monotonic() - t < 0.6: pass"
    for p in [child(busy) for _ in range(3 * (os.cpu_count() or 1))]:
        p.wait(timeout=30)
    kept = cpu_pressure_ns()
    with open("/proc/pressure/cpu") as fh:
        fresh = int(fh.readline().rsplit("total=", 1)[1]) * 1000
    assert kept is not None and kept - before > 50 * MS
    assert 0 <= fresh - kept < 50 * MS  # read just after: the same count, give or take


def test_the_cpus_a_process_last_ran_on_are_its_threads_and_none_once_gone():
    """Pinned to one CPU, every thread of a process last ran there; a process gone has
    none (the steal on such a CPU renews a silence's excuse: runtime/central/excuse.py)."""
    from ctrlunit.runtime.roles.supervise import process_cpus

    cpu = min(os.sched_getaffinity(0))
    p = subprocess.Popen(["taskset", "-c", str(cpu), sys.executable, "-c",
                          "import time; time.sleep(30)"])
    try:
        deadline = time.monotonic() + 10
        while process_state(p.pid) != "sleeping" and time.monotonic() < deadline:
            time.sleep(0.01)
        assert process_cpus(p.pid) == {cpu}
    finally:
        p.kill()
        p.wait(timeout=5)
    assert process_cpus(p.pid) == set()


def test_a_role_takes_its_place_itself_so_that_it_is_started_without_a_fork(tmp_path,
                                                                            monkeypatch):
    """A peripheral started again mid-run stalled the unit 4-12 ms while Python forked
    the launcher to run a ``preexec_fn`` (docs/measurements/2026-11-29-restart-without-
    fork.md). ``spawn_role`` passes none (so Python uses vfork); the child takes its CPUs,
    ignores the terminal's Ctrl-C and hang-up and dies with its parent itself
    (runtime/host/launched.py), and ends at once when its parent is gone already."""
    from ctrlunit.runtime.host import launched
    from ctrlunit.runtime.roles import supervise

    seen: dict = {}

    class Popen:
        def __init__(self, args: list[str], **kw: object) -> None:
            seen.update(kw, args=args)

    spec = tmp_path / "spec.json"
    spec.write_text('{"run": {"unit": "u-spawn"}}')
    monkeypatch.setattr(supervise.subprocess, "Popen", Popen)
    supervise.spawn_role(spec, "peripheral", 2, "tcp/127.0.0.1:1", tmp_path / "log",
                         cpus={0})
    monkeypatch.undo()  # the subprocess module's own Popen again, for the probes below
    assert seen.get("preexec_fn") is None and seen["args"][2] == "ctrlunit.runtime.host.launched"
    assert seen["env"][launched.CPUS_ENV] == "0"
    assert seen["env"][launched.PARENT_ENV] == str(os.getpid())
    probe = ("import os, signal; from ctrlunit.runtime.host.launched import take_place; "
             "take_place(); print(sorted(os.sched_getaffinity(0)), "
             "signal.getsignal(signal.SIGINT) is signal.SIG_IGN, "
             "signal.getsignal(signal.SIGHUP) is signal.SIG_IGN, "
             "'CTRLUNIT_CPUS' in os.environ)")
    env = os.environ | {launched.CPUS_ENV: "0", launched.PARENT_ENV: str(os.getpid())}
    res = subprocess.run([sys.executable, "-c", probe], env=env, capture_output=True,
                         text=True, timeout=60)
    assert res.returncode == 0 and res.stdout.split() == ["[0]", "True", "True", "False"], (
        res.stdout, res.stderr)
    env[launched.PARENT_ENV] = "1"  # not this child's parent: the launcher is gone
    res = subprocess.run([sys.executable, "-c", probe], env=env, capture_output=True,
                         text=True, timeout=60)
    assert res.returncode == 1 and "the launcher ended before this role started" in res.stderr
