"""``ctrlunit bench``, the one place that runs the benchmarks, and ``ctrlunit latency``."""

from __future__ import annotations

import contextlib
import json
from collections.abc import Callable, Iterator
from typing import Any

import click

from ..config import EXIT_CONFIG, parse_duration
from ..host.idle import IDLE_CHOICES
from ..roles.stopping import raise_if_stopped, stop_signals
from .base import FilePath, FiniteRange, _fail, _json_safe, _rt_priority, cli


def _stages(_ctx: Any, _param: click.Parameter, text: str) -> tuple[str, ...]:
    """``--stages``: the names given, in the bench's order; a name that is not a stage is
    a usage error (exit 2), as a value outside a flag's choices is."""
    from ...bench.sweep import STAGES

    names = [t.strip() for t in text.split(",") if t.strip()]
    if names == ["all"]:
        return STAGES
    if not names or any(n not in STAGES for n in names):
        raise click.BadParameter(f"{text!r}: allowed a comma-separated list of "
                                 f"{', '.join(STAGES)}, or all")
    return tuple(n for n in STAGES if n in names)


def _duration(_ctx: Any, param: click.Parameter, text: str) -> float:
    """A duration flag (``1ms``, ``0.001``, ``0``) in seconds; one that does not read is a
    usage error (exit 2), as it is for ``ctrlunit start``; its range is the command's to
    check (exit 1)."""
    try:
        return parse_duration(text, field_name=f"--{param.name}", zero=True)
    except ValueError as exc:
        raise click.BadParameter(str(exc)) from None


@cli.command()
@click.option("--out", "out_dir", type=FilePath(file_okay=False), default="bench-out",
              show_default=True, help="Directory for report.md, report.json and figures.")
@click.option("--quick", is_flag=True, help="One repeat, short runs (under 3 minutes).")
@click.option("--repeats", type=click.IntRange(1, 20), default=None)
@click.option("--realtime-period", "rt_periods", multiple=True, default=("3ms",),
              show_default=True, help="Realtime periods to include (repeatable).")
@click.option("--thesis-scale", type=FiniteRange(1.0, 1000.0), default=60.0,
              show_default=True, help="T-800 time scale of the runs compared with 1994: "
              "large enough that an exchange weighs on the arithmetic about as a "
              "Transputer link did (README, bench).")
@click.option("--realtime-runs", type=click.IntRange(0, 200), default=None,
              help="Runs of the main job (each followed by its n = 0 baseline) in the "
                   "realtime stage, as many again at --period 500us.  [default: 20; with "
                   "--quick 2]")
@click.option("--realtime-long", "rt_long", default=None,
              help="Length of the realtime stage's long run of the main job, e.g. 60s; 0: "
                   "none.  [default: 60s; with --quick 0]")
@click.option("--stages", "stages", default="all", show_default=True, callback=_stages,
              help="Comma-separated stages to run: floor, sweep, recording, thesis, "
                   "balance, target, realtime (e.g. thesis,floor); all: every one.")
@click.option("--check", is_flag=True,
              help="Check the options and list the runs the bench would make; run nothing.")
def bench(out_dir: str, quick: bool, repeats: int | None, rt_periods: tuple[str, ...],
          thesis_scale: float, realtime_runs: int | None, rt_long: str | None,
          stages: tuple[str, ...], check: bool) -> None:
    """Sweep n x depth x cost model, measure the floor, compare with the 1994 unit and
    check its guarded figures, write reports and figures.

    Exits 1 when a figure of the thesis stage leaves its guarded range (report.md lists
    them)."""
    from ...bench.sweep import bench as run_bench
    from ...bench.thesis import guard_lines

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
    if check:
        click.echo("\n".join(_bench_plan(
            stages, quick=quick, repeats=repeats, periods=periods, scale=thesis_scale,
            runs_rt=runs_rt, long_rt=long_rt, out_dir=out_dir)))
        return
    if stages == ("realtime",):
        with stop_signals():  # SIGTERM / SIGHUP end the stage as Ctrl-C does
            _realtime_only(out_dir, runs_rt, long_rt)
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


def _bench_plan(stages: tuple[str, ...], *, quick: bool, repeats: int | None,
                periods: list[float], scale: float, runs_rt: int, long_rt: float,
                out_dir: str) -> list[str]:
    """``bench --check``: what each stage asked would run, stage by stage."""
    from ...bench.runs import cycles_for, thesis_cycles, thesis_pairs
    from ...bench.sweep import plan_configs

    runs = repeats or (1 if quick else 3)
    configs = plan_configs(quick=quick, realtime_periods=periods, scale=scale, stages=stages)
    lines = []
    if "floor" in stages:
        lines.append(f"  floor: {500 if quick else 3000} scatter/gather rounds to 1, 2 and 3 "
                     f"peripherals over pipes and over Zenoh, then {300 if quick else 3000} "
                     "rounds paced at 1 ms over each")
    lines += [f"  {c.key}  {cycles_for(c, quick)} intervals x {runs}" for c in configs]
    if "thesis" in stages:
        lines.append(f"  thesis: {thesis_pairs(quick, repeats)} alternated pairs of 3 runs, "
                     f"{thesis_cycles(quick)} intervals each, t800 x {scale:g}")
    if "balance" in stages:
        lines.append(f"  balance: balance's placement for the n = 3 runs of each depth, "
                     f"re-run alternately with the default one ({4 * runs} runs)")
    if "target" in stages:
        lines.append(f"  target: the freerun period at n = 3, depth 2 against 0.5 ms, the "
                     "default and balance's placement, each under the default policy and "
                     f"under SCHED_FIFO where permitted (up to {4 * runs} runs)")
    if "realtime" in stages:
        at = 1 if quick else runs_rt  # bench/sweep.py: the thesis's period, once in --quick
        lines.append(f"  realtime: {runs_rt} main-job runs, each with its baseline, then "
                     f"{at} at the thesis's 0.5 ms, each with its baseline"
                     + (f", then {long_rt:g} s of the main job" if long_rt else ""))
    lines.append(f"stages {', '.join(stages)}"
                 + (f": {len(configs)} configurations x {runs} repeat(s)" if configs else "")
                 + f"; reports into {out_dir}/; nothing was run")
    return lines


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


@cli.command(short_help="This machine's wake-up latency; with --unit the unit's traversal.")
@click.option("--period", default="1ms", show_default=True, callback=_duration,
              help="Tick period.")
@click.option("--duration", default="10s", show_default=True, callback=_duration,
              help="How long to measure.")
@click.option("--unit", "with_unit", is_flag=True,
              help="Also run the unit's admission trial (no motion): its sample-to-command "
              "traversal at the period, and the shortest period it holds.")
@click.option("--peripherals", type=click.IntRange(0, 3), default=3, show_default=True)
@click.option("--pipeline", type=click.IntRange(1, 2), default=2, show_default=True)
@click.option("--plot", type=FilePath(dir_okay=False), default=None,
              help="Draw the histogram of the wake-up latencies into this PNG file.")
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
def latency(period: float, duration: float, with_unit: bool, peripherals: int, pipeline: int,
            plot: str | None, rt_priority: str | int, idle: str, as_json: bool) -> None:
    """Measure how late this machine wakes a process at each tick of PERIOD (the realtime
    plant's own sleep), as LinuxCNC's latency-test does, for DURATION; print p50, p99,
    p99.9 and max and the shortest period of the admission ladder that leaves half of
    each period for the work. With --unit, then run the unit's admission trial at the
    period: the traversal the unit itself shows, and the period it holds."""
    from ..config import ConfigError
    from ..host.idle import IdlePermissionError
    from ..host.sched import RtPermissionError
    from ..launch.latency import histogram_png, latency_lines, latency_report

    period_s, duration_s = period, duration
    if duration_s <= 0:
        _fail(f"--duration = {duration_s:g} s: allowed more than 0", EXIT_CONFIG)
        return
    try:
        rep, lat = latency_report(period_s, duration_s, rt_priority=rt_priority, idle=idle)
    except (ConfigError, ValueError, RtPermissionError, IdlePermissionError) as exc:
        _fail(str(exc), EXIT_CONFIG)
        return
    if plot:
        try:
            histogram_png(lat, plot, period_s=period_s,
                          title=f"wake-up latency at {period_s * 1e3:g} ms, "
                                f"{rep['ticks']} ticks")
        except OSError as exc:
            _fail(f"--plot {plot}: {exc.strerror or exc}", EXIT_CONFIG)
            return
        rep["plot"] = plot
    if with_unit:
        from ..launch.latency import trial_config
        from ..launch.launcher import start

        rc = trial_config(peripherals=peripherals, pipeline=pipeline, period_s=period_s,
                          idle=idle)

        def say(line: Any) -> None:  # the placement chosen is start's news, not latency's
            if not str(line).startswith("ctrlunit: --placement auto"):
                click.echo(line, err=True)

        code, urep = start(rc, echo=say)
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
    lines = latency_lines(rep, period_s=period_s, peripherals=peripherals,
                          pipeline=pipeline)
    click.echo("\n".join(lines))
