"""Recording every interval to MCAP; replay --verify; report from the file; salvage."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

import jsonschema
import pytest
from ctrlunit.runtime.recording.reader import read
from ctrlunit.runtime.recording.recorder import CHUNK_SIZE
from ctrlunit.runtime.recording.replay import verify
from mcap.reader import make_reader
from runner import ctrlunit, kill_unit, start_json, unit_id, wait_gone, wait_status

pytestmark = pytest.mark.zenoh
CYCLES = int(os.environ.get("CTRLUNIT_RECORD_CYCLES", "3000"))
"""Intervals of the module's recording: 3000 in CI; the 10 000-interval file (the size
the recording's figures are quoted for) is the slow test below."""


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    d = tmp_path_factory.mktemp("rec")
    path = d / "run.mcap"
    code, rep, out = start_json(d, "--peripherals", "3", "--pipeline", "2", "--clock",
                                "freerun", "--cycles", str(CYCLES), "--record", str(path),
                                tag="rec", timeout=400)
    assert code == 0, out
    return path, rep


@pytest.mark.slow
def test_a_10000_interval_recording_verifies_bit_for_bit(tmp_path):
    path = tmp_path / "long.mcap"
    code, _, out = start_json(tmp_path, "--peripherals", "3", "--pipeline", "2", "--clock",
                                "freerun", "--cycles", "10000", "--record", str(path),
                                tag="long", timeout=600)
    assert code == 0, out
    n, div = verify(read(path))
    assert div is None and n == 10000, div


def test_replay_verify_finds_no_divergence(recorded):
    path, _ = recorded
    res = ctrlunit("replay", str(path), "--verify", timeout=600)
    assert res.returncode == 0, res.stdout + res.stderr
    assert f"verified {CYCLES} intervals" in res.stdout


@pytest.mark.parametrize(("block", "cycle"), [("jdot", 1234 % CYCLES), ("observer0", 77),
                                              ("dyn_central", CYCLES - 3)])
def test_altered_kernel_is_caught_at_its_cycle_and_block(recorded, block, cycle):
    path, _ = recorded
    n, div = verify(read(path), alter=(block, cycle))
    assert div is not None
    assert div.cycle == cycle
    assert div.block == block
    assert n == cycle  # every interval before it was identical


def test_report_from_file_equals_live_report(recorded, tmp_path):
    path, live = recorded
    res = ctrlunit("report", str(path), "--report", str(tmp_path / "r.json"))
    assert res.returncode == 0, res.stderr
    again = json.loads((tmp_path / "r.json").read_text())
    for key in ("cycles", "period_s", "traversal_s", "business", "t1_s", "efficiency",
                "speedup", "deadline_misses", "round_trips", "command_digest", "torque_nm",
                "cpu_per_interval_s", "cpu_cores", "cpu_bound_period_s"):
        assert again[key] == live[key], key


def test_json_channels_validate_against_their_schemas(recorded):
    path, _ = recorded
    with open(path, "rb") as fh:
        reader = make_reader(fh)
        checked = 0
        validators: dict[bytes, jsonschema.Validator] = {}
        for schema, channel, msg in reader.iter_messages(topics=["/signals/state"]):
            assert channel.message_encoding == "json"
            assert schema.encoding == "jsonschema"
            doc = json.loads(msg.data)  # strict JSON: NaN would not parse as null
            if schema.data not in validators:  # checked once, then compiled
                js = json.loads(schema.data)
                jsonschema.Draft202012Validator.check_schema(js)
                validators[schema.data] = jsonschema.Draft202012Validator(js)
            validators[schema.data].validate(doc)
            checked += 1
            if checked > 2000:
                break
    assert checked > 0


def test_metadata_names_configuration_and_host(recorded):
    rec = read(recorded[0])
    meta = rec.metadata["ctrlunit"]
    for key in ("config", "placement", "version", "host", "cores", "clock"):
        assert meta[key]
    assert not rec.salvaged


def _chunks(data: bytes) -> list[int]:
    """Where each chunk record of an MCAP file begins (its data section, record by
    record: opcode, u64 length, body)."""
    out, pos = [], 8
    while pos < len(data) - 8 and data[pos] != 0x0F:  # up to DataEnd
        if data[pos] == 0x06:
            out.append(pos)
        pos += 9 + int.from_bytes(data[pos + 1:pos + 9], "little")
    return out


def test_a_damaged_whole_recording_is_not_passed_for_a_cut_off_one(recorded, tmp_path):
    """Three bytes flipped inside a chunk of a whole file (its footer intact): the reader
    says it is damaged and salvages only what comes before the damage; ``replay --verify``
    fails however many intervals before it compare equal. The same file cut off (a crash)
    is salvaged as before, and verifies."""
    path, rep = recorded
    data = bytearray(path.read_bytes())
    chunk = _chunks(bytes(data))[len(_chunks(bytes(data))) // 2]
    for d in (200, 207, 219):
        data[chunk + d] ^= 0xFF
    damaged, cut = tmp_path / "damaged.mcap", tmp_path / "cut.mcap"
    damaged.write_bytes(data)
    cut.write_bytes(path.read_bytes()[: chunk + 100])
    rec = read(damaged)
    assert rec.salvaged and rec.damaged and "is damaged" in rec.note
    assert 0 < len(rec.topics["/plant/command"]) < rep["cycles"]
    res = ctrlunit("replay", str(damaged), "--verify")
    assert res.returncode == 1 and "the recording is damaged" in res.stderr, res.stderr
    rec = read(cut)
    assert rec.salvaged and not rec.damaged and "cut off" in rec.note
    res = ctrlunit("replay", str(cut), "--verify")
    assert res.returncode == 0 and "verified" in res.stdout, res.stderr


def test_a_byte_changed_in_the_summary_or_footer_is_damage(recorded, tmp_path):
    """The seeking reader checks each chunk's CRC, not the file's: a byte changed in the
    summary section (the indexes, the statistics), the footer or the run's result record
    passed ``replay --verify`` in about half the places tried (2026-11-29). MCAP's
    ``summary_crc`` and ``data_section_crc`` now decide: every such change is damage, and
    verify fails; the file unchanged still reads whole."""
    import struct

    path, rep = recorded
    data = path.read_bytes()
    assert not read(path).salvaged
    footer = len(data) - 8 - 29
    start = struct.unpack_from("<Q", data, footer + 9)[0]
    assert 8 < start < footer
    places = sorted({*range(start, footer + 29, max(1, (footer + 29 - start) // 40)),
                     footer + 25, footer + 28})
    for at in places:
        bad = bytearray(data)
        bad[at] ^= 0x40
        damaged = tmp_path / "summary.mcap"
        damaged.write_bytes(bad)
        rec = read(damaged)
        assert rec.damaged and "is damaged" in rec.note, (at - start, rec.note)
        assert "but ;" not in rec.note  # a reason, always
        whole = not rec.salvaged  # the records read whole: every interval is there
        assert not whole or f"all {rep['cycles']} intervals were read" in rec.note, rec.note
    res = ctrlunit("replay", str(damaged), "--verify")
    assert res.returncode == 1 and "the recording is damaged" in res.stderr, res.stderr
    # a summary damaged, its records whole: every interval was read and compares
    bad = bytearray(data)
    bad[start + 40] ^= 0x40
    damaged.write_bytes(bad)
    rec = read(damaged)
    assert rec.damaged and not rec.salvaged and "summary section's CRC" in rec.note
    res = ctrlunit("replay", str(damaged), "--verify")
    assert res.returncode == 1, res.stderr
    assert f"all {rep['cycles']} are bit-identical" in res.stderr, res.stderr
    res = ctrlunit("report", str(damaged))  # the run's own result, and the note
    assert res.returncode == 0 and "is damaged" in res.stderr
    assert "FAULT" not in res.stdout and "completed" in res.stdout, res.stdout[-800:]
    # the run's result record, between the chunks (MCAP metadata: no CRC of its own)
    bad = bytearray(data)
    at = data.index(b"block_cost_s") + len(b"block_cost_s") + 4  # past its value's length
    bad[at] ^= 0x40
    damaged.write_bytes(bad)
    rec = read(damaged)
    assert rec.damaged and not rec.salvaged and "data section's CRC" in rec.note, rec.note
    res = ctrlunit("replay", str(damaged), "--verify")
    assert res.returncode == 1 and "damaged outside its intervals" in res.stderr, res.stderr


def test_kill_9_of_the_central_leaves_a_salvageable_recording(tmp_path):
    unit = unit_id("kill")
    path, status = tmp_path / "cut.mcap", tmp_path / "status"
    proc = subprocess.Popen(
        [sys.executable, "-m", "ctrlunit.runtime.cli", "start", "--unit", unit, "--clock",
         "freerun", "--pipeline", "2", "--cycles", "1000000", "--record", str(path),
         "--status-file", str(status)],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    try:
        wait_status(status, 3000)
        os.kill(proc.pid, signal.SIGSTOP)  # freeze it to read how far it got
        done = int(status.read_text())
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(timeout=5)
    finally:
        kill_unit(unit)
        if proc.poll() is None:
            proc.kill()
    assert not wait_gone(unit, timeout=3), "children outlived the killed central"
    with pytest.raises(Exception):  # noqa: B017 - the seeking reader needs the footer
        with open(path, "rb") as fh:
            list(make_reader(fh).iter_messages())
    rec = read(path)
    assert rec.salvaged and "cut off" in rec.note
    salvaged = len(rec.topics["/plant/command"])
    print(f"killed after >= {done} intervals; salvaged {salvaged}")
    # lost: the open chunk and at most one closed chunk not yet written (an interval here
    # is over 3 KB uncompressed), and the status file's granularity of 10 intervals
    chunk_intervals = CHUNK_SIZE // 3000
    assert done - salvaged <= 2 * chunk_intervals + 10
    res = ctrlunit("report", str(path))
    assert res.returncode == 0 and "salvaged" in res.stderr
    n, div = verify(rec)
    assert div is None and n >= salvaged - 1


@pytest.fixture(scope="module")
def short(tmp_path_factory):
    """A 200-interval lockstep recording (n = 1) and its commands' recorded times and
    cycles."""
    d = tmp_path_factory.mktemp("short")
    path = d / "short.mcap"
    code, _, out = start_json(d, "--peripherals", "1", "--clock", "lockstep", "--cycles",
                              "200", "--record", str(path), tag="short")
    assert code == 0, out
    cmds = [(t, m["cycle"]) for t, m in read(path).decoded("/plant/command")]
    return path, cmds


def _republished(path, *options: str) -> list[tuple[int, int]]:
    """``ctrlunit replay FILE OPTIONS`` (the CLI's entry point, in this process) to a
    subscriber of its own: each command's arrival time (ns) and cycle."""
    import queue as q

    import msgpack
    import zenoh
    from click.testing import CliRunner
    from ctrlunit.runtime.cli import cli
    from ctrlunit.runtime.transport.zsession import make_config
    from test_fuzz import free_port

    port, unit = free_port(), unit_id("replay")
    got: q.SimpleQueue = q.SimpleQueue()

    def on(x) -> None:
        got.put((time.monotonic_ns(), str(x.key_expr), x.payload.to_bytes()))

    with zenoh.open(make_config(listen=[f"tcp/127.0.0.1:{port}"])) as s:
        sub = s.declare_subscriber(f"ctrlunit/{unit}/**", on)
        res = CliRunner().invoke(cli, ["replay", str(path), "--unit", unit, "--connect",
                                       f"tcp/127.0.0.1:{port}", "--topics", "/plant/command",
                                       "--wait-subscribers", "10", *options])
        time.sleep(0.3)
        sub.undeclare()
    assert res.exit_code == 0, (res.output, res.exception)
    out = []
    while not got.empty():
        t, key, data = got.get()
        assert key == f"ctrlunit/{unit}/plant/command"
        out.append((t, msgpack.unpackb(data)["cycle"]))
    return out


def test_replay_options_do_what_they_say(short):
    """--rate scales the pace (two rates side by side: the arrival spans' ratio), --cycles
    selects exactly its intervals, --start-offset starts at the recorded time asked, --loop
    starts again from the first interval, --csv writes the intervals asked."""
    path, cmds = short
    slow = _republished(path, "--rate", "0.5")
    fast = _republished(path, "--rate", "2")
    assert [c for _, c in slow] == [c for _, c in fast] == [c for _, c in cmds]
    span = [(m[-1][0] - m[0][0]) / 1e9 for m in (slow, fast)]
    recorded = (cmds[-1][0] - cmds[0][0]) / 1e9
    print(f"recorded span {recorded:.3f} s; republished at rate 0.5 in {span[0]:.3f} s, at "
          f"rate 2 in {span[1]:.3f} s (ratio {span[0] / span[1]:.2f}, 4 asked)")
    # 4 asked; this machine stalls up to ~45 ms, which the shorter span may take
    assert 2.5 < span[0] / span[1] < 6.0
    assert span[0] == pytest.approx(2.0 * recorded, rel=0.3)

    sel = _republished(path, "--rate", "10", "--cycles", "50:60")
    assert [c for _, c in sel] == list(range(50, 60))

    t100 = next(t for t, c in cmds if c == 100)
    offset = (t100 - cmds[0][0]) / 1e9 - 1e-7
    late = _republished(path, "--rate", "10", "--start-offset", repr(offset))
    assert [c for _, c in late] == list(range(100, 200))

    looped = _republished(path, "--rate", "10", "--cycles", "0:20", "--loop",
                          "--max-seconds", "0.5")
    cycles = [c for _, c in looped]
    assert len(cycles) > 40, len(cycles)  # more than two passes
    assert cycles == (list(range(20)) * (len(cycles) // 20 + 1))[:len(cycles)]

    from click.testing import CliRunner
    from ctrlunit.runtime.cli import cli

    csv_dir = path.parent / "csv"
    res = CliRunner().invoke(cli, ["replay", str(path), "--csv", str(csv_dir), "--cycles",
                                   "10:20"])
    assert res.exit_code == 0, res.output
    rows = (csv_dir / "signals.csv").read_text().splitlines()
    assert rows[0].startswith("cycle,t,p_x") and len(rows) == 11
    assert [int(r.split(",")[0]) for r in rows[1:]] == list(range(10, 20))


def test_replay_follows_the_link_rule(short, tmp_path):
    """A republished recording carries the run's samples and commands: an endpoint
    another host can reach, or a unix socket in a folder others may write, is refused
    (exit 1, naming it and --insecure) before anything is sent, as the unit's own links
    are (an attacker's review, 2026-11-28, found replay unchecked)."""
    from click.testing import CliRunner
    from ctrlunit.runtime.cli import cli

    path, _ = short
    shared = tmp_path / "shared"
    shared.mkdir()
    shared.chmod(0o1777)
    for args, says in ((["--listen", "tcp/0.0.0.0:0"], "can be reached from other hosts"),
                       (["--connect", "tcp/192.0.2.1:7447"], "can be reached from other hosts"),
                       (["--connect", f"unixsock-stream/{shared}/c.sock"],
                        f"its folder {shared} may be written by others")):
        res = CliRunner().invoke(cli, ["replay", str(path), *args])
        assert res.exit_code == 1, (args, res.output)
        assert says in res.output and "--insecure" in res.output, res.output


def test_replay_selects_the_intervals_of_json_channels_too(short):
    """``--cycles A:B`` keeps the messages of those intervals on every channel that names
    its interval, the JSON ``/signals/state`` too (it used to keep none of them: only
    msgpack was read, and replay printed "republished 0 messages")."""
    from ctrlunit.runtime.recording import republish

    path, _ = short
    rec = read(path)
    want = [json.loads(d)["cycle"] for _, d in rec.topics["/signals/state"]]
    want = [c for c in want if 50 <= c < 100]
    assert want  # the recording holds states there
    sent = republish.republish(rec, unit=unit_id("json"), rate=1000.0,
                               topics=["/signals/state"], cycles=(50, 100),
                               wait_subscribers=0.0)
    assert sent == len(want)


def test_replay_waits_for_subscribers_at_most_the_time_asked(short, monkeypatch):
    """With nobody listening, ``replay --wait-subscribers S`` polls Zenoh's matching
    status for S seconds, then sends anyway: the CLI with a real session, on a clock the
    test moves (each 5 ms poll advances it), so the bound is exact, not a wall-time
    window."""
    from click.testing import CliRunner
    from ctrlunit.runtime.cli import cli
    from ctrlunit.runtime.recording import republish

    class Clock:
        def __init__(self) -> None:
            self.now, self.polls = 1000.0, 0.0

        def monotonic(self) -> float:
            return self.now

        def sleep(self, s: float) -> None:
            self.polls += s if s == 0.005 else 0.0  # the matching status's polls
            self.now += s

    path, _ = short
    waited = {}
    for wait in ("0", "1.5"):
        clock = Clock()
        monkeypatch.setattr(republish, "time", clock)
        res = CliRunner().invoke(cli, ["replay", str(path), "--unit", unit_id("nobody"),
                                       "--topics", "/plant/command", "--cycles", "0:5",
                                       "--rate", "100", "--wait-subscribers", wait])
        assert res.exit_code == 0, res.output
        assert "republished 5 messages" in res.output
        waited[wait] = clock.polls
    assert waited["0"] == 0.0
    assert 1.5 <= waited["1.5"] <= 1.5 + 0.005 + 1e-9


def test_report_of_a_recording_gives_the_live_tracking_figures_to_the_bit(tmp_path):
    """``ctrlunit report FILE.mcap`` against the run's own report: the same tracking max
    and rms to the bit. The reference at a sample time once came from the task's cache,
    filled by whichever nearby time asked first (the live run's blocks; nothing in the
    report), so the rms differed in its last bits."""
    mcap = tmp_path / "run.mcap"
    code, live, out = start_json(tmp_path, "--peripherals", "3", "--pipeline", "2",
                                 "--clock", "lockstep", "--record", str(mcap), tag="rms")
    assert code == 0, out
    res = ctrlunit("report", str(mcap), "--json", timeout=120)
    assert res.returncode == 0, res.stderr
    again = json.loads(res.stdout)
    assert again["tracking_error_m"] == live["tracking_error_m"]
    assert again["command_digest"] == live["command_digest"]


def test_a_cut_off_recording_gives_no_central_business_it_cannot_know(recorded, tmp_path):
    """A new user's review: a cut-off file's report gave 'business central 20 %' where
    the run's was 70 %: without the result record the figures come from the spans, and
    the central's spans are its blocks alone, not its busy time. That one is left out;
    the peripherals' spans are their busy time, and stay."""
    from ctrlunit.runtime.recording.recorded_report import report_from_recording

    path, _ = recorded
    data = path.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) // 2])
    whole, part = report_from_recording(read(path)), report_from_recording(read(cut))
    assert "central" in whole["business"] and "central" not in part["business"]
    assert set(part["business"]) == {"peripheral_1", "peripheral_2", "peripheral_3"}
