"""The options of ``ctrlunit start`` and of the single roles, and the run's
configuration they resolve to: the defaults, then ``--profile``, the run file
(``--config``), ``--set`` and the flags given (runtime/config/run_file.py)."""

from __future__ import annotations

from typing import Any

import click

from ...plant.simulator import MAX_SUBSTEP_BELT_S, MAX_SUBSTEP_S
from ...topology.graph import MODEL_STATES
from ...topology.pipeline import HOLD_RULES
from ..config import FLAT, LATE_POLICIES, MISSED_COMMANDS, ConfigError, RunConfig, parse_duration
from ..host.idle import IDLE_CHOICES
from .base import _rt_priority


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
    """Options shared by start and the single roles (README, ctrlunit start); those not
    in :data:`EVERYDAY` are hidden from ``--help`` (``--help-all`` shows them)."""
    opts = [o for group in (_what_runs, _outputs, _computation, _links, _late_data, _host,
                            _plant, _run_file) for o in group()]
    for o in reversed(opts):
        fn = o(fn)
    for param in getattr(fn, "__click_params__", []):
        if param.name not in EVERYDAY:
            param.hidden = True
    return fn


def _what_runs() -> list[Any]:
    """What the unit is: its processes, pipeline, clock and period, the task and the law."""
    return [
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
    ]


def _outputs() -> list[Any]:
    """What a run writes and shows, and under which unit id."""
    return [
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
    ]


def _computation() -> list[Any]:
    """How the unit computes: cost model, placement, parameters, observer, model state, gains."""
    return [
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
    ]


def _links() -> list[Any]:
    """The links between the roles and when a silent one is a fault."""
    return [
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
    ]


def _late_data() -> list[Any]:
    """Late data, missed commands, overload, the tracking limit and the pipeline's rules."""
    return [
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
    ]


def _host() -> list[Any]:
    """The host's CPUs and scheduling."""
    return [
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
    ]


def _plant() -> list[Any]:
    """The simulated robot."""
    return [
        click.option("--plant-substeps", type=click.IntRange(1, 1000), default=None,
                     help="RK4 sub-steps of the plant per period; default: the fewest of "
                     f"at most {MAX_SUBSTEP_S * 1e3:g} ms ({MAX_SUBSTEP_BELT_S * 1e3:g} ms "
                     "with --belt)."),
        click.option("--plant-lag", default="0s", callback=_duration_or_zero,
                     help="Actuator time constant (Eq. IV.6)."),
        click.option("--plant-friction", type=click.FloatRange(0.0, 100.0), default=0.0,
                     show_default=True, help="Viscous friction on each joint (N m s/rad)."),
        click.option("--belt", is_flag=True, help="Simulate the elastic belt (§ V.6.3)."),
    ]


def _run_file() -> list[Any]:
    """The run file, profiles, and the launcher's own options."""
    return [
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


def given_settings() -> set[str]:
    """The settings (flat names) that flags given on the command line set."""
    return {f for p in explicit_params() for f in PARAM_FLATS.get(p, (p,)) if f in FLAT}


def make_rc(kw: dict[str, Any]) -> RunConfig:
    """The run's configuration: the defaults, then ``--profile``, the run file
    (``--config``), ``--set``, and the flags given (runtime/config/run_file.py)."""
    from ..config.run_file import parse_set, profile, read_run_file

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
    from ..compute.setup import load_spec

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
        from ..launch.admission import LADDER_S

        kw["period"], kw["period_auto"] = LADDER_S[0], True
    options = {k: v for k, v in kw.items() if k in FLAT}
    options.update(plant_lag=kw.get("plant_lag", 0.0), listen=listen, connect=connect)
    if unit:
        options["unit"] = unit
    return options


__all__ = ["EVERYDAY", "make_rc", "run_options"]
