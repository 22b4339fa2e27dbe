"""Settings beyond the everyday flags: profiles, the run file and ``--set``.

A run's settings come, each overriding the one before: the defaults (the realtime main
job), a profile (``--profile``), a run file (``--config run.toml``, with the sections of
:class:`.RunConfig`: ``[control]``, ``[schedule]``, ``[plant]``, ``[transport]``,
``[run]``, each key a field of its section), ``--set SECTION.KEY=VALUE``, and the flags
given on the command line. ``ctrlunit config`` prints them (:func:`to_toml`).
"""

from __future__ import annotations

import json
import re
import tomllib
from typing import Any

from ...kernels.small_file import read_small_text
from . import BY_FIELD, ConfigError
from .sections import SECTIONS
from .spellings import USER, not_a_setting, read_setting, user_view

PROFILES: dict[str, dict[str, Any]] = {
    "main-job": {"peripherals": 3, "pipeline": 2},
    "thesis": {"model_state": "sample", "placement": "axes", "observer": "previous"},
}
"""Settings of each profile by flat name, as a user gives them, over the defaults.
``main-job``: README's main job, ``ctrlunit start --peripherals 3 --pipeline 2``
(realtime at the period the admission holds, the model foreseen, placement auto).
``thesis``: the thesis's graph (the model at the sample, the axes placement, the observer
from the previous estimate with two Newton-Raphson iterations), as the 1994 comparison
runs it. Without ``--profile`` a run has the defaults alone."""


def _flat(section: str, key: str, where: str) -> str:
    flat = BY_FIELD.get((section, key))
    if flat is not None and (bad := not_a_setting(flat, where)) is not None:
        raise bad
    if flat is None:
        keys = sorted(name for sec, name in BY_FIELD
                      if sec == section and BY_FIELD[(sec, name)] in USER)
        if section not in SECTIONS:
            raise ConfigError(f"{where}: no section [{section}] (allowed: "
                              f"{', '.join(SECTIONS)})")
        raise ConfigError(f"{where}: [{section}] has no {key!r} (allowed: {', '.join(keys)})"
                          f"{_belongs(key)}")
    return flat


def _belongs(key: str) -> str:
    """For an error on a key in the wrong place: the section it is a setting of."""
    homes = sorted(sec for sec, name in BY_FIELD if name == key and BY_FIELD[(sec, name)] in USER)
    return f"; {key} is a key of [{homes[0]}]" if homes else ""


def read_run_file(path: str) -> dict[str, Any]:
    """The settings of a run file by flat name, each read as its flag reads it and
    checked (runtime/config/spellings.py, ``read_setting``).

    Raises
    ------
    ConfigError
        Naming the file and the section, key or line at fault."""
    text = read_small_text(path, whose=f"--config {path}", error=ConfigError)
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"--config {path}: {exc}{_quote_hint(path, str(exc))}") from None
    out: dict[str, Any] = {}
    for section, table in data.items():
        if not isinstance(table, dict):
            raise ConfigError(f"--config {path}: {section!r} must be a section "
                              f"([{section}]) holding keys{_belongs(section)}")
        for key, value in table.items():
            where = f"--config {path}: [{section}] {key}"
            flat = _flat(section, key, where)
            out[flat] = read_setting(flat, value, where)
    return out


def _quote_hint(path: str, error: str) -> str:
    """For a TOML error on a line ``key = word`` whose value is a bare word (``clock =
    lockstep``, ``period = 2ms``): the line as TOML wants it, the text in quotes."""
    at = re.search(r"at line (\d+)", error)
    try:
        with open(path, encoding="utf-8", errors="replace") as fh:
            line = fh.read().splitlines()[int(at.group(1)) - 1] if at else ""
    except (OSError, IndexError):
        return ""
    m = re.fullmatch(r"\s*([A-Za-z0-9_]+)\s*=\s*([A-Za-z0-9_.+-]*[A-Za-z_][A-Za-z0-9_.+-]*)\s*",
                     line)
    if m is None or m.group(2) in ("true", "false", "inf", "nan"):
        return ""
    return f"; text goes in quotes: {m.group(1)} = \"{m.group(2)}\""


def parse_set(items: list[str] | tuple[str, ...]) -> dict[str, Any]:
    """``--set SECTION.KEY=VALUE`` items by flat name. VALUE is read as TOML (``5``,
    ``0.5``, ``true``, ``"x"``, ``["a", "b"]``); a bare word is a string (``wait``,
    ``2ms``); then as the setting's flag reads it (``read_setting``), an error naming
    ``--set SECTION.KEY``."""
    out: dict[str, Any] = {}
    for item in items:
        name, eq, text = item.partition("=")
        section, dot, key = name.strip().partition(".")
        if not eq or not dot:
            raise ConfigError(f"--set {item!r}: expected SECTION.KEY=VALUE, e.g. "
                              "schedule.late_policy=wait")
        where = f"--set {name.strip()}"
        flat = _flat(section, key, where)
        try:
            value = tomllib.loads(f"v = {text.strip()}")["v"]
        except tomllib.TOMLDecodeError:
            value = text.strip()
        out[flat] = read_setting(flat, value, where)
    return out


def profile(name: str) -> dict[str, Any]:
    if name not in PROFILES:
        raise ConfigError(f"--profile {name!r}: allowed {', '.join(PROFILES)}")
    return dict(PROFILES[name])


def to_toml(settings: dict[str, Any]) -> str:
    """Settings by flat name as a run file: every section, every key with its help above
    it (runtime/config/settings_doc.py); unset ones as comments, since TOML has no null.
    The fields of a configuration (``RunConfig.to_dict``) are written as the user's
    settings (``period = "auto"``), the run's state left out (``user_view``)."""
    from .settings_doc import help_lines, settings_of

    settings = user_view(settings)
    lines: list[str] = []
    for section in SECTIONS:
        lines.append(f"[{section}]")
        for flat, name, _, about in settings_of(section):
            if flat not in settings:
                continue
            lines += help_lines(about)
            value = settings[flat]
            if value is None:
                lines.append(f"# {name} = VALUE  # unset: put a value in place of VALUE")
            elif isinstance(value, bool):
                lines.append(f"{name} = {'true' if value else 'false'}")
            elif isinstance(value, dict):
                inner = ", ".join(f"{json.dumps(k)} = {json.dumps(v)}" for k, v in value.items())
                lines.append(f"{name} = {{{inner}}}")
            else:
                lines.append(f"{name} = {json.dumps(value)}")
        lines.append("")
    return "\n".join(lines)
