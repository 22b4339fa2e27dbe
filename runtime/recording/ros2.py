"""The recording's ROS 2 channels: what ``ros2 bag``, rosbags, PlotJuggler and Foxglove read
as ROS 2 messages.

Every recording holds, beside its own channels, four channels of profile ``ros2`` (schema
encoding ``ros2msg``, message encoding ``cdr``, little-endian CDR as rmw writes it):

- ``/joint_states`` (``sensor_msgs/msg/JointState``), every interval: the three joints'
  measured angle (rad) and velocity (rad/s) as the central received them, and the
  command's torque (N m) as ``effort``;
- ``/platform/pose`` (``geometry_msgs/msg/PoseStamped``), every interval whose platform
  position the clock knows (the plant's true position: not in realtime);
- ``/platform/reference`` (``geometry_msgs/msg/PoseStamped``), every interval that has a
  reference (not in freerun); both poses in frame :data:`FRAME`, orientation the identity
  (a Delta's platform does not turn);
- ``/ctrlunit/diagnostics`` (``diagnostic_msgs/msg/DiagnosticArray``), every
  :data:`DIAGNOSTICS_EVERY_NS` of the run and at its end: period, traversal, deadline
  misses, skipped samples, rejected messages; level WARN once a miss or skip occurred.

Stamps and log times are the interval's command time on the run's clock (host monotonic,
ns), the log time of ``/signals/state``. NaN stands for a value the JSON channel writes
as null.

The message definitions come from rosbags' bundled type store (ROS 2 Jazzy), inside the
installed package: nothing is fetched at run time. The diagnostics are encoded by rosbags'
CDR serialiser; the per-interval messages, whose layout never changes, by one
``struct`` call each, byte for byte what rosbags writes (tests/test_recording_ros2.py):
rosbags took 12-18 us a message on the central's thread, 0.7-1 us packed
(docs/measurements/2026-11-27-ros2-recording.md).
"""

from __future__ import annotations

import math
import struct
from collections.abc import Sequence
from functools import cache
from typing import Any

JOINT_STATE = "sensor_msgs/msg/JointState"
POSE_STAMPED = "geometry_msgs/msg/PoseStamped"
DIAGNOSTIC_ARRAY = "diagnostic_msgs/msg/DiagnosticArray"
TOPICS: dict[str, str] = {
    "/joint_states": JOINT_STATE,
    "/platform/pose": POSE_STAMPED,
    "/platform/reference": POSE_STAMPED,
    "/ctrlunit/diagnostics": DIAGNOSTIC_ARRAY,
}
"""The ROS 2 topics of a recording and their message types."""
JOINTS = ("joint_1", "joint_2", "joint_3")
"""``JointState.name``: the axes in the order of the recording's ``q`` and ``torque``."""
FRAME = "base"
"""The poses' frame: the robot's base, in which the kinematics place the platform (m)."""
DIAGNOSTICS_EVERY_NS = 100_000_000
"""The diagnostics' period on the run's clock (10 Hz; ROS 2 diagnostics run at 1 Hz)."""
STATUS_NAME = "ctrlunit: central"
PROFILE = "ros2"
SCHEMA_ENCODING = "ros2msg"
MESSAGE_ENCODING = "cdr"
_ENCAPSULATION = b"\x00\x01\x00\x00"  # CDR, little-endian
_NAN3 = (math.nan, math.nan, math.nan)


@cache
def typestore() -> Any:
    """rosbags' type store of ROS 2 Jazzy (loaded once, 0.2 s)."""
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_JAZZY)


@cache
def definition(msgtype: str) -> str:
    """``msgtype``'s full definition as ROS 2 writes it into an MCAP schema
    (``ros2msg``: the message, then each type it uses after a line of ``=``)."""
    text, _ = typestore().generate_msgdef(msgtype, ros_version=2)
    return str(text)


class _Cdr:
    """The constant bytes of a fixed-layout message, aligned as CDR aligns them (offsets
    count from after the 4-byte encapsulation header)."""

    def __init__(self) -> None:
        self.buf = bytearray()

    def align(self, n: int) -> None:
        self.buf += b"\x00" * (-len(self.buf) % n)

    def string(self, s: str) -> None:
        self.align(4)
        data = s.encode() + b"\x00"
        self.buf += struct.pack("<I", len(data)) + data

    def count(self, n: int) -> None:
        self.align(4)
        self.buf += struct.pack("<I", n)


def _joint_state_struct() -> tuple[struct.Struct, bytes, bytes]:
    """``<stamp> <frame ''> <names> 3 x (<count> <pad> 3 doubles)``, one format."""
    head = _Cdr()
    head.buf += b"\x00" * 8  # stamp: sec, nanosec
    head.string("")
    head.count(len(JOINTS))
    for n in JOINTS:
        head.string(n)
    head.count(3)
    head.align(8)
    const = bytes(head.buf[8:])
    between = _Cdr()  # after 3 doubles (8-aligned): the next count, padded to 8
    between.count(3)
    between.align(8)
    pad = bytes(between.buf)
    return struct.Struct(f"<4siI{len(const)}s3d{len(pad)}s3d{len(pad)}s3d"), const, pad


_JS, _JS_CONST, _JS_PAD = _joint_state_struct()


def _pose_struct() -> tuple[struct.Struct, bytes]:
    head = _Cdr()
    head.buf += b"\x00" * 8
    head.string(FRAME)
    head.align(8)
    const = bytes(head.buf[8:])
    return struct.Struct(f"<4siI{len(const)}s7d"), const


_POSE, _POSE_CONST = _pose_struct()


def stamp(t_ns: int) -> tuple[int, int]:
    """``builtin_interfaces/Time`` (sec, nanosec) of ``t_ns`` on the run's clock."""
    return t_ns // 1_000_000_000, t_ns % 1_000_000_000


def _floats(v: Sequence[float | None] | None) -> tuple[float, ...]:
    """Three floats (NaN for None); raises ValueError on any other count."""
    if v is None:
        return _NAN3
    out = tuple(math.nan if x is None else float(x) for x in v)
    if len(out) != 3:
        raise ValueError(f"expected 3 values (one per axis), got {len(out)}")
    return out


def joint_state(t_ns: int, q: Sequence[float | None], qd: Sequence[float | None] | None,
                torque: Sequence[float | None]) -> bytes:
    """A ``sensor_msgs/msg/JointState`` of the three axes (``qd`` None: NaN)."""
    sec, nsec = divmod(t_ns, 1_000_000_000)
    try:  # the common case: three floats each
        return _JS.pack(_ENCAPSULATION, sec, nsec, _JS_CONST, *q, _JS_PAD,
                        *(_NAN3 if qd is None else qd), _JS_PAD, *torque)
    except (TypeError, struct.error):  # a null (non-finite) value, or not three of them
        return _JS.pack(_ENCAPSULATION, sec, nsec, _JS_CONST, *_floats(q), _JS_PAD,
                        *_floats(qd), _JS_PAD, *_floats(torque))


def pose(t_ns: int, p: dict[str, float | None]) -> bytes:
    """A ``geometry_msgs/msg/PoseStamped`` at ``p`` (``{"x", "y", "z"}``, m)."""
    sec, nsec = divmod(t_ns, 1_000_000_000)
    xyz = (p.get("x"), p.get("y"), p.get("z"))
    try:
        return _POSE.pack(_ENCAPSULATION, sec, nsec, _POSE_CONST, *xyz, 0.0, 0.0, 0.0, 1.0)
    except (TypeError, struct.error):  # a null (non-finite) coordinate
        return _POSE.pack(_ENCAPSULATION, sec, nsec, _POSE_CONST, *_floats(xyz), 0.0, 0.0,
                          0.0, 1.0)


def diagnostics(t_ns: int, *, unit: str, period_s: float | None, traversal_s: float | None,
                misses: int, skipped: int, rejected: int) -> bytes:
    """A ``diagnostic_msgs/msg/DiagnosticArray`` of the central's status (rosbags'
    serialiser)."""
    ts = typestore()
    t = ts.types
    sec, nsec = stamp(t_ns)
    trouble = misses or skipped
    values = [("period_s", period_s), ("traversal_s", traversal_s), ("deadline_misses", misses),
              ("skipped_samples", skipped), ("rejected_messages", rejected)]
    status = t["diagnostic_msgs/msg/DiagnosticStatus"](
        level=1 if trouble else 0, name=STATUS_NAME,
        message=(f"{misses} deadline misses, {skipped} skipped samples" if trouble
                 else "running"),
        hardware_id=unit,
        values=[t["diagnostic_msgs/msg/KeyValue"](key=k, value=_text(v)) for k, v in values])
    header = t["std_msgs/msg/Header"](
        stamp=t["builtin_interfaces/msg/Time"](sec=sec, nanosec=nsec), frame_id="")
    msg = t[DIAGNOSTIC_ARRAY](header=header, status=[status])
    return bytes(ts.serialize_cdr(msg, DIAGNOSTIC_ARRAY))


def _text(v: float | int | None) -> str:
    if v is None:
        return "nan"
    return str(v) if isinstance(v, int) else repr(float(v))


class Ros2Channels:
    """The four ROS 2 channels of one recording: registered on the MCAP writer, filled
    from each interval's ``/signals/state`` message.

    Parameters
    ----------
    register : ``(topic, msgtype, definition) -> channel id``: a channel of encoding
        :data:`MESSAGE_ENCODING` with a :data:`SCHEMA_ENCODING` schema.
    add : ``(channel id, log time ns, data) -> None``.
    unit : the unit id (the diagnostics' ``hardware_id``).
    """

    def __init__(self, register: Any, add: Any, unit: str) -> None:
        self.add = add
        self.unit = unit
        self.ids = {topic: register(topic, msgtype, definition(msgtype).encode())
                    for topic, msgtype in TOPICS.items()}
        # the type store builds its serializer at the first message (150 ms here): now,
        # before the run, not in its first interval on the central's thread
        diagnostics(0, unit=unit, period_s=None, traversal_s=None, misses=0, skipped=0,
                    rejected=0)
        self.last_diagnostics: int | None = None
        self.period_s: float | None = None
        self.traversal_s: float | None = None

    def interval(self, t_ns: int, sig: dict[str, Any], qd: Sequence[float] | None) -> None:
        """One interval's joint states and poses (``sig``: its ``/signals/state``
        message; ``qd``: the measured joint velocities)."""
        ids = self.ids
        add = self.add
        add(ids["/joint_states"], t_ns, joint_state(t_ns, sig["q"], qd, sig["torque"]))
        p = sig.get("p")
        if p is not None:
            add(ids["/platform/pose"], t_ns, pose(t_ns, p))
        ref = sig.get("reference")
        if ref is not None:
            add(ids["/platform/reference"], t_ns, pose(t_ns, ref))
        self.period_s = sig.get("period")
        self.traversal_s = sig.get("traversal")

    def due(self, t_ns: int) -> bool:
        """Whether a diagnostics message is due at ``t_ns`` (the first interval, then every
        :data:`DIAGNOSTICS_EVERY_NS`)."""
        last = self.last_diagnostics
        return last is None or t_ns - last >= DIAGNOSTICS_EVERY_NS

    def status(self, t_ns: int, *, misses: int, skipped: int, rejected: int) -> None:
        """A ``/ctrlunit/diagnostics`` message now (the last interval's period and
        traversal)."""
        self.last_diagnostics = t_ns
        self.add(self.ids["/ctrlunit/diagnostics"], t_ns, diagnostics(
            t_ns, unit=self.unit, period_s=self.period_s, traversal_s=self.traversal_s,
            misses=misses, skipped=skipped, rejected=rejected))
