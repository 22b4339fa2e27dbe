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
    res = ctrlunit("start", "--period", "5us", "--peripherals", "0")
    assert res.returncode == 1 and "period" in res.stderr and "20us to 1s" in res.stderr
    res = ctrlunit("start", "--period", "fast")
    assert res.returncode == 2 and "--period" in res.stderr
    res = ctrlunit("start", "--peripherals", "4")
    assert res.returncode == 2 and "0<=x<=3" in res.stderr.replace(" ", "")
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
