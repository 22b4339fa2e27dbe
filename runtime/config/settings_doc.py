"""Every setting as a person reads it, from its declaration (runtime/config/setting.py):
the help above each key of the run file ``ctrlunit config`` prints, and the table of
docs/settings.md (``ctrlunit config --table``)."""

from __future__ import annotations

import json
import textwrap
import typing
from dataclasses import MISSING
from typing import Any

from . import BY_FIELD
from .sections import SECTIONS
from .setting import About, abouts, user_allowed
from .value_types import type_name


def settings_of(section: str) -> list[tuple[str, str, Any, About]]:
    """``(flat name, key, default, about)`` of each setting of a section, in order; the
    default None for one made afresh per run (the unit id)."""
    return [(BY_FIELD[(section, f.name)], f.name,
             None if f.default is MISSING else f.default, a)
            for f, a in abouts(SECTIONS[section])]


def help_lines(a: About, *, width: int = 88) -> list[str]:
    """A setting's help as TOML comment lines."""
    return textwrap.wrap(a.help, width=width - 2, initial_indent="# ",
                         subsequent_indent="# ")


def _cell(text: str) -> str:
    return text.replace("|", "\\|")


def _default(value: Any) -> str:
    return "" if value is None else f"`{json.dumps(value)}`"


def _flag(flat: str, a: About) -> str:
    if a.flag is None or a.flag.hidden:
        return ""
    name = "--" + (a.flag.name or flat.replace("_", "-"))
    if a.flag.kind == "switch":
        return f"`{name}/--no-{name[2:]}`"
    return f"`{name} {a.flag.metavar}`" if a.flag.metavar else f"`{name}`"


def settings_table(defaults: dict[str, Any] | None = None) -> str:
    """Markdown: one table per section, a row per setting a user gives (key, flag,
    default, allowed, help), then the run's own state the configuration carries beside
    them. ``defaults``: the value of each setting by flat name as the command line
    resolves it when nothing is given (``ctrlunit config``'s, as the user's settings:
    ``period = "auto"``); else each field's."""
    out: list[str] = []
    state: list[str] = []
    for section in SECTIONS:
        hints = typing.get_type_hints(SECTIONS[section])
        out += [f"### [{section}]", "", "| key | flag | default | allowed | what it does |",
                "|---|---|---|---|---|"]
        for flat, key, default, a in settings_of(section):
            if a.internal:
                state.append(f"- `{section}.{key}`: {a.help}")
                continue
            allowed = user_allowed(a) if (a.choices or a.bounds or a.allowed) \
                else type_name(hints[key])
            shown = defaults.get(flat) if defaults is not None else default
            out.append(f"| `{key}` | {_flag(flat, a)} | {_default(shown)} | "
                       f"{_cell(allowed)} | {_cell(a.help)} |")
        out.append("")
    return "\n".join(out + ["### The run's own state", "",
                            "Fields of the configuration no user gives: the run's spec, the "
                            "configuration handed to a role and a recording carry them; a "
                            "run file or `--set` that names one is refused.", "", *state, ""])


__all__ = ["help_lines", "settings_of", "settings_table"]
