"""``ctrlunit start`` and ``ctrlunit config`` (the single roles: runtime/cli/roles.py)."""

from __future__ import annotations

import json
import sys
from typing import Any

import click

from ..config import EXIT_CONFIG, ConfigError, RunConfig
from ..config.spellings import user_view
from .base import FilePath, _emit, _fail, _json_safe, cli, exit_line, kept_note
from .options import given_in, make_rc, run_options, said_where, where_given


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

    asked = dict(kw)  # make_rc takes the run file's and --set's options out of kw
    try:
        rc = make_rc(kw)
        rc.validate(roles=rc.started_roles)  # with --keys, every role's before any starts
    except ConfigError as exc:
        _fail(str(said_where(exc, where_given(asked))), EXIT_CONFIG)
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
        _fail(report["fault"]["message"] + kept_note(report), code)
        return
    unwritten = None
    if rc.run.report:
        try:
            with open(rc.run.report, "w") as fh:
                json.dump(_json_safe(report), fh, indent=2)
        except OSError as exc:  # the summary below still says what the run measured
            unwritten = f"--report {rc.run.report}: not written: {exc}"
    from ..observe.summary import summary

    click.echo(json.dumps(_json_safe(report)) if as_json else summary(report))
    if plot_dir:
        # a run longer than the exact window has histogram quantiles: the index then
        # shows the recording's summary, exact as the plots are
        _plot_run(rc.run.record, plot_dir, summary(report)
                  if (report.get("timing") or {}).get("exact", True) else None)
    if code:
        click.echo(exit_line(report.get("fault") or {}, code, as_json=as_json), err=True)
    elif report.get("recording_failed") or unwritten:  # what the run was to keep is not
        code = EXIT_CONFIG
        for said in (f"--record {rc.run.record}: writing {report['recording_failed']}"
                     if report.get("recording_failed") else None, unwritten):
            if said:
                click.echo(f"ctrlunit: error: {said}", err=True)
    if report.get("logs_kept"):
        click.echo(f"ctrlunit: the roles' logs are kept in {report['logs_kept']}", err=True)
    sys.exit(code)


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
        period = (f"auto (the shortest that the admission's trials hold, from {period} up, "
                  "or down where it holds)"
                  if rc.schedule.clock == "realtime" and rc.schedule.admission
                  else f"{period} (auto)")
    intervals = f"{setup.cycles} intervals"
    if period.startswith("auto") and rc.run.cycles is None:  # a time: they follow the period
        intervals += (f" at {rc.schedule.period * 1e3:g} ms (more at a shorter period, "
                      "fewer at a longer one)")
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
    asked_unit = "unit" in given_in(kw)
    asked = dict(kw)  # make_rc takes the run file's and --set's options out of kw
    try:
        rc = make_rc(kw).validate()
    except ConfigError as exc:
        _fail(str(said_where(exc, where_given(asked))), EXIT_CONFIG)
        return
    settings = rc.to_dict()
    if not asked_unit:  # a fresh random id per run: a file that fixed it would share it
        settings["unit"] = None
    click.echo(to_toml(settings), nl=False)

