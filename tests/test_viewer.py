"""The live view (``ctrlunit start --foxglove``): a client speaking the Foxglove WebSocket
protocol gets valid ``/signals/state`` and ``/report/running`` messages from a running
unit, a client that stops reading does not hold the unit back, and the commands are
those of the in-process reference, bit for bit."""

from __future__ import annotations

import contextlib
import gc
import json
import socket
import struct
import subprocess
import sys
import time
from typing import Any

import jsonschema
import pytest
from ctrlunit.kernels.laws import Gains
from ctrlunit.kernels.params import DELTA_IA as P
from ctrlunit.kernels.trajectory import pick_place_task
from ctrlunit.runtime.compute.controller import simulate
from ctrlunit.runtime.config import ConfigError, parse_host_port
from ctrlunit.runtime.observe.report import command_digest
from runner import ctrlunit, kill_unit, unit_id
from test_fuzz import free_port
from websockets.exceptions import ConnectionClosed
from websockets.sync.client import ClientConnection, connect

pytestmark = pytest.mark.zenoh
SUBPROTOCOL = "foxglove.sdk.v1"
CYCLES = 1500


def open_client(port: int, *, deadline: float, rcvbuf: int | None = None,
                max_queue: int | None = 16) -> ClientConnection:
    """Connect once the server listens (bounded by ``deadline``, monotonic s)."""
    while True:
        sock = socket.socket()
        if rcvbuf:  # before connect: the TCP window is agreed then
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, rcvbuf)
        try:
            sock.connect(("127.0.0.1", port))
            return connect(f"ws://127.0.0.1:{port}", sock=sock, subprotocols=[SUBPROTOCOL],
                           max_queue=max_queue, open_timeout=5)
        except OSError:
            sock.close()
            if time.monotonic() > deadline:
                raise
            time.sleep(0.02)


def subscribe_all(ws: ClientConnection) -> dict[int, dict[str, Any]]:
    """Read serverInfo and the advertisement; subscribe to every channel (subscription id
    = channel id). Returns the advertised channels by id."""
    channels: dict[int, dict[str, Any]] = {}
    end = time.monotonic() + 10
    while len(channels) < 2 and time.monotonic() < end:
        msg = json.loads(ws.recv(timeout=10))
        assert ws.subprotocol == SUBPROTOCOL
        if msg["op"] == "advertise":
            channels.update({c["id"]: c for c in msg["channels"]})
    ws.send(json.dumps({"op": "subscribe", "subscriptions": [
        {"id": cid, "channelId": cid} for cid in channels]}))
    return channels


def message_data(frame: bytes) -> tuple[int, int, bytes]:
    """A binary ``messageData`` frame: opcode 1, subscription id (u32), log time (u64),
    payload; all little-endian."""
    assert frame[0] == 1, f"opcode {frame[0]}"
    sub, t = struct.unpack_from("<IQ", frame, 1)
    return sub, t, frame[13:]


def test_parse_host_port_names_the_option_and_the_range():
    assert parse_host_port("8765", field_name="--foxglove") == ("127.0.0.1", 8765)
    assert parse_host_port("0.0.0.0:0", field_name="--foxglove") == ("0.0.0.0", 0)
    assert parse_host_port("[::1]:9", field_name="--foxglove") == ("::1", 9)
    for bad in ("", "65536", "host:", ":80", "a b:1", "-1", "1e3"):
        with pytest.raises(ConfigError, match=r"--foxglove = .*\[HOST:\]PORT.*0 to 65535"):
            parse_host_port(bad, field_name="--foxglove")


def test_a_bad_foxglove_address_is_refused_before_anything_starts():
    res = ctrlunit("start", "--clock", "lockstep", "--cycles", "5", "--foxglove", "70000",
                   timeout=60)
    assert res.returncode == 1, res.stderr
    assert "--foxglove = '70000'" in res.stderr and "Traceback" not in res.stderr
    with socket.socket() as taken:  # a port someone else listens on
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        res = ctrlunit("start", "--clock", "lockstep", "--cycles", "5", "--foxglove",
                       f"127.0.0.1:{port}", timeout=60)
    assert res.returncode == 1, res.stderr
    assert f"--foxglove 127.0.0.1:{port}: cannot listen there" in res.stderr
    assert "Traceback" not in res.stderr


def test_a_foxglove_client_gets_valid_messages_beside_one_that_does_not_read(tmp_path):
    """A real run's live view: a reader gets schema-valid messages and the report's
    figures while a second client subscribes and stops reading. The 1 500 messages fit in
    the kernel's socket buffers, so that client never reaches the server's backlog here,
    and lockstep commands cannot show timing: that a stalled viewer holds nothing back is
    :func:`test_a_viewer_that_stops_reading_never_blocks_the_callers_thread`'s to show."""
    port, unit = free_port(), unit_id("fox")
    report = tmp_path / "run.json"
    proc = subprocess.Popen(
        [sys.executable, "-m", "ctrlunit.runtime.cli", "start", "--unit", unit, "--clock",
         "lockstep", "--peripherals", "1", "--pipeline", "2", "--cycles", str(CYCLES),
         "--foxglove", f"127.0.0.1:{port}", "--foxglove-rate", "0", "--report", str(report)],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    frames: list[bytes] = []
    with contextlib.ExitStack() as clients:
        clients.callback(kill_unit, unit)
        clients.callback(lambda: proc.poll() is None and proc.kill())
        deadline = time.monotonic() + 60
        # a viewer that subscribes and then stops reading: a 4 KB socket buffer and one
        # queued frame, so that the server's sends to it back up at once
        stalled = clients.enter_context(
            open_client(port, deadline=deadline, rcvbuf=4096, max_queue=1))
        subscribe_all(stalled)
        reader = clients.enter_context(open_client(port, deadline=deadline))
        channels = subscribe_all(reader)
        end = time.monotonic() + 120
        while time.monotonic() < end:
            try:
                m = reader.recv(timeout=1)
            except TimeoutError:
                if proc.poll() is not None:
                    break
                continue
            except ConnectionClosed:  # the run ended and the server stopped
                break
            if isinstance(m, bytes):
                frames.append(m)
        out, _ = proc.communicate(timeout=60)
        stalled_got = 0
        try:  # what the stalled viewer had been sent, read now
            while True:
                stalled_got += isinstance(stalled.recv(timeout=2), bytes)
        except (TimeoutError, ConnectionClosed):
            pass
    assert proc.returncode == 0, out
    assert f"live view on ws://127.0.0.1:{port}" in out

    by_topic = {c["topic"]: c for c in channels.values()}
    assert set(by_topic) == {"/signals/state", "/report/running"}
    validators = {}
    for cid, c in channels.items():
        assert c["encoding"] == "json" and c["schemaEncoding"] == "jsonschema"
        schema = json.loads(c["schema"])
        jsonschema.Draft202012Validator.check_schema(schema)
        validators[cid] = jsonschema.Draft202012Validator(schema)
    states, running = [], []
    for f in frames:
        sub, _t, payload = message_data(f)
        doc = json.loads(payload)  # strict JSON: a NaN would not parse
        validators[sub].validate(doc)
        (states if sub == by_topic["/signals/state"]["id"] else running).append(doc)
    assert len(states) >= 100, f"{len(states)} states"
    cycles = [s["cycle"] for s in states]
    assert cycles == sorted(set(cycles)) and cycles[-1] == CYCLES - 1
    assert max(s["tracking_error"] for s in states) < 1e-3
    assert running and running[-1]["cycles"] == CYCLES and running[-1]["dropped"] == 0

    rep = json.loads(report.read_text())
    assert rep["live_view"]["sent"] == CYCLES and rep["live_view"]["dropped"] == 0
    # the view's tracking error is the report's
    assert running[-1]["tracking_error_m"]["max"] == pytest.approx(
        rep["tracking_error_m"]["max"], rel=1e-9)
    print(f"the stalled viewer had {stalled_got} frames waiting, the reader read "
          f"{len(frames)}")
    ref = simulate(P, pick_place_task(), gains=Gains.from_bandwidth(20.0), cycles=CYCLES,
                   delay=2)
    assert rep["command_digest"] == command_digest([x for c in ref.commands for x in c])


def fake_progress(cycle: int, t_ns: int) -> tuple[Any, dict]:
    """What the central hands its ``on_cycle`` hooks after interval ``cycle``
    (runtime/central/snapshot.py), with the context's values the view reads."""
    from ctrlunit.runtime.central.records import CycleLog
    from ctrlunit.runtime.central.snapshot import History, Progress

    log = CycleLog(true_p={cycle: (0.1, 0.0, -0.35)})
    log.times.append(t_ns, 400_000)
    log.errors.append(1e-4)
    progress = Progress(cycle, cycle + 1, cycle + 1, 20_000, 1e-3, t_ns, None, 400_000,
                        (0.1, 0.0, -0.35), 0, 0, {}, (), (), History(log, list))
    return progress, {"qmeas_i": [0.1, 0.2, 0.3], "cmd": [1.0, -2.0, 3.0]}


def test_a_viewer_that_stops_reading_never_blocks_the_callers_thread():
    """20 000 intervals (9 MB of messages, more than the kernel's 4 MB send buffer and the
    server's backlog together) with one client subscribed that never reads: the central's
    callback returns at once every time, and the view's thread goes on sending."""
    from ctrlunit.runtime.observe.viewer import LiveView

    n = 20_000
    task = pick_place_task()
    with contextlib.ExitStack() as stack:
        view = LiveView(host="127.0.0.1", port=0, task=task, period_s=1e-3, cycles=n,
                        rate_hz=0)
        stack.callback(view.close)
        deadline = time.monotonic() + 30
        stalled = stack.enter_context(
            open_client(view.port, deadline=deadline, rcvbuf=4096, max_queue=1))
        subscribe_all(stalled)
        time.sleep(0.2)  # the subscription reaches the server
        slowest = 0.0
        t0 = time.monotonic_ns()
        # the collector's pauses (20 ms at the first full collection here) are not the
        # view's: kept out of the loop
        gc.disable()
        stack.callback(gc.enable)
        for k in range(n):
            progress, ctx = fake_progress(k, t0 + k * 1_000_000)
            c0 = time.perf_counter()
            view(progress, ctx)
            slowest = max(slowest, time.perf_counter() - c0)
            if k % 250 == 249:
                time.sleep(0.02)  # 12.5 kHz in bursts: a fast freerun
        end = time.monotonic() + 30
        while view.sent + view.dropped < n and time.monotonic() < end:
            time.sleep(0.05)
        assert view.sent + view.dropped == n
        sent = view.sent
        view.close()
        got = 0
        with contextlib.suppress(TimeoutError, ConnectionClosed):
            while True:
                got += isinstance(stalled.recv(timeout=1), bytes)
    print(f"slowest callback {slowest * 1e6:.0f} us; the view sent {sent}, the stalled "
          f"client could take {got}")
    # the stall was real: the server dropped for that client rather than wait for it
    assert got < sent
    # the view's thread sent every interval it was handed (it never waited on the client)
    assert sent == n
    # generous: a callback that waited on the client would wait seconds, not 50 ms
    assert slowest < 0.05


def test_the_foxglove_layout_plots_fields_the_view_sends():
    """docs/foxglove-layout.json: every plotted path names a topic of the view and a
    field of that topic's schema."""
    import re
    from pathlib import Path

    from ctrlunit.runtime.observe.signals import SIGNALS_SCHEMA
    from ctrlunit.runtime.observe.viewer import RUNNING_SCHEMA, RUNNING_TOPIC, STATE_TOPIC

    layout = json.loads((Path(__file__).parents[1] / "docs" / "foxglove-layout.json")
                        .read_text())
    schemas = {STATE_TOPIC: SIGNALS_SCHEMA, RUNNING_TOPIC: RUNNING_SCHEMA}
    paths = [p["value"] for c in layout["configById"].values() for p in c.get("paths", [])]
    paths += [c["topicPath"] for c in layout["configById"].values() if "topicPath" in c]
    plotted = set()
    for path in paths:
        m = re.fullmatch(r"(/[a-z/]+?)(?:\.([a-z_]+)(?:\[(\d)\])?)?", path)
        assert m and m.group(1) in schemas, path
        if m.group(2):
            field = schemas[m.group(1)]["properties"][m.group(2)]
            if m.group(3):
                assert field["type"] == "array" and int(m.group(3)) < field["maxItems"], path
            plotted.add(m.group(2))
    assert {"tracking_error", "torque", "period"} <= plotted


def test_the_rate_limits_states_and_the_running_figures_count_every_interval():
    """At 100 Hz a 1 kHz run shows every tenth interval; the running figures still come
    from every interval of the central's logs (period, misses, tracking error)."""

    from ctrlunit.runtime.central.records import CycleLog
    from ctrlunit.runtime.central.snapshot import History, Progress
    from ctrlunit.runtime.observe.viewer import LiveView

    n, t0 = 2000, 10**12
    log = CycleLog()
    history = History(log, list)
    ctx = {"qmeas_i": [0.1, 0.2, 0.3], "cmd": [1.0, -2.0, 3.0]}
    with LiveView(host="127.0.0.1", port=0, task=None, period_s=1e-3, cycles=n,
                  rate_hz=100) as view:
        for k in range(n):
            log.times.append(t0 + k * 1_000_000 + (700_000 if k == 1234 else 0), 300_000)
            log.errors.append(2e-4 if k == 777 else 1e-4)
            cmd = log.cmd_ns
            view(Progress(k, k + 1, k + 1, n, 1e-3, cmd[-1], cmd[-2] if k else None,
                          log.traversal_ns[-1], None, k // 500, 0, {}, (), (), history), ctx)
        assert view.appended == n // 10  # k = 0, 10, 20, ...
        end = time.monotonic() + 10
        while view.sent < view.appended and time.monotonic() < end:
            time.sleep(0.01)
        run = view.running()
    assert view.sent == view.appended and view.dropped == 0
    assert run["cycles"] == n and run["deadline_misses"] == 3
    assert run["period_s"]["p50"] == pytest.approx(1e-3)
    assert run["period_s"]["p99"] == pytest.approx(1e-3)  # 2 of 1999 periods are off
    assert view.stats.count == n - 1
    assert view.stats.hist[1000] == n - 3 and view.stats.hist[1700] == 1
    assert view.stats.hist[300] == 1
    assert run["tracking_error_m"] == {"now": 1e-4, "max": 2e-4}
