"""A viewer for benchmarks: a Foxglove WebSocket client that subscribes to every channel
of a live view (``ctrlunit start --foxglove``) and reads everything, on its own thread, as
Foxglove would; so that what the view costs the unit is measured with someone watching."""

from __future__ import annotations

import json
import threading
import time

SUBPROTOCOL = "foxglove.sdk.v1"


class ViewerClient:
    """Connects to ``ws://127.0.0.1:PORT`` as soon as it listens (within ``wait_s``),
    subscribes to every advertised channel and counts the messages it reads until the
    server closes or :meth:`stop` is called.

    Parameters
    ----------
    port : the live view's port.
    wait_s : how long to keep trying to connect.
    """

    def __init__(self, port: int, *, wait_s: float = 60.0) -> None:
        self.port, self.wait_s = port, wait_s
        self.messages = 0
        self.error: str | None = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="viewer-client", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        from websockets.exceptions import ConnectionClosed
        from websockets.sync.client import connect
        from websockets.typing import Subprotocol

        end = time.monotonic() + self.wait_s
        while not self._stop.is_set():
            try:
                ws = connect(f"ws://127.0.0.1:{self.port}", subprotocols=[Subprotocol(SUBPROTOCOL)],
                             open_timeout=2)
                break
            except OSError as exc:
                if time.monotonic() > end:
                    self.error = f"no live view on port {self.port}: {exc}"
                    return
                time.sleep(0.02)
        else:
            return
        with ws:
            try:
                subscribed: set[int] = set()
                while not self._stop.is_set():
                    try:
                        m = ws.recv(timeout=0.2)
                    except TimeoutError:
                        continue
                    if isinstance(m, bytes):
                        self.messages += 1
                        continue
                    msg = json.loads(m)
                    if msg.get("op") == "advertise":
                        new = [c["id"] for c in msg["channels"] if c["id"] not in subscribed]
                        subscribed.update(new)
                        ws.send(json.dumps({"op": "subscribe", "subscriptions": [
                            {"id": cid, "channelId": cid} for cid in new]}))
            except ConnectionClosed:
                pass

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5.0)
