"""Run-time commands of the ``ctrlunit`` CLI: start and the single roles."""

from __future__ import annotations

import json
import math
import sys
from typing import Any

import click

from .cli import _fail, _json_safe, cli
from .config import EXIT_CONFIG, ConfigError, RunConfig, parse_duration


def _duration(_ctx: Any, param: click.Parameter, value: str | None) -> float | None:
    if value is None:
        return None
    try:
        return parse_duration(value, field_name=f"--{param.name}")
    except ConfigError as exc:
        raise click.BadParameter(str(exc)) from None


def run_options(fn: Any) -> Any:
    """Options shared by start and the single roles (see the brief's Interfaces)."""
    opts = [
        click.option("--peripherals", type=click.IntRange(0, 3), default=3, show_default=True,
                     help="Number of peripheral processes (0 = single processor)."),
        click.option("--pipeline", type=click.IntRange(1, 2), default=1, show_default=True,
                     help="Pipeline depth (§ IV.7.2)."),
        click.option("--clock", type=click.Choice(["lockstep", "realtime", "freerun"]),
                     default="realtime", show_default=True),
        click.option("--period", default="1ms", show_default=True, callback=_duration,
                     help="Sampling period: 500us, 1ms, or seconds."),
        click.option("--task", default="pick-place", show_default=True,
                     help="pick-place, circle, or a JSON task file."),
        click.option("--law", type=click.Choice(["resolved-acceleration", "computed-torque",
                                                 "pd-feedforward", "pd-gravity", "pd",
                                                 "kinematics"]),
                     default="resolved-acceleration", show_default=True,
                     help="Control law; 'kinematics' runs the kinematics part alone "
                     "(benchmarks: its commands are joint accelerations, not torques)."),
        click.option("--model", type=click.Choice(["complete", "simplified"]),
                     default="complete", show_default=True),
        click.option("--cycles", type=click.IntRange(1, 10**9), default=None,
                     help="Intervals to run (default: one loop of the task)."),
        click.option("--duration", default=None, callback=_duration,
                     help="Run length instead of --cycles (e.g. 30s)."),
        click.option("--record", type=click.Path(dir_okay=False), default=None,
                     help="Record every interval to an MCAP file."),
        click.option("--report", type=click.Path(dir_okay=False), default=None,
                     help="Write the report as JSON."),
        click.option("--unit", default=None, help="Unit id (keys ctrlunit/<unit>/...)."),
        click.option("--cost-model", type=click.Choice(["native", "t800"]), default="native",
                     show_default=True),
        click.option("--cost-scale", type=click.FloatRange(0.01, 1000.0), default=1.0,
                     show_default=True, help="Multiply the T-800 block times (t800 cost "
                     "model): reproduce the 1994 ratio of arithmetic to communication."),
        click.option("--placement", type=click.Path(dir_okay=False), default=None),
        click.option("--params", type=click.Path(dir_okay=False), default=None,
                     help="TOML file of Delta parameters."),
        click.option("--observer", type=click.Choice(["predict", "previous"]),
                     default="predict", show_default=True,
                     help="Newton-Raphson start: prediction (1 iteration) or previous (2)."),
        click.option("--bandwidth", "bandwidth_hz", type=float, default=None,
                     help="Closed-loop bandwidth of the gains in Hz (default: 20, at most "
                     "1/(50 period))."),
        click.option("--listen", multiple=True, help="Zenoh endpoint to listen on."),
        click.option("--connect", multiple=True, help="Zenoh endpoint to connect to."),
        click.option("--zenoh-config", type=click.Path(dir_okay=False), default=None),
        click.option("--timeout", default="2s", show_default=True, callback=_duration,
                     help="Reply timeout in lockstep and freerun (realtime: --fault-periods)."),
        click.option("--fault-periods", default=3.0, type=click.FloatRange(1.0, 1000.0),
                     show_default=True, help="Realtime: a peripheral, the plant or a link "
                     "silent for this many periods is a fault (the robot is stopped)."),
        click.option("--late-policy", type=click.Choice(["wait", "hold", "fault"]),
                     default="wait", show_default=True,
                     help="Realtime: a peripheral's late reply is waited for, replaced by "
                     "its last values (hold), or a fault."),
        click.option("--late", "late_items", multiple=True, metavar="BLOCK=POLICY",
                     help="Late-data policy for one block (overrides --late-policy)."),
        click.option("--max-error", default=0.02, type=click.FloatRange(1e-5, 1.0),
                     show_default=True, help="Tracking error (m) beyond which the unit "
                     "stops the robot (a fault)."),
        click.option("--replies", type=click.Choice(["auto", "fused", "each"]), default="auto",
                     show_default=True,
                     help="Depth 2: peripherals answer a fused request in one reply "
                     "(fused), or each round as soon as it is computed, first rounds first, "
                     "so the central works on one interval while they work on the other "
                     "(each); auto: each when the central's work between two rounds "
                     "exceeds a round trip measured at warm-up."),
        click.option("--pin", default=None, help="CPUs for this process, e.g. 0 or 0,1."),
        click.option("--cpus", type=click.Choice(["same", "split"]), default=None,
                     help="start: pin every role on CPU 0 (same), or the central on 0 and "
                     "the others on 1 (split); default: no pinning."),
        click.option("--rt-priority", type=click.IntRange(0, 99), default=0,
                     show_default=True,
                     help="SCHED_FIFO priority of every role of the unit (the roles "
                     "inherit it from start); 0: leave the policy as it is. Needs root, "
                     "CAP_SYS_NICE or ulimit -r. Use it at a period the machine sustains: "
                     "when overloaded, the kernel's RT throttling freezes the unit for up "
                     "to 50 ms a second."),
        click.option("--plant-substeps", type=click.IntRange(1, 1000), default=None,
                     help="RK4 sub-steps of the plant per period; default: the fewest of "
                     "at most 0.25 ms (0.1 ms with --belt)."),
        click.option("--plant-lag", default="0s", callback=_duration_or_zero,
                     help="Actuator time constant (Eq. IV.6)."),
        click.option("--plant-friction", type=click.FloatRange(0.0, 100.0), default=0.0,
                     show_default=True, help="Viscous friction on each joint (N m s/rad)."),
        click.option("--belt", is_flag=True, help="Simulate the elastic belt (§ V.6.3)."),
        click.option("--spec", type=click.Path(dir_okay=False), default=None,
                     help="Run configuration written by ctrlunit start (internal)."),
        click.option("--status-file", type=click.Path(dir_okay=False), default=None,
                     hidden=True, help="Write the completed-interval count every 10."),
    ]
    for o in reversed(opts):
        fn = o(fn)
    return fn


def _duration_or_zero(ctx: Any, param: click.Parameter, value: str) -> float:
    if value in ("0", "0s", 0):
        return 0.0
    return _duration(ctx, param, value) or 0.0


def make_rc(kw: dict[str, Any]) -> RunConfig:
    from .launcher import load_spec

    spec = kw.pop("spec", None)
    listen = list(kw.pop("listen", ()) or ()) or None
    connect = list(kw.pop("connect", ()) or ()) or None
    if spec:
        rc = load_spec(spec)
        rc.listen = listen  # the central's endpoints are its own, not the children's
        rc.connect = connect
        rc.pin = kw.get("pin") or None
        return rc
    unit = kw.pop("unit", None)
    late: dict[str, str] = {}
    for item in kw.pop("late_items", ()) or ():
        block, _, pol = item.partition("=")
        if not block or not pol:
            raise ConfigError(f"--late {item!r}: expected BLOCK=POLICY (wait, hold, fault)")
        late[block] = pol
    kw["late"] = late
    rc = RunConfig(**{k: v for k, v in kw.items() if k in RunConfig.__dataclass_fields__})
    rc.plant_lag = kw.get("plant_lag", 0.0)
    rc.listen, rc.connect = listen, connect
    if unit:
        rc.unit = unit
    return rc


@cli.command()
@run_options
@click.option("--json", "as_json", is_flag=True, help="Print the report as JSON.")
@click.option("--progress/--no-progress", default=None,
              help="Progress display (default: when stdout is a terminal).")
def start(as_json: bool, progress: bool | None, **kw: Any) -> None:
    """Start plant, central and peripherals on this host and run the task."""
    from .launcher import start as run_start

    try:
        rc = make_rc(kw).validate()
    except ConfigError as exc:
        _fail(str(exc), EXIT_CONFIG)
        return
    show = sys.stdout.isatty() if progress is None else progress
    prog, finish = _progress(show)
    code, report = run_start(rc, echo=lambda m: click.echo(m, err=True), progress=prog)
    finish()
    if "cycles" not in report:
        _fail(report["fault"]["message"], code)
        return
    if rc.report:
        with open(rc.report, "w") as fh:
            json.dump(_json_safe(report), fh, indent=2)
    from .report import summary

    click.echo(json.dumps(_json_safe(report)) if as_json else summary(report))
    if code:
        f = report.get("fault") or {}
        click.echo(f"ctrlunit: fault in {f.get('process')}: {f.get('message')}", err=True)
    sys.exit(code)


def _progress(show: bool) -> tuple[Any, Any]:
    if not show:
        return None, lambda: None
    from rich.progress import BarColumn, Progress, TextColumn, TimeRemainingColumn

    prog = Progress(TextColumn("[bold]ctrlunit"), BarColumn(), TextColumn("{task.completed}/"
                    "{task.total} intervals"), TextColumn("{task.fields[stat]}"),
                    TimeRemainingColumn(), transient=True)
    state: dict[str, Any] = {}

    def on_cycle(central: Any, cycle: int, _ctx: dict) -> None:
        if "task" not in state:
            prog.start()
            state["task"] = prog.add_task("run", total=central.cycles, stat="")
        if central.done % 100 == 0 or central.done == central.cycles:
            log = central.log.cmd_ns
            stat = ""
            if len(log) > 101:
                stat = f"period {(log[-1] - log[-101]) / 100 / 1e3:.0f} us"
            prog.update(state["task"], completed=central.done, stat=stat)

    def finish() -> None:
        if "task" in state:
            prog.stop()

    return on_cycle, finish


@cli.command()
@run_options
@click.option("--index", type=click.IntRange(1, 3), required=True)
def peripheral(index: int, **kw: Any) -> None:
    """Run peripheral K of a unit (connects to the central's endpoint)."""
    from .launcher import run_peripheral

    setup, conf = _role_setup(kw)
    if index > setup.placement.peripherals:
        _fail(f"--index {index} is outside [1, {setup.placement.peripherals}]", EXIT_CONFIG)
    sys.exit(_quiet(lambda: run_peripheral(setup, index, conf)))


def _role_setup(kw: dict[str, Any]) -> tuple[Any, Any]:
    """Setup and Zenoh configuration of a single role (exits on a configuration error)."""
    from .launcher import make_setup
    from .sched import RtPermissionError, apply_rt
    from .zsession import make_config, pin_cpus

    rc = make_rc(kw)
    try:
        setup = make_setup(rc)
    except (ConfigError, ValueError) as exc:
        _fail(str(exc), EXIT_CONFIG)
    pin_cpus(rc.pin)
    try:  # before zenoh.open: its threads inherit it
        apply_rt(rc.rt_priority)
    except RtPermissionError as exc:
        _fail(str(exc), EXIT_CONFIG)
    return setup, make_config(listen=rc.listen, connect=rc.connect,
                              config_file=rc.zenoh_config)


@cli.command()
@run_options
def plant(**kw: Any) -> None:
    """Run the simulated Delta as a Zenoh node (connects to the central's endpoint)."""
    from .launcher import run_plant

    setup, conf = _role_setup(kw)
    sys.exit(_quiet(lambda: run_plant(setup, conf)))


@cli.command()
@run_options
@click.option("--json", "as_json", is_flag=True)
def central(as_json: bool, **kw: Any) -> None:
    """Run the central alone; plant and peripherals are started separately
    (``ctrlunit plant`` / ``ctrlunit peripheral --index K`` with the same options and
    ``--connect`` to this process's ``--listen`` endpoint)."""
    from .launcher import central_only

    rc = make_rc(kw)
    try:
        rc.validate()
    except ConfigError as exc:
        _fail(str(exc), EXIT_CONFIG)
        return
    if not rc.listen:
        _fail("central needs --listen ENDPOINT (e.g. tcp/127.0.0.1:7447)", EXIT_CONFIG)
    code, report = central_only(rc)
    from .report import summary

    if "cycles" in report:
        if rc.report:
            with open(rc.report, "w") as fh:
                json.dump(_json_safe(report), fh, indent=2)
        click.echo(json.dumps(_json_safe(report)) if as_json else summary(report))
    else:
        click.echo(f"ctrlunit: error: {report['fault']['message']}", err=True)
    sys.exit(code)


def _quiet(fn: Any) -> int:
    """Run a role; Ctrl-C (sent to the whole process group) ends it quietly."""
    try:
        return fn()
    except KeyboardInterrupt:
        return 130


_ = math


def _cycle_range(_ctx: Any, _param: Any, value: str | None) -> tuple[int, int] | None:
    if value is None:
        return None
    try:
        a, b = value.split(":")
        lo, hi = int(a or 0), int(b) if b else 2**62
    except ValueError:
        raise click.BadParameter(f"--cycles {value!r}: expected A:B (e.g. 100:200)") from None
    if lo < 0 or hi <= lo:
        raise click.BadParameter(f"--cycles {value!r}: need 0 <= A < B")
    return lo, hi


def _open_recording(path: str) -> Any:
    from .recording import read

    try:
        rec = read(path)
    except (OSError, ValueError) as exc:
        _fail(str(exc))
    if rec.salvaged:
        click.echo(f"ctrlunit: note: {rec.note}", err=True)
    return rec


@cli.command()
@click.argument("file", type=click.Path(exists=True, dir_okay=False))
@click.option("--verify", is_flag=True, help="Re-execute every block and bit-compare.")
@click.option("--cycles", "cycle_range", default=None, callback=_cycle_range,
              help="Intervals A:B only.")
@click.option("--csv", "csv_dir", type=click.Path(file_okay=False), default=None,
              help="Export the signals as CSV into DIR.")
@click.option("--rate", type=click.FloatRange(min=1e-3, max=1e3), default=1.0,
              show_default=True, help="Republish speed factor.")
@click.option("--loop", is_flag=True, help="Republish in a loop.")
@click.option("--start-offset", type=click.FloatRange(min=0.0), default=0.0,
              help="Start this many seconds into the recording.")
@click.option("--topics", multiple=True, help="Only these topics (e.g. /plant/command).")
@click.option("--unit", default=None, help="Unit id to republish under (default: replay-<id>).")
@click.option("--connect", multiple=True, help="Zenoh endpoint to connect to.")
@click.option("--listen", multiple=True, help="Zenoh endpoint to listen on.")
@click.option("--max-seconds", type=float, default=None, hidden=True)
def replay(file: str, verify: bool, cycle_range: tuple[int, int] | None, csv_dir: str | None,
           rate: float, loop: bool, start_offset: float, topics: tuple[str, ...],
           unit: str | None, connect: tuple[str, ...], listen: tuple[str, ...],
           max_seconds: float | None) -> None:
    """Replay a recording: --verify bit-compares every block; --csv exports; otherwise
    republish its messages on Zenoh at the recorded pace."""
    from . import replay as rp

    rec = _open_recording(file)
    if verify:
        n, div = rp.verify(rec, cycles=cycle_range)
        if div is not None:
            click.echo(f"DIVERGENCE after {n} identical intervals: {div}")
            sys.exit(1)
        click.echo(f"verified {n} intervals: every block's outputs are bit-identical to the "
                   "recording")
        return
    if csv_dir:
        for p in rp.export_csv(rec, csv_dir, cycles=cycle_range):
            click.echo(f"wrote {p}")
        return
    from .zsession import make_config

    conf = make_config(listen=list(listen) or None, connect=list(connect) or None)
    target = unit or f"replay-{rec.config.get('unit', 'x')}"
    sent = rp.republish(rec, unit=target, rate=rate, loop=loop, start_offset=start_offset,
                        topics=list(topics) or None, cycles=cycle_range, conf=conf,
                        max_seconds=max_seconds)
    click.echo(f"republished {sent} messages under ctrlunit/{target}/")


@cli.command("report")
@click.argument("file", type=click.Path(exists=True, dir_okay=False))
@click.option("--json", "as_json", is_flag=True)
@click.option("--report", "report_file", type=click.Path(dir_okay=False), default=None,
              help="Write the report as JSON.")
def report_cmd(file: str, as_json: bool, report_file: str | None) -> None:
    """Regenerate the run's report from a recording alone."""
    from .recording import report_from_recording
    from .report import summary

    rec = _open_recording(file)
    rep = report_from_recording(rec)
    if report_file:
        with open(report_file, "w") as fh:
            json.dump(_json_safe(rep), fh, indent=2)
    click.echo(json.dumps(_json_safe(rep)) if as_json else summary(rep))


@cli.command()
@click.option("--out", "out_dir", type=click.Path(file_okay=False), default="bench-out",
              show_default=True, help="Directory for report.md, report.json and figures.")
@click.option("--quick", is_flag=True, help="One repeat, short runs (under 3 minutes).")
@click.option("--repeats", type=click.IntRange(1, 20), default=None)
@click.option("--realtime-period", "rt_periods", multiple=True, default=("3ms",),
              show_default=True, help="Realtime periods to include (repeatable).")
@click.option("--thesis-scale", type=click.FloatRange(1.0, 1000.0), default=30.0,
              show_default=True, help="T-800 time scale of the runs compared with 1994: "
              "large enough that an exchange weighs on the arithmetic about as a "
              "Transputer link did (README, bench).")
def bench(out_dir: str, quick: bool, repeats: int | None, rt_periods: tuple[str, ...],
          thesis_scale: float) -> None:
    """Sweep n x depth x cost model, measure the floor, write reports and figures."""
    from rich.progress import Progress

    from ..bench.sweep import bench as run_bench

    periods = [parse_duration(p, field_name="--realtime-period") for p in rt_periods]
    with Progress(transient=True) as prog:
        task = prog.add_task("bench", total=None)

        def tick(what: str, done: int, total: int) -> None:
            prog.update(task, description=what[:70], completed=done, total=total)

        rep = run_bench(out_dir, quick=quick, repeats=repeats, realtime_periods=periods,
                        scale=thesis_scale, progress=tick)
    click.echo(f"wrote {out_dir}/report.md, report.json and {len(rep['figures'])} figures "
               f"in {rep['wall_s']:.0f} s")


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

    from ..bench.balance import analyse, compare, load_report, write_placement

    try:
        a = analyse(load_report(source))
        cmp = compare(a, load_report(rerun)) if rerun else None
    except (ValueError, KeyError, OSError) as exc:
        _fail(f"balance: {exc}", EXIT_CONFIG)
        return
    write_placement(a, out)
    if figure:
        from ..bench.figures import gantt_figure

        d = a["pipeline"]
        panels = {f"depth {d}, measured": a["measured"]["gantt_ms"],
                  f"depth {d}, model of the same run": a["current"]["gantt_ms"],
                  f"depth {d}, predicted with the new placement": a["predicted"]["gantt_ms"]}
        if cmp is not None:
            panels[f"depth {cmp['depth']}, re-run with the new placement (measured)"] = \
                cmp["gantt_ms"]
        gantt_figure(Path(figure), panels)
    if as_json:
        click.echo(json.dumps(_json_safe(a | ({"compare": cmp} if cmp else {}))))
        return

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
    click.echo("\n".join(lines))
