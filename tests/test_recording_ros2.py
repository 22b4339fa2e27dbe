"""The recording's ROS 2 channels (runtime/recording/ros2.py) and ``ctrlunit export
--rosbag2`` (runtime/recording/rosbag2.py), read by ROS 2 readers this project did not
write: mcap-ros2-support's ``read_ros2_messages`` and rosbags (its CDR decoder on the
recording, its rosbag2 reader on the exported directory). Every ``/joint_states`` message
carries the recording's own signals; a recording made before these channels still
replays, reports and exports."""

from __future__ import annotations

import json
import math
import time
import warnings
from pathlib import Path
from typing import Any

import pytest
from click.testing import CliRunner
from ctrlunit.runtime.cli import cli
from ctrlunit.runtime.recording import reader, replay, ros2
from ctrlunit.runtime.recording.rosbag2 import VERSION, export_rosbag2
from loopback import record_lockstep
from mcap.reader import make_reader
from mcap.writer import Writer
from rosbags.rosbag2 import Reader as BagReader
from ruamel.yaml import YAML
from runner import unit_id

with warnings.catch_warnings():  # its module names a deprecated ROS 1 reader when imported
    warnings.simplefilter("ignore", DeprecationWarning)
    from mcap_ros2.reader import read_ros2_messages

CYCLES = 240


@pytest.fixture(scope="module")
def made(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("ros2") / "run.mcap"
    record_lockstep(str(path), unit_id("ros2"), peripherals=3, pipeline=2, cycles=CYCLES,
                    max_error=1.0, task="circle")
    return path


@pytest.fixture(scope="module")
def old(made, tmp_path_factory) -> Path:
    """The same recording as one made before the ROS 2 channels: without them, profile
    empty."""
    path = tmp_path_factory.mktemp("old") / "old.mcap"
    with open(made, "rb") as src, open(path, "wb") as dst:
        r = make_reader(src)
        w = Writer(dst)
        w.start(profile="", library="ctrlunit before ROS 2")
        ids: dict[int, int] = {}
        for schema, channel, msg in r.iter_messages(log_time_order=False):
            if channel.topic in ros2.TOPICS:
                continue
            if channel.id not in ids:
                sid = 0 if schema is None else w.register_schema(schema.name, schema.encoding,
                                                                 schema.data)
                ids[channel.id] = w.register_channel(channel.topic, channel.message_encoding,
                                                     sid)
            w.add_message(ids[channel.id], msg.log_time, msg.data, msg.publish_time,
                          msg.sequence)
        for m in r.iter_metadata():
            w.add_metadata(m.name, dict(m.metadata))
        w.finish()
    return path


def signals(path: Path) -> list[tuple[int, dict]]:
    return [(t, json.loads(d)) for t, d in reader.read(path).topics["/signals/state"]]


def velocities(path: Path) -> list[list[float]]:
    """The measured joint velocities as replay decodes them from the recorded samples."""
    rec = reader.read(path)
    return [list(i[3]) for i in replay.recorded_inputs(rec, replay._setup(rec))]


def same(a: Any, b: Any) -> bool:
    """Equal floats, NaN equal to NaN or to the JSON channel's null."""
    return all((x is None or math.isnan(x)) and math.isnan(y) if x is None or x != x
               else x == y for x, y in zip(a, b, strict=True))


def check_joint_states(msgs: list[tuple[int, Any]], path: Path) -> None:
    """Every decoded JointState against the recording's /signals/state and samples."""
    sig = signals(path)
    qd = velocities(path)
    assert len(msgs) == len(sig) == len(qd) == CYCLES
    for (t, m), (ts, s), v in zip(msgs, sig, qd):
        assert t == ts == m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec
        assert list(m.name) == list(ros2.JOINTS)
        assert same(s["q"], list(m.position))
        assert same(s["torque"], list(m.effort))
        assert list(m.velocity) == v
    assert any(any(x != 0 for x in v) for v in qd)  # the joints moved


# -- the encoding ---------------------------------------------------------------------------


@pytest.mark.parametrize("q", [[0.1, -2.5, 3e-9], [None, 1.0, math.inf]])
def test_packed_messages_are_rosbags_own_bytes(q):
    ts = ros2.typestore()
    t = ts.types
    header = t["std_msgs/msg/Header"](stamp=t["builtin_interfaces/msg/Time"](
        sec=12, nanosec=345), frame_id="")
    floats = [math.nan if x is None else x for x in q]
    import numpy as np

    js = t[ros2.JOINT_STATE](header=header, name=list(ros2.JOINTS),
                             position=np.array(floats), velocity=np.array([1.0, 2, 3]),
                             effort=np.array(floats[::-1]))
    assert ros2.joint_state(12_000_000_345, q, [1.0, 2, 3], q[::-1]) == \
        bytes(ts.serialize_cdr(js, ros2.JOINT_STATE))
    header.frame_id = ros2.FRAME
    p = t[ros2.POSE_STAMPED](header=header, pose=t["geometry_msgs/msg/Pose"](
        position=t["geometry_msgs/msg/Point"](x=floats[0], y=floats[1], z=floats[2]),
        orientation=t["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0)))
    got = ros2.pose(12_000_000_345, dict(zip("xyz", q)))
    assert got == bytes(ts.serialize_cdr(p, ros2.POSE_STAMPED))


def test_a_wrong_number_of_axes_is_refused_by_name():
    with pytest.raises(ValueError, match="expected 3 values"):
        ros2.joint_state(0, [1.0, 2.0], None, [0.0, 0.0, 0.0])


# -- the recording --------------------------------------------------------------------------


def test_the_recording_declares_ros2_channels(made):
    with open(made, "rb") as fh:
        r = make_reader(fh)
        assert r.get_header().profile == "ros2"
        summary = r.get_summary()
        assert summary is not None
        by_topic = {c.topic: c for c in summary.channels.values()}
        for topic, msgtype in ros2.TOPICS.items():
            c = by_topic[topic]
            schema = summary.schemas[c.schema_id]
            assert (c.message_encoding, schema.encoding, schema.name) == \
                ("cdr", "ros2msg", msgtype)
        assert "/signals/state" in by_topic  # beside today's channels


def test_read_ros2_messages_decodes_every_joint_state_of_a_recording(made):
    msgs = [(m.log_time_ns, m.ros_msg) for m in
            read_ros2_messages(str(made), topics=["/joint_states"])]
    check_joint_states(msgs, made)


def test_rosbags_decodes_every_joint_state_of_a_recording(made):
    ts = ros2.typestore()
    with open(made, "rb") as fh:
        msgs = [(msg.log_time, ts.deserialize_cdr(msg.data, schema.name)) for schema, _, msg
                in make_reader(fh).iter_messages(topics=["/joint_states"])]
    check_joint_states(msgs, made)


def test_poses_and_diagnostics_carry_the_recorded_signals(made):
    sig = dict(signals(made))
    poses = {"/platform/pose": "p", "/platform/reference": "reference"}
    seen = dict.fromkeys(poses, 0)
    diag = []
    for m in read_ros2_messages(str(made), topics=[*poses, "/ctrlunit/diagnostics"]):
        topic = m.channel.topic
        if topic == "/ctrlunit/diagnostics":
            diag.append((m.log_time_ns, m.ros_msg))
            continue
        pos = m.ros_msg.pose.position
        assert [pos.x, pos.y, pos.z] == list(sig[m.log_time_ns][poses[topic]].values())
        assert m.ros_msg.header.frame_id == ros2.FRAME
        seen[topic] += 1
    assert seen == dict.fromkeys(poses, CYCLES)  # lockstep: the plant's position is known
    assert diag and diag[0][0] == min(sig)
    values = {kv.key: kv.value for kv in diag[0][1].status[0].values}
    assert set(values) == {"period_s", "traversal_s", "deadline_misses", "skipped_samples",
                           "rejected_messages"}
    assert values["traversal_s"] == repr(sig[diag[0][0]]["traversal"])


# -- export ---------------------------------------------------------------------------------


def exported(path: Path, out: Path) -> list[tuple[int, Any]]:
    """The bag's /joint_states, its times back on the recording's clock (the bag's are the
    wall clock: it starts within a day of now, not near 1970)."""
    res = CliRunner().invoke(cli, ["export", str(path), "--rosbag2", str(out)],
                             prog_name="ctrlunit")
    assert res.exit_code == 0, res.output
    assert "1970" not in res.stderr
    meta = YAML(typ="safe").load((out / "metadata.yaml").read_text())[
        "rosbag2_bagfile_information"]
    assert meta["version"] == VERSION and meta["storage_identifier"] == "mcap"
    offset = int(reader.read(path).metadata["ctrlunit"]["epoch_offset_ns"])
    start = meta["starting_time"]["nanoseconds_since_epoch"]
    assert abs(start - time.time_ns()) < 86_400e9, start
    (mcap_file,) = out.glob("*.mcap")
    assert meta["relative_file_paths"] == [mcap_file.name]
    ts = ros2.typestore()
    with BagReader(out) as bag:
        assert {c.topic: c.msgtype for c in bag.connections} == ros2.TOPICS
        conns = [c for c in bag.connections if c.topic == "/joint_states"]
        msgs = [(t, ts.deserialize_cdr(raw, c.msgtype)) for c, t, raw in bag.messages(conns)]
    other = [(m.log_time_ns, m.ros_msg) for m in
             read_ros2_messages(str(mcap_file), topics=["/joint_states"])]
    assert [t for t, _ in other] == [t for t, _ in msgs]
    return [(t - offset, m) for t, m in msgs]


def test_an_exported_rosbag2_directory_holds_every_joint_state(made, tmp_path):
    check_joint_states(exported(made, tmp_path / "bag"), made)


def test_an_old_recording_replays_reports_and_exports(old, made, tmp_path):
    runner = CliRunner()
    res = runner.invoke(cli, ["replay", str(old), "--verify"], prog_name="ctrlunit")
    assert res.exit_code == 0 and f"verified {CYCLES} intervals" in res.output, res.output
    res = runner.invoke(cli, ["report", str(old), "--json"], prog_name="ctrlunit")
    assert res.exit_code == 0 and json.loads(res.stdout)["cycles"] == CYCLES, res.output
    check_joint_states(exported(old, tmp_path / "bag"), old)
    # built from the old file's own channels: the messages the recorder writes today
    live, built = reader.read(made), export_rosbag2(reader.read(old), tmp_path / "again")
    assert built.converted
    with BagReader(tmp_path / "again") as bag:
        got: dict[str, list[tuple[int, bytes]]] = {}
        for c, t, raw in bag.messages():
            got.setdefault(c.topic, []).append((t, bytes(raw)))
    offset = int(live.metadata["ctrlunit"]["epoch_offset_ns"])
    for topic in ("/joint_states", "/platform/pose", "/platform/reference"):
        assert [(t - offset, d) for t, d in got[topic]] == live.topics[topic], topic


def test_a_recording_without_the_wall_clock_offset_exports_on_its_own_clock(made, tmp_path):
    """One recorded before the offset was kept: the bag's times are its log times, and
    the command says that bag tools will date it near 1970."""
    rec = reader.read(made)
    del rec.metadata["ctrlunit"]["epoch_offset_ns"]
    done = export_rosbag2(rec, tmp_path / "bag")
    assert not done.dated
    with BagReader(tmp_path / "bag") as bag:
        times = [t for c, t, _ in bag.messages() if c.topic == "/joint_states"]
    assert times == [t for t, _ in rec.topics["/joint_states"]]
    rec.metadata["ctrlunit"]["epoch_offset_ns"] = "soon"  # malformed: the same
    assert not export_rosbag2(rec, tmp_path / "bag2").dated


def test_export_refuses_what_it_cannot_write(made, tmp_path):
    runner = CliRunner()
    (tmp_path / "there").mkdir()
    res = runner.invoke(cli, ["export", str(made), "--rosbag2", str(tmp_path / "there")],
                        prog_name="ctrlunit")
    assert res.exit_code == 1 and "it exists" in res.stderr and "there" in res.stderr
    rec = reader.read(made)
    for topic in (*ros2.TOPICS, "/signals/state"):
        rec.topics.pop(topic, None)
    with pytest.raises(ValueError, match=r"run\.mcap: holds no ROS 2 channels and no "
                                         r"/signals/state"):
        export_rosbag2(rec, tmp_path / "none")
    assert not (tmp_path / "none").exists()
