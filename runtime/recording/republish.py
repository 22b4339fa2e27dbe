"""``ctrlunit replay`` without ``--verify``: a recording's messages published again on
Zenoh at their recorded pace (rosbag2's ``--rate``, ``--loop``, ``--start-offset``,
``--topics``), or its plottable signals written as CSV."""

from __future__ import annotations

import csv
import json
import time
from pathlib import Path
from typing import Any

import msgpack

from .reader import Recording


def export_csv(rec: Recording, out_dir: str | Path, *, cycles: tuple[int, int] | None = None
               ) -> list[Path]:
    """Write the plottable signals (and commands) as CSV files in ``out_dir``."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    path = out / "signals.csv"
    cols = ["cycle", "t", "p_x", "p_y", "p_z", "ref_x", "ref_y", "ref_z", "q1", "q2", "q3",
            "tau1", "tau2", "tau3", "tracking_error", "period", "traversal"]
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(cols)
        for _, data in rec.topics.get("/signals/state", []):
            s = json.loads(data)
            if cycles and not cycles[0] <= s["cycle"] < cycles[1]:
                continue
            p = s.get("p") or {}
            r = s.get("reference") or {}
            w.writerow([s["cycle"], s["t"], p.get("x"), p.get("y"), p.get("z"), r.get("x"),
                        r.get("y"), r.get("z"), *s["q"], *s["torque"], s["tracking_error"],
                        s["period"], s["traversal"]])
    return [path]


def _cycle_of(data: bytes) -> int | None:
    """The interval a recorded message names (``cycle``), msgpack or JSON (the
    ``/signals/state`` channel's), or None."""
    for load in (lambda b: msgpack.unpackb(b, raw=False), json.loads):
        try:
            c = load(data).get("cycle")
        except Exception:  # not this encoding, or not a map
            continue
        return c if isinstance(c, int) else None
    return None


def republish(rec: Recording, *, unit: str, rate: float = 1.0, loop: bool = False,
              start_offset: float = 0.0, topics: list[str] | None = None,
              cycles: tuple[int, int] | None = None, conf: Any = None,
              max_seconds: float | None = None, wait_subscribers: float = 1.0) -> int:
    """Publish the recorded messages on ``ctrlunit/<unit>/<topic>`` at their recorded pace
    scaled by ``rate`` (rosbag2's ``--rate``, ``--loop``, ``--start-offset``,
    ``--topics``). Returns the number of messages published.

    Before the first message, wait up to ``wait_subscribers`` seconds until every topic
    to be sent has a matching subscriber (Zenoh's matching status), so that a viewer
    connected when replay starts receives the first interval too; after that time the
    replay starts whether or not anyone listens."""
    import zenoh

    from ..transport.zsession import make_config

    msgs = []
    for topic, items in rec.topics.items():
        if topics and topic not in topics:
            continue
        for t, data in items:
            if cycles is not None:
                c = _cycle_of(data)
                if c is None or not cycles[0] <= c < cycles[1]:
                    continue
            msgs.append((t, topic, data))
    msgs.sort(key=lambda x: x[0])
    if not msgs:
        return 0
    t0 = msgs[0][0] + int(start_offset * 1e9)
    msgs = [m for m in msgs if m[0] >= t0]
    sent = 0
    with zenoh.open(conf or make_config()) as session:
        pubs: dict[str, Any] = {topic: session.declare_publisher(f"ctrlunit/{unit}{topic}")
                                for topic in sorted({m[1] for m in msgs})}
        wait_for_subscribers(list(pubs.values()), wait_subscribers)
        deadline = None if max_seconds is None else time.monotonic() + max_seconds
        while True:
            wall0 = time.monotonic()
            for t, topic, data in msgs:
                due = wall0 + (t - t0) / 1e9 / rate
                delay = due - time.monotonic()
                if delay > 0:
                    time.sleep(delay)
                pubs[topic].put(data)
                sent += 1
                if deadline is not None and time.monotonic() > deadline:
                    return sent
            if not loop:
                return sent


def wait_for_subscribers(pubs: list[Any], seconds: float) -> bool:
    """Poll the publishers' matching status until each has a subscriber or ``seconds``
    pass (bounded: at most ``seconds`` + one 5 ms poll). True when all matched."""
    deadline = time.monotonic() + max(0.0, seconds)
    while True:
        if all(p.matching_status.matching for p in pubs):
            return True
        if time.monotonic() >= deadline:
            return False
        time.sleep(0.005)


__all__ = ["export_csv", "republish", "wait_for_subscribers"]
