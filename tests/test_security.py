"""--zenoh-config passes a Zenoh configuration through: with user/password authentication,
a peer without credentials cannot publish commands into the unit."""

from __future__ import annotations

import json
import subprocess
import sys
import time

import pytest
import zenoh
from ctrlunit.runtime.codec import encode
from ctrlunit.runtime.zsession import Keys, make_config
from runner import kill_unit, start_json, unit_id
from test_fuzz import free_port

pytestmark = pytest.mark.zenoh


def auth_config(tmp_path) -> str:
    users = tmp_path / "users.txt"
    users.write_text("ctrl:s3cret\n")
    conf = tmp_path / "auth.json5"
    conf.write_text(json.dumps({
        "mode": "peer",
        "scouting": {"multicast": {"enabled": False}, "gossip": {"enabled": False}},
        "transport": {"auth": {"usrpwd": {"user": "ctrl", "password": "s3cret",
                                          "dictionary_file": str(users)}}},
    }))
    return str(conf)


def test_peer_without_credentials_cannot_publish_commands(tmp_path):
    conf, port = auth_config(tmp_path), free_port()
    unit = unit_id("auth")
    report, status = tmp_path / "r.json", tmp_path / "status"
    common = ["--clock", "lockstep", "--cycles", "1500"]
    proc = subprocess.Popen(
        [sys.executable, "-m", "ctrlunit.runtime.cli", "start", "--unit", unit,
         "--zenoh-config", conf, "--listen", f"tcp/127.0.0.1:{port}", "--report", str(report),
         "--status-file", str(status), *common, "--peripherals", "3"],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        deadline = time.monotonic() + 60
        while not status.exists() and time.monotonic() < deadline:
            time.sleep(0.05)
        keys = Keys(unit)
        with zenoh.open(make_config(connect=[f"tcp/127.0.0.1:{port}"])) as intruder:
            time.sleep(1.0)
            refused = len(list(intruder.info.peers_zid())) == 0
            pub = intruder.declare_publisher(keys.command)
            for k in range(2000):  # well-formed commands for the coming cycles
                pub.put(encode(unit, k, "command", tau=[20.0, -20.0, 20.0]))
        out, _ = proc.communicate(timeout=300)
    finally:
        kill_unit(unit)
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, out
    assert refused, "the unauthenticated peer was admitted"
    rep = json.loads(report.read_text())
    # undisturbed: the one-process unit (the star's commands equal its bit for bit)
    _, clean, _ = start_json(tmp_path, *common, "--peripherals", "0", tag="authclean")
    assert rep["command_digest"] == clean["command_digest"]
    assert rep["tracking_error_m"] == clean["tracking_error_m"]
    print(f"intruder refused; {rep['cycles']} intervals as without it, rejections "
          f"{rep['rejected_messages']}")
