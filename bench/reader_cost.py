"""What one reader costs a put: a session configured as the central is (``make_config``,
DROP congestion control, a loopback TCP listener) puts 300-byte messages on a key of
the control path every 0.5 ms, with no reader, with one that subscribes to every key
and reads, and with one that takes a message and then never reads again
(docs/measurements/2026-11-28-stopped-readers.md). Each twice: as a unit's role is
without keys (the link rule: the TCP peer gets the observers' keys alone,
runtime/transport/security.py ``socket_rule``) and as with ``--insecure`` (it gets
everything).

``python -m ctrlunit.bench.reader_cost [--seconds 12]`` prints, per reader, the put's
wall time (p50, p99, max) and thread CPU in the first 2 s and in the second half.
"""

from __future__ import annotations

import argparse
import os
import socket
import statistics
import subprocess
import sys
import time

import zenoh

from ..runtime.transport.zsession import make_config

READER = """
import sys, time, zenoh
from ctrlunit.runtime.transport.zsession import make_config
endpoint, frozen, seconds = sys.argv[1], sys.argv[2] == "frozen", float(sys.argv[3])
with zenoh.open(make_config(connect=[endpoint])) as s:
    if frozen:  # its receive thread blocks on a full channel: its socket fills
        sub = s.declare_subscriber("ctrlunit/**", zenoh.handlers.FifoChannel(1))
    else:
        sub = s.declare_subscriber("ctrlunit/**", lambda sample: None)
    print("subscribed", flush=True)
    time.sleep(seconds)
"""
"""A reader of every key, in a process of its own (``argv``: endpoint, mode, seconds)."""

EVERY_S = 0.0005


def _port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _quantile(xs: list[int], q: float) -> float:
    return sorted(xs)[int(q * (len(xs) - 1))] / 1e3


def measure(mode: str, seconds: float, *, insecure: bool = False) -> list[str]:
    """Put for ``seconds`` beside a reader (``none``, ``reading``, ``frozen``), under the
    link rule or ``insecure``; the lines of its table."""
    endpoint = f"tcp/127.0.0.1:{_port()}"
    reader = None
    with zenoh.open(make_config(listen=[endpoint], control=not insecure)) as session:
        pub = session.declare_publisher("ctrlunit/bench/peripheral/request",
                                        congestion_control=zenoh.CongestionControl.DROP)
        try:
            if mode != "none":
                reader = subprocess.Popen(
                    [sys.executable, "-c", READER, endpoint, mode, str(seconds + 10)],
                    stdout=subprocess.PIPE, text=True)
                assert reader.stdout is not None
                if reader.stdout.readline().strip() != "subscribed":
                    raise RuntimeError(f"the {mode} reader did not subscribe")
                time.sleep(0.5)
            payload = os.urandom(300)
            wall: list[int] = []
            cpu: list[int] = []
            t_next = time.monotonic()
            end = t_next + seconds
            while time.monotonic() < end:
                t_next += EVERY_S
                t0, c0 = time.perf_counter_ns(), time.thread_time_ns()
                pub.put(payload)
                cpu.append(time.thread_time_ns() - c0)
                wall.append(time.perf_counter_ns() - t0)
                time.sleep(max(0.0, t_next - time.monotonic()))
        finally:
            if reader is not None:
                reader.kill()
                reader.wait()
    n, first = len(wall), int(2.0 / EVERY_S)
    lines = []
    for label, part in (("first 2 s", slice(0, first)), ("second half", slice(n // 2, n))):
        w, c = wall[part], cpu[part]
        lines.append(f"| {'insecure' if insecure else 'rule'} | {mode} | {label} | "
                     f"{len(w)} | {_quantile(w, 0.5):.1f} | "
                     f"{_quantile(w, 0.99):.1f} | {max(w) / 1e3:.0f} | "
                     f"{statistics.mean(c) / 1e3:.1f} |")
    return lines


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(prog="python -m ctrlunit.bench.reader_cost",
                                 description=(__doc__ or "").split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=12.0, help="puts per reader, seconds")
    args = ap.parse_args(argv)
    print("| links | reader | window | puts | wall p50 (us) | p99 (us) | max (us) | "
          "CPU mean (us) |")
    print("|---|---|---|---|---|---|---|---|")
    for mode in ("none", "reading", "frozen"):
        for insecure in (False, True):  # side by side
            print("\n".join(measure(mode, args.seconds, insecure=insecure)), flush=True)


if __name__ == "__main__":
    main()
