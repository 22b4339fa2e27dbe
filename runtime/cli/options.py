"""The options of ``ctrlunit start`` and of the single roles, and the run's
configuration they resolve to: the defaults, then ``--profile``, the run file
(``--config``), ``--set`` and the flags given (runtime/config/run_file.py)."""

from __future__ import annotations

import contextlib
import typing
from typing import Any

import click

from ..config import FLAT, ConfigError, RunConfig
from ..config.handed import FILE_SETTINGS, ROLE_OWN
from ..config.run_file import PROFILES
from ..config.sections import SECTIONS
from ..config.setting import About, integers, user_allowed
from ..config.settings_doc import settings_of
from ..config.spellings import DERIVED, read_setting, to_fields
from .base import FilePath


def _read(_ctx: Any, param: click.Parameter, value: Any) -> Any:
    """A flag's value read as ``--set`` and the run file read the setting's
    (runtime/config/spellings.py): ``2ms``, ``0.002``, ``auto`` where the setting takes it."""
    flat = "late" if param.name == "late_items" else str(param.name)
    # a ConfigError: one line and exit 1, as every value out of its range
    return read_setting(flat, value, f"--{param.opts[0].lstrip('-')}", ranged=False)


def _ranged(base: type[click.IntRange] | type[click.FloatRange], a: About) -> click.ParamType:
    """Click's range type (its range shown in ``--help``) whose refusal is the
    configuration's: ``--peripherals = 9: allowed 0, 1, 2 or 3``, exit 1, as ``--set`` and the
    run file say it, not click's usage error (exit 2)."""
    assert a.bounds is not None

    class Ranged(base):  # type: ignore[valid-type,misc]
        def convert(self, value: Any, param: click.Parameter | None,
                    ctx: click.Context | None) -> Any:
            try:
                return super().convert(value, param, ctx)
            except click.BadParameter:
                opt = param.opts[0] if isinstance(param, click.Option) else "value"
                allowed = user_allowed(a)
                if issubclass(base, click.IntRange):  # 1e3: in the range, and no integer
                    allowed = integers(allowed)
                raise ConfigError(f"{opt} = {value}: allowed {allowed}") from None

    return Ranged(a.bounds[0], a.bounds[1])


def run_options(fn: Any) -> Any:
    """Options shared by start and the single roles (README, ctrlunit start): one per
    setting that has a flag (runtime/config/sections.py, in :data:`CLI_SECTIONS`' order),
    then the run file's; those not everyday are hidden from ``--help`` (``--help-all``
    shows them)."""
    return _with_options(fn, role=False)


def role_options(fn: Any) -> Any:
    """:func:`run_options` for ``ctrlunit plant`` and ``ctrlunit peripheral``, which take
    the run's configuration from the central at the handshake (runtime/config/handed.py):
    ``--help`` shows only the settings such a role keeps of its own (``ROLE_OWN``) and
    the files it reads on its host (``FILE_SETTINGS``)."""
    return _with_options(fn, role=True)


def _with_options(fn: Any, *, role: bool) -> Any:
    opts = [_option(flat, a, shown=(flat in ROLE_OWN or flat in FILE_SETTINGS) if role
                    else None)
            for section in CLI_SECTIONS for flat, a in _flags_of(section)]
    for o in reversed(opts + _run_file(role=role)):
        fn = o(fn)
    return fn


CLI_SECTIONS = ("schedule", "control", "run", "transport", "plant")
"""The order in which ``--help`` lists the sections' flags: how the work is spread and
timed, what it computes, what the run writes, the links, the plant."""


def _flags_of(section: str) -> list[tuple[str, About]]:
    """The settings of a section that have a flag, by flat name, in declaration order."""
    return [(flat, a) for flat, _, _, a in settings_of(section) if a.flag is not None]


def _option(flat: str, a: About, *, shown: bool | None = None) -> Any:
    """The click option of one setting, from its declaration; ``shown``: whether
    ``--help`` shows it (None: if the flag is everyday)."""
    fl = a.flag
    assert fl is not None
    name = "--" + (fl.name or flat.replace("_", "-"))
    field_default = _DEFAULTS[flat]
    default = fl.default if fl.default is not None else field_default
    everyday = fl.everyday if shown is None else shown
    about: dict[str, Any] = dict(help=a.help, hidden=fl.hidden or not everyday,
                                 metavar=fl.metavar)
    if fl.kind == "flag":
        return click.option(name, flat, is_flag=True, **about)
    if fl.kind == "switch":
        return click.option(f"{name}/--no-{name[2:]}", flat, default=default,
                            show_default=True, **about)
    if fl.kind in ("many", "late"):
        return click.option(name, "late_items" if fl.kind == "late" else flat,
                            multiple=True, **about)
    callback = _read if fl.kind in ("duration", "period", "priority") else None
    if fl.bare is not None:  # --ros2 alone, or --ros2 5
        bare = fl.bare() if callable(fl.bare) else fl.bare
        return click.option(name, flat, type=_click_type(flat, a), default=default,
                            is_flag=False, flag_value=bare, callback=callback, **about)
    return click.option(name, flat, type=_click_type(flat, a), default=default,
                        show_default=default is not None, callback=callback, **about)


def _click_type(flat: str, a: About) -> Any:
    """The click type of a value setting: its choices, its bounds, a path, or its type."""
    fl = a.flag
    assert fl is not None
    if fl.kind == "file":
        return FilePath(dir_okay=False)
    if fl.kind == "dir":
        return FilePath(file_okay=False)
    if fl.kind != "value":
        return None  # read by the callback
    if a.choices is not None:
        return click.Choice(list(a.choices))
    base = _BASE_TYPES[flat]
    if a.bounds is not None and base is int:
        return _ranged(click.IntRange, a)
    if a.bounds is not None and base is float:
        return _ranged(click.FloatRange, a)
    return base


def _base_type(tp: Any) -> Any:
    """``int`` of ``int | None``, and so on; str for anything else."""
    args = [t for t in typing.get_args(tp) if t is not type(None)] or [tp]
    return args[0] if args[0] in (int, float, bool) else str


_DEFAULTS = {flat: default for section in SECTIONS
             for flat, _, default, _ in settings_of(section)}
_BASE_TYPES = {flat: _base_type(typing.get_type_hints(SECTIONS[sec])[name])
               for flat, (sec, name) in FLAT.items()}


def _run_file(*, role: bool = False) -> list[Any]:
    """The run file, profiles, ``--check``, and the launcher's own options (``role``: a
    role started by hand, whose configuration is the central's: the layers hidden)."""
    return [
        click.option("--check", is_flag=True,
                     help="Check the options and files (task, placement, parameters, Zenoh "
                     "configuration) and exit: nothing is started."),
        click.option("--spec", type=FilePath(dir_okay=False), default=None, hidden=True,
                     help="Run configuration written by ctrlunit start (internal)."),
        click.option("--profile", type=click.Choice(list(PROFILES)), default=None,
                     hidden=role,
                     help="Settings over the defaults: main-job is README's main job "
                     "(--peripherals 3 --pipeline 2), thesis the thesis's graph (model "
                     "at the sample, axes placement, observer previous)."),
        click.option("--config", "config_file", type=FilePath(dir_okay=False),
                     default=None, hidden=role, help="A run file (TOML, the sections "
                     "ctrlunit config prints) over the profile."),
        click.option("--set", "set_items", multiple=True, metavar="SECTION.KEY=VALUE",
                     hidden=role, help="One setting over the run file (repeatable), e.g. "
                     "schedule.late_policy=wait."),
        click.option("--help-all", is_flag=True, expose_value=False, is_eager=True,
                     callback=_help_all, help="Show every option, the tuning ones too."),

    ]

NEVER_SHOWN = frozenset({"status_file"})
"""Options even ``--help-all`` hides: what the launcher passes to the roles it starts."""


def _help_all(ctx: click.Context, _param: click.Parameter, value: bool) -> None:
    """``--help-all``: the help with every option shown."""
    if not value or ctx.resilient_parsing:
        return
    for p in ctx.command.params:
        if isinstance(p, click.Option) and p.name not in NEVER_SHOWN:
            p.hidden = False
    click.echo(ctx.get_help())
    ctx.exit()


PARAM_SETTINGS = {"late_items": "late"}
"""Flags whose parameter is not named as their setting."""


def explicit_params() -> set[str]:
    """The parameters given on the command line (or by environment), not defaulted."""
    ctx = click.get_current_context(silent=True)
    if ctx is None:
        return set()
    given = (click.core.ParameterSource.COMMANDLINE, click.core.ParameterSource.ENVIRONMENT)
    return {n for n in ctx.params if ctx.get_parameter_source(n) in given}


def _given_flags() -> set[str]:
    """The settings (flat names) whose flags were given on the command line."""
    return {PARAM_SETTINGS.get(p, p) for p in explicit_params()} & set(FLAT)


def given_settings() -> set[str]:
    """The fields (flat names) that flags given on the command line set."""
    return {f for s in _given_flags() for f in DERIVED.get(s, (s,))}


def make_rc(kw: dict[str, Any]) -> RunConfig:
    """The run's configuration: the defaults, then ``--profile``, the run file
    (``--config``), ``--set``, and the flags given (runtime/config/run_file.py), each a
    user's setting read the same way (runtime/config/spellings.py); the fields each sets,
    the run's state among them (``period = "auto"``: ``period_auto``), follow from the
    settings once merged."""
    from ..config.run_file import parse_set, profile, read_run_file

    name = kw.pop("profile", None)
    layered: dict[str, Any] = profile(name) if name else {}
    config_file = kw.pop("config_file", None)
    if config_file:
        layered = _over(layered, read_run_file(config_file))
    layered = _over(layered, parse_set(kw.pop("set_items", ()) or ()))
    options = _flag_options(kw)
    if isinstance(options, RunConfig):  # a role the launcher started: the run's spec
        return options
    settings = _over(options | layered, {f: options[f] for f in _given_flags() if f in options})
    return RunConfig.of(**to_fields(settings))


RUN_LENGTH = ("cycles", "duration")
"""The run's length, given as either setting: one layer's replaces a lower layer's."""


def _over(lower: dict[str, Any], upper: dict[str, Any]) -> dict[str, Any]:
    """``upper``'s settings over ``lower``'s; a run length in ``upper`` (``--cycles`` or
    ``--duration``) replaces ``lower``'s, whichever it was (both in one layer are
    refused: ``RunConfig.validate``)."""
    if any(upper.get(k) is not None for k in RUN_LENGTH):
        lower = {k: v for k, v in lower.items() if k not in RUN_LENGTH}
    return lower | upper


def _flag_options(kw: dict[str, Any]) -> dict[str, Any] | RunConfig:
    """The flags as settings by flat name (every flag, defaulted ones too, each read by
    :func:`_read` or its click type); the run's spec instead for a role the launcher
    started."""
    from ..compute.setup import load_spec

    spec = kw.pop("spec", None)
    if spec:
        # the central's endpoints are its own, not the children's
        return load_spec(spec).replace(listen=list(kw.get("listen") or ()) or None,
                                       connect=list(kw.get("connect") or ()) or None,
                                       pin=kw.get("pin") or None)
    kw["late"] = kw.pop("late_items", ())
    return {k: read_setting(k, v, f"--{_FLAG_NAMES[k]}") if k in _READ_AFTER else v
            for k, v in kw.items() if k in FLAT}


_FLAG_NAMES = {flat: a.flag.name or flat.replace("_", "-") for section in SECTIONS
               for flat, _, _, a in settings_of(section) if a.flag is not None}
_READ_AFTER = {flat for section in SECTIONS for flat, _, _, a in settings_of(section)
               if a.kind in ("many", "late", "placement")}
"""Flags read with the configuration (an error exits 1, as ``--set``'s), not by click."""


def given_in(kw: dict[str, Any]) -> set[str]:
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


def where_given(kw: dict[str, Any]) -> dict[str, str]:
    """Where each setting that no flag gave came from (flat name -> ``--set``, ``--config
    FILE`` or ``--profile NAME``, the last layer that set it), from the options as
    given (:func:`make_rc` takes those out of its ``kw``); read on an error only."""
    from ..config.run_file import parse_set, profile, read_run_file

    out: dict[str, str] = {}
    with contextlib.suppress(ConfigError):  # make_rc's error to report
        if kw.get("profile"):
            out |= dict.fromkeys(profile(kw["profile"]), f"--profile {kw['profile']}")
        if kw.get("config_file"):
            out |= dict.fromkeys(read_run_file(kw["config_file"]),
                                 f"--config {kw['config_file']}")
        out |= dict.fromkeys(parse_set(kw.get("set_items") or ()), "--set")
    return {f: o for f, o in out.items() if f not in _given_flags()}


def said_where(exc: ConfigError, where: dict[str, str]) -> ConfigError:
    """``exc``, told where its setting came from when the message begins with the flag of
    a setting that a run file, ``--set`` or a profile gave (``--balance live: ...`` for
    ``schedule.balance`` in a run file: the user wrote no ``--balance``)."""
    text = str(exc)
    for flat, origin in where.items():
        flag = f"--{_FLAG_NAMES.get(flat, flat.replace('_', '-'))}"
        if text.startswith((f"{flag} ", f"{flag}:")):
            section, name = FLAT[flat]
            return ConfigError(f"{text} ({flag} given as {section}.{name} by {origin})")
    return exc


__all__ = ["CLI_SECTIONS", "given_in", "given_settings", "make_rc", "role_options",
           "run_options", "said_where", "where_given"]
