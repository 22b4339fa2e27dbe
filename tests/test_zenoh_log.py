"""Zenoh's own log is off unless ``RUST_LOG`` asks for it (runtime/transport/zsession.py,
``zenoh_log``): a role's output stays the unit's, and a user who sets ``RUST_LOG`` gets
Zenoh's log on the process's standard output (the roles started by ``ctrlunit start``
inherit it)."""

from __future__ import annotations

import os
import subprocess
import sys

SCRIPT = """
import zenoh
from ctrlunit.runtime.transport.zsession import make_config
with zenoh.open(make_config(listen=[])) as s:
    print("zid", s.info.zid())
"""


def run(env: dict[str, str]) -> str:
    base = {k: v for k, v in os.environ.items() if k != "RUST_LOG"}
    res = subprocess.run([sys.executable, "-c", SCRIPT], env=base | env, capture_output=True,
                         text=True, timeout=60)
    assert res.returncode == 0, res.stderr
    return res.stdout + res.stderr


def test_zenohs_log_is_off_unless_rust_log_asks_for_it():
    quiet = run({})
    assert quiet.startswith("zid ") and "INFO" not in quiet
    loud = run({"RUST_LOG": "zenoh=info"})
    assert "Using ZID" in loud and "INFO" in loud
