"""A recording is input too: an edited, forged or damaged file's metadata gives one line
naming what is wrong, never a traceback, and what a recording holds is printed checked
(a fault's text stays one summary line). Also ``--late`` names only blocks the law has."""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from click.testing import CliRunner
from ctrlunit.runtime.cli import cli
from loopback import record_lockstep
from mcap.reader import make_reader
from mcap.writer import Writer
from runner import unit_id

Edit = Callable[[str, dict[str, str]], dict[str, str] | None]


@pytest.fixture(scope="module")
def recorded(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("rec") / "run.mcap"
    record_lockstep(str(path), unit_id("recin"), peripherals=1, cycles=30)
    return path


def forged(src: Path, dst: Path, edit: Edit,
           message: Callable[[str, int, bytes], bytes] | None = None) -> Path:
    """``src`` written again with each metadata record passed through ``edit`` (None:
    left out) and each message's data through ``message(topic, index in its topic,
    data)``, everything else as it was."""
    with open(src, "rb") as fh:
        r = make_reader(fh)
        summary = r.get_summary()
        assert summary is not None
        messages = list(r.iter_messages(log_time_order=False))
        metadata = list(r.iter_metadata())
    with open(dst, "wb") as out:
        w = Writer(out)
        w.start(profile="", library="test")
        schemas = {sid: w.register_schema(s.name, s.encoding, s.data)
                   for sid, s in summary.schemas.items()}
        channels = {cid: w.register_channel(c.topic, c.message_encoding,
                                            schemas.get(c.schema_id, 0), c.metadata)
                    for cid, c in summary.channels.items()}
        seen: dict[str, int] = {}
        for _schema, channel, m in messages:
            k = seen[channel.topic] = seen.get(channel.topic, -1) + 1
            data = m.data if message is None else message(channel.topic, k, m.data)
            w.add_message(channels[channel.id], m.log_time, data, m.publish_time)
        for m in metadata:
            kept = edit(m.name, dict(m.metadata))
            if kept is not None:
                w.add_metadata(m.name, kept)
        w.finish()
    return dst


def result(**fields: str) -> Edit:
    return lambda name, md: md | fields if name == "ctrlunit.result" else md


def run(*args: str) -> tuple[int, str]:
    res = CliRunner().invoke(cli, list(args))
    return res.exit_code, res.output


@pytest.mark.parametrize(("edit", "said"), [
    (result(fault="{oops"), "its result record's fault = '{oops': allowed JSON"),
    (result(busy=json.dumps({"central_wait_ns": 1, "plant_busy_ns": 1,
                             "periph_busy_ns": []})),
     "busy.periph_busy_ns = '[]': allowed a list of 1 integers"),
    (result(busy=json.dumps({"central_wait_ns": -10**12, "plant_busy_ns": 1,
                             "periph_busy_ns": [1]})), "busy.central_wait_ns"),
    (result(rejected="[1, 2]"), "rejected = '[1, 2]': allowed an object"),
    (result(rejected=json.dumps({"\x1b]0;t\x07": 1})), "rejected key"),
    (result(rejected=json.dumps({"a": -5})), "allowed an integer 0 or more"),
    (result(cpu=json.dumps({"cpu_per_interval_s": "abc"})), "cpu.cpu_per_interval_s"),
    (result(t1_s="-1"), "t1_s = '-1': allowed a number of seconds"),
    (result(block_cost_s=json.dumps({"reference": "7e-6"})), "block_cost_s.reference"),
    (result(block_cost_s=json.dumps({"zz": 1e-6})), "block_cost_s key = 'zz'"),
    (result(live=json.dumps({"late": "x"})), "the recording's metadata will not do"),
    (result(live=json.dumps({"nosuchkey": 1})), "live key = 'nosuchkey'"),
    (result(fault=json.dumps({"process": "plant", "message": "m", "code": "x"})),
     "allowed an object with process and message (text) and code (an exit code"),
    (result(t_start_ns="abc"), "t_start_ns = 'abc': allowed an integer of nanoseconds"),
    (lambda name, md: None, "no run configuration in it"),
    (lambda name, md: md | {"config": "[1, 2]"} if name == "ctrlunit" else md,
     "is not a JSON object: '[1, 2]'"),
])
def test_edited_metadata_is_one_line_naming_it(recorded, tmp_path, edit, said):
    path = forged(recorded, tmp_path / "forged.mcap", edit)
    code, out = run("report", str(path))
    assert code == 1 and said in out and "Traceback" not in out, out


def test_a_fault_s_text_is_printed_on_its_own_line(recorded, tmp_path):
    """Newlines and escape codes in a recorded fault are shown as spaces: the summary's
    FAULT line stays one line, and nothing the file holds moves the terminal's cursor."""
    fault = {"process": "plant\nX", "message": "first\n  FAKE second\x1b[2J", "code": 4}
    path = forged(recorded, tmp_path / "f.mcap", result(fault=json.dumps(fault)))
    code, out = run("report", str(path))
    assert code == 0, out
    line = next(x for x in out.splitlines() if "FAULT" in x)
    assert line == "  FAULT in plant X: first   FAKE second [2J (exit 4)"
    assert "\x1b" not in out and not any(x.startswith("  FAKE") for x in out.splitlines())


def test_report_checks_where_it_writes_before_reading(recorded, tmp_path):
    code, out = run("report", str(recorded), "--report", str(tmp_path / "no" / "r.json"))
    assert code == 1 and "the directory" in out and "does not exist" in out, out


def test_late_names_a_per_axis_block_of_the_law():
    code, out = run("start", "--check", "--late", "nosuchblock=wait")
    assert code == 1 and "no per-axis block 'nosuchblock'" in out and "allowed: accel" in out
    code, out = run("start", "--check", "--late", "jdot=hold")
    assert code == 0, out


@pytest.mark.parametrize(("cut", "said"), [
    (8, "cut off before its first interval was written"),
    (100, "cut off before its first interval was written"),
    (0, "not a readable MCAP recording"),
])
def test_a_file_cut_in_its_first_bytes_says_it_was_cut_off(recorded, tmp_path, cut, said):
    """A recording cut within its first records (a crash right after the start) says so;
    a file that is no MCAP at all says that."""
    path = tmp_path / "cut.mcap"
    path.write_bytes(recorded.read_bytes()[:cut] if cut else b"not an mcap file at all")
    code, out = run("report", str(path))
    assert code == 1 and said in out and "Traceback" not in out, out


def test_a_whole_file_damaged_near_its_start_is_not_called_cut_off(recorded, tmp_path):
    """An attacker's review: one byte flipped at offset 200 of a whole recording read as
    "cut off before its first interval"; the file ends with MCAP's magic, so it was
    changed, not cut off, and says so."""
    data = bytearray(recorded.read_bytes())
    data[200] ^= 0xFF
    path = tmp_path / "flipped.mcap"
    path.write_bytes(bytes(data))
    code, out = run("report", str(path))
    assert code == 1 and "is damaged" in out and "not cut off" in out, out
    assert "Traceback" not in out


def test_a_disk_that_fills_ends_the_recording_not_the_run(tmp_path, monkeypatch):
    """An attacker's review: ``--record`` on a file that stops taking writes (a full disk,
    /dev/full) raised in the central's loop mid-run, then again in its clean-up, past the
    safe stop. A failed write now ends the recording: the run goes to its end, the
    recorder says after how many intervals it stopped and why, and the file holds what
    came before, readable."""
    import errno

    from ctrlunit.runtime.observe.summary_end import end_lines
    from ctrlunit.runtime.recording import recorder as recorder_module
    from ctrlunit.runtime.recording.reader import read

    class Filling:
        """A file that takes 200 kB, then refuses as a full disk does."""

        def __init__(self, path: str, mode: str) -> None:
            self.fh, self.taken = open(path, mode), 0

        def write(self, data: bytes) -> int:
            self.taken += len(data)
            if self.taken > 200_000:
                raise OSError(errno.ENOSPC, "No space left on device")
            return self.fh.write(data)

        def __getattr__(self, name: str) -> object:
            return getattr(self.fh, name)

    monkeypatch.setattr(recorder_module, "open", Filling, raising=False)
    path = tmp_path / "full.mcap"
    unit = record_lockstep(str(path), unit_id("recfull"), peripherals=1, cycles=2000)
    assert unit.central.done == 2000  # every interval ran
    rec_failed = unit.recorder.failed
    assert rec_failed and "No space left on device" in rec_failed, rec_failed
    kept = int(rec_failed.split("after ")[1].split(" ")[0])
    assert 0 < kept < 2000
    salvaged = read(path)
    assert salvaged.salvaged and 0 < len(salvaged.topics["/plant/command"]) <= kept + 2
    said = end_lines({"recording_failed": rec_failed, "cycles": 2000, "periods": 2000,
                      "rejected_messages": {}, "fault": None, "clock": "lockstep"})
    assert any(line.startswith("  recording   stopped after") for line in said), said


def _one(topic: str, k: int, change: Callable[[Any], Any], *, as_json: bool = False
         ) -> Callable[[str, int, bytes], bytes]:
    """A message edit: the ``k``-th message of ``topic`` decoded, changed, encoded again."""
    import msgpack

    def edit(t: str, i: int, data: bytes) -> bytes:
        if t != topic or i != k:
            return data
        if as_json:
            return json.dumps(change(json.loads(data))).encode()
        return msgpack.packb(change(msgpack.unpackb(data, raw=False)))
    return edit


@pytest.mark.parametrize(("name", "message"), [
    ("command-int", _one("/plant/command", 10, lambda m: 0)),
    ("sample-list", _one("/central/sample", 10, lambda m: [1, 2, 3])),
    ("sample-t-inf", _one("/central/sample", 10, lambda m: m | {"t_ns": float("inf")})),
    ("sample-p-text", _one("/central/sample", 10, lambda m: m | {"p": "abc"})),
    ("state-text", _one("/signals/state", 10, lambda m: m | {"period": "x", "q": "x",
                                                             "torque": [1]}, as_json=True)),
])
def test_a_forged_message_is_no_traceback_for_any_command(recorded, tmp_path, name, message):
    """An attacker's review: one message of a recording replaced (a command by 0, a
    sample by a list, a time by infinity, a position by text, a signal by text) ended
    ``report``, ``plot`` and ``replay --verify`` in tracebacks. The readers take a sample
    or a command only as the live roles would, and a signal that is not a number is a
    gap: every command ends in its output or one line, and ``replay --verify`` does not
    verify a forged wire message."""
    import msgpack
    from ctrlunit.runtime.recording.reader import read

    path = forged(recorded, tmp_path / f"{name}.mcap", lambda n, md: md, message)
    for args in (("report", str(path)), ("plot", str(path), "--out", str(tmp_path / "p")),
                 ("replay", str(path), "--verify")):
        res = CliRunner().invoke(cli, list(args))
        assert res.exception is None or isinstance(res.exception, SystemExit), (
            args, res.exception)
        assert "Traceback" not in res.output, res.output
        if args[0] == "replay" and not name.startswith("state"):
            assert res.exit_code == 1 and "diverges" in res.output, res.output
    kept = read(path)
    for topic in ("/plant/command", "/central/sample"):
        assert all(isinstance(m, dict) for _, m in kept.decoded(topic))
    raw = read(recorded)
    assert len(raw.decoded("/central/sample")) == len(raw.topics["/central/sample"])
    assert msgpack.unpackb(raw.topics["/plant/command"][0][1])["cycle"] == 0


def test_a_forged_live_fact_is_named(recorded, tmp_path):
    """A result record whose ``live`` facts have the report's names and the wrong shapes
    named no field (``will not do: AttributeError``); the first such fact is named."""
    path = forged(recorded, tmp_path / "live.mcap",
                  result(live=json.dumps({"late": {}, "degraded": "x", "scheduling": []})))
    code, out = run("report", str(path))
    assert code == 1 and "its result record's live.degraded = 'x'" in out, out


def _config(**fields: object) -> Edit:
    def edit(name: str, md: dict[str, str]) -> dict[str, str]:
        if name == "ctrlunit":
            return md | {"config": json.dumps(json.loads(md["config"]) | fields)}
        return md
    return edit


@pytest.mark.parametrize(("fields", "said"), [
    ({"params": "/dev/zero"}, "params file /dev/zero is not a regular file"),
    ({"placement": "FIFO"}, "is not a regular file"),
    ({"task": "/nonexistent/task.json"}, "task file /nonexistent/task.json: No such file"),
])
def test_a_recording_naming_a_hostile_file_is_refused_by_name(recorded, tmp_path, fields,
                                                              said):
    """An attacker's review: a recording naming /dev/zero as its parameters exhausted the
    reader's memory, and a FIFO as its placement hung report, replay and plot."""
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    fields = {k: str(fifo) if v == "FIFO" else v for k, v in fields.items()}
    path = forged(recorded, tmp_path / "hostile.mcap", _config(**fields))
    for command in (("report",), ("replay", "--verify"), ("plot", "--out",
                                                          str(tmp_path / "p"))):
        code, out = run(command[0], str(path), *command[1:])
        assert code == 1 and said in out and "Traceback" not in out, (command, out)


def test_a_readers_setup_ignores_the_recorded_links(recorded, tmp_path):
    """A Zenoh file of /dev/zero (read until memory ran out) and keys: the run's links are
    no reader's business."""
    path = forged(recorded, tmp_path / "links.mcap",
                  _config(zenoh_config="/dev/zero", keys=str(tmp_path / "nokeys")))
    code, out = run("report", str(path))
    assert code == 0, out


def test_report_and_verify_read_the_task_file_the_run_read(tmp_path):
    """An attacker's review: a task file edited after the run changed the recording's
    report (51 mm, "completed as planned", against 2.4 mm) and failed replay --verify;
    deleted, it made the recording unreadable. The recording holds the file."""
    task = tmp_path / "mine.json"
    task.write_text(json.dumps({"name": "mine", "dwell": 0.05, "segments": [
        {"type": "half-ellipse", "start": [0.125, 0.0, -0.35], "top": [0.0, 0.0, -0.31],
         "end": [-0.125, 0.0, -0.35], "accel": 20.0}]}))
    rec = tmp_path / "task.mcap"
    code, out = run("start", "--clock", "lockstep", "--cycles", "200", "--unit",
                    unit_id("rectask"), "--task", str(task), "--record", str(rec))
    assert code == 0, out
    _, before = run("report", str(rec), "--json")
    task.write_text(task.read_text().replace("-0.31", "-0.2"))
    _, edited = run("report", str(rec), "--json")
    assert json.loads(edited)["tracking_error_m"] == json.loads(before)["tracking_error_m"]
    task.unlink()
    code, out = run("replay", str(rec), "--verify")
    assert code == 0 and "verified 200 intervals" in out, out


def test_a_forged_cycle_number_in_the_signals_is_no_traceback_for_plot(recorded, tmp_path):
    """An attacker's review: one /signals/state message with cycle 1e308 ended plot in an
    OverflowError traceback."""
    def huge(topic: str, k: int, data: bytes) -> bytes:
        if topic == "/signals/state" and k == 10:
            return json.dumps(json.loads(data) | {"cycle": 1e308}).encode()
        return data
    path = forged(recorded, tmp_path / "huge.mcap", lambda name, md: md, huge)
    code, out = run("plot", str(path), "--out", str(tmp_path / "p"))
    assert code == 0 and "Traceback" not in out, out
