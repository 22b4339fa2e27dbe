"""``ctrlunit bench`` and ``ctrlunit balance``: the one place that runs the benchmarks."""

from __future__ import annotations

import contextlib
import json
import math
from collections.abc import Callable, Iterator
from typing import Any

import click

from ..config import EXIT_CONFIG, parse_duration
from ..host.idle import IDLE_CHOICES
from ..roles.stopping import raise_if_stopped, stop_signals
from .base import _fail, _json_safe, _rt_priority, cli


@cli.command()
@click.option("--out", "out_dir", type=click.Path(file_okay=False), default="bench-out",
              show_default=True, help="Directory for report.md, report.json and figures.")
@click.option("--quick", is_flag=True, help="One repeat, short runs (under 3 minutes).")
@click.option("--repeats", type=click.IntRange(1, 20), default=None)
@click.option("--realtime-period", "rt_periods", multiple=True, default=("3ms",),
              show_default=True, help="Realtime periods to include (repeatable).")
@click.option("--thesis-scale", type=click.FloatRange(1.0, 1000.0), default=60.0,
              show_default=True, help="T-800 time scale of the runs compared with 1994: "
              "large enough that an exchange weighs on the arithmetic about as a "
              "Transputer link did (README, bench).")
@click.option("--realtime-runs", type=click.IntRange(0, 200), default=None,
              help="Runs of the main job (each followed by its n = 0 baseline) in the "
                   "realtime stage.  [default: 20; with --quick 2]")
@click.option("--realtime-long", "rt_long", default=None,
              help="Length of the realtime stage's long run of the main job, e.g. 60s; 0: "
                   "none.  [default: 60s; with --quick 0]")
@click.option("--stages", "stages_text", default="all", show_default=True,
              help="Comma-separated stages to run: floor, sweep, recording, thesis, "
                   "balance, target, realtime (e.g. thesis,floor); all: every one.")
@click.option("--check", is_flag=True,
              help="Check the options and list the runs the bench would make; run nothing.")
def bench(out_dir: str, quick: bool, repeats: int | None, rt_periods: tuple[str, ...],
          thesis_scale: float, realtime_runs: int | None, rt_long: str | None,
          stages_text: str, check: bool) -> None:
    """Sweep n x depth x cost model, measure the floor, compare with the 1994 unit and
    check its guarded figures, write reports and figures.

    Exits 1 when a figure of the thesis stage leaves its guarded range (report.md lists
    them)."""
    from ...bench.runs import cycles_for, thesis_cycles, thesis_pairs
    from ...bench.sweep import STAGES, plan_configs
    from ...bench.sweep import bench as run_bench
    from ...bench.thesis import guard_lines

    stages = _stages(stages_text, STAGES)
    if stages is None:
        return

    periods = [parse_duration(p, field_name="--realtime-period") for p in rt_periods]
    for p in periods:
        if not 20e-6 <= p <= 1.0:
            _fail(f"--realtime-period = {p:g} s: allowed 20us to 1s", EXIT_CONFIG)
            return
    long_s = None if rt_long is None else (
        0.0 if rt_long.strip() == "0" else parse_duration(rt_long, field_name="--realtime-long"))
    if long_s is not None and not 0 <= long_s <= 3600:
        _fail(f"--realtime-long = {long_s:g} s: allowed 0 to 3600s", EXIT_CONFIG)
        return
    runs_rt = realtime_runs if realtime_runs is not None else (2 if quick else 20)
    long_rt = long_s if long_s is not None else (0.0 if quick else 60.0)
    if stages == ("realtime",):
        if check:
            click.echo(f"realtime stage: {runs_rt} main-job runs, each with its baseline"
                       + (f", then {long_rt:g} s of the main job" if long_rt else ""))
            return
        with stop_signals():  # SIGTERM / SIGHUP end the stage as Ctrl-C does
            _realtime_only(out_dir, runs_rt, long_rt)
        return
    if check:
        configs = plan_configs(quick=quick, realtime_periods=periods, scale=thesis_scale,
                               stages=stages)
        runs = repeats or (1 if quick else 3)
        for c in configs:
            click.echo(f"  {c.key}  {cycles_for(c, quick)} intervals x {runs}")
        if "thesis" in stages:
            click.echo(f"  thesis: {thesis_pairs(quick, repeats)} alternated pairs of 3 runs, "
                       f"{thesis_cycles(quick)} intervals each, t800 x {thesis_scale:g}")
        click.echo(f"{len(configs)} configurations x {runs} repeat(s); stages "
                   f"{', '.join(stages)}"
                   + (f" (realtime: {runs_rt} main-job runs"
                      + (f", {long_rt:g} s long run" if long_rt else "") + ")"
                      if "realtime" in stages else "")
                   + f"; reports into {out_dir}/")
        return
    with stop_signals(), _ticker("bench") as tick:
        rep = run_bench(out_dir, stages=stages, quick=quick, repeats=repeats,
                        realtime_periods=periods, scale=thesis_scale, realtime_runs=runs_rt,
                        realtime_long_s=long_rt, progress=tick)
    click.echo(f"wrote {out_dir}/report.md, report.json and {len(rep['figures'])} figures "
               f"in {rep['wall_s']:.0f} s")
    th = rep.get("thesis")
    if th:
        for line in guard_lines(th):
            click.echo(f"  {line}")
        failed = [g["name"] for g in th["guards"] if not g["ok"]]
        if failed:
            _fail(f"guarded figures out of range: {', '.join(failed)} ({out_dir}/report.md)",
                  EXIT_CONFIG)


def _stages(text: str, allowed: tuple[str, ...]) -> tuple[str, ...] | None:
    """``--stages``: the names given, in the bench's order; None (after the error) when a
    name is not a stage."""
    names = [t.strip() for t in text.split(",") if t.strip()]
    if names == ["all"]:
        return allowed
    unknown = [n for n in names if n not in allowed]
    if unknown or not names:
        _fail(f"--stages = {text!r}: allowed a comma-separated list of "
              f"{', '.join(allowed)}, or all", EXIT_CONFIG)
        return None
    return tuple(n for n in allowed if n in names)


@contextlib.contextmanager
def _ticker(label: str) -> Iterator[Callable[[str, int, int], None]]:
    """A transient progress bar and the ``progress(what, done, total)`` that moves it."""
    from rich.progress import Progress

    with Progress(transient=True) as prog:
        task = prog.add_task(label, total=None)

        def tick(what: str, done: int, total: int) -> None:
            prog.update(task, description=what[:70], completed=done, total=total)

        yield tick


def _realtime_only(out_dir: str, runs: int, long_s: float) -> None:
    """``ctrlunit bench --stages realtime``: the realtime stage into report.json and
    report.md, its summary on the terminal."""
    import time
    from pathlib import Path

    from ...bench.realtime import markdown_lines, realtime_stage, stage_steps
    from ...bench.runs import machine_info

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.monotonic()
    with _ticker("realtime") as tick:
        st = realtime_stage(runs=runs, long_s=long_s, progress=tick, done=0,
                            total=stage_steps(runs, long_s))
    rep: dict[str, Any] = {"machine": machine_info(), "realtime": st,
                           "wall_s": time.monotonic() - t0}
    (out / "report.json").write_text(json.dumps(_json_safe(rep), indent=2))
    m = rep["machine"]
    text = "\n".join(["# ctrlunit benchmark: the realtime stage", "",
                      f"Machine: {m['platform']}, {m['cores']} cores, Python {m['python']}; "
                      f"{rep['wall_s']:.0f} s.", "", *markdown_lines(st)])
    (out / "report.md").write_text(text)
    click.echo(text)


@cli.command(short_help="Where the time goes; recommend and write a placement.")
@click.argument("source", type=click.Path(exists=True, dir_okay=False))
@click.option("--write", "out", type=click.Path(dir_okay=False), default="placement.json",
              show_default=True, help="Placement file to write.")
@click.option("--compare", "rerun", type=click.Path(exists=True, dir_okay=False),
              help="Report of a re-run with the written placement: measured against the "
                   "prediction.")
@click.option("--figure", type=click.Path(dir_okay=False),
              help="PNG: measured and predicted Gantt charts side by side.")
@click.option("--json", "as_json", is_flag=True)
def balance(source: str, out: str, rerun: str | None, figure: str | None,
            as_json: bool) -> None:
    """Block costs, t_s (Eq. IV.24), t_p (Eq. IV.25), business, and the period predicted by
    a schedule model calibrated on a run (--report JSON or a recording); recommends a
    placement by the rules of § IV.7.2 and writes it."""
    from pathlib import Path

    from ...topology.balance import analyse, compare, write_placement

    try:
        a = analyse(load_report(source), source=source)
        cmp = compare(a, load_report(rerun), source=rerun) if rerun else None
    except (ValueError, KeyError, OSError) as exc:
        _fail(f"balance: {exc}", EXIT_CONFIG)
        return
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
    if as_json:
        click.echo(json.dumps(_json_safe(a | ({"compare": cmp} if cmp else {}))))
        return

    click.echo(_balance_text(a, cmp, source=source, out=out, figure=figure))


def _balance_text(a: dict[str, Any], cmp: dict[str, Any] | None, *, source: str, out: str,
                  figure: str | None) -> str:
    """``ctrlunit balance``'s printed analysis ``a`` (and the re-run's comparison)."""

    def us(x: float | None) -> str:
        return "n/a" if x is None or not math.isfinite(x) else f"{x * 1e6:.0f} us"

    mc = a["model_costs_s"]
    d = a["pipeline"]
    lines = [f"balance of {source} ({a['law']}, n = {a['peripherals']}, depth {d})",
             "  block costs (3 axes):"]
    for k, v in sorted(a["block_cost_s"].items(), key=lambda kv: -kv[1]):
        lines.append(f"    {k:16s} {v * 1e6:8.1f} us")
    lines += [
        f"  t_s (Eq. IV.24) {us(a['t_s_s'])}   t_p (Eq. IV.25) {us(a['t_p_s'])}",
        "  business " + ", ".join(f"{k} {v * 100:.0f} %" for k, v in a["business"].items()),
        f"  model: central {us(mc['send'])} per request, {us(mc['reply'])} per reply, "
        f"{us(mc['step'])} per run of steps, {us(mc['start'])} + {us(mc['finish'])} to start "
        f"and finish an interval; latency {us(mc['latency'])} one way (fitted)",
        f"  now: measured period {us(a['measured']['period_s'])} (mean); model depth 1 "
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
    lines.append(f"  with the new placement: predicted period depth 1 "
                 f"{us(a['predicted']['depth1']['period_s'])}, depth 2 "
                 f"{us(a['predicted']['depth2']['period_s'])}; written to {out} "
                 f"(ctrlunit start --peripherals {a['placement']['peripherals']} "
                 f"--placement {out})")
    if cmp is not None:
        lines.append(f"  re-run (depth {cmp['depth']}): measured {us(cmp['measured_period_s'])} "
                     f"against {us(cmp['predicted_period_s'])} predicted "
                     f"({cmp['error'] * 100:+.1f} %); before {us(cmp['before_period_s'])} "
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


@cli.command(short_help="This machine's wake-up latency; with --unit the unit's traversal.")
@click.option("--period", default="1ms", show_default=True, help="Tick period.")
@click.option("--duration", default="10s", show_default=True, help="How long to measure.")
@click.option("--unit", "with_unit", is_flag=True,
              help="Also run the unit's admission trial (no motion): its sample-to-command "
              "traversal at the period, and the shortest period it holds.")
@click.option("--peripherals", type=click.IntRange(0, 3), default=3, show_default=True)
@click.option("--pipeline", type=click.IntRange(1, 2), default=2, show_default=True)
@click.option("--plot", type=click.Path(dir_okay=False), default="latency.png",
              show_default=True, help="Histogram of the wake-up latencies (PNG).")
@click.option("--rt-priority", default="auto", show_default=True, callback=_rt_priority,
              metavar="auto|0-99",
              help="Scheduling of the wake-up test, as for ctrlunit start: auto is the "
              "policy the unit's roles get (SCHED_FIFO 10 where permitted and the kernel "
              "throttles real-time tasks); 0: the policy as it is.")
@click.option("--idle", type=click.Choice(list(IDLE_CHOICES)), default="auto",
              show_default=True,
              help="Idle CPUs during the test, as for ctrlunit start: poll holds the CPU "
              "latency request at 0 us (needs root); auto: poll where permitted and a "
              "deeper idle state exists; default: leave them alone.")
@click.option("--json", "as_json", is_flag=True, help="Print the figures as JSON.")
def latency(period: str, duration: str, with_unit: bool, peripherals: int, pipeline: int,
            plot: str, rt_priority: str | int, idle: str, as_json: bool) -> None:
    """Measure how late this machine wakes a process at each tick of PERIOD (the realtime
    plant's own sleep), as LinuxCNC's latency-test does, for DURATION; print p50, p99,
    p99.9 and max and the shortest period of the admission ladder that leaves half of
    each period for the work. With --unit, then run the unit's admission trial at the
    period: the traversal the unit itself shows, and the period it holds."""
    from ..config import ConfigError, RunConfig
    from ..host.idle import IdlePermissionError
    from ..host.sched import RtPermissionError
    from ..launch.latency import histogram_png, latency_report

    try:
        period_s = parse_duration(period, field_name="--period")
        duration_s = parse_duration(duration, field_name="--duration")
        rep, lat = latency_report(period_s, duration_s, rt_priority=rt_priority, idle=idle)
    except (ConfigError, ValueError, RtPermissionError, IdlePermissionError) as exc:
        _fail(str(exc), EXIT_CONFIG)
        return
    histogram_png(lat, plot, period_s=period_s,
                  title=f"wake-up latency at {period_s * 1e3:g} ms, {rep['ticks']} ticks")
    rep["plot"] = plot
    if with_unit:
        from ..launch.launcher import start

        rc = RunConfig.of(peripherals=peripherals, pipeline=pipeline, clock="realtime",
                       period=period_s, trial_only=True, idle=idle)
        code, urep = start(rc, echo=lambda m: click.echo(m, err=True))
        raise_if_stopped(code, urep)
        adm = urep.get("admission")
        if not adm:
            fault = (urep.get("fault") or {}).get("message", "no admission figures")
            _fail(f"the unit's trial did not run: {fault}", code or EXIT_CONFIG)
            return
        first = adm["rungs"][0]
        rep["unit"] = {"peripherals": peripherals, "pipeline": pipeline,
                       "traversal_s": {k: first[f"traversal_{k}_s"]
                                       for k in ("p50", "p99", "p999", "max")},
                       "late": first["late"], "intervals": first["intervals"],
                       "rungs": adm["rungs"],
                       "sustainable_period_s": adm["sustainable_period_s"]}
        rep["sustainable_period_s"] = adm["sustainable_period_s"]
        rep["sustainable_period_from"] = "the unit's admission trial"
    if as_json:
        click.echo(json.dumps(_json_safe(rep), indent=2))
        return
    q = rep["wakeup_latency_s"]

    def us(x: float | None) -> str:
        return "n/a" if x is None or not math.isfinite(x) else f"{x * 1e6:.0f} us"

    def ms(x: float | None) -> str:
        return "none of the ladder" if x is None else f"{x * 1e3:g} ms"

    polling = ", idle CPUs poll" if rep["idle"]["in_force"] == "poll" else ""
    lines = [f"wake-up latency at {period_s * 1e3:g} ms over {rep['ticks']} ticks "
             f"({rep['scheduling']}{polling}): p50 "
             f"{us(q['p50'])}  p99 {us(q['p99'])}  p99.9 {us(q['p999'])}  max "
             f"{us(q['max'])}; {rep['ticks_lost']} tick(s) woken more than a period late"]
    if "unit" in rep:
        u = rep["unit"]
        t = u["traversal_s"]
        lines.append(f"unit (n = {peripherals}, depth {pipeline}) traversal, command transit "
                     f"included: p50 {us(t['p50'])}  p99 {us(t['p99'])}  p99.9 "
                     f"{us(t['p999'])}  max {us(t['max'])}; {u['late']} of {u['intervals']} "
                     "trial intervals late")
    lines.append(f"shortest sustainable period ({rep['sustainable_period_from']}): "
                 f"{ms(rep['sustainable_period_s'])}")
    lines.append(f"histogram: {plot}")
    click.echo("\n".join(lines))
