"""The floor: the unit's scatter/gather pattern over raw pipes, and the same over Zenoh.

A central process sends one 64-byte message to each of ``n`` peripheral processes and
waits for all replies, ``rounds`` times after a warm-up. Over pipes this is the cheapest
exchange these processes can have; over Zenoh it is what the unit pays per round.

:func:`paced_link` asks what a message costs at the unit's own cadence: one request and
one reply per period between two processes, the caller sleeping to each tick as the
realtime plant does, so that both sides wake cold every period; it reports the CPU time
each process spent per round (every thread, Zenoh's included), over pipes and over Zenoh.
That is the price of the plant's sample and command (one such round per interval) and of
each peripheral's request and reply. It runs with the idle CPUs a realtime unit gets
(``--idle``, runtime/host/idle.py: by default polling where the machine allows): on the
reference VM polling took a third off the CPU of a round over Zenoh and 40 % off its round
trip (docs/measurements/2026-11-25-realtime.md).
"""

from __future__ import annotations

import contextlib
import multiprocessing as mp
import os
import queue
import resource
import shutil
import statistics
import tempfile
import time
from multiprocessing.process import BaseProcess
from typing import Any

PAYLOAD = b"x" * 64


RESET, QUIT = b"w", b"q"
"""The echo's orders: start counting CPU now (after the warm-up); reply with the CPU
time counted and exit."""


def _cpu_s() -> float:
    """This process's CPU time (user and system, every thread)."""
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def _echo(data: bytes, c0: float) -> tuple[bytes, float]:
    """What an echoing child answers to ``data`` (to ``QUIT``, its CPU time, after which
    it exits), and its CPU counter's new start."""
    if data == RESET:
        return RESET, _cpu_s()
    if data == QUIT:
        return repr(_cpu_s() - c0).encode(), c0
    return data, c0


def _pipe_child(rfd: int, wfd: int) -> None:
    c0 = _cpu_s()
    while True:
        data = os.read(rfd, 4096)
        if not data:
            return
        out, c0 = _echo(data, c0)
        os.write(wfd, out)
        if data == QUIT:
            return


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
            os.write(w, QUIT)
        for p in procs:
            p.join(timeout=2)
            if p.is_alive():
                p.kill()
    return out


def _zenoh_child(endpoint: str, index: int, unit: str) -> None:
    from ..runtime.transport.node import Node
    from ..runtime.transport.zsession import make_config

    with Node(make_config(connect=[endpoint]), unit, f"floor-{index}",
              inbox="peripheral") as node:
        node.route(node.keys.request, "req")
        pub = node.publisher(node.keys.reply(index + 1))
        hello = node.publisher(node.keys.hello(node.role))
        deadline = time.monotonic() + 60
        c0 = _cpu_s()
        while time.monotonic() < deadline:
            try:
                ev = node.events.get(timeout=0.05)
            except queue.Empty:
                hello.put(str(index).encode())
                continue
            out, c0 = _echo(ev.data, c0)
            pub.put(out)
            if ev.data == QUIT:
                break


def zenoh_round_trip(n: int, *, rounds: int = 2000, warmup: int = 300) -> list[float]:
    """Per-round times (s) of the same scatter/gather over Zenoh (the unit's settings, keys
    and inboxes)."""
    from ..runtime.transport.node import Node
    from ..runtime.transport.zsession import make_config

    run_dir = tempfile.mkdtemp(prefix="ctrlunit-floor-")
    endpoint = f"unixsock-stream/{run_dir}/c.sock"
    unit = f"floor{os.getpid()}"
    node = Node(make_config(listen=[endpoint]), unit, "central")
    for k in range(n):
        node.route(node.keys.reply(k + 1), "rep", k)
        node.route(node.keys.hello(f"floor-{k}"), "hello")
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
        pub.put(QUIT)
        for p in procs:
            p.join(timeout=3)
            if p.is_alive():
                p.kill()
        node.close()
        shutil.rmtree(run_dir, ignore_errors=True)
    return out


class _Link:
    """One echoing child over pipes or over Zenoh (the unit's settings, keys and inboxes):
    ``send`` a payload, ``recv`` the answer; ``close`` ends the child."""

    def __init__(self, kind: str) -> None:
        self.kind = kind
        if kind == "pipe":
            a_r, a_w = os.pipe()  # caller -> child
            b_r, b_w = os.pipe()  # child -> caller
            self.proc: BaseProcess = mp.get_context("fork").Process(
                target=_pipe_child, args=(a_r, b_w), daemon=True)
            self.proc.start()
            self._w, self._r = a_w, b_r
            return
        from ..runtime.transport.node import Node
        from ..runtime.transport.zsession import make_config

        self.run_dir = tempfile.mkdtemp(prefix="ctrlunit-floor-")
        endpoint = f"unixsock-stream/{self.run_dir}/c.sock"
        unit = f"floor{os.getpid()}"
        self.node = Node(make_config(listen=[endpoint]), unit, "central")
        self.node.route(self.node.keys.reply(1), "rep")
        self.node.route(self.node.keys.hello("floor-0"), "hello")
        self.pub = self.node.publisher(self.node.keys.request)
        self.proc = mp.get_context("spawn").Process(target=_zenoh_child,
                                                    args=(endpoint, 0, unit), daemon=True)
        self.proc.start()
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline:  # the child is there once it says hello
            with contextlib.suppress(queue.Empty):
                if self.node.events.get(timeout=0.1).kind == "hello":
                    break
        time.sleep(0.1)
        with contextlib.suppress(queue.Empty):
            while True:  # drain the hellos
                self.node.events.get_nowait()

    def send(self, data: bytes) -> None:
        if self.kind == "pipe":
            os.write(self._w, data)
        else:
            self.pub.put(data)

    def recv(self) -> bytes:
        if self.kind == "pipe":
            return os.read(self._r, 4096)
        while True:
            ev = self.node.events.get(timeout=2.0)
            if ev.kind == "rep":
                return ev.data

    def close(self) -> None:
        self.proc.join(timeout=3)
        if self.proc.is_alive():
            self.proc.kill()
        if self.kind != "pipe":
            self.node.close()
            shutil.rmtree(self.run_dir, ignore_errors=True)


def paced_link(kind: str, *, period_s: float = 1e-3, rounds: int = 2000,
               warmup: int = 200) -> dict[str, Any]:
    """One request and one reply of 250 bytes per period between two processes, over
    ``kind`` (``pipe`` or ``zenoh``), the caller sleeping to each tick.

    Returns ``{"cpu_caller_s", "cpu_echo_s"}`` (CPU time per round of each process, after
    ``warmup`` rounds) and ``round_trip_s`` {p50, p99}."""
    if kind not in ("pipe", "zenoh"):
        raise ValueError(f"kind = {kind!r}: allowed 'pipe' or 'zenoh'")
    payload = b"x" * 250  # a request or reply of the unit
    link = _Link(kind)
    times: list[float] = []
    try:
        for _ in range(warmup):
            link.send(payload)
            link.recv()
        link.send(RESET)
        link.recv()
        c0, tick = _cpu_s(), time.monotonic()
        for _ in range(rounds):
            tick += period_s
            ahead = tick - time.monotonic()
            if ahead > 0:
                time.sleep(ahead)
            t0 = time.perf_counter()
            link.send(payload)
            link.recv()
            times.append(time.perf_counter() - t0)
        caller = _cpu_s() - c0
        link.send(QUIT)
        echo = float(link.recv())
    finally:
        link.close()
    times.sort()
    return {"cpu_caller_s": caller / rounds, "cpu_echo_s": echo / rounds,
            "round_trip_s": {"p50": statistics.median(times),
                             "p99": times[min(len(times) - 1, int(0.99 * len(times)))]}}


def floor(ns: tuple[int, ...] = (1, 3), *, rounds: int = 2000,
          paced_rounds: int | None = None, idle: str = "auto") -> dict[str, Any]:
    """p50/p99 of both, and the Zenoh round as a ratio to the pipe round, per ``n``; and
    ``paced``: :func:`paced_link` over both at 1 ms, ``paced_rounds`` rounds each
    (``rounds`` unless given), with the idle CPUs ``--idle idle`` gives a realtime unit
    (``paced["idle"]`` says which)."""
    from ..runtime.host.idle import idle_request

    res: dict[str, Any] = {"payload_bytes": len(PAYLOAD), "rounds": rounds, "by_n": {}}
    n_paced = rounds if paced_rounds is None else paced_rounds
    with idle_request(idle, clock="realtime") as choice:
        res["paced"] = {"period_s": 1e-3, "rounds": n_paced, "idle": choice,
                        **{kind: paced_link(kind, rounds=n_paced)
                           for kind in ("pipe", "zenoh")}}
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


def main(argv: list[str] | None = None) -> None:
    """``python -m ctrlunit.bench.floor [--rounds N]``: the floor on this machine, printed."""
    import argparse

    ap = argparse.ArgumentParser(prog="python -m ctrlunit.bench.floor",
                                 description=__doc__.split("\n\n")[0])
    ap.add_argument("--rounds", type=int, default=2000,
                    help="rounds of each measurement after the warm-up (100 to 100000)")
    ap.add_argument("--idle", choices=("auto", "poll", "default"), default="auto",
                    help="idle CPUs for the rounds at the unit's cadence, as for ctrlunit "
                    "start in realtime (default: auto)")
    args = ap.parse_args(argv)
    if not 100 <= args.rounds <= 100_000:
        ap.error(f"--rounds = {args.rounds}: allowed 100 to 100000")
    from ..runtime.host.idle import IdlePermissionError

    try:
        res = floor((1, 3), rounds=args.rounds, idle=args.idle)
    except IdlePermissionError as exc:
        ap.exit(1, f"{ap.prog}: error: {exc}\n")
    for n, f in res["by_n"].items():
        print(f"scatter/gather to {n}: pipes p50 {f['pipe_s']['p50'] * 1e6:.0f} us, Zenoh p50 "
              f"{f['zenoh_s']['p50'] * 1e6:.0f} us (p99 {f['zenoh_s']['p99'] * 1e6:.0f}), "
              f"{f['ratio_p50']:.1f}x")
    paced = res["paced"]
    polling = " (idle CPUs poll)" if paced["idle"]["in_force"] == "poll" else ""
    for kind in ("pipe", "zenoh"):
        x = paced[kind]
        print(f"one round every {paced['period_s'] * 1e3:g} ms over {kind}{polling}: CPU "
              f"{x['cpu_caller_s'] * 1e6:.0f} us caller + {x['cpu_echo_s'] * 1e6:.0f} us echo "
              f"per round, round trip p50 {x['round_trip_s']['p50'] * 1e6:.0f} us")


if __name__ == "__main__":
    main()
