"""``ctrlunit start --help`` is for people: the everyday options, at most 20, in at most 60
lines; every option ``start`` ever had is still there, listed by ``--help-all``."""

from __future__ import annotations

import re

from runner import ctrlunit

FORMER = """check peripherals pipeline clock command-delay period admission task law model
cycles duration record record-compression foxglove foxglove-rate report unit cost-model
cost-scale placement params observer model-state bandwidth listen connect zenoh-config
timeout fault-periods late-policy late missed-command overload max-error replies hold-rounds
pin cpus rt-priority idle plant-substeps plant-lag plant-friction belt spec json progress
plot""".split()
"""The 50 options ``start`` had when --help began to show only the everyday ones."""


def options_in(text: str) -> set[str]:
    return set(re.findall(r"^  (?:-\w, )?--([a-z-]+)", text, re.MULTILINE))


def test_start_help_shows_the_everyday_options_on_one_screen():
    res = ctrlunit("start", "--help")
    assert res.returncode == 0
    lines = res.stdout.splitlines()
    shown = options_in(res.stdout)
    assert len(lines) <= 60, len(lines)
    assert len(shown) <= 20, sorted(shown)
    assert {"peripherals", "pipeline", "clock", "period", "record", "profile", "config", "set",
            "help-all"} <= shown
    assert "ctrlunit start --help-all" in res.stdout


def test_every_former_option_is_still_there_and_help_all_lists_it():
    res = ctrlunit("start", "--help-all")
    assert res.returncode == 0
    assert set(FORMER) | {"keys", "insecure"} <= options_in(res.stdout)
    # a hidden option still works: the tuning ones are only out of the way
    ok = ctrlunit("start", "--check", "--clock", "lockstep", "--command-delay", "short",
                  "--late-policy", "wait", "--hold-rounds", "never", "--replies", "each",
                  "--fault-periods", "5", "--foxglove-rate", "10")
    assert ok.returncode == 0, ok.stderr
