"""The observers' relay: a Zenoh router between the view and the readers of a keyless
``--listen`` port (``ctrlunit start --listen tcp/...``).

Zenoh closes the link of a reader that froze (its receive thread blocked, its keep-alives
stopped) once its lease ends, and the close of a TCP socket holding unread data lingers up
to 10 s in the closing worker thread. Where that link ended in the central's process, two
readers closed together stalled its receiving 4-14 ms under SCHED_FIFO and the run ended
on the plant's silence: 11 of 13 runs with two or three frozen readers, none with the
relay in front (docs/measurements/2026-11-29-frozen-observers-and-250us.md, last
section). So the readers' links end here, in a process of its own at the default policy:
it listens on the ``--listen`` port and on a unix socket in the run's folder
(:data:`SOCKET`), and the view (runtime/observe/zview.py) publishes into a client session
of it. Its access control is the unit's (runtime/transport/security.py ``socket_rule``):
the socket's peer everything, a TCP peer the observers' keys alone. The central's own
session then listens on its local socket alone; the control path never reaches the relay.

``python -m ctrlunit.runtime.observe.relay --socket PATH --listen ENDPOINT ...``, started
by the launcher (runtime/launch/run_parts.py, ``start_relay``); it prints ``ready`` once it
listens, or ``error: ...`` and exits 1, and ends when its standard input closes (its
launcher ended, SIGKILL included) or on SIGTERM.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import signal
import sys
import threading

SOCKET = "view.sock"
"""The relay's unix socket in the run's folder, which the view connects to."""

NICE = 5
"""How much lower than the launcher the relay runs: the readers' traffic and their
lingering closes take what the roles leave."""


def serve(listen: list[str], socket: str) -> None:
    """Run the relay until standard input closes or SIGTERM comes."""
    with contextlib.suppress(OSError):  # the launcher may run under FIFO: not the relay
        os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    with contextlib.suppress(OSError):
        os.nice(NICE)
    import zenoh

    from ..transport.zsession import make_config

    conf = make_config(listen=[*listen, f"unixsock-stream/{socket}"], lowlatency=False,
                       control=True)
    conf.insert_json5("mode", '"router"')
    done = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: done.set())
    try:
        session = zenoh.open(conf)
    except Exception as exc:  # a port taken: one line for the launcher to name
        print(f"error: {str(exc).split(' at /')[0]}", flush=True)
        sys.exit(1)
    with session:
        print("ready", flush=True)
        def until_eof() -> None:  # the launcher's end closes the pipe, SIGKILL included
            sys.stdin.read()
            done.set()

        threading.Thread(target=until_eof, daemon=True).start()
        done.wait()


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(prog="python -m ctrlunit.runtime.observe.relay")
    ap.add_argument("--socket", required=True)
    ap.add_argument("--listen", nargs="+", required=True)
    args = ap.parse_args(argv)
    serve(args.listen, args.socket)


if __name__ == "__main__":
    main()
