"""The first commands: ik, fk, trajectory, workspace."""

from __future__ import annotations

import json
import math
import subprocess
import sys

import pytest


def run(*args: str, timeout: float = 120) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "ctrlunit.runtime.cli", *args],
        capture_output=True, text=True, timeout=timeout,
    )


def test_ik_json_gives_radians():
    res = run("ik", "0", "0", "-0.35", "--json")
    assert res.returncode == 0, res.stderr
    q = json.loads(res.stdout)["q"]
    assert all(math.isclose(math.degrees(v), -21.2825, abs_tol=1e-3) for v in q)


def test_fk_inverts_ik_in_degrees():
    res = run("fk", "-21.28254473", "-21.28254473", "-21.28254473", "--deg", "--json")
    assert res.returncode == 0, res.stderr
    p = json.loads(res.stdout)["p"]
    assert math.isclose(p[2], -0.35, abs_tol=1e-8) and abs(p[0]) < 1e-9


def test_unreachable_point_fails_on_stderr():
    res = run("ik", "0", "0", "-2", "--json")
    assert res.returncode != 0
    assert "(0, 0, -2)" in res.stderr and res.stdout == ""


@pytest.mark.parametrize("name", ["circle", "pick-place"])
def test_trajectory_json_keys(name):
    res = run("trajectory", name, "--json")
    assert res.returncode == 0, res.stderr
    data = json.loads(res.stdout)
    for key in ("length_m", "duration_s", "peak_speed_mps", "peak_accel_mps2", "min_eig",
                "q_min_rad", "q_max_rad"):
        assert isinstance(data[key], float)


def test_unknown_task_is_refused():
    res = run("trajectory", "figure-eight")
    assert res.returncode != 0 and "circle" in res.stderr


def test_workspace_writes_png(tmp_path):
    png = tmp_path / "ws.png"
    res = run("workspace", "--png", str(png), "--grid", "21", "--json")
    assert res.returncode == 0, res.stderr
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    data = json.loads(res.stdout)
    assert len(data["slices"]) == 7 and 0.0 < data["box_min_eig"] < 1.0
