"""The single roles, started by hand or by ``ctrlunit start``: ``central``, ``plant``
and ``peripheral``. A role started by hand takes the run's configuration from the
central at its handshake (runtime/config/handed.py)."""

from __future__ import annotations

import contextlib
import json
import sys
from typing import Any

import click

from ..config import EXIT_CONFIG, EXIT_LINK, ConfigError
from .base import _fail, _json_safe, cli, kept_note
from .options import given_in, make_rc, role_options, run_options


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
    given = given_in(kw)
    name = role if index is None else f"{role}-{index}"
    rc = make_rc(kw)
    try:
        setup = make_setup(rc.validate(roles=[name]))  # with --keys, its own credentials
    except (ConfigError, ValueError, OSError) as exc:
        _fail(str(exc), EXIT_CONFIG)
    _check_index(index, setup.placement.peripherals)  # by hand: the unit's, again below
    if by_hand:
        if "unit" not in given:
            _fail(f"ctrlunit {role} needs --unit ID: the unit id the central was started "
                  "with (it prints it)", EXIT_CONFIG)
        _check_control_link(rc, "connect")
    if check:
        click.echo(f"ctrlunit {role}: the options are valid; nothing was started.")
        sys.exit(0)
    if by_hand:
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
                           role=name, limits=Limits.of(rc.transport),
                           control=not rc.transport.insecure)
    except (FileNotFoundError, ValueError) as exc:
        _fail(str(exc), EXIT_CONFIG)
    return setup, conf, held


def _check_control_link(rc: Any, way: str) -> None:
    """Exits if a role started by hand could not reach the unit's control path over its
    ``way`` (``listen``, ``connect``) links (runtime/transport/security.py,
    ``control_link_error``)."""
    from ..transport.security import control_link_error

    t = rc.transport
    try:
        ends = [ln["endpoint"] for ln in rc.links() if ln["way"] == way]
    except ValueError as exc:  # validate said so already
        _fail(str(exc), EXIT_CONFIG)
        return
    if (why := control_link_error(ends, way=way, keys=t.keys, insecure=t.insecure)):
        _fail(why, EXIT_CONFIG)


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
                           keys=t.keys, role=name, limits=Limits.of(t),
                           control=not t.insecure)
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
    from ..launch.run_parts import listen_ports
    from ..transport.endpoints import is_socket

    check = kw.pop("check", False)
    rc = make_rc(kw)
    try:
        make_setup(rc.validate(roles=["central"]))  # with --keys, its own credentials
    except (ConfigError, ValueError, OSError) as exc:
        _fail(str(exc), EXIT_CONFIG)
        return
    if not rc.transport.listen:
        _fail("central needs --listen ENDPOINT (e.g. unixsock-stream/PATH; with --keys "
              "tcp/127.0.0.1:7447)", EXIT_CONFIG)
    _check_control_link(rc, "listen")
    if check:
        click.echo("ctrlunit central: the options are valid; nothing was started.")
        sys.exit(0)
    rc = listen_ports(rc)  # a port 0 chosen now: the line below names where it listens
    t = rc.transport
    roles_at = next((e for e in t.listen or [] if t.keys or is_socket(e)),
                    (t.listen or ["ENDPOINT"])[0])
    click.echo(f"ctrlunit central: unit {t.unit} on {', '.join(t.listen or [])}: start the "
               f"other roles with --unit {t.unit} --connect {roles_at}", err=True)
    code, report = central_only(rc)
    from ..observe.summary import summary

    if "cycles" in report:
        if rc.run.report:
            with open(rc.run.report, "w") as fh:
                json.dump(_json_safe(report), fh, indent=2)
        click.echo(json.dumps(_json_safe(report)) if as_json else summary(report))
    else:
        _fail(report["fault"]["message"] + kept_note(report), code)
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
