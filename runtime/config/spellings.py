"""A user's settings, read the same way wherever they are given: a flag, ``--set`` or a run
file (runtime/config/run_file.py), and the configuration's fields each one sets.

A setting's value is read by its declared kind (runtime/config/setting.py, ``KINDS``): a
duration takes ``2ms``, ``0.002`` or ``"0.002s"`` in each of the three; a period takes
``auto`` too; the placement ``auto``, ``axes`` or a file. :func:`read_setting` reads and
checks one (the error names the setting as the user gave it: ``--set
schedule.late_policy``, ``--config run.toml: [schedule] late_policy``, ``--late-policy``);
:func:`fields_of` turns it into the fields of :class:`~.RunConfig` it sets
(``period = "auto"`` is the admission ladder's start and ``period_auto``);
:func:`user_view` is the way back, what ``ctrlunit config`` prints.

The fields declared ``internal`` (``period_auto``, ``placement_auto``, ``central_blocks``,
...) are the run's own state: derived here or by the launcher, the admission and the
warm-up, never given by a user.
"""

from __future__ import annotations

import typing
from typing import Any

from ..host.sched import MAX_PRIORITY
from . import _ABOUT, _FLAT_TYPES, FLAT, ConfigError, parse_duration
from .choices import LATE_POLICIES
from .sections import ScheduleConfig
from .setting import About, allowed_text, integers, out_of_range, user_allowed
from .value_types import has_type, type_name

USER = tuple(flat for flat in FLAT if not _ABOUT[flat].internal)
"""The settings a user gives, by flat name, in the sections' order."""

STATE = tuple(flat for flat in FLAT if _ABOUT[flat].internal)
"""The run's own state, by flat name: fields of the configuration no user gives."""

DERIVED = {"period": ("period", "period_auto"), "placement": ("placement", "placement_auto")}
"""Settings that set a field of the run's state beside their own (:func:`fields_of`)."""

STATE_FROM = {"period_auto": "period", "placement_auto": "placement",
              "central_blocks": "placement"}
"""The setting from which a field of the run's state follows, for an error that names it."""

PERIOD_AUTO_START_S: float = ScheduleConfig.period
"""``period = "auto"``: the period the admission starts from (the field's default), which
it then leaves for a longer or a shorter period of its ladder (runtime/launch/admission.py,
``LADDER_S``)."""

PLACEMENT_WORDS = ("auto", "axes")
"""The placements named by a word; any other text is a placement file."""


def _bad(where: str, value: Any, allowed: str) -> ConfigError:
    shown = repr(value) if len(repr(value)) <= 60 else repr(value)[:57] + "..."
    return ConfigError(f"{where} = {shown}: allowed {allowed}")


def _unitless(where: str, a: About, given: Any, seconds: Any) -> ConfigError | None:
    """A period given as a bare number above its range (``period = 2``, ``--period 2``):
    the refusal says it was read as seconds and how to write milliseconds."""
    text = str(given).strip()
    try:
        float(text)
    except ValueError:
        return None  # it had a unit (or is a word)
    if isinstance(given, bool) or a.bounds is None or not isinstance(seconds, float) \
            or seconds <= a.bounds[1]:
        return None
    return ConfigError(f"{where} = {text}: allowed {user_allowed(a)}; a number without a "
                       f"unit is seconds: {text} was read as {seconds:g} s (milliseconds: "
                       f'"{text}ms")')


def _base(flat: str) -> Any:
    """``int`` of ``int | None``, and so on."""
    tp = _FLAT_TYPES[flat]
    args = [t for t in typing.get_args(tp) if t is not type(None)]
    return args[0] if len(args) == 1 else tp


def _read_duration(flat: str, a: About, value: Any, where: str) -> float | None:
    if value is None:
        return None
    zero = a.bounds is not None and a.bounds[0] == 0.0
    try:
        if isinstance(value, bool) or not isinstance(value, int | float | str):
            raise ConfigError("not a duration")
        return parse_duration(value, field_name=where, zero=zero)
    except ConfigError:
        raise _bad(where, value, user_allowed(a)) from None


def _read_late(value: Any, where: str) -> dict[str, str]:
    """``late``: ``{BLOCK = "POLICY"}``, or ``BLOCK=POLICY`` items (the flag's spelling),
    one or a list."""
    if isinstance(value, dict):
        return {str(k): str(v) for k, v in value.items()}
    items = [value] if isinstance(value, str) else value
    if not isinstance(items, list | tuple) or not all(isinstance(i, str) for i in items):
        raise _bad(where, value, 'BLOCK=POLICY items or a table {BLOCK = "POLICY"}')
    out: dict[str, str] = {}
    for item in items:
        block, _, pol = item.partition("=")
        if not block.strip() or not pol.strip():
            raise ConfigError(f"{where} {item!r}: expected BLOCK=POLICY (POLICY one of "
                              f"{', '.join(LATE_POLICIES)})")
        out[block.strip()] = pol.strip()
    for block, pol in out.items():
        if pol not in LATE_POLICIES:
            raise ConfigError(f"{where} {block}={pol}: the policy must be one of "
                              f"{', '.join(LATE_POLICIES)}")
    return out


def _read_kind(flat: str, a: About, value: Any, where: str) -> Any:
    """A value of a setting whose kind is not its type's plain one, as its flag reads it."""
    kind = a.kind
    if kind in ("duration", "period"):
        if kind == "period" and isinstance(value, str) and value.strip() == "auto":
            return "auto"
        return _read_duration(flat, a, value, where)
    if kind == "priority":
        text = value.strip() if isinstance(value, str) else value
        if text == "auto":
            return "auto"
        if isinstance(text, str) and text.lstrip("-").isdigit():
            text = int(text)
        if isinstance(text, bool) or not isinstance(text, int) or not (
                0 <= text <= MAX_PRIORITY):
            raise _bad(where, text, allowed_text(a))
        return text
    if kind == "placement":
        if value is None or (isinstance(value, str) and value.strip()):
            return value.strip() if isinstance(value, str) else value
        raise _bad(where, value, user_allowed(a))
    if kind == "late":
        return _read_late(value, where)
    if kind == "many" and isinstance(value, str):
        return [value]
    if kind == "many" and isinstance(value, tuple):
        return list(value) or None
    return value


def read_setting(flat: str, value: Any, where: str, *, ranged: bool = True) -> Any:
    """A user's value of setting ``flat`` in any spelling it accepts -> the value as
    :func:`fields_of` takes it, checked against the setting's type, choices and bounds.

    Parameters
    ----------
    flat : the setting's flat name (one of :data:`USER`, or a flag's internal one).
    value : as given: the flag's text, ``--set``'s TOML value or bare word, the run
        file's TOML value.
    where : how the user gave it, for the error (``--set schedule.period``).
    ranged : check the choices and bounds too (a flag's value: ``RunConfig.validate``
        does, with the same message).

    Raises
    ------
    ConfigError
        ``WHERE = VALUE: allowed ...``, the values the setting takes.
    """
    a = _ABOUT[flat]
    base = _base(flat)
    given = value
    if a.kind != "value" and a.kind not in ("switch", "flag", "file", "dir"):
        value = _read_kind(flat, a, value, where)
        if a.kind == "period" and (why := _unitless(where, a, given, value)):
            raise why
    elif base is str and isinstance(value, int | float) and not isinstance(value, bool):
        value = str(value)  # --set run.foxglove=8765 as --foxglove 8765
    elif base is float and isinstance(value, str):
        try:
            value = float(value)
        except ValueError:
            raise _bad(where, value, allowed_text(a) if a.bounds or a.allowed
                       else type_name(_FLAT_TYPES[flat])) from None
    elif base is int and isinstance(value, str) and value.strip().lstrip("-").isdigit():
        value = int(value)
    if a.kind in ("period", "priority", "placement") and isinstance(value, str):
        return value  # auto, or what validate checks (a priority, a file)
    tp = _FLAT_TYPES[flat]
    if not has_type(value, tp) or (ranged and out_of_range(a, value)):
        allowed = user_allowed(a) if a.choices or a.bounds or a.allowed else type_name(tp)
        if base is int:
            allowed = integers(allowed)
        shown = given if a.kind in ("duration", "period") or not isinstance(
            value, int | float) else value  # a duration as typed: '30s', not 30
        raise _bad(where, shown, allowed)
    return float(value) if base is float and value is not None else value


def fields_of(flat: str, value: Any) -> dict[str, Any]:
    """The fields of the configuration by flat name that a setting read by
    :func:`read_setting` sets: itself, and for :data:`DERIVED` the state that follows
    (``period = "auto"``: the ladder's start, ``period_auto``; ``placement = "axes"``: no
    file, ``placement_auto`` false). The unit id None is a fresh one per run."""
    if flat == "period":
        auto = value == "auto"
        return {"period": PERIOD_AUTO_START_S if auto else value, "period_auto": auto}
    if flat == "placement":
        word = value if value in PLACEMENT_WORDS else None
        return {"placement": None if word or value is None else value,
                "placement_auto": word == "auto"}
    if flat == "unit" and value is None:
        return {}
    return {flat: value}


def to_fields(settings: dict[str, Any]) -> dict[str, Any]:
    """The fields of the configuration by flat name that the user's ``settings`` (by
    flat name, each as :func:`read_setting` returns it) set: ``RunConfig.of(**...)``."""
    out: dict[str, Any] = {}
    for flat, value in settings.items():
        out |= fields_of(flat, value)
    return out


def user_view(options: dict[str, Any]) -> dict[str, Any]:
    """A configuration's fields by flat name (``RunConfig.to_dict``) as the user's
    settings: ``period`` ``"auto"`` where the admission chooses it, ``placement``
    ``"auto"``, ``"axes"`` or the file; the run's state left out."""
    out = {flat: options[flat] for flat in USER if flat in options}
    if options.get("period_auto"):
        out["period"] = "auto"
    if "placement" in out and out["placement"] is None:
        out["placement"] = "auto" if options.get("placement_auto") else "axes"
    return out


def not_a_setting(flat: str, where: str) -> ConfigError | None:
    """The error for the run's state given as a setting, naming the setting it follows."""
    if flat in USER:
        return None
    source = STATE_FROM.get(flat)
    return ConfigError(f"{where}: {flat} is the run's own state, not a setting"
                       + (f"; give {source} (e.g. {source} = \"auto\")" if source else ""))


__all__ = ["DERIVED", "PERIOD_AUTO_START_S", "PLACEMENT_WORDS", "STATE", "STATE_FROM", "USER",
           "fields_of", "not_a_setting", "read_setting", "to_fields", "user_view"]
