"""Bad input is refused before any motion, naming the point or field and the bound."""

from __future__ import annotations

import json

from runner import ctrlunit


def test_task_leaving_the_usable_workspace_is_refused_before_motion(tmp_path):
    task = tmp_path / "reach.json"
    task.write_text(json.dumps({"segments": [
        {"type": "line", "start": [0, 0, -0.4], "end": [0, 0, -0.15], "accel": 20}]}))
    res = ctrlunit("start", "--task", str(task), "--clock", "lockstep", "--peripherals", "0")
    assert res.returncode == 1
    assert "refused at sample" in res.stderr and "beta_max" in res.stderr
    assert "intervals" not in res.stdout  # nothing ran


def test_out_of_range_options_name_the_field_and_range():
    """One line, exit 1, however the value is wrong (a new user's review found click's
    usage error, exit 2, for some and this for others)."""
    res = ctrlunit("start", "--period", "5us", "--peripherals", "0")
    assert res.returncode == 1 and "period" in res.stderr and "20us to 1s" in res.stderr
    for args, said in ((("--period", "fast"), "--period = 'fast': allowed auto, or 20us to 1s"),
                       (("--period", "-1ms"), "--period = '-1ms': allowed auto, or 20us"),
                       (("--peripherals", "4"), "--peripherals = 4: allowed 0, 1, 2 or 3"),
                       (("--max-error", "0"),
                        "--max-error = 0: allowed 1e-05 to 1, in metres (10 um to 1 m)")):
        res = ctrlunit("start", "--check", *args)
        err = res.stderr.strip().splitlines()
        assert res.returncode == 1 and len(err) == 1, (args, res.stderr)
        assert err[0].startswith(f"ctrlunit: error: {said}"), (args, err)
    res = ctrlunit("start", "--unit", "bad/unit")
    assert res.returncode == 1 and "unit" in res.stderr


def test_bad_placement_file_is_refused(tmp_path):
    pl = tmp_path / "p.json"
    pl.write_text(json.dumps({"peripherals": 2, "axes": [[0, 1], [1]]}))
    res = ctrlunit("start", "--peripherals", "2", "--placement", str(pl))
    assert res.returncode == 1 and "cover axes 0, 1, 2 exactly once" in res.stderr


def test_bad_parameter_file_is_refused(tmp_path):
    f = tmp_path / "robot.toml"
    f.write_text("[delta]\nm_c = -3\n")
    res = ctrlunit("start", "--params", str(f), "--peripherals", "0")
    assert res.returncode == 1 and "m_c" in res.stderr and "[0.0, 100.0] kg" in res.stderr


# -- edge inputs: exit 0 only with a finite answer; otherwise one line naming the input --


def one_line_error(res) -> str:
    """The error a command printed: exactly one line on stderr, no traceback."""
    assert "Traceback" not in res.stderr + res.stdout
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1, res.stderr
    assert lines[0].startswith("ctrlunit: error: ")
    return lines[0]


def test_ik_of_a_point_so_far_that_its_squares_overflow_is_refused():
    res = ctrlunit("ik", "0", "0", "1e308")
    assert res.returncode == 1 and "nan" not in res.stdout
    assert "(0, 0, 1e+308) m is out of reach" in one_line_error(res)


def test_fk_names_the_angle_out_of_range_not_a_point():
    res = ctrlunit("fk", "0", "0", "1e308")
    assert res.returncode == 1
    assert "Q3 = 1e+308 rad is outside [-3.14159, 3.14159] rad" in one_line_error(res)
    res = ctrlunit("fk", "3", "3", "3")  # inside the range, but no loop closes
    err = one_line_error(res)
    assert res.returncode == 1 and "joint angles [3, 3, 3] rad give no platform position" in err
    assert "point" not in err


def test_a_task_file_reaching_1e308_m_gives_the_same_one_line_error_to_every_command(tmp_path):
    task = tmp_path / "far.json"
    task.write_text(json.dumps({"segments": [
        {"type": "line", "start": [0, 0, -0.35], "end": [1e308, 0, -0.35], "accel": 10}]}))
    want = "segments[0].end must be a list of 3 numbers within +-10 m"
    res = ctrlunit("trajectory", str(task))
    assert res.returncode == 1 and want in one_line_error(res)
    res = ctrlunit("start", "--task", str(task), "--clock", "lockstep", "--peripherals", "0")
    assert res.returncode == 1 and want in one_line_error(res)
    task.write_text(json.dumps({"segments": [
        {"type": "line", "start": [0, 0, -0.35], "end": [0.1, 0, -0.35], "accel": True}]}))
    res = ctrlunit("trajectory", str(task))
    assert res.returncode == 1 and "segments[0].accel must be in (0, 1000]" in one_line_error(res)


def test_a_task_name_is_a_string_shown_in_quotes(tmp_path):
    task = tmp_path / "named.json"
    segment = {"type": "line", "start": [0, 0, -0.35], "end": [0.1, 0, -0.35], "accel": 10}
    for name in ("INF", "nan", 'a "quoted"\nname'):
        task.write_text(json.dumps({"name": name, "segments": [segment]}))
        res = ctrlunit("trajectory", str(task))
        assert res.returncode == 0, res.stderr
        assert res.stdout.splitlines()[0] == "task " + json.dumps(name)  # not a figure
    for name in (float("nan"), 1, "", "x" * 201, None):
        task.write_text(json.dumps({"name": name, "segments": [segment]}))
        res = ctrlunit("trajectory", str(task))
        assert res.returncode == 1
        assert "name must be a string of 1 to 200 characters" in one_line_error(res)


def test_report_of_a_recording_cut_before_its_first_interval_is_an_error(tmp_path):
    from ctrlunit.runtime.recording.mcap_writer import LeanWriter

    path = tmp_path / "cut.mcap"
    with open(path, "wb") as fh:
        w = LeanWriter(fh)
        w.start(profile="ctrlunit", library="ctrlunit")
        w.add_metadata("ctrlunit", {"config": "{}"})
        w.finish()
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])  # no footer, no message
    res = ctrlunit("report", str(path))
    assert res.returncode == 1 and "salvaged 0" not in res.stdout + res.stderr
    assert "cut off before its first interval" in one_line_error(res)


# -- an attacker's inputs (2026-11-28): each was a traceback, a hang, a memory blow-up or a
# -- segfault; each is now one line on stderr and exit 1

def _one_error(res, *words: str) -> None:
    err = res.stderr.strip().splitlines()
    assert res.returncode == 1 and len(err) == 1, (res.returncode, res.stderr[-2000:])
    assert err[0].startswith("ctrlunit: error: ") and all(w in err[0] for w in words), err


def test_a_fifo_or_a_device_given_as_a_file_is_refused_not_read(tmp_path):
    """A FIFO hung report, plot, replay, export and balance; /dev/zero filled balance's
    memory (12 GB in 10 s)."""
    import os

    fifo = tmp_path / "r.mcap"
    os.mkfifo(fifo)
    for args in (["report", str(fifo)], ["replay", str(fifo), "--verify"],
                 ["balance", str(fifo)], ["balance", "/dev/zero"]):
        _one_error(ctrlunit(*args, timeout=60), "is not a regular file")
    # an attacker's review: --placement read a FIFO for ever, /dev/zero until memory ran out
    for path in (fifo, "/dev/zero"):
        _one_error(ctrlunit("start", "--check", "--clock", "lockstep", "--placement",
                            str(path), timeout=60), str(path), "not a regular file")


def test_input_nested_too_deeply_or_not_utf8_is_refused(tmp_path):
    deep = tmp_path / "deep.json"
    deep.write_text("[" * 100_000 + "]" * 100_000)
    _one_error(ctrlunit("balance", str(deep), timeout=60), "nested too deeply")
    # Zenoh's own parser died of SIGSEGV on it (exit 139)
    _one_error(ctrlunit("start", "--check", "--clock", "lockstep", "--zenoh-config",
                        str(deep), timeout=60), "--zenoh-config", "nested 100000 levels")
    garbage = tmp_path / "run.toml"
    garbage.write_bytes(b"\xff\xfe[a]\n")
    _one_error(ctrlunit("start", "--check", "--config", str(garbage), timeout=60),
               "not UTF-8")


def test_every_input_file_is_read_by_one_rule(tmp_path):
    """A task, a parameters file, a placement, a run file and a Zenoh configuration: each
    larger than 1 MiB or not UTF-8 is refused naming the file, as kernels/small_file.py
    says, before anything starts (an attacker's review parsed a run file of 100 MB)."""
    big = tmp_path / "big.json"
    big.write_text(" " * ((1 << 20) + 1))
    bad = tmp_path / "bad.json"
    bad.write_bytes(b"\xff\xfe{}")
    for flag, name in (("--task", "task file"), ("--params", "parameters file"),
                       ("--placement", "placement file"), ("--config", "--config"),
                       ("--zenoh-config", "--zenoh-config")):
        for path, said in ((big, "is larger than 1048576 bytes"), (bad, "is not UTF-8 text")):
            _one_error(ctrlunit("start", "--check", "--clock", "lockstep", flag, str(path),
                                timeout=60), f"{name} {path} {said}")


def test_a_pin_that_names_no_cpu_of_this_machine_is_refused_at_the_check():
    """--check let ``--pin a,b`` (and 99999, -1) pass; the run then raised from
    sched_setaffinity and left its run directory behind."""
    for pin in ("a,b", "99999", "-1", "0,"):
        _one_error(ctrlunit("start", "--check", "--clock", "lockstep", f"--pin={pin}",
                            timeout=60), f"--pin '{pin}'", "allowed CPUs of this machine")
    assert ctrlunit("start", "--check", "--clock", "lockstep", "--pin=0",
                    timeout=60).returncode == 0


def test_a_task_file_s_path_is_continuous_and_each_segment_a_curve(tmp_path):
    """A new attacker's review: a gap between two segments passed every check and then
    faulted the run at 50 mm of tracking error; a half ellipse whose top lies on its chord
    divided by zero; an unknown field and 20 000 segments went through. Each is refused by
    the file, the segment and the field, before any motion."""
    import pytest
    from ctrlunit.kernels.task_file import MAX_SEGMENTS, task_from_json

    def line(a: list[float], b: list[float], **extra: object) -> dict:
        return {"type": "line", "start": a, "end": b, "accel": 50, **extra}

    task = tmp_path / "t.json"
    p0, p1, p2 = [0, 0, -0.35], [0.05, 0, -0.35], [0.1, 0, -0.35]
    task.write_text(json.dumps({"segments": [line(p0, p1), line(p1, p2)]}))
    assert len(task_from_json(task).segments) == 2  # joined: accepted
    for segments, said in (
            ([line(p0, p1), line(p2, p1)],
             "segments[1] starts 50 mm from where segments[0] ends (0.05, 0, -0.35)"),
            ([{"type": "half-ellipse", "start": p0, "top": [0.025, 0, -0.35], "end": p1,
               "accel": 50}], "segments[0]: half-ellipse: start and end must differ, and top "
             "lie off the line"),
            ([line(p0, p1, zz=1)], "segments[0]: unknown field 'zz' (a line has type, start, "
             "end and accel)"),
            ([line(p0, p1)] * (MAX_SEGMENTS + 1), f"a task has 1 to {MAX_SEGMENTS} segments")):
        task.write_text(json.dumps({"segments": segments}))
        with pytest.raises(ValueError, match=None) as err:
            task_from_json(task)
        assert said in str(err.value) and str(task) in str(err.value), str(err.value)
    with pytest.raises(ValueError, match="not a regular file"):
        task_from_json(tmp_path)
    task.write_text(json.dumps({"segments": [line(p0, p1), line(p2, p1)]}))
    res = ctrlunit("start", "--task", str(task), "--clock", "lockstep", "--peripherals", "0")
    assert res.returncode == 1 and "the path must be continuous" in one_line_error(res)
    assert "intervals" not in res.stdout  # nothing ran
