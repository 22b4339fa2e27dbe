"""``ctrlunit ik``, ``fk``, ``trajectory`` and ``workspace``: the kernels on the command
line."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import click
import numpy as np

from ...kernels.params import DeltaParams, ParameterError
from .base import NUMERIC, FilePath, _emit, _fail, _params, cli, params_option, warn


@cli.command(context_settings=NUMERIC, short_help="Inverse kinematics: joint angles of a point.")
@click.argument("x", type=float)
@click.argument("y", type=float)
@click.argument("z", type=float)
@click.option("--deg", is_flag=True, help="Print joint angles in degrees.")
@click.option("--json", "as_json", is_flag=True, help="JSON on stdout.")
@params_option
def ik(x: float, y: float, z: float, deg: bool, as_json: bool, params_file: str | None) -> None:
    """Inverse kinematics (Eq. V.16-V.21): joint angles for platform position X Y Z (m)."""
    from ...kernels.kinematics import UnreachableError, inverse_kinematics
    from ...kernels.workspace import check_point

    try:
        params = _params(params_file)
        q = inverse_kinematics(params, (x, y, z))
    except (UnreachableError, ParameterError, ValueError) as exc:
        _fail(str(exc))
        return
    chk = check_point(params, (x, y, z))
    qo = np.degrees(q) if deg else q
    unit = "deg" if deg else "rad"
    data = {"q": qo.tolist(), "unit": unit, "usable": chk.ok, "min_eig": chk.min_eig}
    _emit(data, as_json, "q = [" + ", ".join(f"{v:.9g}" for v in qo) + f"] {unit}")
    if not chk.ok:  # an answer all the same (exit 0); --json says it as "usable": false
        warn(chk.reason)


@cli.command(context_settings=NUMERIC,
             short_help="Forward kinematics: platform position of joint angles.")
@click.argument("q1", type=float)
@click.argument("q2", type=float)
@click.argument("q3", type=float)
@click.option("--deg", is_flag=True, help="Joint angles are in degrees.")
@click.option("--json", "as_json", is_flag=True, help="JSON on stdout.")
@params_option
def fk(q1: float, q2: float, q3: float, deg: bool, as_json: bool, params_file: str | None) -> None:
    """Forward kinematics: platform position (m) for joint angles Q1 Q2 Q3 (rad)."""
    from ...kernels.forward import fk_closed_form, fk_newton
    from ...kernels.kinematics import UnreachableError

    unit = "deg" if deg else "rad"
    bound = 180.0 if deg else math.pi
    for name, v in (("Q1", q1), ("Q2", q2), ("Q3", q3)):
        if not -bound <= v <= bound:  # NaN too
            _fail(f"{name} = {v:g} {unit} is outside [{-bound:g}, {bound:g}] {unit} "
                  "(an arm angle)")
    q = np.array([q1, q2, q3], dtype=float)
    if deg:
        q = np.radians(q)
    try:
        params = _params(params_file)
    except ParameterError as exc:
        _fail(str(exc))
        return
    no_pose = (f"joint angles [{q1:g}, {q2:g}, {q3:g}] {unit} give no platform position: "
               f"the forearms (l_b = {params.l_b} m) cannot close the three loops")
    try:
        p0 = fk_closed_form(params, q)
        # refine with the Newton-Raphson observer to one encoder increment
        p = np.array(fk_newton(params, q, p0, tol=1e-12).p)
    except (UnreachableError, ValueError, ZeroDivisionError, FloatingPointError):
        _fail(no_pose)
        return
    if not np.all(np.isfinite(p)):
        _fail(no_pose)
    _emit({"p": p.tolist()}, as_json, "p = [" + ", ".join(f"{v:.9g}" for v in p) + "] m")


def trajectory_summary(params: DeltaParams, name: str, *, samples: int = 2001) -> dict[str, Any]:
    """Figures of a task's path, one way (see ``ctrlunit trajectory``)."""
    from ...kernels.kinematics import inverse_kinematics
    from ...kernels.task_file import get_task
    from ...kernels.workspace import stiffness_eigenvalues

    task = get_task(name)
    ts = np.linspace(0.0, task.duration, samples)
    pts, speed, acc = [], 0.0, 0.0
    for t in ts:
        p, v, a = task.sample_path(float(t))
        pts.append(p)
        speed = max(speed, float(np.linalg.norm(v)))
        acc = max(acc, float(np.linalg.norm(a)))
    qs = np.array([inverse_kinematics(params, p) for p in pts])
    eigs = np.array([stiffness_eigenvalues(params, p) for p in pts])
    tangential = max(s.accel for s in task.segments)
    return {
        "task": task.name,
        "length_m": task.length,
        "duration_s": task.duration,
        "peak_speed_mps": speed,
        "peak_accel_mps2": tangential,
        "peak_total_accel_mps2": acc,
        "min_eig": float(eigs[:, 0].min()),
        "max_eig": float(eigs[:, -1].max()),
        "q_min_rad": float(qs.min()),
        "q_max_rad": float(qs.max()),
        "in_joint_box": bool(qs.min() >= params.q_min and qs.max() <= params.q_max),
        "usable": bool(
            eigs[:, 0].min() >= params.beta_min and eigs[:, -1].max() <= params.beta_max
        ),
        "thesis_length_m": task.reference_length_m,
        "thesis_duration_s": task.reference_duration_s,
    }


@cli.command(short_help="Figures of a task: length, duration, peaks, joint range.")
@click.argument("name")
@click.option("--json", "as_json", is_flag=True, help="JSON on stdout.")
@params_option
def trajectory(name: str, as_json: bool, params_file: str | None) -> None:
    """Figures of a task (circle, pick-place or a JSON file): length, duration, peaks,
    smallest eigenvalue of l_a^2 J^-T J^-1 (Eq. V.33), joint range."""
    from ..observe.report import quoted

    try:
        data = trajectory_summary(_params(params_file), name)
    except (ValueError, ParameterError) as exc:
        _fail(str(exc))
        return
    lines = [
        f"task {quoted(data['task'])}",
        f"  length            {data['length_m']:.4f} m"
        + (f"   (thesis: {data['thesis_length_m']} m)" if data["thesis_length_m"] else ""),
        f"  duration          {data['duration_s']:.4f} s"
        + (f"   (thesis: {data['thesis_duration_s']} s)" if data["thesis_duration_s"] else ""),
        f"  peak speed        {data['peak_speed_mps']:.3f} m/s",
        f"  peak tangential   {data['peak_accel_mps2']:.1f} m/s^2"
        f"   (total {data['peak_total_accel_mps2']:.1f} m/s^2)",
        f"  eig l_a^2 J^-T J^-1 in [{data['min_eig']:.3f}, {data['max_eig']:.3f}]"
        f"   usable (Eq. V.33): {'yes' if data['usable'] else 'NO'}",
        f"  q in [{math.degrees(data['q_min_rad']):.2f}, {math.degrees(data['q_max_rad']):.2f}]"
        f" deg   inside the joint box (Eq. V.32): {'yes' if data['in_joint_box'] else 'no'}",
    ]
    _emit(data, as_json, "\n".join(lines))


@cli.command(short_help="Workspace maps (Fig. 28-29) and the usable workspace.")
@click.option("--png", type=FilePath(dir_okay=False), default=None, help="Write the maps.")
@click.option("--json", "as_json", is_flag=True, help="JSON on stdout.")
@click.option("--grid", type=click.IntRange(11, 401), default=61, show_default=True,
              help="Grid points per side of each slice.")
@params_option
def workspace(png: str | None, as_json: bool, grid: int, params_file: str | None) -> None:
    """Usable workspace: det J maps on horizontal slices (Fig. 28) and the smallest
    eigenvalue of l_a^2 J^-T J^-1 against the joint bounds (Fig. 29)."""
    from ...bench.workspace_maps import workspace_report

    try:
        params = _params(params_file)
        data = workspace_report(params, png=Path(png) if png else None, grid=grid)
    except (ValueError, ParameterError, OSError) as exc:
        _fail(str(exc))
        return
    lines = [f"usable workspace (Eq. V.33, beta_min = {params.beta_min:g})"]
    for s in data["slices"]:
        lines.append(
            f"  z = {s['z_m']:+.3f} m: reachable {s['reachable_fraction']*100:5.1f} %, usable "
            f"{s['usable_fraction']*100:5.1f} %, min eig {s['min_eig']:.3f}"
        )
    lines.append(
        f"  joint box [{data['q_min_deg']:.0f}, {data['q_max_deg']:.0f}] deg: smallest eigenvalue "
        f"{data['box_min_eig']:.3f} (thesis: beta = 0.1 for [-125, 15] deg)"
    )
    if png:
        lines.append(f"  maps written to {png}")
    _emit(data, as_json, "\n".join(lines))
