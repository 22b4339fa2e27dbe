"""The floods of issue 56 (items 2 and 3) against the realtime main job, the attacker at
``nice 19`` (``python tests/flood_rt.py KIND RUNS``; KIND: ``peripheral``, ``viewer``,
``connections`` or ``none``). Each run: a keyed ``ctrlunit start --peripherals 3
--pipeline 2`` for 12 s on a loopback TCP port; once it has run 2 s, a process at nice
19 floods it for up to 8 s (1 MB puts as peripheral 1 on its own reply key, or as the
viewer on the sample key; or 150 held connections sending garbage); prints the exit
code, the fault, the period, misses and the tracking error of each run. Every process
started is ended; loopback only. Figures: docs/measurements/2026-11-27-busy-machine.md."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))

from runner import kill_unit, unit_id
from test_fuzz import free_port

ATTACK = """
import os, sys, time
sys.path.insert(0, {tests!r})
os.nice(19)
from pathlib import Path
from test_transport_limits import connection_flood, flood
from ctrlunit.runtime.transport.zsession import Keys
kind, port, keys, unit = sys.argv[1], int(sys.argv[2]), Path(sys.argv[3]), sys.argv[4]
t0 = time.monotonic()
if kind == "peripheral":
    flood(port, keys, "peripheral-1", Keys(unit).reply(1), 4000,
          until=lambda: time.monotonic() - t0 > 8)
elif kind == "viewer":
    flood(port, keys, "viewer", Keys(unit).sample, 4000, until=lambda: time.monotonic() - t0 > 8)
elif kind == "connections":
    print(connection_flood(port, held=150, seconds=8.0), flush=True)
"""


def one(kind: str, keys: Path, work: Path) -> dict:
    port, unit = free_port(), unit_id(f"rt{kind[:4]}")
    report, status = work / f"{unit}.json", work / f"{unit}.status"
    proc = subprocess.Popen(
        [sys.executable, "-m", "ctrlunit.runtime.cli", "start", "--unit", unit,
         "--listen", f"tcp/127.0.0.1:{port}", "--peripherals", "3", "--pipeline", "2",
         "--duration", "12s", "--keys", str(keys), "--report", str(report),
         "--status-file", str(status)],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True)
    attacker, said = None, ""
    try:
        deadline = time.monotonic() + 90
        while not status.exists() and time.monotonic() < deadline and proc.poll() is None:
            time.sleep(0.05)
        time.sleep(2.0)
        if kind != "none" and proc.poll() is None:
            attacker = subprocess.Popen(
                [sys.executable, "-c", ATTACK.format(tests=str(Path(__file__).parent)),
                 kind, str(port), str(keys), unit], stdout=subprocess.PIPE,
                stderr=subprocess.STDOUT, text=True, start_new_session=True)
        proc.communicate(timeout=180)
    finally:
        for p in (attacker, proc):
            if p is not None and p.poll() is None:
                p.kill()
        if attacker is not None:
            said = attacker.communicate()[0][-300:]
        if proc.poll() is None:
            proc.communicate()
        kill_unit(unit)
    rep = json.loads(report.read_text()) if report.exists() else {}
    fault = rep.get("fault") or {}
    return {"exit": proc.returncode, "fault": f"{fault.get('process')}: "
            f"{str(fault.get('message'))[:120]}" if fault else None,
            "period_ms": (rep.get("nominal_period_s") or 0) * 1e3,
            "misses": rep.get("deadline_misses"), "periods": rep.get("periods"),
            "tracking_max_mm": (rep.get("tracking_error_m") or {}).get("max", 0) * 1e3,
            "scheduling": sorted(set((rep.get("scheduling") or {}).values())),
            "attacker": said or None}


def main(kind: str, runs: int) -> None:
    from ctrlunit.runtime.transport.security import make_keys

    with tempfile.TemporaryDirectory() as d:
        keys = Path(d) / "keys"
        make_keys(keys, peripherals=3)
        for i in range(runs):
            print(kind, i + 1, json.dumps(one(kind, keys, Path(d))), flush=True)


if __name__ == "__main__":
    os.environ.setdefault("PYTHONUNBUFFERED", "1")
    main(sys.argv[1], int(sys.argv[2]) if len(sys.argv) > 2 else 1)
