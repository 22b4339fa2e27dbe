"""What observers that stop reading cost the realtime main job: runs of ``ctrlunit start
--peripherals 3 --pipeline 2`` at every default, listening on a loopback TCP port and
publishing ROS 2 topics (``--ros2``, through a Zenoh router of this bench's own on
another loopback port), alternated with the same runs where, once 200 intervals are done,
three readers connect and stop reading: one of the view's keys and one of the whole unit
through the unit's listener (without keys the link rule gives them the observers' keys
alone), and one of ``/joint_states`` through the router, as a ROS 2 subscriber over
rmw_zenoh would. Each takes one message into a channel of one and never reads again, so
its socket fills; 2 s after connecting each is stopped whole (SIGSTOP), so that its
keep-alives end and Zenoh closes its link (the two ways a reader has stopped a unit:
docs/measurements/2026-11-28-stopped-readers.md).

``--reading``: the same three readers keep reading every message instead (what live
observers cost).

``python -m ctrlunit.bench.frozen_observers [--pairs 5] [--duration 20s] [--reading]``
prints each run's exit code, period, misses per 1000 and tracking error, and the
acceptance figure of issues 56 and 61: the runs with readers whose misses stay within
``max(1, baseline + 1)`` per 1000, the baseline being the median of the runs without.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import time
import uuid
from pathlib import Path
from typing import Any

READER = """
import json, sys, time, zenoh
endpoint, key, seconds = sys.argv[1], sys.argv[2], float(sys.argv[3])
reading = len(sys.argv) > 4 and sys.argv[4] == "reading"
print("ready", flush=True)
sys.stdin.readline()
conf = zenoh.Config.from_json5(json.dumps({"mode": "peer", "connect": {"endpoints": [
    endpoint]}, "scouting": {"multicast": {"enabled": False}}}))
with zenoh.open(conf) as s:
    if reading:  # it reads every message until it ends
        got = []
        s.declare_subscriber(key, lambda sample: got.append(1))
        time.sleep(seconds)
        print(f"got {len(got)}", flush=True)
        sys.exit(0)
    sub = s.declare_subscriber(key, zenoh.handlers.FifoChannel(1))
    end = time.monotonic() + seconds
    got = None
    while got is None and time.monotonic() < end:
        got = sub.try_recv()
        time.sleep(0.01)
    print(f"got {0 if got is None else 1}", flush=True)
    time.sleep(max(0.0, end - time.monotonic()))
"""
"""A reader that takes one message and never reads again (``argv``: endpoint, key
expression, seconds, and ``reading`` for one that reads every message instead); it
prints ``ready`` once Zenoh is imported and connects on a line."""

ROUTER = """
import json, sys, time, zenoh
conf = zenoh.Config.from_json5(json.dumps({"mode": "router", "listen": {"endpoints": [
    "tcp/127.0.0.1:" + sys.argv[1]]}, "scouting": {"multicast": {"enabled": False}}}))
with zenoh.open(conf):
    print("ready", flush=True)
    time.sleep(float(sys.argv[2]))
"""
"""A Zenoh router (what ``rmw_zenohd`` is to ROS 2), bounded to ``argv[2]`` seconds."""

AFTER = 200
"""Intervals done before the readers connect."""

STOP_AFTER_S = 2.0
"""How long after connecting each reader is stopped whole."""


def _port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _ready(args: list[str]) -> subprocess.Popen:
    """A helper process started from ``args``, once it has printed ``ready``."""
    proc = subprocess.Popen([sys.executable, "-c", *args], stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    line = proc.stdout.readline() if proc.stdout else ""  # it prints it, or exits (EOF)
    if line.strip() != "ready":
        proc.kill()
        raise RuntimeError(f"a helper process did not start: {line!r}")
    return proc


def run(*, duration_s: float, router_port: int, readers: bool, workdir: Path,
        reading: bool = False, timeout_s: float = 300.0) -> dict[str, Any]:
    """One main job, with readers or without (``reading``: readers that keep reading,
    neither frozen nor stopped); its figures."""
    unit = f"bench-frozen-{uuid.uuid4().hex[:8]}"
    port = _port()
    report, status = workdir / f"{unit}.json", workdir / f"{unit}.status"
    keys = [(f"tcp/127.0.0.1:{port}", f"ctrlunit/{unit}/view/**"),
            (f"tcp/127.0.0.1:{port}", f"ctrlunit/{unit}/**"),
            (f"tcp/127.0.0.1:{router_port}", "*/joint_states/**")]
    mode = ["reading"] if reading else []
    procs = [_ready([READER, ep, key, str(duration_s + 60), *mode]) for ep, key in keys] \
        if readers else []
    env = os.environ | {"ZENOH_CONFIG_OVERRIDE":
                        f'connect/endpoints=["tcp/127.0.0.1:{router_port}"]'}
    proc = subprocess.Popen(
        [sys.executable, "-m", "ctrlunit.runtime.cli", "start", "--unit", unit,
         "--peripherals", "3", "--pipeline", "2", "--duration", f"{duration_s}s",
         "--listen", f"tcp/127.0.0.1:{port}", "--ros2", "--report", str(report),
         "--status-file", str(status)],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env,
        start_new_session=True)
    got: list[str] = []
    try:
        deadline = time.monotonic() + timeout_s
        while procs and proc.poll() is None and time.monotonic() < deadline:
            text = status.read_text() if status.exists() else ""
            if text.strip().isdigit() and int(text) >= AFTER:
                break
            time.sleep(0.01)
        for p in procs:
            assert p.stdin is not None
            p.stdin.write("\n")
            p.stdin.flush()
        if procs and not reading:
            time.sleep(STOP_AFTER_S)
            for p in procs:
                os.kill(p.pid, signal.SIGSTOP)
        out, _ = proc.communicate(timeout=max(1.0, deadline - time.monotonic()))
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
        for p in procs:
            p.kill()  # SIGKILL ends a stopped process too
            lines = (p.communicate(timeout=10)[0] or "").split()
            got.append(" ".join(lines[-2:]))
    rep = json.loads(report.read_text()) if report.exists() else {}
    periods = rep.get("periods") or 0
    return {"exit": proc.returncode, "period_s": rep.get("nominal_period_s"),
            "misses_per_1000": 1000 * (rep.get("deadline_misses") or 0) / max(periods, 1),
            "halved": (rep.get("overload") or {}).get("halved_periods", 0),
            "halved_at": [c.get("at_interval") for c in (rep.get("overload") or {}).get(
                "changes", []) if c.get("stride") == 2],
            "taken_over": [d["peripheral"] for d in rep.get("degraded") or []],
            "tracking_max_m": (rep.get("tracking_error_m") or {}).get("max"),
            "ros2_sent": (rep.get("ros2") or {}).get("sent"), "readers": got,
            "tail": "" if proc.returncode == 0 else out[-400:]}


def _line(tag: str, r: dict[str, Any]) -> str:
    return (f"{tag}: exit {r['exit']}, period {(r['period_s'] or 0) * 1e3:g} ms, misses "
            f"{r['misses_per_1000']:.2f}/1000, halved {r['halved']} (at {r['halved_at']}), "
            f"taken over {r['taken_over']}, tracking max "
            f"{(r['tracking_max_m'] or float('nan')) * 1e3:.3f} mm, ros2 sent {r['ros2_sent']}, "
            f"readers {r['readers']} {r['tail']}")


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(prog="python -m ctrlunit.bench.frozen_observers",
                                 description=__doc__.split("\n\n")[0])
    ap.add_argument("--pairs", type=int, default=5, help="runs with readers (and without)")
    ap.add_argument("--duration", default="20s", help="length of each run")
    ap.add_argument("--reading", action="store_true",
                    help="readers that keep reading instead (a live subscriber's cost)")
    args = ap.parse_args(argv)
    from ..runtime.config import parse_duration

    seconds = parse_duration(args.duration, field_name="--duration")
    router_port = _port()
    router = _ready([ROUTER, str(router_port), str(args.pairs * 2 * (seconds + 90))])
    frozen, base = [], []
    try:
        with tempfile.TemporaryDirectory(prefix="ctrlunit-frozen-") as tmp:
            for k in range(args.pairs):
                for readers in ((False, True) if k % 2 == 0 else (True, False)):
                    r = run(duration_s=seconds, router_port=router_port, readers=readers,
                            workdir=Path(tmp), reading=args.reading)
                    (frozen if readers else base).append(r)
                    print(_line(f"pair {k + 1} {'readers' if readers else 'none   '}", r),
                          flush=True)
    finally:
        router.kill()
        router.wait()
    baseline = statistics.median(b["misses_per_1000"] for b in base)
    bound = max(1.0, baseline + 1.0)
    within = [r for r in frozen if r["exit"] == 0 and r["misses_per_1000"] <= bound]
    kind = "reading" if args.reading else "frozen"
    print(f"with {kind} readers: {len(within)} of {len(frozen)} ended normally with misses "
          f"within max(1, baseline {baseline:.2f} + 1) per 1000; exit 0 without readers in "
          f"{sum(b['exit'] == 0 for b in base)} of {len(base)}")


if __name__ == "__main__":
    main()
