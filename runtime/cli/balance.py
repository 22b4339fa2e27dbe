"""``ctrlunit balance``: where a run's time goes, the placement the thesis's rules
recommend, and the command that runs it as the prediction assumes."""

from __future__ import annotations

import json
import math
import shlex
from typing import Any

import click

from ..config import EXIT_CONFIG
from .base import FilePath, _fail, _json_safe, cli, warn


@cli.command(short_help="Where the time goes; recommend a placement (--write saves it).")
@click.argument("source", type=FilePath(exists=True, dir_okay=False))
@click.option("--write", "out", type=FilePath(dir_okay=False), default=None,
              help="Write the recommended placement to this file (for ctrlunit start "
                   "--placement FILE).")
@click.option("--compare", "rerun", type=FilePath(exists=True, dir_okay=False),
              help="Report of a re-run with the written placement: measured against the "
                   "prediction.")
@click.option("--figure", type=FilePath(dir_okay=False),
              help="PNG: measured and predicted Gantt charts side by side.")
@click.option("--json", "as_json", is_flag=True)
def balance(source: str, out: str | None, rerun: str | None, figure: str | None,
            as_json: bool) -> None:
    """Block costs, t_s (Eq. IV.24), t_p (Eq. IV.25), business, and the period predicted by
    a schedule model calibrated on a run (--report JSON or a recording); recommends a
    placement by the rules of § IV.7.2, prints the command that runs it as the
    prediction assumes, and writes it with --write. Nothing else is written."""
    from pathlib import Path

    from ...topology.balance import analyse, compare, write_placement

    try:
        a = analyse(load_report(source), source=source)
        cmp = compare(a, load_report(rerun), source=rerun) if rerun else None
    except (ValueError, KeyError, OSError) as exc:
        _fail(f"balance: {exc}", EXIT_CONFIG)
        return
    if out:
        try:
            write_placement(a, out)
        except OSError as exc:
            _fail(f"balance: --write {out}: {exc.strerror or exc}", EXIT_CONFIG)
            return
    if figure:
        from ..recording.plots import gantt_figure

        d = a["pipeline"]
        panels = {f"depth {d}, measured": a["measured"]["gantt_ms"],
                  f"depth {d}, model of the same run": a["current"]["gantt_ms"],
                  f"depth {d}, predicted with the new placement": a["predicted"]["gantt_ms"]}
        if cmp is not None:
            panels[f"depth {cmp['depth']}, re-run with the new placement (measured)"] = \
                cmp["gantt_ms"]
        try:
            gantt_figure(Path(figure), panels)
        except OSError as exc:
            _fail(f"balance: --figure {figure}: {exc.strerror or exc}", EXIT_CONFIG)
            return
    command = rerun_command(a, out or "FILE")
    if a["run"]["clock"] == "realtime":  # a new user's: 712 us predicted, 2519 measured
        warn(f"balance: {source} is a realtime run, whose period its clock sets: the model, "
             "calibrated on its traversal, predicts the period of free-running intervals, "
             "which the printed command (--clock freerun) measures")
    if a["run"]["clock"] == "lockstep":  # a new user's: 97 us predicted, 1072 us measured
        warn(f"balance: {source} is a lockstep run, whose intervals the plant's simulation "
             "paces: the model takes that pace for the exchanges, and predicts too short a "
             "period for fewer of them; balance a freerun or realtime run's report")
    if as_json:
        click.echo(json.dumps(_json_safe(a | {"command": command, "written": out}
                                         | ({"compare": cmp} if cmp else {}))))
        return

    click.echo(_balance_text(a, cmp, source=source, out=out, figure=figure,
                             command=command))


def rerun_command(a: dict[str, Any], placement_file: str) -> str:
    """The ``ctrlunit start`` command that runs the recommended placement as the
    prediction of analysis ``a`` assumes: the model is calibrated on the source run, so
    everything that run's figures depend on is the same (clock, period, depth, law, model,
    observer, model state, cost model, replies, lone rounds, length, task); a setting left
    out is the one the run had by default. A task read from a file is named by its name
    only: the command then ends with a note to give the file."""
    from ...kernels.trajectory import TASKS
    from ..config import RunConfig

    run = a["run"]
    n = a["placement"]["peripherals"]
    # the model plays free-running intervals: a realtime run's is measured in freerun
    clock = "freerun" if run["clock"] == "realtime" else run["clock"]
    opts: list[tuple[str, Any]] = [("--peripherals", n), ("--pipeline", a["pipeline"]),
                                   ("--clock", clock)]
    if clock != "freerun" and run["period_s"]:
        opts.append(("--period", f"{run['period_s'] * 1e3:g}ms"))
    if run["cycles"]:
        opts.append(("--cycles", run["cycles"]))
    defaults = RunConfig.of(peripherals=n, pipeline=a["pipeline"], clock=clock,
                            law=a["law"])  # the model state's default follows the law
    task = run.get("task")
    for flag, value, default in (
            ("--law", a["law"], RunConfig.of().control.law),
            ("--model", a["model"], defaults.control.model),
            ("--observer", a["observer"], defaults.control.observer),
            ("--model-state", a["model_state"], defaults.resolved_model_state),
            ("--cost-model", run["cost_model"], defaults.control.cost_model),
            ("--replies", run["replies"], defaults.schedule.replies),
            ("--hold-rounds", run["hold_rounds"], defaults.schedule.hold_rounds)):
        if value != default:
            opts.append((flag, value))
    if run["cost_model"] == "t800" and run["cost_scale"] != 1.0:
        opts.append(("--cost-scale", f"{run['cost_scale']:g}"))
    if task in TASKS and task != RunConfig.of().control.task:
        opts.append(("--task", task))
    opts.append(("--placement", placement_file))
    note = (f"  # and --task FILE: the run followed task {task!r} from a file"
            if task is not None and task not in TASKS else "")
    return "ctrlunit start " + " ".join(f"{k} {shlex.quote(str(v))}" for k, v in opts) + note


def _balance_text(a: dict[str, Any], cmp: dict[str, Any] | None, *, source: str,
                  out: str | None, figure: str | None, command: str) -> str:
    """``ctrlunit balance``'s printed analysis ``a`` (and the re-run's comparison)."""

    def us(x: float | None) -> str:
        return "n/a" if x is None or not math.isfinite(x) else f"{x * 1e6:.0f} us"

    mc = a["model_costs_s"]
    d = a["pipeline"]
    lines = [f"balance of {source} ({a['law']}, n = {a['peripherals']}, depth {d}, "
             f"{a['run']['clock']})", "  block costs (3 axes):"]
    for k, v in sorted(a["block_cost_s"].items(), key=lambda kv: -kv[1]):
        lines.append(f"    {k:16s} {v * 1e6:8.1f} us")
    lines += [
        f"  t_s (Eq. IV.24) {us(a['t_s_s'])}   t_p (Eq. IV.25) {us(a['t_p_s'])}",
        "  business " + ", ".join(f"{k} {v * 100:.0f} %" for k, v in a["business"].items()),
        f"  model: central {us(mc['send'])} per request, {us(mc['reply'])} per reply, "
        f"{us(mc['step'])} per run of steps, {us(mc['start'])} + {us(mc['finish'])} to start "
        f"and finish an interval; latency {us(mc['latency'])} one way (fitted)",
        f"  now: measured period {us(a['measured']['period_s'])} (mean"
        f"{'; the realtime clock sets it' if a['run']['clock'] == 'realtime' else ''}); "
        "model depth 1 "
        f"{us(a['current']['depth1']['period_s'])}, depth 2 "
        f"{us(a['current']['depth2']['period_s'])}",
    ]
    cpu = a.get("cpu") or {}
    if cpu.get("bound_period_s"):
        per = cpu["per_interval_s"]
        lines.append(
            f"  CPU: {us(per.get('total'))} per interval (central {us(per.get('central'))}) "
            f"on {cpu['cores']} core(s): no period below {us(cpu['bound_period_s'])}, the "
            f"measured mean is {a['measured']['period_s'] / cpu['bound_period_s']:.2f}x that "
            "(the model does not charge the cores the processes share)")
    for c in a["candidates"][:6]:
        lines.append(f"  candidate: {c['why']}: {us(c['period_s'])}")
    lines += [f"  recommendation: {r}" for r in a["recommendations"]]
    where = (f"written to {out}" if out else
             "not written (--write FILE writes it)")
    lines += [f"  with the new placement: predicted period depth 1 "
              f"{us(a['predicted']['depth1']['period_s'])}, depth 2 "
              f"{us(a['predicted']['depth2']['period_s'])}; {where}"]
    floor = cpu.get("bound_period_s") or 0.0
    if floor and a["predicted"][f"depth{d}"]["period_s"] < floor:
        lines.append(f"  the predicted depth {d} period is below this run's CPU floor "
                     f"({us(floor)} on {cpu['cores']} core(s)): the model does not charge "
                     "the cores the processes share, and the new placement's CPU is not "
                     "known before it runs: the printed command measures what holds")
    lines.append(f"  the prediction (depth {d}) assumes: {command}")
    if cmp is not None:
        lines.append(f"  re-run (depth {cmp['depth']}): measured {us(cmp['measured_period_s'])} "
                     f"against {us(cmp['predicted_period_s'])} predicted "
                     f"({cmp['error'] * 100:+.1f} %); before {us(cmp['before_period_s'])} "
                     f"({cmp['before_is']}) "
                     f"(gain {cmp['gain'] * 100:+.1f} %)")
    if figure:
        lines.append(f"  Gantt charts: {figure}")
    return "\n".join(lines)


def load_report(path: str) -> dict[str, Any]:
    """A run's report from ``--report`` JSON or from a recording."""
    from pathlib import Path

    if Path(path).suffix == ".mcap":
        from ..recording.reader import read
        from ..recording.recorded_report import report_from_recording

        return report_from_recording(read(path))
    try:
        return json.loads(Path(path).read_text())
    except UnicodeDecodeError:
        raise ValueError(f"{path}: not a JSON report (not UTF-8 text)") from None
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}: not a JSON report ({exc})") from None
