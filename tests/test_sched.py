"""The unit's scheduling policy (--rt-priority): applied, inherited, refused, restored.

Each check that changes a policy runs in a child interpreter, so that pytest's own
process is never left under SCHED_FIFO."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest
from ctrlunit.runtime import sched
from ctrlunit.runtime.config import ConfigError, RunConfig
from runner import start_json


def _child(code: str) -> dict:
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=60, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_priority_outside_0_to_99_is_refused_with_the_range() -> None:
    with pytest.raises(ConfigError, match=r"--rt-priority = 120: allowed 0 .* to 99"):
        RunConfig.of(rt_priority=120).validate()
    with pytest.raises(ValueError, match="--rt-priority = -1"):
        sched.check_priority(-1)
    with pytest.raises(ValueError, match="--rt-priority = None"):
        sched.check_priority(None)  # type: ignore[arg-type]
    RunConfig.of(rt_priority=0).validate()
    RunConfig.of(rt_priority=99).validate()


def test_refused_fifo_is_an_error_that_says_what_it_needs(monkeypatch) -> None:
    def refuse(*_a: object) -> None:
        raise PermissionError(1, "Operation not permitted")

    monkeypatch.setattr(sched.os, "sched_setscheduler", refuse)
    with pytest.raises(sched.RtPermissionError, match=r"--rt-priority 20: .*ulimit -r"):
        sched.apply_rt(20)
    assert sched.apply_rt(0) == sched.policy_name()  # 0 asks for nothing


def test_policy_reaches_threads_started_later_and_is_restored() -> None:
    """Every thread (Zenoh's are started later, by the thread that opens the session)
    runs under the unit's policy; restore() puts every one back."""
    if not sched.fifo_permitted():
        pytest.skip("this process may not use SCHED_FIFO")
    got = _child(
        "import json, threading, os\n"
        "from ctrlunit.runtime import sched\n"
        "before = threading.Thread(target=threading.Event().wait, args=(5,), daemon=True)\n"
        "before.start()\n"
        "saved = sched.current()\n"
        "applied = sched.apply_rt(23)\n"
        "seen = {}\n"
        "def later():\n"
        "    seen['later'] = sched.policy_name()\n"
        "t = threading.Thread(target=later); t.start(); t.join()\n"
        "seen['before'] = sched.policy_name(before.native_id)\n"
        "sched.restore(saved)\n"
        "seen['restored'] = sched.policy_name(before.native_id)\n"
        "seen['main'] = sched.policy_name()\n"
        "print(json.dumps({'applied': applied, **seen}))")
    assert got == {"applied": "SCHED_FIFO 23", "later": "SCHED_FIFO 23",
                   "before": "SCHED_FIFO 23", "restored": "SCHED_OTHER",
                   "main": "SCHED_OTHER"}


def test_zero_leaves_a_policy_given_from_outside_alone() -> None:
    """``chrt -f 5 ctrlunit start`` keeps its policy: 0 changes nothing."""
    if not sched.fifo_permitted():
        pytest.skip("this process may not use SCHED_FIFO")
    got = _child(
        "import json, os\n"
        "from ctrlunit.runtime import sched\n"
        "os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(5))\n"
        "print(json.dumps({'policy': sched.apply_rt(0)}))")
    assert got == {"policy": "SCHED_FIFO 5"}


@pytest.mark.zenoh
def test_every_role_of_a_unit_reports_the_launchers_policy(tmp_path) -> None:
    """The roles inherit the launcher's policy; the report names each role's. Without
    the option nothing changes (the default policy)."""
    permitted = sched.fifo_permitted()
    code, rep, out = start_json(tmp_path, "--peripherals", "2", "--pipeline", "2", "--clock",
                                "freerun", "--cycles", "300", "--rt-priority",
                                "7" if permitted else "0", tag="rt")
    assert code == 0, out
    want = "SCHED_FIFO 7" if permitted else "SCHED_OTHER"
    assert rep["scheduling"] == {"central": want, "peripheral_1": want, "peripheral_2": want}
    assert f"scheduling  {want}, every role" in out
    code, rep, out = start_json(tmp_path, "--peripherals", "1", "--clock", "freerun",
                                "--cycles", "100", tag="rt0")
    assert code == 0, out
    assert rep["scheduling"] == {"central": "SCHED_OTHER", "peripheral_1": "SCHED_OTHER"}


@pytest.mark.zenoh
def test_a_unit_run_inside_a_longer_process_leaves_its_policy_as_it_was() -> None:
    """``ctrlunit bench`` runs units in its own process: after each, every thread of it
    (Zenoh's runtime threads outlive the session) is back to the policy it had."""
    if not sched.fifo_permitted():
        pytest.skip("this process may not use SCHED_FIFO")
    got = _child(
        "import json, os\n"
        "from ctrlunit.runtime import sched\n"
        "from ctrlunit.runtime.config import RunConfig\n"
        "from ctrlunit.runtime.launcher import start\n"
        f"rc = RunConfig.of(peripherals=1, pipeline=2, clock='freerun', cycles=200,"
        f" rt_priority=10, unit='t-rt-{os.getpid()}').validate()\n"
        "code, rep = start(rc, echo=lambda m: None)\n"
        "tids = os.listdir('/proc/self/task')\n"
        "print(json.dumps({'code': code, 'during': rep['scheduling'], 'threads': len(tids),"
        " 'after': sorted({sched.policy_name(int(t)) for t in tids})}))")
    assert got["code"] == 0
    assert got["during"] == {"central": "SCHED_FIFO 10", "peripheral_1": "SCHED_FIFO 10"}
    assert got["threads"] > 3  # Zenoh's threads are still there, and back to normal
    assert got["after"] == ["SCHED_OTHER"]
