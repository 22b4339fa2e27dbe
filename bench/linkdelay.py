"""A user-space network link with a fixed one-way delay, where the kernel has no netem.

Every TCP connection accepted on ``listen`` is forwarded to ``target``; each chunk read in
either direction is held until ``delay`` after it arrived, then written on (a delay line:
bytes and order kept, nothing dropped). Combined with a ``tc tbf`` rate limit on the same
path it emulates a slow, distant link, e.g. a Transputer link (20 Mbit/s) or a WAN hop.

Run by hand, in the namespace or host of the connecting side::

    python -m ctrlunit.bench.linkdelay --listen 127.0.0.1:7000 --to 10.77.1.1:7447 --delay 1ms

and point the role at the relay (``--connect tcp/127.0.0.1:7000``). The multi-host test
uses it for the delay on each veth link of its star.
"""

from __future__ import annotations

import argparse
import queue
import socket
import threading
import time

CHUNK = 65536


def _pump(src: socket.socket, dst: socket.socket, delay: float, stop: threading.Event) -> None:
    """Forward ``src`` to ``dst`` with ``delay``: a reader and a writer thread."""
    line: queue.SimpleQueue[tuple[float, bytes]] = queue.SimpleQueue()

    def read() -> None:
        try:
            while not stop.is_set():
                data = src.recv(CHUNK)
                line.put((time.monotonic() + delay, data))
                if not data:
                    return
        except OSError:
            line.put((0.0, b""))

    def write() -> None:
        try:
            while True:
                due, data = line.get()
                wait = due - time.monotonic()
                if wait > 0:
                    time.sleep(wait)
                if not data:
                    break
                dst.sendall(data)
        except OSError:
            pass
        finally:
            stop.set()
            for s in (src, dst):
                try:
                    s.shutdown(socket.SHUT_RDWR)
                except OSError:
                    pass

    threading.Thread(target=read, daemon=True).start()
    threading.Thread(target=write, daemon=True).start()


def _addr(text: str) -> tuple[str, int]:
    host, _, port = text.rpartition(":")
    if not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise ValueError(f"address {text!r}: expected HOST:PORT with a port in 1-65535")
    return host, int(port)


def serve(listen: str, target: str, delay: float, *, ready: threading.Event | None = None,
          stop: threading.Event | None = None) -> None:
    """Accept connections on ``listen`` and relay each to ``target`` with ``delay`` (s)
    each way, until ``stop`` is set."""
    if not 0.0 <= delay <= 10.0:
        raise ValueError(f"delay must be in [0, 10] s, got {delay!r}")
    stop = stop or threading.Event()
    with socket.create_server(_addr(listen)) as srv:
        srv.settimeout(0.2)
        if ready is not None:
            ready.set()
        while not stop.is_set():
            try:
                conn, _ = srv.accept()
            except TimeoutError:
                continue
            try:
                up = socket.create_connection(_addr(target), timeout=5)
            except OSError:
                conn.close()
                continue
            for s in (conn, up):
                s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                s.settimeout(None)
            done = threading.Event()
            _pump(conn, up, delay, done)
            _pump(up, conn, delay, done)


def main(argv: list[str] | None = None) -> None:
    from ..runtime.config import parse_duration

    ap = argparse.ArgumentParser(prog="python -m ctrlunit.bench.linkdelay",
                                 description=__doc__.split("\n\n")[0])
    ap.add_argument("--listen", required=True, help="HOST:PORT to accept on")
    ap.add_argument("--to", required=True, help="HOST:PORT to forward to")
    ap.add_argument("--delay", default="1ms", help="one-way delay (500us, 1ms, 0.002)")
    args = ap.parse_args(argv)
    serve(args.listen, args.to, parse_duration(args.delay))


if __name__ == "__main__":
    main()
