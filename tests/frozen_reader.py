"""A reader that stops reading: it subscribes to KEY through ENDPOINT, takes one message
and then never reads again, so that Zenoh's receive thread blocks on its full channel and
its socket fills (``python frozen_reader.py ENDPOINT KEY SECONDS [KEYS_DIR ROLE]``).
It prints ``ready`` once imported and connects when a line comes on its standard input
(the test starts it before the run, so that importing Zenoh, a second of CPU, is not
part of what the run meets). It prints ``subscribed`` once declared and ``got N`` when it
takes its one message; it exits after SECONDS. Lowlatency on its side, as an attacker
would choose where it can."""

from __future__ import annotations

import sys
import time

import zenoh
from ctrlunit.runtime.transport.zsession import make_config


def main(endpoint: str, key: str, seconds: float, keys: str | None, role: str) -> None:
    print("ready", flush=True)
    sys.stdin.readline()
    conf = make_config(connect=[endpoint], keys=keys, role=role,
                       lowlatency=endpoint.startswith(("unixsock", "tls")) or None)
    with zenoh.open(conf) as session:
        sub = session.declare_subscriber(key, zenoh.handlers.FifoChannel(1))
        print("subscribed", flush=True)
        end = time.monotonic() + seconds
        got = None
        while got is None and time.monotonic() < end:
            got = sub.try_recv()
            time.sleep(0.01)
        print(f"got {0 if got is None else 1}", flush=True)
        time.sleep(max(0.0, end - time.monotonic()))  # and never reads again


if __name__ == "__main__":
    args = sys.argv[1:]
    main(args[0], args[1], float(args[2]), args[3] if len(args) > 3 else None,
         args[4] if len(args) > 4 else "viewer")
