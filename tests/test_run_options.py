"""Every option of ``ctrlunit start`` that README documents does what it says, seen in
what the run produces (lockstep runs: their commands are exact, so an option that is
ignored or wired to the wrong thing changes a digest)."""

from __future__ import annotations

import shutil
import subprocess
import sys

import pytest
from ctrlunit.kernels.laws import Gains
from ctrlunit.kernels.params import DELTA_IA as P
from ctrlunit.kernels.trajectory import pick_place_task
from ctrlunit.plant.simulator import PlantConfig
from ctrlunit.runtime.compute.controller import simulate
from ctrlunit.runtime.observe.report import command_digest
from runner import start_json, unit_id

pytestmark = pytest.mark.zenoh
CYCLES = 150


def reference_digest(**kw) -> str:
    """The in-process closed loop's commands (depth 1: the command acts one period after
    the next sample), as a digest."""
    ref = simulate(P, pick_place_task(), gains=Gains.from_bandwidth(20.0), cycles=CYCLES,
                   delay=1, **kw)
    return command_digest([x for c in ref.commands for x in c])


@pytest.mark.parametrize(("option", "value", "reference"), [
    ("--model", "simplified", {"model": "simplified"}),
    ("--observer", "previous", {"observer": "previous"}),
    ("--belt", None, {"plant_config": PlantConfig(period=1e-3, belt=True)}),
])
def test_a_model_observer_or_plant_option_gives_the_reference_of_that_option(
        tmp_path, option, value, reference):
    args = [option] if value is None else [option, value]
    code, rep, out = start_json(tmp_path, "--peripherals", "1", "--clock", "lockstep",
                                "--cycles", str(CYCLES), "--max-error", "1",
                                "--placement", "axes", *args,
                                tag=option.strip("-"))
    assert code == 0, out
    assert rep["command_digest"] == reference_digest(**reference)
    assert rep["command_digest"] != reference_digest()  # the option changed the commands
    if option == "--observer":  # two Newton-Raphson iterations: one more round trip
        assert rep["observer"] == "previous" and rep["round_trips"] == 3
    if option == "--model":
        assert rep["model"] == "simplified"


@pytest.mark.parametrize("mode", ["fused", "each"])
def test_replies_fused_answer_once_an_interval_and_each_once_a_round(tmp_path, mode):
    """Depth 2, freerun: with fused replies a peripheral answers each interval's fused
    request once; with each, once per round (the thesis's placement, two rounds: twice)."""
    code, rep, out = start_json(tmp_path, "--peripherals", "1", "--pipeline", "2", "--clock",
                                "freerun", "--cycles", "300", "--replies", mode,
                                "--placement", "axes", tag=mode)
    assert code == 0, out
    assert rep["replies"]["mode"] == mode
    per_interval = rep["central_costs_s"]["replies_per_interval"]  # n = 1: per peripheral
    print(f"--replies {mode}: {per_interval:.2f} replies per interval and peripheral, "
          f"{rep['exchanges_per_interval']:.2f} exchanges per interval")
    assert per_interval == pytest.approx(1.0 if mode == "fused" else 2.0, abs=0.05)


@pytest.mark.skipif(shutil.which("setpriv") is None, reason="needs util-linux's setpriv")
def test_rt_priority_without_the_right_to_it_is_refused_before_anything_starts(tmp_path):
    """SCHED_FIFO asked for by a process that may not use it (CAP_SYS_NICE dropped from
    its bounding set, real-time limit 0): exit 1 (configuration), a message that says what
    is needed, and no role started."""
    unit = unit_id("rt-refused")
    res = subprocess.run(
        ["setpriv", "--bounding-set", "-sys_nice", "--inh-caps", "-sys_nice", "--",
         "prlimit", "--rtprio=0", "--", sys.executable, "-m", "ctrlunit.runtime.cli",
         "start", "--rt-priority", "10", "--clock", "lockstep", "--cycles", "10",
         "--peripherals", "1", "--unit", unit],
        capture_output=True, text=True, timeout=60)
    if "setpriv:" in res.stderr or "prlimit:" in res.stderr:
        pytest.skip(f"cannot drop the right here: {res.stderr.strip()}")
    assert res.returncode == 1, res.stdout + res.stderr
    assert "--rt-priority 10: this process may not use SCHED_FIFO" in res.stderr + res.stdout
    assert "ulimit -r" in res.stderr + res.stdout
    assert "cycles" not in res.stdout  # no report: nothing ran


def test_the_heap_is_frozen_for_the_run_and_released_after_it(monkeypatch):
    """The set-up's objects are out of the collector's reach while the unit runs (a full
    collection took longer than a period), and a process that hosts runs (bench, tests)
    gets them back afterwards; the commands are those of the reference."""
    import gc

    from ctrlunit.runtime.central import Central
    from ctrlunit.runtime.config import RunConfig
    from ctrlunit.runtime.launch.launcher import start

    frozen: list[int] = []
    run = Central.run

    def run_seen(self):
        frozen.append(gc.get_freeze_count())
        return run(self)

    monkeypatch.setattr(Central, "run", run_seen)
    rc = RunConfig.of(peripherals=1, pipeline=1, clock="lockstep", cycles=CYCLES,
                      unit=unit_id("freeze"))
    code, rep = start(rc, echo=lambda m: None)
    assert code == 0, rep.get("fault")
    assert frozen and frozen[0] > 1000  # the set-up: tens of thousands of objects
    assert gc.get_freeze_count() == 0
    assert rep["command_digest"] == reference_digest()
