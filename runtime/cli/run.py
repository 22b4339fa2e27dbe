"""``ctrlunit start`` and the single roles (``central``, ``plant``, ``peripheral``)."""

from __future__ import annotations

import contextlib
import json
import sys
from typing import Any

import click

from ...plant.simulator import MAX_SUBSTEP_BELT_S, MAX_SUBSTEP_S
from ...topology.graph import MODEL_STATES
from ...topology.pipeline import HOLD_RULES
from ..config import (
    EXIT_CONFIG,
    FLAT,
    LATE_POLICIES,
    MISSED_COMMANDS,
    ConfigError,
    RunConfig,
    parse_duration,
)
from ..idle import IDLE_CHOICES
from .base import _emit, _fail, _json_safe, _rt_priority, cli


def _duration(_ctx: Any, param: click.Parameter, value: str | None) -> float | None:
    if value is None:
        return None
    try:
        return parse_duration(value, field_name=f"--{param.name}")
    except ConfigError as exc:
        raise click.BadParameter(str(exc)) from None


def _period(ctx: Any, param: click.Parameter, value: str) -> float | str:
    if isinstance(value, str) and value.strip() == "auto":
        return "auto"
    return _duration(ctx, param, value) or 0.0


def run_options(fn: Any) -> Any:
    """Options shared by start and the single roles (README, ctrlunit start)."""
    opts = [
        click.option("--check", is_flag=True,
                     help="Check the options and files (task, placement, parameters, Zenoh "
                     "configuration), print the plan and exit: nothing is started."),
        click.option("--peripherals", type=click.IntRange(0, 3), default=3, show_default=True,
                     help="Number of peripheral processes (0 = single processor)."),
        click.option("--pipeline", type=click.IntRange(1, 2), default=1, show_default=True,
                     help="Pipeline depth (§ IV.7.2)."),
        click.option("--clock", type=click.Choice(["lockstep", "realtime", "freerun"]),
                     default="realtime", show_default=True),
        click.option("--command-delay", type=click.Choice(["full", "short"]), default="full",
                     show_default=True,
                     help="When the plant applies the command of sample k: full (causal) "
                     "in the period that begins at tick k + depth; short: the earlier "
                     "convention, one period sooner, on physics that began before the "
                     "command was due."),
        click.option("--period", default="auto", show_default=True, callback=_period,
                     help="Sampling period: 500us, 1ms, or seconds; auto: in realtime the "
                     "shortest period from 1 ms up that the admission trial shows this "
                     "machine holds (1 ms in the other clocks)."),
        click.option("--admission/--no-admission", default=True, show_default=True,
                     help="Realtime: a trial at the period before the first command; a "
                     "period that does not hold is refused (exit 7) before any motion."),
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
        click.option("--record-compression", type=click.Choice(["zstd", "lz4", "none"]),
                     default="zstd", show_default=True,
                     help="MCAP chunk compression of --record, done on a writer thread "
                     "off the control path (zstd: about 3x smaller)."),
        click.option("--foxglove", default=None, metavar="[HOST:]PORT",
                     help="Serve a live view to Foxglove (WebSocket; host 127.0.0.1 "
                     "unless given; port 0: any free one), off the control path."),
        click.option("--foxglove-rate", type=float, default=200.0, show_default=True,
                     metavar="HZ", help="/signals/state messages per second of the live "
                     "view; 0: every interval (each costs the central ~0.1 ms of CPU)."),
        click.option("--report", type=click.Path(dir_okay=False), default=None,
                     help="Write the report as JSON."),
        click.option("--unit", default=None, help="Unit id (keys ctrlunit/<unit>/...)."),
        click.option("--cost-model", type=click.Choice(["native", "t800"]), default="native",
                     show_default=True),
        click.option("--cost-scale", type=click.FloatRange(0.01, 1000.0), default=1.0,
                     show_default=True, help="Multiply the T-800 block times (t800 cost "
                     "model): reproduce the 1994 ratio of arithmetic to communication."),
        click.option("--placement", default="auto", show_default=True, metavar="auto|axes|FILE",
                     help="Which process runs which block: axes (each peripheral all of "
                     "its axes' blocks, § IV.7), auto (at warm-up, a round cheaper than its "
                     "round trip moves to the central) or a FILE from ctrlunit balance."),
        click.option("--params", type=click.Path(dir_okay=False), default=None,
                     help="TOML file of Delta parameters."),
        click.option("--observer", type=click.Choice(["predict", "previous"]),
                     default="predict", show_default=True,
                     help="Newton-Raphson start: prediction (1 iteration) or previous (2)."),
        click.option("--model-state", type=click.Choice(["auto", *MODEL_STATES]),
                     default="auto", show_default=True,
                     help="Resolved acceleration: servo the state predicted for the period "
                     "in which the command acts (carried forward at the commands in flight) "
                     "and evaluate the model (second round's kinematics, dynamics) there, "
                     "from a velocity taken from the observed positions (acting); the same "
                     "with the model's kinematics at that state foreseen from the previous "
                     "interval, so that at depth 2 the peripherals compute them before the "
                     "sample (foreseen); the same from the estimate of two intervals back, "
                     "the observer's prediction too, so that two intervals' rounds go in "
                     "one exchange (foreseen2); or servo and evaluate at the sample's estimate "
                     "with pdot = J qdot as the thesis (sample); auto: foreseen2 in "
                     "realtime at depth 2, acting otherwise."),
        click.option("--bandwidth", "bandwidth_hz", type=float, default=None,
                     help="Closed-loop bandwidth of the gains in Hz (default: 20, at most "
                     "1/(12.5 period) with resolved acceleration at the acting state, "
                     "1/(50 period) otherwise)."),
        click.option("--listen", multiple=True, help="Zenoh endpoint to listen on."),
        click.option("--connect", multiple=True, help="Zenoh endpoint to connect to."),
        click.option("--keys", "keys", type=click.Path(file_okay=False), default=None,
                     help="The unit's credentials (ctrlunit keys init DIR): every link but "
                     "the local socket is mutual TLS under the unit's access control."),
        click.option("--insecure", is_flag=True,
                     help="Allow links beyond this host without --keys (a lab bench)."),
        click.option("--zenoh-config", type=click.Path(dir_okay=False), default=None),
        click.option("--timeout", default="2s", show_default=True, callback=_duration,
                     help="Reply timeout in lockstep and freerun (realtime: --fault-periods)."),
        click.option("--fault-periods", default=3.0, type=click.FloatRange(1.0, 1000.0),
                     show_default=True, help="Realtime: a peripheral, the plant or a link "
                     "silent for this many periods is a fault (the robot is stopped)."),
        click.option("--late-policy", type=click.Choice(list(LATE_POLICIES)),
                     default="compute", show_default=True,
                     help="Realtime: a peripheral's late reply is waited for, computed by "
                     "the central itself (compute: the same arithmetic, so the same "
                     "commands), replaced by its last values (hold), or a fault."),
        click.option("--late", "late_items", multiple=True, metavar="BLOCK=POLICY",
                     help="Late-data policy for one block (overrides --late-policy)."),
        click.option("--missed-command", type=click.Choice(list(MISSED_COMMANDS)),
                     default="extrapolate", show_default=True,
                     help="Realtime: in a period whose command is late the plant applies "
                     "the command the central extrapolated for it and sent with the one "
                     "before (at the full control rate), or holds the last one that came."),
        click.option("--overload", type=click.Choice(["auto", "halve", "continue"]),
                     default="auto", show_default=True,
                     help="Realtime: when 10 of the last 100 intervals were late (their "
                     "command left after its deadline, or their sample was skipped), halve "
                     "the control rate: the unit takes every second sample and the plant "
                     "holds each command two periods, still ticking at --period (the "
                     "report's overload says from where); continue: go on as it is; auto: "
                     "halve with the admission on where the gains keep their margin at "
                     "twice the period, else continue."),
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
        click.option("--hold-rounds", type=click.Choice(list(HOLD_RULES)),
                     default="auto", show_default=True,
                     help="Depth 2: a lone round ready early waits to travel with the next "
                     "interval's first round (always: one exchange per interval), or goes "
                     "at once (never: two exchanges, no wait for the next sample); auto: "
                     "never in realtime (a held round waits up to a period for the next "
                     "sample), always otherwise."),
        click.option("--pin", default=None, help="CPUs for this process, e.g. 0 or 0,1."),
        click.option("--cpus", type=click.Choice(["same", "split"]), default=None,
                     help="start: pin every role on CPU 0 (same), or the central on 0 and "
                     "the others on 1 (split); default: no pinning."),
        click.option("--rt-priority", default="auto", show_default=True,
                     callback=_rt_priority, metavar="auto|0-99",
                     help="SCHED_FIFO priority of every role of the unit (the roles "
                     "inherit it from start); 0: leave the policy as it is (1-99 needs "
                     "root, CAP_SYS_NICE or ulimit -r). auto: FIFO at 10 in realtime with "
                     "the admission, where permitted and the kernel throttles real-time "
                     "tasks; the admission then refuses a period that keeps a CPU "
                     "over 85 % of the kernel's real-time budget, and the run goes back to "
                     "the default policy if it stays over 95 % of it for a second or "
                     "passes it (the report says which and why)."),
        click.option("--idle", type=click.Choice(list(IDLE_CHOICES)),
                     default="auto", show_default=True,
                     help="poll holds the kernel's CPU latency request at 0 us while this "
                     "process runs (/dev/cpu_dma_latency), so that idle CPUs spin "
                     "instead of halting and every wake-up is quicker, at the cost of "
                     "the CPUs spinning while idle (needs root); auto: poll in realtime "
                     "where permitted and a deeper idle state exists; default: leave "
                     "them alone."),
        click.option("--plant-substeps", type=click.IntRange(1, 1000), default=None,
                     help="RK4 sub-steps of the plant per period; default: the fewest of "
                     f"at most {MAX_SUBSTEP_S * 1e3:g} ms ({MAX_SUBSTEP_BELT_S * 1e3:g} ms "
                     "with --belt)."),
        click.option("--plant-lag", default="0s", callback=_duration_or_zero,
                     help="Actuator time constant (Eq. IV.6)."),
        click.option("--plant-friction", type=click.FloatRange(0.0, 100.0), default=0.0,
                     show_default=True, help="Viscous friction on each joint (N m s/rad)."),
        click.option("--belt", is_flag=True, help="Simulate the elastic belt (§ V.6.3)."),
        click.option("--spec", type=click.Path(dir_okay=False), default=None,
                     help="Run configuration written by ctrlunit start (internal)."),
        click.option("--status-file", type=click.Path(dir_okay=False), default=None,
                     hidden=True, help="Write the completed-interval count every 10."),
        click.option("--profile", type=click.Choice(["main-job", "thesis"]),
                     default="main-job", show_default=True,
                     help="Settings for an intent: the realtime main job, or the thesis's "
                     "graph (model at the sample, axes placement, observer previous)."),
        click.option("--config", "config_file", type=click.Path(dir_okay=False),
                     default=None, help="A run file (TOML, the sections ctrlunit config "
                     "prints) over the profile."),
        click.option("--set", "set_items", multiple=True, metavar="SECTION.KEY=VALUE",
                     help="One setting over the run file (repeatable), e.g. "
                     "schedule.late_policy=wait."),
        click.option("--help-all", is_flag=True, expose_value=False, is_eager=True,
                     callback=_help_all, help="Show every option, the tuning ones too."),
    ]
    for o in reversed(opts):
        fn = o(fn)
    for param in getattr(fn, "__click_params__", []):
        if param.name not in EVERYDAY:
            param.hidden = True
    return fn


EVERYDAY = frozenset({"check", "peripherals", "pipeline", "clock", "period", "task", "law",
                      "cycles", "duration", "record", "report", "foxglove", "placement",
                      "profile", "config_file", "set_items", "help_all", "as_json",
                      "plot_dir"})
"""The options ``--help`` shows (the rest: ``--help-all``, README's table): what a person
running the unit sets; the others are tuning levers with good defaults."""


def _help_all(ctx: click.Context, _param: click.Parameter, value: bool) -> None:
    """``--help-all``: the help with every option shown."""
    if not value or ctx.resilient_parsing:
        return
    for p in ctx.command.params:
        if isinstance(p, click.Option) and p.name != "status_file":  # the launcher's
            p.hidden = False
    click.echo(ctx.get_help())
    ctx.exit()


def _duration_or_zero(ctx: Any, param: click.Parameter, value: str) -> float:
    if value in ("0", "0s", 0):
        return 0.0
    return _duration(ctx, param, value) or 0.0


PARAM_FLATS = {"placement": ("placement", "placement_auto"), "period": ("period", "period_auto"),
               "late_items": ("late",)}
"""Options a flag sets other than its own name."""


def explicit_params() -> set[str]:
    """The parameters given on the command line (or by environment), not defaulted."""
    ctx = click.get_current_context(silent=True)
    if ctx is None:
        return set()
    given = (click.core.ParameterSource.COMMANDLINE, click.core.ParameterSource.ENVIRONMENT)
    return {n for n in ctx.params if ctx.get_parameter_source(n) in given}


def make_rc(kw: dict[str, Any]) -> RunConfig:
    """The run's configuration: the defaults, then ``--profile``, the run file
    (``--config``), ``--set``, and the flags given (runtime/run_file.py)."""
    from ..run_file import parse_set, profile, read_run_file

    layered: dict[str, Any] = profile(kw.pop("profile", None) or "main-job")
    config_file = kw.pop("config_file", None)
    if config_file:
        layered |= read_run_file(config_file)
    layered |= parse_set(kw.pop("set_items", ()) or ())
    options = _flag_options(kw)
    if isinstance(options, RunConfig):  # a role the launcher started: the run's spec
        return options
    if not layered:
        return RunConfig.of(**options)
    given = {f for p in explicit_params() for f in PARAM_FLATS.get(p, (p,)) if f in options}
    return RunConfig.of(**(options | layered | {f: options[f] for f in given}))


def _flag_options(kw: dict[str, Any]) -> dict[str, Any] | RunConfig:
    """The flags as options by flat name (every flag, defaulted ones too); the run's
    spec instead for a role the launcher started."""
    from ..setup import load_spec

    spec = kw.pop("spec", None)
    listen = list(kw.pop("listen", ()) or ()) or None
    connect = list(kw.pop("connect", ()) or ()) or None
    if spec:
        # the central's endpoints are its own, not the children's
        return load_spec(spec).replace(listen=listen, connect=connect,
                                       pin=kw.get("pin") or None)
    unit = kw.pop("unit", None)
    late: dict[str, str] = {}
    for item in kw.pop("late_items", ()) or ():
        block, _, pol = item.partition("=")
        if not block or not pol:
            raise ConfigError(f"--late {item!r}: expected BLOCK=POLICY (POLICY one of "
                              f"{', '.join(LATE_POLICIES)})")
        late[block] = pol
    kw["late"] = late
    placement = kw.get("placement")
    if placement in ("auto", "axes"):
        kw["placement"], kw["placement_auto"] = None, placement == "auto"
    if kw.get("period") == "auto":
        from ..admission import LADDER_S

        kw["period"], kw["period_auto"] = LADDER_S[0], True
    options = {k: v for k, v in kw.items() if k in FLAT}
    options.update(plant_lag=kw.get("plant_lag", 0.0), listen=listen, connect=connect)
    if unit:
        options["unit"] = unit
    return options


@cli.command(epilog="Every other setting (the pipeline's and the scheduler's levers, late "
             "data, overload, the plant model, the transport) has a default that suits "
             "the main job: ctrlunit start --help-all lists them, README's table says what "
             "each does.")
@run_options
@click.option("--json", "as_json", is_flag=True, help="Print the report as JSON.")
@click.option("--progress/--no-progress", default=None, hidden=True,
              help="Progress display (default: when stdout is a terminal).")
@click.option("--plot", "plot_dir", type=click.Path(file_okay=False), default=None,
              help="At the end, draw the run into DIR (as ctrlunit plot does); records it "
              "to DIR/run.mcap unless --record is given.")
def start(as_json: bool, progress: bool | None, plot_dir: str | None, check: bool,
          **kw: Any) -> None:
    """Start plant, central and peripherals on this host and run the task."""
    from ..launcher import start as run_start

    try:
        rc = make_rc(kw).validate()
    except ConfigError as exc:
        _fail(str(exc), EXIT_CONFIG)
        return
    if check:
        _check(rc, as_json)
        return
    if plot_dir and not rc.run.record:
        from pathlib import Path

        try:
            Path(plot_dir).mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            _fail(f"--plot {plot_dir}: {exc}", EXIT_CONFIG)
            return
        rc = rc.replace(record=str(Path(plot_dir) / "run.mcap"))
    show = sys.stdout.isatty() if progress is None else progress
    prog, echo, finish = _progress(show)
    try:
        code, report = run_start(rc, echo=echo, progress=prog)
    finally:
        finish()
    if "cycles" not in report:
        _fail(report["fault"]["message"], code)
        return
    if rc.run.report:
        with open(rc.run.report, "w") as fh:
            json.dump(_json_safe(report), fh, indent=2)
    from ..summary import summary

    click.echo(json.dumps(_json_safe(report)) if as_json else summary(report))
    if plot_dir:
        _plot_run(rc.run.record, plot_dir, summary(report))
    if code:
        f = report.get("fault") or {}
        click.echo(f"ctrlunit: fault in {f.get('process')}: {f.get('message')}", err=True)
    sys.exit(code)


def _check(rc: RunConfig, as_json: bool) -> None:
    """``start --check``: everything ``start`` derives before it starts a process."""
    from ..report import quoted
    from ..setup import make_setup

    try:
        setup = make_setup(rc)
    except (ConfigError, ValueError, OSError) as exc:
        _fail(str(exc), EXIT_CONFIG)
        return
    plan = setup.plan
    data = {"valid": True, "peripherals": setup.placement.peripherals,
            "pipeline": rc.schedule.pipeline, "clock": rc.schedule.clock,
            "period_s": None if rc.schedule.period_auto else rc.schedule.period,
            "period_auto": rc.schedule.period_auto,
            "task": setup.task.name, "task_loop_s": setup.task.period,
            "cycles": setup.cycles, "law": rc.control.law, "model": rc.control.model,
            "placement": setup.placement.to_dict(), "round_trips": plan.round_trips,
            "placement_auto": rc.schedule.placement_auto,
            "command_delay_periods": rc.delay_periods,
            "overload": "halve" if rc.halves_on_overload else "continue"}
    period = "auto" if rc.schedule.period_auto else f"{rc.schedule.period * 1e3:g} ms"
    overload = (f"  on overload: halve the control rate (--overload {rc.schedule.overload})\n"
                if rc.halves_on_overload else "")
    _emit(data, as_json,
          f"ctrlunit start: the options are valid; nothing was started.\n"
          f"  {setup.placement.peripherals} peripheral(s), pipeline depth {rc.schedule.pipeline}, "
          f"clock {rc.schedule.clock}, period {period}\n"
          f"  task {quoted(setup.task.name)} (a loop of {setup.task.period:.3f} s), {setup.cycles} "
          f"intervals, {rc.control.law} + {rc.control.model} model\n"
          + overload +
          f"  {plan.round_trips} round trip(s) per interval"
          + (" (placement auto: the warm-up may move a round to the central)"
             if rc.schedule.placement_auto and setup.placement.peripherals else "")
          + ":\n    " + plan.describe().replace("\n", "\n    "))


def _plot_run(record: str | None, plot_dir: str, text: str) -> None:
    """``start --plot``: the run's figures, from its recording (salvaged if it was cut)."""
    from ..plots import plot_recording
    from ..recording import read

    try:
        plots = plot_recording(read(record or ""), plot_dir, summary=text)
    except (OSError, ValueError) as exc:
        click.echo(f"ctrlunit: no plots: {exc}", err=True)
        return
    click.echo(f"ctrlunit: figures of the run in {plots.index}", err=True)


def _progress(show: bool) -> tuple[Any, Any, Any]:
    """The live line (runtime/live.py) on the terminal only: the central's ``on_cycle``
    callback, ``echo`` for messages during the run (written above the line), and the
    function that clears it."""
    def echo(m: str) -> None:
        click.echo(m, err=True)

    if not show:
        return None, echo, lambda: None
    from ..live import LiveLine, TerminalLine

    line = TerminalLine(sys.stdout)
    return LiveLine(line.show), lambda m: line.above(m, sys.stderr), line.close


@cli.command()
@run_options
@click.option("--index", type=click.IntRange(1, 3), required=True)
def peripheral(index: int, **kw: Any) -> None:
    """Run peripheral K of a unit (connects to the central's endpoint)."""
    from ..peripheral import run_peripheral

    setup, conf, held = _role_setup(kw, role="peripheral", index=index)
    with held:
        code = _quiet(lambda: run_peripheral(setup, index, conf))
    sys.exit(code)


def _role_setup(kw: dict[str, Any], *, role: str,
                index: int | None = None) -> tuple[Any, Any, contextlib.ExitStack]:
    """Setup and Zenoh configuration of a single role, and its CPU idle request
    (runtime/idle.py: a role started on another host holds it for that host; close it
    when the role ends). Exits on a configuration error; with ``--check``, exits 0 once
    everything is checked, before anything starts."""
    from ..idle import IdlePermissionError, idle_request
    from ..sched import RtPermissionError, apply_choice
    from ..setup import make_setup
    from ..zsession import make_config, pin_cpus

    check = kw.pop("check", False)
    rc = make_rc(kw)
    try:
        setup = make_setup(rc.validate())
    except (ConfigError, ValueError, OSError) as exc:
        _fail(str(exc), EXIT_CONFIG)
    if index is not None and index > setup.placement.peripherals:
        _fail(f"--index = {index}: allowed 1 to {setup.placement.peripherals} (the unit's "
              "peripherals)" if setup.placement.peripherals else
              f"--index = {index}: the unit has no peripherals (--peripherals 0)", EXIT_CONFIG)
    if check:
        click.echo(f"ctrlunit {role}: the options are valid; nothing was started.")
        sys.exit(0)
    pin_cpus(rc.schedule.pin)
    try:  # before zenoh.open: its threads inherit it
        apply_choice(rc.schedule.rt_priority, clock=rc.schedule.clock,
                     admission=rc.schedule.admission, guarded=False)
    except RtPermissionError as exc:
        _fail(str(exc), EXIT_CONFIG)
    held = contextlib.ExitStack()
    try:
        held.enter_context(idle_request(rc.schedule.idle, clock=rc.schedule.clock))
    except IdlePermissionError as exc:
        _fail(str(exc), EXIT_CONFIG)
    name = role if index is None else f"{role}-{index}"
    try:
        conf = make_config(listen=rc.transport.listen, connect=rc.transport.connect,
                           config_file=rc.transport.zenoh_config, keys=rc.transport.keys,
                           role=name)
    except (FileNotFoundError, ValueError) as exc:
        _fail(str(exc), EXIT_CONFIG)
    return setup, conf, held


@cli.command()
@run_options
def plant(**kw: Any) -> None:
    """Run the simulated Delta as a Zenoh node (connects to the central's endpoint)."""
    from ..plant_node import run_plant

    setup, conf, held = _role_setup(kw, role="plant")
    with held:
        code = _quiet(lambda: run_plant(setup, conf))
    sys.exit(code)


@cli.command()
@run_options
@click.option("--json", "as_json", is_flag=True)
def central(as_json: bool, **kw: Any) -> None:
    """Run the central alone; plant and peripherals are started separately
    (``ctrlunit plant`` / ``ctrlunit peripheral --index K`` with the same options and
    ``--connect`` to this process's ``--listen`` endpoint)."""
    from ..launcher import central_only
    from ..setup import make_setup

    check = kw.pop("check", False)
    rc = make_rc(kw)
    try:
        make_setup(rc.validate())
    except (ConfigError, ValueError, OSError) as exc:
        _fail(str(exc), EXIT_CONFIG)
        return
    if not rc.transport.listen:
        _fail("central needs --listen ENDPOINT (e.g. tcp/127.0.0.1:7447)", EXIT_CONFIG)
    if check:
        click.echo("ctrlunit central: the options are valid; nothing was started.")
        sys.exit(0)
    code, report = central_only(rc)
    from ..summary import summary

    if "cycles" in report:
        if rc.run.report:
            with open(rc.run.report, "w") as fh:
                json.dump(_json_safe(report), fh, indent=2)
        click.echo(json.dumps(_json_safe(report)) if as_json else summary(report))
    else:
        _fail(report["fault"]["message"], code)
    sys.exit(code)


def _quiet(fn: Any) -> int:
    """Run a role; Ctrl-C ends it quietly (a role run by hand: those ``ctrlunit start``
    starts ignore it and wait for the launcher's stop order, runtime/supervise.py)."""
    try:
        return fn()
    except KeyboardInterrupt:
        return 130


@cli.command("config")
@run_options
def config_cmd(check: bool, **kw: Any) -> None:
    """Print the run's settings as a run file: the defaults, or what the given profile,
    run file, --set and flags resolve to (ctrlunit start --config reads it back)."""
    from ..run_file import to_toml

    del check
    asked_unit = bool(kw.get("unit")) or any(
        i.strip().startswith("transport.unit") for i in kw.get("set_items") or ())
    try:
        if kw.get("config_file"):
            from ..run_file import read_run_file

            asked_unit |= "unit" in read_run_file(kw["config_file"])
        rc = make_rc(kw).validate()
    except ConfigError as exc:
        _fail(str(exc), EXIT_CONFIG)
        return
    settings = rc.to_dict()
    if not asked_unit:  # a fresh random id per run: a file that fixed it would share it
        settings["unit"] = None
    click.echo(to_toml(settings), nl=False)

