"""``--idle``: the CPU latency request that keeps idle CPUs polling (runtime/host/idle.py)."""

from __future__ import annotations

import os
import time
from pathlib import Path

import pytest
from ctrlunit.runtime.config import ConfigError, RunConfig
from ctrlunit.runtime.host import idle


def _cpuidle(tmp_path: Path, states: list[tuple[str, int, int]]) -> Path:
    """A fake ``cpuidle`` directory: (name, exit latency in us, disabled) per state."""
    root = tmp_path / "cpuidle"
    for k, (name, latency, disabled) in enumerate(states):
        d = root / f"state{k}"
        d.mkdir(parents=True)
        (d / "name").write_text(name + "\n")
        (d / "latency").write_text(f"{latency}\n")
        (d / "disable").write_text(f"{disabled}\n")
    root.mkdir(parents=True, exist_ok=True)
    return root


def _open_fds(under: Path) -> int:
    """This process's open files under ``under`` (others, such as a collected subprocess
    pipe of an earlier test, may come and go meanwhile)."""
    count = 0
    for fd in os.listdir("/proc/self/fd"):
        try:
            count += os.readlink(f"/proc/self/fd/{fd}").startswith(str(under))
        except OSError:
            continue
    return count


def test_auto_polls_only_in_realtime_where_a_deeper_state_exists_and_the_file_is_writable(
        tmp_path):
    dev = tmp_path / "cpu_dma_latency"
    dev.write_bytes(b"")
    halt = _cpuidle(tmp_path, [("POLL", 0, 0), ("haltpoll idle", 1, 0)])
    hold, why = idle.choose("auto", clock="realtime", dev=dev, cpuidle=halt)
    assert hold and "haltpoll idle" in why
    for clock in ("lockstep", "freerun"):
        hold, why = idle.choose("auto", clock=clock, dev=dev, cpuidle=halt)
        assert not hold and f"the {clock} clock" in why
    # only the polling state, or the deeper one disabled: a request changes nothing
    for states in ([("POLL", 0, 0)], [("POLL", 0, 0), ("C1", 2, 1)], []):
        poll_only = _cpuidle(tmp_path / str(len(states)) / str(sum(s[2] for s in states)),
                             states)
        hold, why = idle.choose("auto", clock="realtime", dev=dev, cpuidle=poll_only)
        assert not hold and "no idle state deeper than polling" in why
    missing = tmp_path / "no" / "cpu_dma_latency"
    hold, why = idle.choose("auto", clock="realtime", dev=missing, cpuidle=halt)
    assert not hold and str(missing) in why
    # the others as asked, whatever the clock
    assert idle.choose("poll", clock="lockstep", dev=missing, cpuidle=halt)[0]
    assert not idle.choose("default", clock="realtime", dev=dev, cpuidle=halt)[0]


def test_the_request_writes_zero_microseconds_and_ends_with_the_block(tmp_path):
    dev = tmp_path / "cpu_dma_latency"
    dev.write_bytes(b"")
    halt = _cpuidle(tmp_path, [("POLL", 0, 0), ("C1", 5, 0)])
    before = _open_fds(tmp_path)
    with idle.idle_request("auto", clock="realtime", dev=dev, cpuidle=halt) as choice:
        assert choice == {"asked": "auto", "in_force": "poll",
                          "why": "the realtime clock: idle CPUs poll instead of entering C1"}
        assert _open_fds(tmp_path) == before + 1  # held open: the kernel keeps the request as long
        assert dev.read_bytes() == (0).to_bytes(4, "little", signed=True)
    assert _open_fds(tmp_path) == before
    # an error inside the block still ends the request
    with pytest.raises(RuntimeError), idle.idle_request("poll", clock="lockstep", dev=dev,
                                                        cpuidle=halt):
        assert _open_fds(tmp_path) == before + 1
        raise RuntimeError("boom")
    assert _open_fds(tmp_path) == before
    with idle.idle_request("default", clock="realtime", dev=dev, cpuidle=halt) as choice:
        assert choice["in_force"] == "default" and _open_fds(tmp_path) == before


def test_poll_asked_where_the_request_cannot_be_made_is_an_error_naming_the_file(tmp_path):
    missing = tmp_path / "no" / "cpu_dma_latency"
    halt = _cpuidle(tmp_path, [("POLL", 0, 0), ("C1", 5, 0)])
    before = _open_fds(tmp_path)
    with pytest.raises(idle.IdlePermissionError, match=r"--idle poll: .*no/cpu_dma_latency "
                       r"cannot be written .*--idle default"), \
            idle.idle_request("poll", clock="realtime", dev=missing, cpuidle=halt):
        pass
    # auto where the file turns out not writable: the CPUs as they are, and why
    directory = tmp_path / "a-directory"
    directory.mkdir()
    with idle.idle_request("auto", clock="realtime", dev=directory, cpuidle=halt) as choice:
        assert choice["in_force"] == "default" and "could not be written" in choice["why"]
    assert _open_fds(tmp_path) == before


def test_a_value_other_than_auto_poll_or_default_is_refused_naming_the_option():
    with pytest.raises(ValueError, match=r"--idle = 'spin': allowed auto .*, poll or default"):
        idle.check_idle("spin")
    with pytest.raises(ConfigError, match="--idle = 'spin'"):
        RunConfig.of(idle="spin").validate()
    assert RunConfig.of().schedule.idle == "auto"


def _usage(name_filter: str) -> int:
    """Entries into the idle states of every CPU whose exit latency is (not) zero."""
    total = 0
    for state in Path("/sys/devices/system/cpu").glob("cpu[0-9]*/cpuidle/state[0-9]*"):
        zero = int((state / "latency").read_text()) == 0
        if zero == (name_filter == "poll"):
            total += int((state / "usage").read_text())
    return total


@pytest.mark.skipif(not idle.choose("auto", clock="realtime")[0],
                    reason="no idle state deeper than polling here, or not root")
def test_under_the_request_the_machines_cpus_enter_no_deeper_idle_state():
    """The real kernel: while the request is held no CPU enters a state with an exit
    latency, and the polling state is used instead; afterwards the deeper ones again."""
    with idle.idle_request("auto", clock="realtime") as choice:
        assert choice["in_force"] == "poll"
        time.sleep(0.05)  # a CPU already in a deeper state leaves it at its next wake-up
        deep, poll = _usage("deep"), _usage("poll")
        for _ in range(30):  # idle CPUs, woken by this sleep and the kernel's own work
            time.sleep(0.01)
        deep_held, poll_held = _usage("deep") - deep, _usage("poll") - poll
    deep = _usage("deep")
    for _ in range(300):  # until a CPU goes deeper again (3 s at most: a busy host may
        time.sleep(0.01)  # keep both CPUs from idling for a while)
        if _usage("deep") - deep > deep_held:
            break
    deep_after = _usage("deep") - deep
    assert deep_held <= 1 and poll_held > 0
    assert deep_after > deep_held


def _holds_request(pid: int) -> bool:
    """Whether process ``pid`` has the kernel's CPU latency request open."""
    try:
        fds = os.listdir(f"/proc/{pid}/fd")
    except OSError:
        return False
    for fd in fds:
        try:
            if os.readlink(f"/proc/{pid}/fd/{fd}") == str(idle.CPU_LATENCY_DEV):
                return True
        except OSError:
            continue
    return False


@pytest.mark.skipif(not idle.choose("auto", clock="realtime")[0],
                    reason="no idle state deeper than polling here, or not root")
def test_a_role_started_on_its_own_holds_the_request_for_its_host_while_it_runs():
    """``ctrlunit plant`` started apart (on another host, say) holds the request there
    under the unit's ``--idle auto`` in realtime, and not under ``--idle default``: it takes
    the setting from the central at its handshake (runtime/config/handed.py)."""
    import subprocess
    import sys

    from runner import kill_unit, unit_id
    from test_fuzz import free_port

    seen: dict[str, bool] = {}
    waited = 0.0
    py = [sys.executable, "-m", "ctrlunit.runtime.cli"]
    for asked in ("auto", "default"):
        unit, endpoint = unit_id(f"idle-{asked}"), f"tcp/127.0.0.1:{free_port()}"
        procs = [subprocess.Popen(
            [*py, "central", "--unit", unit, "--listen", endpoint, "--clock", "realtime",
             "--peripherals", "0", "--duration", "60s", "--idle", asked,
             "--insecure"],  # a loopback port: the link rule is not this test's subject
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)]
        procs.append(subprocess.Popen([*py, "plant", "--unit", unit, "--connect", endpoint,
                                       "--insecure"],
                                      stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
        plant = procs[1]
        try:
            t0 = time.monotonic()
            # auto: until the plant holds it (bounded); default: at least as long as that took
            limit = 30.0 if asked == "auto" else waited + 1.0
            while time.monotonic() - t0 < limit and plant.poll() is None:
                if _holds_request(plant.pid):
                    break
                time.sleep(0.05)
            seen[asked] = _holds_request(plant.pid)
            waited = time.monotonic() - t0
        finally:
            for p in procs:
                p.kill()
                p.wait(timeout=10)
            kill_unit(unit)
    assert seen == {"auto": True, "default": False}


def test_start_with_poll_where_the_request_cannot_be_made_refuses_before_any_role(
        tmp_path, monkeypatch):
    """The launcher's error is a configuration error naming the file; no role started."""
    from ctrlunit.runtime.config import EXIT_CONFIG
    from ctrlunit.runtime.launch import launcher, unit_start

    monkeypatch.setattr(idle, "CPU_LATENCY_DEV", tmp_path / "no" / "cpu_dma_latency")
    spawned: list[str] = []
    monkeypatch.setattr(unit_start, "spawn_role", lambda *a, **k: spawned.append(a[1]))
    code, rep = launcher.start(RunConfig.of(peripherals=1, clock="lockstep", cycles=10,
                                            idle="poll").validate(), echo=lambda m: None)
    assert code == EXIT_CONFIG and spawned == []
    assert rep["fault"]["process"] == "configuration"
    assert "--idle poll: " in rep["fault"]["message"]
    assert "no/cpu_dma_latency cannot be written" in rep["fault"]["message"]


def test_the_command_line_refuses_an_unknown_idle_choice_naming_the_allowed_ones():
    from runner import ctrlunit

    res = ctrlunit("start", "--idle", "spin", "--check", timeout=60)
    assert res.returncode == 1  # a value refused, as in --set (docs/faults-and-errors.md)
    assert res.stderr.startswith("ctrlunit: error: ")
    assert "'spin' is not one of 'auto', 'poll', 'default'" in res.stderr
