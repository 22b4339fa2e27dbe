"""README's table of ``ctrlunit start``'s options and the command agree: every option the
command has is documented in README's section on it (the launcher's internal ones
aside), every option the table names exists, and each default the table states is the
command's own. Change a default or add an option without README and this fails."""

from __future__ import annotations

import re
from pathlib import Path

import click
import pytest
from ctrlunit.runtime.cli import cli
from ctrlunit.runtime.config import RunConfig

README = Path(__file__).resolve().parent.parent / "README.md"
INTERNAL = {"spec", "status_file", "progress"}
"""Options the launcher passes to the roles it starts, or the terminal decides."""
WORDS = {"on": True, "off": False, "random": None}
"""How the table writes a default that is not the value itself."""
COMPUTED = {"--bandwidth": lambda: RunConfig.of().bandwidth}
"""Options whose default the configuration computes (the flag's own is None): the table
states the value computed for the defaults of the other options."""


def start_section() -> str:
    text = README.read_text()
    start = text.index("### `ctrlunit start`")
    return text[start:text.index("\n### ", start + 1)]


def table() -> list[tuple[list[list[str]], list[list[str]]]]:
    """Each row of the table: its options and its stated defaults, in ``;``-separated
    groups of ``,``-separated entries."""
    rows = []
    for line in start_section().splitlines():
        if not line.startswith("| `"):
            continue
        cells = [c.strip() for c in line.replace("\\|", "¦").strip("|").split(" | ")]
        groups = [re.findall(r"--[a-z][a-z0-9-]*(?:/--[a-z0-9-]+)?", g)
                  for g in cells[0].split(";")]
        defaults = [[d.strip() for d in g.split(",")] for g in cells[1].split(";")]
        rows.append((groups, defaults))
    return rows


def options() -> dict[str, click.Option]:
    """``ctrlunit start``'s options by each of their flags."""
    cmd = cli.commands["start"]
    return {flag: p for p in cmd.params if isinstance(p, click.Option)
            for flag in (*p.opts, *p.secondary_opts)}


def test_every_option_of_start_is_in_readme():
    section = start_section()
    missing = sorted({p.opts[0] for p in options().values() if p.name not in INTERNAL
                      and not any(f"`{o}" in section for o in p.opts)})
    assert not missing, f"not in README's section on ctrlunit start: {missing}"


def test_every_option_readme_names_exists():
    known = options()
    named = {o.split("/")[0] for groups, _ in table() for g in groups for o in g}
    assert named and not sorted(named - set(known))


def stated(cell: str) -> object:
    """A default as the table states it, as the command holds it."""
    if cell in WORDS:
        return WORDS[cell]
    if cell == "":
        return None
    try:
        return float(cell)
    except ValueError:
        return cell


def same(default: object, cell: str) -> bool:
    want = stated(cell)
    if isinstance(want, float) and not isinstance(default, bool):
        try:
            return float(default) == want  # type: ignore[arg-type]
        except (TypeError, ValueError):
            return False
    if default == cell:  # "off" is also a choice's name (--balance)
        return True
    if want is None:
        return default in (None, False, (), "")
    return default == want


def test_each_default_readme_states_is_the_commands():
    known, checked, wrong = options(), 0, []
    for groups, defaults in table():
        if len(groups) != len(defaults):
            continue
        for opts, cells in zip(groups, defaults, strict=True):
            if len(opts) != len(cells) or cells == [""]:
                continue  # one default for several options, or none stated
            for opt, cell in zip(opts, cells, strict=True):
                flag = opt.split("/")[0]
                default = COMPUTED[flag]() if flag in COMPUTED else known[flag].default
                checked += 1
                if not same(default, cell):
                    wrong.append(f"{opt}: README {cell!r}, the command {default!r}")
    assert checked >= 25 and not wrong, wrong


@pytest.mark.parametrize("default, cell, ok", [
    (3, "3", True), (1.0, "1", True), ("auto", "auto", True), (True, "on", True),
    (None, "random", True), (None, "", True), (2.0, "3", False), ("zstd", "lz4", False),
])
def test_the_comparison_tells_a_wrong_default(default, cell, ok):
    assert same(default, cell) is ok
