"""Two units on one Zenoh network at once: nothing crosses."""

from __future__ import annotations

import json
import subprocess
import sys
import time

import pytest
from ctrlunit.kernels.laws import Gains
from ctrlunit.kernels.params import DELTA_IA as P
from ctrlunit.kernels.trajectory import pick_place_task
from ctrlunit.runtime.compute.controller import simulate
from ctrlunit.runtime.observe.report import command_digest
from runner import kill_unit, unit_id
from test_fuzz import free_port

pytestmark = pytest.mark.zenoh


def test_two_units_on_one_network_do_not_cross(tmp_path):
    pa, pb = free_port(), free_port()
    ua, ub = unit_id("isoA"), unit_id("isoB")
    common = ["--clock", "lockstep", "--peripherals", "3"]  # A runs on after B's end
    cli = [sys.executable, "-m", "ctrlunit.runtime.cli", "start"]
    status = tmp_path / "a.status"
    a = subprocess.Popen(cli + ["--unit", ua, "--listen", f"tcp/127.0.0.1:{pa}", "--report",
                                str(tmp_path / "a.json"), "--status-file", str(status),
                                "--cycles", "6000", *common],
                         stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    deadline = time.monotonic() + 60
    while not status.exists() and time.monotonic() < deadline:  # A is up and running
        time.sleep(0.05)
    b = subprocess.Popen(cli + ["--unit", ub, "--listen", f"tcp/127.0.0.1:{pb}", "--connect",
                                f"tcp/127.0.0.1:{pa}", "--report", str(tmp_path / "b.json"),
                                "--cycles", "2000", *common, "--law", "computed-torque"],
                         stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        out_a, _ = a.communicate(timeout=300)
        out_b, _ = b.communicate(timeout=300)
    finally:
        kill_unit(ua)
        kill_unit(ub)
    assert a.returncode == 0, out_a
    assert b.returncode == 0, out_b
    ra = json.loads((tmp_path / "a.json").read_text())
    rb = json.loads((tmp_path / "b.json").read_text())
    # counters: neither unit saw a single message of the other
    assert ra["rejected_messages"] == {} and rb["rejected_messages"] == {}
    assert (ra["cycles"], rb["cycles"]) == (6000, 2000)
    # ... although they were on one network: B's central was connected to A's port,
    # which is A's observers' relay (runtime/observe/relay.py), a router that A's view
    # publishes into: one more than B's four roles
    assert len(set(rb["zenoh"]["peers"])) == 5, rb["zenoh"]
    assert ra["zenoh"]["zid"] not in rb["zenoh"]["peers"]  # A's central: its socket alone
    # and each computed exactly what it computes alone: the one-process closed loop's
    # commands (depth 1), which a unit alone gives bit for bit (tests/test_star.py)
    for rep, law in ((ra, "resolved-acceleration"), (rb, "computed-torque")):
        ref = simulate(P, pick_place_task(), law=law, gains=Gains.from_bandwidth(20.0),
                       cycles=rep["cycles"], delay=1)
        assert rep["command_digest"] == command_digest([x for c in ref.commands for x in c])
