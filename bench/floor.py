"""The floor: the unit's scatter/gather pattern over raw pipes, and the same over Zenoh.

A central process sends one 64-byte message to each of ``n`` peripheral processes and
waits for all replies, ``rounds`` times after a warm-up. Over pipes this is the cheapest
exchange these processes can have; over Zenoh it is what the unit pays per round.
"""

from __future__ import annotations

import multiprocessing as mp
import os
import queue
import shutil
import statistics
import tempfile
import time
from typing import Any

PAYLOAD = b"x" * 64


def _pipe_child(rfd: int, wfd: int) -> None:
    while True:
        data = os.read(rfd, 4096)
        if not data or data == b"q":
            return
        os.write(wfd, data)


def pipe_round_trip(n: int, *, rounds: int = 2000, warmup: int = 200) -> list[float]:
    """Per-round times (s) of a scatter/gather over pipes with ``n`` children."""
    ctx = mp.get_context("fork")
    links = []
    procs = []
    for _ in range(n):
        a_r, a_w = os.pipe()  # central -> child
        b_r, b_w = os.pipe()  # child -> central
        p = ctx.Process(target=_pipe_child, args=(a_r, b_w), daemon=True)
        p.start()
        procs.append(p)
        links.append((a_w, b_r))
    out = []
    try:
        for k in range(warmup + rounds):
            t0 = time.perf_counter()
            for w, _ in links:
                os.write(w, PAYLOAD)
            for _, r in links:
                os.read(r, 4096)
            if k >= warmup:
                out.append(time.perf_counter() - t0)
    finally:
        for w, _ in links:
            os.write(w, b"q")
        for p in procs:
            p.join(timeout=2)
            if p.is_alive():
                p.kill()
    return out


def _zenoh_child(endpoint: str, index: int, unit: str) -> None:
    from ctrlunit.runtime.node import Node
    from ctrlunit.runtime.zsession import make_config

    with Node(make_config(connect=[endpoint]), unit, f"floor-{index}",
              inbox="peripheral") as node:
        node.route(node.keys.request, "req")
        pub = node.publisher(node.keys.reply(index + 1))
        hello = node.publisher(node.keys.hello)
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            try:
                ev = node.events.get(timeout=0.05)
            except queue.Empty:
                hello.put(str(index).encode())
                continue
            if ev.data == b"q":
                break
            pub.put(ev.data)


def zenoh_round_trip(n: int, *, rounds: int = 2000, warmup: int = 300) -> list[float]:
    """Per-round times (s) of the same scatter/gather over Zenoh (the unit's settings, keys
    and inboxes)."""
    from ctrlunit.runtime.node import Node
    from ctrlunit.runtime.zsession import make_config

    run_dir = tempfile.mkdtemp(prefix="ctrlunit-floor-")
    endpoint = f"unixsock-stream/{run_dir}/c.sock"
    unit = f"floor{os.getpid()}"
    node = Node(make_config(listen=[endpoint]), unit, "central")
    for k in range(n):
        node.route(node.keys.reply(k + 1), "rep", k)
    node.route(node.keys.hello, "hello")
    pub = node.publisher(node.keys.request)
    ctx = mp.get_context("spawn")
    procs = [ctx.Process(target=_zenoh_child, args=(endpoint, k, unit), daemon=True)
             for k in range(n)]
    for p in procs:
        p.start()
    out: list[float] = []
    try:
        seen: set[bytes] = set()
        deadline = time.monotonic() + 30
        while len(seen) < n and time.monotonic() < deadline:
            try:
                ev = node.events.get(timeout=0.1)
            except queue.Empty:
                continue
            if ev.kind == "hello":
                seen.add(ev.data)
        time.sleep(0.1)
        while True:  # drain hellos
            try:
                node.events.get_nowait()
            except queue.Empty:
                break
        for k in range(warmup + rounds):
            t0 = time.perf_counter()
            pub.put(PAYLOAD)
            got = 0
            while got < n:
                ev = node.events.get(timeout=2.0)
                if ev.kind == "rep":
                    got += 1
            if k >= warmup:
                out.append(time.perf_counter() - t0)
    finally:
        pub.put(b"q")
        for p in procs:
            p.join(timeout=3)
            if p.is_alive():
                p.kill()
        node.close()
        shutil.rmtree(run_dir, ignore_errors=True)
    return out


def floor(ns: tuple[int, ...] = (1, 3), *, rounds: int = 2000) -> dict[str, Any]:
    """p50/p99 of both, and the Zenoh round as a ratio to the pipe round, per ``n``."""
    res: dict[str, Any] = {"payload_bytes": len(PAYLOAD), "rounds": rounds, "by_n": {}}
    for n in ns:
        pipe = sorted(pipe_round_trip(n, rounds=rounds))
        zen = sorted(zenoh_round_trip(n, rounds=rounds))

        def q(xs: list[float], f: float) -> float:
            return xs[min(len(xs) - 1, int(f * len(xs)))]

        res["by_n"][str(n)] = {
            "pipe_s": {"p50": statistics.median(pipe), "p99": q(pipe, 0.99)},
            "zenoh_s": {"p50": statistics.median(zen), "p99": q(zen, 0.99)},
            "ratio_p50": statistics.median(zen) / statistics.median(pipe),
        }
    return res
