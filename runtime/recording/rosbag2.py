"""``ctrlunit export FILE.mcap --rosbag2 DIR``: a recording's ROS 2 channels as a rosbag2
directory (``metadata.yaml`` and one MCAP file) that ROS 2's bag tools read as it is.

The bag's times (each message's, hence ``starting_time`` and ``duration``) are the wall
clock: the recording's log times (the host's monotonic clock) plus the offset the
recorder noted at the start (``epoch_offset_ns``). A recording made before that offset was
kept has none: its bag starts at the monotonic clock's zero (1970 in bag tools), and
:attr:`Exported.dated` says so. The messages' own header stamps stay the run's clock.

The directory is written by rosbags' rosbag2 writer with storage ``mcap``, in rosbag2's
format version :data:`VERSION`; it holds the four topics of :mod:`.ros2` only (a bag's
every topic must be a ROS 2 message type), their messages byte for byte as recorded.

A recording made before the ROS 2 channels existed is converted from its own channels:
the joint angles, torques, poses, period and traversal from ``/signals/state``, the
measured joint velocities from its samples as replay decodes them
(:func:`.replay.recorded_inputs`), the misses from ``/faults/deadline`` and the rejected
messages from ``/faults/rejected`` (written every 500 intervals: a diagnostics message
may count fewer than the live one did); otherwise the messages the recorder writes today.
"""

from __future__ import annotations

import bisect
import heapq
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Final

from .reader import Recording
from .ros2 import TOPICS, Ros2Channels, typestore

VERSION: Final = 8
"""rosbag2's metadata format version written: rosbags writes 8 or 9; 8 keeps the QoS
profiles as the YAML string older rosbag2 releases parse (9 made them a list)."""


@dataclass
class Exported:
    """What :func:`export_rosbag2` wrote."""

    directory: Path
    counts: dict[str, int] = field(default_factory=dict)
    converted: bool = False
    """True when the recording had no ROS 2 channels and they were built from its own."""
    dated: bool = True
    """False when the recording holds no wall-clock offset: the bag's times are the
    host's monotonic clock."""


def has_ros2(rec: Recording) -> bool:
    """Whether the recording holds ROS 2 channels (recorded since they exist)."""
    return any(topic in rec.topics for topic in TOPICS)


def export_rosbag2(rec: Recording, directory: str | Path) -> Exported:
    """Write ``rec``'s ROS 2 messages as a rosbag2 directory ``directory`` (new).

    Raises
    ------
    ValueError
        If ``directory`` exists, or the recording holds neither ROS 2 channels nor the
        ``/signals/state`` they can be built from.
    """
    from rosbags.rosbag2 import StoragePlugin, Writer

    out = Path(directory)
    if out.exists():
        raise ValueError(f"--rosbag2 {out}: it exists; give a directory that does not "
                         "exist yet (rosbag2 writes a new one)")
    converted = not has_ros2(rec)
    offset = epoch_offset_ns(rec)
    messages = _converted(rec) if converted else {t: rec.topics.get(t, []) for t in TOPICS}
    ts = typestore()
    writer = Writer(out, version=VERSION, storage_plugin=StoragePlugin.MCAP)
    with writer:
        conns = {topic: writer.add_connection(topic, msgtype, typestore=ts)
                 for topic, msgtype in TOPICS.items()}
        ordered = heapq.merge(*([(t, topic, data) for t, data in items]
                                for topic, items in messages.items()),
                              key=lambda m: m[0])
        for t, topic, data in ordered:
            writer.write(conns[topic], t + (offset or 0), data)
    return Exported(out, {t: len(items) for t, items in messages.items()}, converted,
                    offset is not None)


def epoch_offset_ns(rec: Recording) -> int | None:
    """What turns the recording's log times into ns since the epoch, or None when it
    holds none (recorded before the offset was kept, or a malformed value)."""
    text = rec.metadata.get("ctrlunit", {}).get("epoch_offset_ns")
    try:
        offset = int(text) if text is not None else None
    except ValueError:
        return None
    return offset if offset is not None and 0 < offset < 1 << 62 else None


def _converted(rec: Recording) -> dict[str, list[tuple[int, bytes]]]:
    """The ROS 2 messages of a recording without them, from its own channels."""
    from .replay import _setup, cycles_in_order, recorded_inputs

    states = rec.topics.get("/signals/state", [])
    if not states:
        raise ValueError(f"{rec.path}: holds no ROS 2 channels and no /signals/state to "
                         "build them from: nothing to export")
    try:
        inputs = recorded_inputs(rec, _setup(rec))
        qd = {k: i[3] for (k, _), i in zip(cycles_in_order(rec), inputs)}
    except Exception as exc:
        raise ValueError(f"{rec.path}: holds no ROS 2 channels, and its samples do not "
                         f"give the joint velocities ({type(exc).__name__}: {exc})") from exc
    out: dict[str, list[tuple[int, bytes]]] = {t: [] for t in TOPICS}
    topic_of: dict[int, str] = {}

    def register(topic: str, _msgtype: str, _definition: bytes) -> int:
        topic_of[len(topic_of)] = topic
        return len(topic_of) - 1

    def add(cid: int, t: int, data: bytes) -> None:
        out[topic_of[cid]].append((t, data))

    channels = Ros2Channels(register, add, str(rec.config.get("unit", "")))
    misses = _deadline(rec)
    rejected = sorted((t, sum(v for v in m.values() if isinstance(v, int)))
                      for t, m in rec.decoded("/faults/rejected") if isinstance(m, dict))
    for t, data in states:
        try:
            sig = json.loads(data)
            cycle = sig["cycle"]
            channels.interval(t, sig, qd.get(cycle))
        except (ValueError, KeyError, TypeError) as exc:
            raise ValueError(f"{rec.path}: /signals/state at log time {t}: not a state "
                             f"message ({type(exc).__name__}: {exc})") from None
        if channels.due(t):
            i = bisect.bisect_right(misses, (cycle, 1 << 62, 1 << 62)) - 1
            j = bisect.bisect_right(rejected, (t, 1 << 62)) - 1
            channels.status(t, misses=misses[i][1] if i >= 0 else 0,
                            skipped=misses[i][2] if i >= 0 else 0,
                            rejected=rejected[j][1] if j >= 0 else 0)
    end = rec.decoded("/faults/deadline")[-1:]  # the recorder's last status, at close
    if end and misses and out["/joint_states"] and end[0][0] > out["/joint_states"][-1][0]:
        channels.status(end[0][0], misses=misses[-1][1], skipped=misses[-1][2],
                        rejected=rejected[-1][1] if rejected else 0)
    return out


def _deadline(rec: Recording) -> list[tuple[int, int, int]]:
    """``(cycle, deadline misses, skipped samples)`` of ``/faults/deadline``, by cycle."""
    out = []
    for _, m in rec.decoded("/faults/deadline"):
        if isinstance(m, dict) and all(type(m.get(k)) is int for k in
                                       ("cycle", "deadline_misses", "skipped_samples")):
            out.append((m["cycle"], m["deadline_misses"], m["skipped_samples"]))
    return sorted(out)


__all__ = ["VERSION", "Exported", "epoch_offset_ns", "export_rosbag2", "has_ros2"]
