"""``ctrlunit start`` and the single roles (``central``, ``plant``, ``peripheral``)."""

from __future__ import annotations

import contextlib
import json
import sys
from typing import Any

import click

from ..config import (
    EXIT_CONFIG,
    EXIT_LINK,
    ConfigError,
    RunConfig,
)
from ..config.spellings import user_view
from .base import FilePath, _emit, _fail, _json_safe, cli, exit_line
from .options import given_settings, make_rc, role_options, run_options


@cli.command(epilog="Every other setting (the pipeline's and the scheduler's levers, late "
             "data, overload, the plant model, the transport) has a default that suits "
             "the main job: ctrlunit start --help-all lists them, README's table says what "
             "each does.")
@run_options
@click.option("--json", "as_json", is_flag=True, help="Print the report as JSON.")
@click.option("--progress/--no-progress", default=None, hidden=True,
              help="Progress display (default: when stdout is a terminal).")
@click.option("--plot", "plot_dir", type=FilePath(file_okay=False), default=None,
              help="At the end, draw the run into DIR (as ctrlunit plot does); records it "
              "to DIR/run.mcap unless --record is given.")
def start(as_json: bool, progress: bool | None, plot_dir: str | None, check: bool,
          **kw: Any) -> None:
    """Start plant, central and peripherals on this host and run the task."""
    from ..launch.launcher import start as run_start

    try:
        rc = make_rc(kw)
        rc.validate(roles=rc.started_roles)  # with --keys, every role's before any starts
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
        _fail(report["fault"]["message"] + _kept(report), code)
        return
    if rc.run.report:
        with open(rc.run.report, "w") as fh:
            json.dump(_json_safe(report), fh, indent=2)
    from ..observe.summary import summary

    click.echo(json.dumps(_json_safe(report)) if as_json else summary(report))
    if plot_dir:
        # a run longer than the exact window has histogram quantiles: the index then
        # shows the recording's summary, exact as the plots are
        _plot_run(rc.run.record, plot_dir, summary(report)
                  if (report.get("timing") or {}).get("exact", True) else None)
    if code:
        click.echo(exit_line(report.get("fault") or {}, code, as_json=as_json), err=True)
    if report.get("logs_kept"):
        click.echo(f"ctrlunit: the roles' logs are kept in {report['logs_kept']}", err=True)
    sys.exit(code)


def _kept(report: dict[str, Any]) -> str:
    """Where the run directory of a faulted run was kept (its spec and the roles' logs),
    as the end of a line."""
    kept = report.get("logs_kept")
    return f"; the roles' logs are kept in {kept}" if kept else ""


def _check(rc: RunConfig, as_json: bool) -> None:
    """``start --check``: everything ``start`` derives before it starts a process."""
    from ..compute.setup import make_setup
    from ..observe.report import quoted

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
            "overload": "halve" if rc.halves_on_overload else "continue",
            "settings": user_view(rc.to_dict())}
    period = f"{rc.schedule.period * 1e3:g} ms"
    if rc.schedule.period_auto:  # what will run: the admission chooses only in realtime
        period = (f"auto (the shortest from {period} up that the admission's trial holds)"
                  if rc.schedule.clock == "realtime" and rc.schedule.admission
                  else f"{period} (auto)")
    intervals = f"{setup.cycles} intervals"
    if period.startswith("auto"):  # a fixed duration: fewer intervals at a longer period
        intervals += f" at {rc.schedule.period * 1e3:g} ms (fewer at a longer period)"
    overload = (f"  on overload: halve the control rate (--overload {rc.schedule.overload})\n"
                if rc.halves_on_overload else "")
    _emit(data, as_json,
          f"ctrlunit start: the options are valid; nothing was started.\n"
          f"  {setup.placement.peripherals} peripheral(s), pipeline depth {rc.schedule.pipeline}, "
          f"clock {rc.schedule.clock}, period {period}\n"
          f"  task {quoted(setup.task.name)} (a loop of {setup.task.period:.3f} s), {intervals}, "
          f"{rc.control.law} + {rc.control.model} model\n"
          + overload +
          f"  {plan.round_trips} round trip(s) per interval"
          + _placement_note(rc, setup.placement.peripherals)
          + ":\n    " + plan.describe().replace("\n", "\n    "))


def _placement_note(rc: RunConfig, peripherals: int) -> str:
    """Which placement ``--check`` shows: auto, axes or the file's."""
    if not peripherals:
        return ""
    if rc.schedule.placement_auto:
        return " (placement auto: the warm-up may move a round to the central)"
    return f" (placement {rc.schedule.placement or 'axes'})"


def _plot_run(record: str | None, plot_dir: str, text: str | None) -> None:
    """``start --plot``: the run's figures, from its recording (salvaged if it was cut)."""
    from ..recording.plots import plot_recording
    from ..recording.reader import read

    try:
        plots = plot_recording(read(record or ""), plot_dir, summary=text)
    except (OSError, ValueError) as exc:
        click.echo(f"ctrlunit: no plots: {exc}", err=True)
        return
    click.echo(f"ctrlunit: figures of the run in {plots.index}", err=True)


def _progress(show: bool) -> tuple[Any, Any, Any]:
    """The live line (runtime/observe/live.py) on the terminal only: the central's ``on_cycle``
    callback, ``echo`` for messages during the run (written above the line), and the
    function that clears it."""
    def echo(m: str) -> None:
        click.echo(m, err=True)

    if not show:
        return None, echo, lambda: None
    from ..observe.live import LiveLine, TerminalLine

    line = TerminalLine(sys.stdout)
    return LiveLine(line.show), lambda m: line.above(m, sys.stderr), line.close


@cli.command(epilog="Every run option (--help-all) is the central's: it sends them at the "
             "handshake, and one given here that differs is replaced (with a note).")
@role_options
@click.option("--index", type=click.IntRange(1, 3), required=True,
              help="Which peripheral of the unit this is (1 to its peripherals).")
def peripheral(index: int, **kw: Any) -> None:
    """Run peripheral K of a unit: connects to the central's endpoint and takes the run's
    configuration from it at the handshake."""
    from ..roles.peripheral import run_peripheral

    setup, conf, held = _role_setup(kw, role="peripheral", index=index)
    with held:
        code = _quiet(lambda: run_peripheral(setup, index, conf))
    sys.exit(code)


def _role_setup(kw: dict[str, Any], *, role: str,
                index: int | None = None) -> tuple[Any, Any, contextlib.ExitStack]:
    """Setup and Zenoh configuration of a single role, and its CPU idle request
    (runtime/host/idle.py: a role started on another host holds it for that host; close it
    when the role ends). Exits on a configuration error; with ``--check``, exits 0 once
    everything is checked, before anything starts."""
    from ..compute.setup import make_setup
    from ..host.idle import IdlePermissionError, idle_request
    from ..host.sched import RtPermissionError, apply_choice
    from ..transport.limits import Limits
    from ..transport.zsession import make_config, pin_cpus

    check = kw.pop("check", False)
    by_hand = not kw.get("spec")  # not started by ctrlunit start: ask the central
    given = _given(kw)
    name = role if index is None else f"{role}-{index}"
    rc = make_rc(kw)
    try:
        setup = make_setup(rc.validate(roles=[name]))  # with --keys, its own credentials
    except (ConfigError, ValueError, OSError) as exc:
        _fail(str(exc), EXIT_CONFIG)
    _check_index(index, setup.placement.peripherals)  # by hand: the unit's, again below
    if check:
        click.echo(f"ctrlunit {role}: the options are valid; nothing was started.")
        sys.exit(0)
    if by_hand:
        if "unit" not in given:
            _fail(f"ctrlunit {role} needs --unit ID: the unit id the central was started "
                  "with (it prints it)", EXIT_CONFIG)
        setup = _unit_config(rc, name, given)
        rc = setup.rc
        _check_index(index, setup.placement.peripherals)
        if role == "plant" and rc.schedule.clock == "freerun":
            _fail("the unit runs --clock freerun, which has no plant", EXIT_CONFIG)
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
    try:
        conf = make_config(listen=rc.transport.listen, connect=rc.transport.connect,
                           config_file=rc.transport.zenoh_config, keys=rc.transport.keys,
                           role=name, limits=Limits.of(rc.transport))
    except (FileNotFoundError, ValueError) as exc:
        _fail(str(exc), EXIT_CONFIG)
    return setup, conf, held


def _given(kw: dict[str, Any]) -> set[str]:
    """The settings (flat names) given rather than defaulted: by flag, ``--set`` or the
    run file; one that cannot be read is :func:`make_rc`'s error to report."""
    from ..config.run_file import parse_set, read_run_file

    given = given_settings()
    with contextlib.suppress(ConfigError):
        given |= set(parse_set(kw.get("set_items") or ()))
    if kw.get("config_file"):
        with contextlib.suppress(ConfigError):
            given |= set(read_run_file(kw["config_file"]))
    return given


def _check_index(index: int | None, peripherals: int) -> None:
    """Exits if peripheral ``index`` is not one of the unit's ``peripherals``."""
    if index is not None and index > peripherals:
        _fail(f"--index = {index}: allowed 1 to {peripherals} (the unit's peripherals)"
              if peripherals else
              f"--index = {index}: the unit has no peripherals (--peripherals 0)", EXIT_CONFIG)


def _unit_config(own: Any, name: str, given: set[str]) -> Any:
    """The setup of a role started by hand, from the run's configuration the central
    hands it at the handshake (runtime/config/handed.py) with the role's own endpoints,
    keys and CPUs. Exits on a link that does not answer or a configuration that does not
    hold here."""
    from ..compute.setup import make_setup
    from ..config.handed import handed
    from ..transport.limits import Limits
    from ..transport.node import Node
    from ..transport.zsession import make_config

    t = own.transport
    try:
        conf = make_config(listen=t.listen, connect=t.connect, config_file=t.zenoh_config,
                           keys=t.keys, role=name, limits=Limits.of(t))
        with Node(conf, t.unit, name) as node:
            msg = node.ask_config(timeout=t.startup_timeout)
    except (FileNotFoundError, ValueError) as exc:
        _fail(str(exc), EXIT_CONFIG)
    except TimeoutError as exc:
        _fail(f"{exc} (is --unit the central's, and --connect its --listen endpoint?)",
              EXIT_LINK)
    try:
        rc, notes = handed(msg, own, given)
        setup = make_setup(rc)
    except (ConfigError, ValueError, OSError) as exc:
        _fail(str(exc), EXIT_CONFIG)
    for note in notes:
        click.echo(f"ctrlunit {name}: {note}", err=True)
    return setup


@cli.command(epilog="Every run option (--help-all) is the central's: it sends them at the "
             "handshake, and one given here that differs is replaced (with a note).")
@role_options
def plant(**kw: Any) -> None:
    """Run the simulated Delta as a Zenoh node: connects to the central's endpoint and
    takes the run's configuration from it at the handshake."""
    from ..roles.plant_node import run_plant

    setup, conf, held = _role_setup(kw, role="plant")
    with held:
        code = _quiet(lambda: run_plant(setup, conf))
    sys.exit(code)


@cli.command()
@run_options
@click.option("--json", "as_json", is_flag=True)
def central(as_json: bool, **kw: Any) -> None:
    """Run the central alone; plant and peripherals are started separately
    (``ctrlunit plant`` / ``ctrlunit peripheral --index K`` with ``--unit``, ``--connect``
    to this process's ``--listen`` endpoint and ``--keys``; they take the run's
    configuration from this process at the handshake)."""
    from ..compute.setup import make_setup
    from ..launch.launcher import central_only

    check = kw.pop("check", False)
    rc = make_rc(kw)
    try:
        make_setup(rc.validate(roles=["central"]))  # with --keys, its own credentials
    except (ConfigError, ValueError, OSError) as exc:
        _fail(str(exc), EXIT_CONFIG)
        return
    if not rc.transport.listen:
        _fail("central needs --listen ENDPOINT (e.g. tcp/127.0.0.1:7447)", EXIT_CONFIG)
    if check:
        click.echo("ctrlunit central: the options are valid; nothing was started.")
        sys.exit(0)
    click.echo(f"ctrlunit central: unit {rc.transport.unit} on "
               f"{', '.join(rc.transport.listen or [])}: start the other roles with --unit "
               f"{rc.transport.unit} --connect ENDPOINT", err=True)
    code, report = central_only(rc)
    from ..observe.summary import summary

    if "cycles" in report:
        if rc.run.report:
            with open(rc.run.report, "w") as fh:
                json.dump(_json_safe(report), fh, indent=2)
        click.echo(json.dumps(_json_safe(report)) if as_json else summary(report))
    else:
        _fail(report["fault"]["message"] + _kept(report), code)
    if report.get("logs_kept"):
        click.echo(f"ctrlunit: the roles' logs are kept in {report['logs_kept']}", err=True)
    sys.exit(code)


def _quiet(fn: Any) -> int:
    """Run a role; Ctrl-C ends it quietly (a role run by hand: those ``ctrlunit start``
    starts ignore it and wait for the launcher's stop order, runtime/roles/supervise.py)."""
    try:
        return fn()
    except KeyboardInterrupt:
        return 130


@cli.command("config")
@run_options
@click.option("--table", is_flag=True,
              help="Print every setting as Markdown tables instead (docs/settings.md).")
def config_cmd(check: bool, table: bool, **kw: Any) -> None:
    """Print the run's settings as a run file, each with its help: the defaults, or what
    the given profile, run file, --set and flags resolve to (ctrlunit start --config reads
    it back)."""
    from ..config.run_file import to_toml

    del check
    if table:  # the defaults as the command line resolves them, whatever else is given
        from ..config.settings_doc import settings_table

        ctx = click.get_current_context()
        flags = {p.name: p.process_value(ctx, p.get_default(ctx)) for p in ctx.command.params
                 if p.name in kw and p.expose_value}
        defaults = user_view(make_rc(flags).to_dict()) | {"unit": None}
        click.echo(settings_table(defaults), nl=False)
        return
    asked_unit = "unit" in _given(kw)
    try:
        rc = make_rc(kw).validate()
    except ConfigError as exc:
        _fail(str(exc), EXIT_CONFIG)
        return
    settings = rc.to_dict()
    if not asked_unit:  # a fresh random id per run: a file that fixed it would share it
        settings["unit"] = None
    click.echo(to_toml(settings), nl=False)

