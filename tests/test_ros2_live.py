"""``ctrlunit start --ros2``: live ROS 2 topics over rmw_zenoh, read by a client that
follows rmw_zenoh's conventions and is not this project's (zenoh-ros2-sdk, in
tests/ros2_sub.py, given the message definitions of tests/data/ros2_msgs).

Each run has a Zenoh router of its own on a free loopback port (a Python session in
router mode, in this process: what ``ros2 run rmw_zenoh_cpp rmw_zenohd`` is to ROS 2),
which the unit reaches through ``ZENOH_CONFIG_OVERRIDE`` as an rmw_zenoh node would. The
subscriber's values are compared with the run's own recording (``--record``), read by
mcap-ros2-support; its key expression holds the type name and hash it computed itself
from the definitions. A subscriber stopped by SIGSTOP costs a realtime run nothing."""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import zenoh
from ctrlunit.bench.frozen_observers import ROUTER  # a Zenoh router bounded in time
from ctrlunit.runtime.recording.ros2 import JOINTS
from ctrlunit.runtime.transport import ros2_zenoh as rz
from runner import kill_unit, slow_task, taken_over_and_back, unit_id
from test_fuzz import free_port

pytestmark = pytest.mark.zenoh

SUB = str(Path(__file__).with_name("ros2_sub.py"))
JOINT_STATE_HASH = "RIHS01_a13ee3a330e346c9d87b5aa18d24e11690752bd33a0350f11c5882bc9179260e"
"""sensor_msgs/msg/JointState's type hash in ROS 2 Jazzy."""


@pytest.fixture
def router():
    """A Zenoh router on a free loopback port, in this process; yields its port."""
    port = free_port()
    conf = zenoh.Config.from_json5(json.dumps({
        "mode": "router", "listen": {"endpoints": [f"tcp/127.0.0.1:{port}"]},
        "scouting": {"multicast": {"enabled": False}}}))
    session = zenoh.open(conf)
    try:
        yield port, session
    finally:
        session.close()




def _router_process(port: int, *, nice: int, seconds: float = 300) -> subprocess.Popen:
    """A Zenoh router on ``port`` in a process of its own at ``nice`` (bounded: it exits
    after ``seconds``); returns once it listens."""
    proc = subprocess.Popen([sys.executable, "-c", ROUTER, str(port), str(seconds)],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            preexec_fn=lambda: os.nice(nice))
    line = proc.stdout.readline() if proc.stdout else ""
    assert line.strip() == "ready", f"the router did not start: {line!r} {proc.poll()}"
    return proc


def _env(port: int) -> dict[str, str]:
    return os.environ | {rz.OVERRIDE_ENV: f'connect/endpoints=["tcp/127.0.0.1:{port}"]'}


def _subscriber(port: int, out: Path, *, most: int = 100_000, seconds: float = 120,
                nice: int = 0) -> tuple[subprocess.Popen, dict]:
    """tests/ros2_sub.py subscribed to /joint_states (bounded: 60 s to subscribe), at
    ``nice``."""
    proc = subprocess.Popen([sys.executable, SUB, str(port), "0", str(out), str(most),
                             str(seconds)], stdout=subprocess.DEVNULL,
                            stderr=subprocess.STDOUT, preexec_fn=lambda: os.nice(nice))
    ready = Path(f"{out}.ready")
    deadline = time.monotonic() + 60
    while not ready.exists() and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.05)
    assert ready.exists(), f"the subscriber did not subscribe (exit {proc.poll()})"
    time.sleep(0.2)  # the file written
    return proc, json.loads(ready.read_text())


def _start(tmp_path: Path, tag: str, port: int, *args: str
           ) -> tuple[subprocess.Popen, str, Path, Path]:
    unit = unit_id(tag)
    report, status = tmp_path / f"{tag}.json", tmp_path / f"{tag}.status"
    proc = subprocess.Popen(
        [sys.executable, "-m", "ctrlunit.runtime.cli", "start", "--unit", unit, "--ros2",
         "--report", str(report), "--status-file", str(status), *args],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=_env(port),
        start_new_session=True)
    return proc, unit, report, status


def _wait_status(proc: subprocess.Popen, status: Path, at_least: int, timeout: float) -> None:
    deadline = time.monotonic() + timeout
    while proc.poll() is None and time.monotonic() < deadline:
        if status.exists() and int(status.read_text() or 0) >= at_least:
            return
        time.sleep(0.02)


def _received(out: Path) -> list[dict]:
    """The messages written whole (a stopped subscriber may leave half a line)."""
    if not out.exists():
        return []
    return [json.loads(line) for line in out.read_text().split("\n")[:-1] if line.strip()]


def _same(a: list, b: list) -> bool:
    return len(a) == len(b) and all(
        (x is None and (y is None or math.isnan(y))) or x == y for x, y in zip(a, b))


def _recorded(path: Path) -> dict[int, object]:
    """The recording's /joint_states by stamp (ns), read by mcap-ros2-support."""
    from mcap_ros2.reader import read_ros2_messages

    return {m.ros_msg.header.stamp.sec * 1_000_000_000 + m.ros_msg.header.stamp.nanosec:
            m.ros_msg for m in read_ros2_messages(str(path), topics=["/joint_states"])}


def _check_against_recording(got: list[dict], rec: Path) -> None:
    recorded = _recorded(rec)
    assert got and recorded
    for g in got:
        r = recorded[g["stamp_ns"]]  # a stamp the recording holds: the same interval
        assert g["name"] == list(JOINTS) == list(r.name)
        assert _same(g["position"], list(r.position)), (g, r)
        assert _same(g["velocity"], list(r.velocity)), (g, r)
        assert _same(g["effort"], list(r.effort)), (g, r)


def _end(proc: subprocess.Popen | None, unit: str, subs: list[subprocess.Popen]) -> None:
    kill_unit(unit)
    if proc is not None and proc.poll() is None:
        proc.kill()
    for s in subs:
        try:
            s.send_signal(signal.SIGCONT)
        except ProcessLookupError:
            pass
        s.kill()
        s.wait(timeout=10)


def test_wire_format_is_rmw_zenohs():
    """Key expression, tokens and attachment as rmw_zenoh writes them; the publisher's
    token parsed as rmw_zenoh's graph cache parses it (13 parts, ``%`` for ``/``), its
    QoS and the attachment read back by zenoh-ros2-sdk."""
    from zenoh_ros2_sdk.attachment import Attachment
    from zenoh_ros2_sdk.qos import QosProfile
    from zenoh_ros2_sdk.utils import demangle_name, ros2_to_dds_type

    msgtype = "sensor_msgs/msg/JointState"
    assert rz.dds_type(msgtype) == ros2_to_dds_type(msgtype)
    assert rz.topic_key(3, "/joint_states", msgtype, JOINT_STATE_HASH) == (
        f"3/joint_states/sensor_msgs::msg::dds_::JointState_/{JOINT_STATE_HASH}")
    token = rz.publisher_token(3, "abc123", "ctrlunit_u1", 1, "/joint_states", msgtype,
                               JOINT_STATE_HASH)
    parts = token.split("/")
    assert len(parts) == 13 and parts[:6] == ["@ros2_lv", "3", "abc123", "0", "1", "MP"]
    assert demangle_name(parts[9]) == "/joint_states" and parts[10] == ros2_to_dds_type(msgtype)
    assert parts[11] == JOINT_STATE_HASH
    assert QosProfile.decode(parts[12]) == QosProfile()  # ROS 2's default
    assert rz.node_token(3, "abc123", "ctrlunit_u1").split("/")[5:] == ["NN", "%", "%",
                                                                        "ctrlunit_u1"]
    att = Attachment.from_bytes(rz.attachment(7, 123, rz.gid(token)))
    assert (att.sequence_id, att.timestamp_ns, att.gid) == (7, 123, rz.gid(token))
    assert rz.node_name("t-a.b") == "ctrlunit_t_a_b"


def test_gid_is_rmw_zenohs_xxh3_of_the_token():
    """rmw_zenoh's GID: XXH3-128 (seed 0) of the liveliness token, low 64 bits then high 64
    bits, little-endian. XXH3-128 of the empty input is 99aa06d3014798d8 6001c324468d497f
    (xxHash's own test value, as high64 low64), so its GID starts with the low word's
    bytes reversed; a token's GID is 16 bytes, differs from another token's, and does
    not depend on the process (no per-run salt)."""
    assert rz.gid("") == bytes.fromhex("7f498d4624c30160" "d8984701d306aa99")
    token = rz.publisher_token(0, "abc123", "ctrlunit_u1", 1, "/joint_states",
                               "sensor_msgs/msg/JointState", JOINT_STATE_HASH)
    other = token.replace("abc123", "abc124")
    assert len(rz.gid(token)) == 16 and rz.gid(token) != rz.gid(other)
    again = subprocess.run(
        [sys.executable, "-c", "import sys; from ctrlunit.runtime.transport import "
         "ros2_zenoh as rz; print(rz.gid(sys.argv[1]).hex())", token],
        capture_output=True, text=True, timeout=60)
    assert again.stdout.strip() == rz.gid(token).hex(), again.stderr


@pytest.mark.parametrize("override", [
    'mode="peer";listen/endpoints={peer:["tcp/0.0.0.0:7447"]}',  # an attacker's review
    'connect/endpoints={client:["tcp/127.0.0.1:7447"],peer:["tcp/192.0.2.1:7447"]}',
    'listen/endpoints=["tcp/0.0.0.0:7447"]', 'scouting/multicast/enabled=true',
    'plugins_loading/enabled=true;plugins={rest:{http_port:"0.0.0.0:8000"}}'])
def test_an_override_that_reaches_beyond_the_host_is_refused_in_any_mode(override):
    """The link rule reads every mode's endpoints of a per-mode object: an override that
    also set the mode once opened a keyless listener the check never saw."""
    with pytest.raises(ValueError, match="--insecure"):
        rz.session_config({rz.OVERRIDE_ENV: override}, insecure=False)
    rz.session_config({rz.OVERRIDE_ENV: override}, insecure=True)  # a lab bench's choice


def test_a_per_mode_override_connects_where_its_mode_says():
    conf = rz.session_config({rz.OVERRIDE_ENV: 'mode="peer";connect/endpoints={client:['
                              '"tcp/127.0.0.1:1"],peer:["tcp/127.0.0.1:2"]}'}, insecure=False)
    assert rz.router_endpoints(conf) == ["tcp/127.0.0.1:2"]


@pytest.mark.parametrize("endpoint, refused", [("tcp/192.0.2.1:7447", True),
                                               ("tcp/127.0.0.1:7447", False)])
def test_a_router_beyond_the_host_follows_the_link_rule(endpoint, refused):
    """``--check`` refuses a ROS 2 router beyond the host without ``--insecure``."""
    env = os.environ | {rz.OVERRIDE_ENV: f'connect/endpoints=["{endpoint}"]'}
    res = subprocess.run([sys.executable, "-m", "ctrlunit.runtime.cli", "start", "--ros2",
                          "--check", "--cycles", "10"], capture_output=True, text=True,
                         env=env, timeout=120)
    assert (res.returncode != 0) == refused, res.stdout + res.stderr
    if refused:
        assert "--insecure" in res.stdout + res.stderr


def test_no_router_refuses_the_start(tmp_path):
    """``--ros2`` with no router answering: refused before anything runs, saying how to
    start one."""
    port = free_port()
    res = subprocess.run([sys.executable, "-m", "ctrlunit.runtime.cli", "start", "--ros2",
                          "--unit", unit_id("norouter"), "--cycles", "10",
                          "--clock", "lockstep"], capture_output=True, text=True,
                         env=_env(port), timeout=120)
    assert res.returncode != 0
    assert "rmw_zenohd" in res.stdout + res.stderr


def test_a_listener_that_answers_no_zenoh_handshake_refuses_the_start(tmp_path):
    """A TCP port that accepts and never answers (another program's, or a stalled one)
    is no router: refused before anything runs, within about a second, naming it. Before
    (a review), the start went on and announced ROS 2 topics nobody could receive."""
    import socket

    with socket.socket() as silent:
        silent.bind(("127.0.0.1", 0))
        silent.listen(8)
        port = silent.getsockname()[1]
        res = subprocess.run([sys.executable, "-m", "ctrlunit.runtime.cli", "start", "--ros2",
                              "--unit", unit_id("silentrouter"), "--cycles", "10", "--clock",
                              "lockstep"], capture_output=True, text=True, env=_env(port),
                             timeout=120)
    assert res.returncode == 1, res.stdout + res.stderr
    assert f"tcp/127.0.0.1:{port} accepted a connection but answered no Zenoh handshake" in \
        res.stderr, res.stderr


def test_lockstep_joint_states_equal_the_recording(tmp_path, router):
    """A lockstep run with ``--ros2 --record``: the ROS 2 graph holds the node and its
    four publishers as ``ros2 topic list`` reads them, and every /joint_states message
    zenoh-ros2-sdk took (on the key of the type name and hash it computed) equals the
    recording's of the same stamp."""
    port, session = router
    out, rec = tmp_path / "js.jsonl", tmp_path / "run.mcap"
    sub, info = _subscriber(port, out)
    proc = unit = None
    try:
        assert info["type_hash"] == JOINT_STATE_HASH
        proc, unit, report, status = _start(tmp_path, "ros2lock", port, "--clock", "lockstep",
                                            "--cycles", "6000", "--record", str(rec))
        _wait_status(proc, status, 1000, timeout=120)
        tokens = [str(r.ok.key_expr) for r in session.liveliness().get("@ros2_lv/0/**",
                                                                       timeout=5) if r.ok]
        out_text, _ = proc.communicate(timeout=240)
        time.sleep(0.5)
    finally:
        _end(proc, unit or "none", [sub])
    assert proc.returncode == 0, out_text[-2000:]
    ours = [t.split("/") for t in tokens if "/ctrlunit_" in t]
    node = rz.node_name(unit)
    assert ["NN", "%", "%", node] in [p[5:] for p in ours], tokens
    topics = {("/" + p[9].lstrip("%").replace("%", "/"), p[10], p[11]) for p in ours
              if p[5] == "MP"}
    assert ("/joint_states", "sensor_msgs::msg::dds_::JointState_", JOINT_STATE_HASH) in topics
    assert {t[0] for t in topics} == {"/joint_states", "/platform/pose", "/platform/reference",
                                      "/ctrlunit/diagnostics"}
    got = _received(out)
    assert len(got) >= 50, len(got)
    _check_against_recording(got, rec)
    rep = json.loads(report.read_text())
    assert rep["ros2"]["sent"] >= len(got) and rep["ros2"]["node"] == "/" + node


@pytest.mark.slow
def test_realtime_joint_states_and_a_frozen_subscriber(tmp_path):
    """A 20 s realtime main job (the slow pick & place, default policy, as the frozen
    readers of tests/test_observers.py) with ``--ros2``: zenoh-ros2-sdk receives
    /joint_states, then is stopped (SIGSTOP) for the rest of the run: the run ends
    normally at its period, and no peripheral is cut off for good (one the host kept
    from its CPU past the silence rule may stand by and serve again, as in
    tests/test_observers.py: at 0.5 ms under the default policy a 3 ms stall of the host
    does that, subscriber or not).

    What is judged is what the frozen subscriber costs the unit, on a host as slow as CI's:
    the router and the subscriber run at nice 19, and the run records nothing (the values
    against the recording are the lockstep test's). Without these, 2 of about 15 starts
    here faulted on tracking in their first 100 intervals, before the subscriber was
    stopped: the ROS 2 side's processes and the recorder took the CPU the start needed
    (docs/measurements/2026-11-27-ros2-live.md)."""
    port = free_port()
    out = tmp_path / "js.jsonl"
    router = _router_process(port, nice=19)
    sub = proc = unit = None
    try:
        sub, _info = _subscriber(port, out, nice=19)
        proc, unit, report, _status = _start(
            tmp_path, "ros2rt", port, "--peripherals", "3", "--pipeline", "2", "--duration",
            "20s", "--task", slow_task(tmp_path), "--rt-priority", "0")
        deadline = time.monotonic() + 120
        while len(_received(out)) < 100 and proc.poll() is None \
                and time.monotonic() < deadline:
            time.sleep(0.1)
        sub.send_signal(signal.SIGSTOP)  # it reads no more, for the rest of the run
        frozen_at = len(_received(out))
        out_text, _ = proc.communicate(timeout=240)
    finally:
        _end(proc, unit or "none", [s for s in (sub, router) if s is not None])
    rep = json.loads(report.read_text()) if report.exists() else {}
    print(f"exit {proc.returncode}, misses {rep.get('deadline_misses')} of "
          f"{rep.get('periods')}, ros2 {rep.get('ros2')}, received {frozen_at}")
    assert proc.returncode == 0, out_text[-2000:]
    assert taken_over_and_back(rep), rep.get("degraded")
    assert 0 <= rep["periods"] - round(20 / rep["nominal_period_s"]) <= 1
    assert frozen_at >= 100
    got = _received(out)
    assert all(g["name"] == list(JOINTS) and len(g["position"]) == len(JOINTS)
               and all(math.isfinite(x) for x in g["position"]) for g in got)
    stamps = [g["stamp_ns"] for g in got]
    assert stamps == sorted(set(stamps))  # one message per interval, in order
