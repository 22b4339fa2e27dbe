"""Every setting takes the same values wherever it is given: its flag, ``--set
SECTION.KEY=VALUE`` and a run file (``--config``), in each spelling it accepts (a duration
as ``2ms``, ``2000us`` or ``0.002``; a period ``auto`` too), resolve to the same
configuration: ``start --check --json`` prints the same, and the setting is the value
meant (runtime/config/spellings.py).

The cases are made from the settings' declarations (runtime/config/sections.py): their
kind, type, choices and bounds; a new setting is covered without a line here, unless it
takes free text (a name, a file, an address), whose sample goes in :data:`SAMPLES`."""

from __future__ import annotations

import json
import math
import typing
from decimal import Decimal
from pathlib import Path
from typing import Any

import pytest
from click.testing import CliRunner
from ctrlunit.runtime.cli import cli
from ctrlunit.runtime.config import _ABOUT, _FLAT_TYPES, FLAT
from ctrlunit.runtime.config.spellings import PERIOD_AUTO_START_S, STATE, USER

ROOT = Path(__file__).resolve().parent.parent
UNIT = "uspelling"

Case = tuple[Any, list[list[str]], list[str], list[str]]
"""A value meant, and its spellings: the flag's arguments (each a list), ``--set``'s
VALUE texts, the run file's TOML value texts."""


def _files(tmp: Path) -> dict[str, list[Any]]:
    """Samples of the settings that take free text, each a value the check accepts."""
    zenoh = tmp / "zenoh.json5"
    zenoh.write_text(json.dumps({"mode": "peer", "scouting": {"multicast": {"enabled": False}}}))
    placement = tmp / "placement.json"
    placement.write_text(json.dumps({"peripherals": 3, "axes": [[0], [1], [2]]}))
    keys = tmp / "keys"
    res = CliRunner().invoke(cli, ["keys", "init", str(keys)])
    assert res.exit_code == 0, res.output
    return {"task": ["circle", "pick-place"], "params": [str(ROOT / "kernels" / "delta_ia.toml")],
            "zenoh_config": [str(zenoh)], "keys": [str(keys)], "unit": ["uother"],
            "record": [str(tmp / "run.mcap")], "report": [str(tmp / "run.json")],
            "pin": ["0", "0,1"], "foxglove": ["8765", "127.0.0.1:8765"],
            "foxglove_rate": [0.0, 1.0, 100000.0], "placement": [str(placement)],
            "listen": [["tcp/127.0.0.1:7447"], ["tcp/127.0.0.1:7447", "tcp/127.0.0.1:7448"]],
            "connect": [["tcp/127.0.0.1:7449"]], "late": [{"jdot": "hold"},
                                                          {"jdot": "hold", "ik": "wait"}]}


SAMPLES: dict[str, list[Any]] = {}
"""Filled per run by the module's fixture (:func:`_files`): temporary files."""


def _base(flat: str) -> Any:
    args = [t for t in typing.get_args(_FLAT_TYPES[flat]) if t is not type(None)]
    return args[0] if len(args) == 1 else _FLAT_TYPES[flat]


def _text(value: Any) -> str:
    """A scalar as the command line writes it."""
    return ("true" if value else "false") if isinstance(value, bool) else str(value)


def _seconds(value: float) -> list[str]:
    """A duration's spellings: seconds bare and with each unit, exactly."""
    exact = Decimal(repr(value))
    scaled = [(exact * m).normalize() for m in (1, 1000, 1_000_000)]
    return [repr(value), *(f"{format(s, 'f')}{u}" for s, u in zip(scaled, ("s", "ms", "us"),
                                                                    strict=True))]


def _numbers(flat: str) -> list[Any]:
    a = _ABOUT[flat]
    if a.bounds is None:
        return []
    lo, hi = a.bounds
    base = _base(flat)
    picks = [lo, hi] + ([2e-3] if a.kind == "period" else [])
    return [int(v) if base is int else float(v) for v in picks]


def _case(flat: str, value: Any) -> Case:
    """The spellings of one value of a setting."""
    a = _ABOUT[flat]
    flag = None if a.flag is None else "--" + (a.flag.name or flat.replace("_", "-"))
    kind, base = a.kind, _base(flat)
    if isinstance(value, bool):
        flags = [[flag] if value else ([] if kind == "flag" else [f"--no-{flag[2:]}"])] \
            if flag else []
        return value, flags, [_text(value)], [_text(value)]
    if isinstance(value, list):  # endpoints: one may be given alone
        one = [json.dumps(value[0])] if len(value) == 1 else []
        flags = [[arg for v in value for arg in (flag, v)]] if flag else []
        return (value, flags, [json.dumps(value), *one, *(value[:1] if one else [])],
                [json.dumps(value), *one])
    if isinstance(value, dict):  # late data
        items = [f"{k}={v}" for k, v in value.items()]
        table = "{" + ", ".join(f"{k} = {json.dumps(v)}" for k, v in value.items()) + "}"
        flags = [[arg for i in items for arg in (flag, i)]] if flag else []
        sets = [table, json.dumps(items)] + ([items[0]] if len(items) == 1 else [])
        return value, flags, sets, [table, json.dumps(items)] + (
            [json.dumps(items[0])] if len(items) == 1 else [])
    if kind in ("duration", "period") and not isinstance(value, str):
        texts = _seconds(value)
        return (value, [[flag, t] for t in texts] if flag else [],
                [*texts, *(json.dumps(t) for t in texts[1:])],
                [texts[0], *(json.dumps(t) for t in texts[1:])])
    if isinstance(value, int | float):
        texts = [_text(value)]
        if base is float:
            texts += [f"{value:g}"] if f"{value:g}" != _text(value) else []
            texts += [str(int(value))] if float(value).is_integer() else []
        return (value, [[flag, t] for t in texts] if flag else [],
                [*texts, json.dumps(texts[0])], [*texts, json.dumps(texts[0])])
    flags = [[flag, value]] if flag else []  # a word, a name, a file
    bare = [value] if value.replace("-", "").replace(",", "").isalnum() or "/" in value \
        else []
    number = [value] if value.replace(".", "").replace(":", "").isdigit() else []
    return value, flags, [*bare, json.dumps(value)], [json.dumps(value), *(
        number if ":" not in value and "," not in value else [])]


def cases(flat: str) -> list[Case]:
    """The values of a setting the test gives, from its declaration."""
    a = _ABOUT[flat]
    if flat in SAMPLES:
        values = list(SAMPLES[flat])
    elif a.choices is not None:
        values = list(a.choices)
    elif _base(flat) is bool:
        values = [True, False]
    else:
        values = _numbers(flat)
    if a.kind in ("period", "placement", "priority"):
        values += ["auto"] + (["axes"] if a.kind == "placement" else [0, 99]
                              if a.kind == "priority" else [])
    assert values, f"{flat}: no values to try: give samples in SAMPLES"
    return [(value, flags, list(dict.fromkeys(sets)), list(dict.fromkeys(files)))
            for value, flags, sets, files in map(lambda v: _case(flat, v), values)]


@pytest.fixture(scope="module", autouse=True)
def _samples(tmp_path_factory: pytest.TempPathFactory) -> None:
    SAMPLES.update(_files(tmp_path_factory.mktemp("spellings")))


CONTEXT: dict[str, list[str]] = {"balance": ["--clock", "freerun"]}
"""Options a setting's every value needs (``--balance live`` is refused in realtime)."""


def _check(args: list[str], flat: str) -> tuple[int, str]:
    unit = [] if flat == "unit" else ["--unit", UNIT]
    res = CliRunner().invoke(cli, ["start", "--check", "--json", *unit,
                                   *CONTEXT.get(flat, []), *args])
    return res.exit_code, res.output


def _run_file(tmp: Path, flat: str, text: str) -> Path:
    section, key = FLAT[flat]
    path = tmp / "run.toml"
    path.write_text(f"[{section}]\n{key} = {text}\n")
    return path


def _meant(flat: str, value: Any) -> Any:
    """The value ``--check``'s settings show for a value given."""
    if flat == "period" and value == "auto":
        return "auto"
    return value


@pytest.mark.parametrize("flat", USER)
def test_the_flag_set_and_run_file_give_the_same_configuration(flat: str, tmp_path: Path):
    section, key = FLAT[flat]
    for value, flags, sets, files in cases(flat):
        outputs: dict[str, tuple[int, str]] = {}
        for args in flags:
            outputs[" ".join(args)] = _check(args, flat)
        for text in sets:
            outputs[f"--set {section}.{key}={text}"] = _check(
                ["--set", f"{section}.{key}={text}"], flat)
        for text in files:
            run = _run_file(tmp_path, flat, text)
            outputs[f"run file {key} = {text}"] = _check(["--config", str(run)], flat)
        assert len(set(outputs.values())) == 1, (value, {k: v[1][-300:] for k, v in
                                                         outputs.items()})
        code, out = next(iter(outputs.values()))
        assert code == 0, (value, out)
        shown = json.loads(out)["settings"][flat]
        meant = _meant(flat, value)
        assert shown == meant or (isinstance(meant, float) and math.isclose(shown, meant,
                                                                           rel_tol=0)), flat


def test_every_setting_is_covered_and_the_run_s_state_is_no_setting(tmp_path: Path):
    assert set(USER) | set(STATE) == set(FLAT) and not set(USER) & set(STATE)
    assert {"period_auto", "placement_auto", "central_blocks"} <= set(STATE)
    for flat in STATE:
        section, key = FLAT[flat]
        code, out = _check(["--set", f"{section}.{key}=true"], flat)
        assert code == 1 and "the run's own state, not a setting" in out, out
        code, out = _check(["--config", str(_run_file(tmp_path, flat, "true"))], flat)
        assert code == 1 and "the run's own state, not a setting" in out, out


def test_the_period_set_is_the_period_that_runs():
    """The issue's case: ``--set schedule.period=0.002`` ran at ``auto``."""
    from ctrlunit.runtime.launch.admission import LADDER_S

    assert PERIOD_AUTO_START_S in LADDER_S  # auto starts on a rung of the ladder
    texts = set()
    for args in (["--period", "2ms"], ["--set", "schedule.period=0.002"],
                 ["--set", "schedule.period=2ms"]):
        res = CliRunner().invoke(cli, ["start", "--check", *args])
        assert res.exit_code == 0, res.output
        assert "period 2 ms" in res.output
        texts.add(res.output)
    assert len(texts) == 1
    res = CliRunner().invoke(cli, ["start", "--check", "--set", "schedule.period=0.002",
                                   "--period", "auto"])  # a flag given is over --set
    assert "period auto" in res.output


@pytest.mark.parametrize("args, message", [
    (["--set", "schedule.late_policy=waitt"],
     "--set schedule.late_policy = 'waitt': allowed wait, compute, hold, fault"),
    (["--set", "schedule.period=5"], "--set schedule.period = 5: allowed auto, or 20us to 1s"),
    (["--set", "transport.timeout=2 hours"], "--set transport.timeout = '2 hours': allowed "
     "0.01 to 600 s (30s or seconds)"),  # the spellings' examples within its range
    (["--set", "plant.lag=\"30s\""], "--set plant.lag = '30s': allowed 0 to 1 s (500us, 2ms "
     "or seconds)"),  # as typed, not 30: a new user read "30: allowed 0 to 1 s"
    (["--set", "run.cycles=1e3"], "--set run.cycles = 1000.0: allowed an integer from 1 to "
     "1000000000"),  # in the range, and no integer
    (["--cycles", "1e3"], "--cycles = 1e3: allowed an integer from 1 to 1000000000"),
    (["--plant-lag", "30s"], "--plant-lag = 30 s: allowed 0 to 1 s (500us, 2ms or seconds)"),
])
def test_a_refused_value_names_the_key_as_typed_and_what_is_allowed(args, message):
    res = CliRunner().invoke(cli, ["start", "--check", *args])
    assert res.exit_code == 1 and message in res.output, res.output


def test_an_unset_line_of_the_run_file_filled_in_is_a_setting(tmp_path):
    """``ctrlunit config`` wrote ``# substeps =  (unset)``, which a new user uncommented and
    filled in only to be told "Invalid value (at line 115, column 13)"."""
    import tomllib

    text = CliRunner().invoke(cli, ["config"]).output
    line = next(ln for ln in text.splitlines() if ln.startswith("# substeps = "))
    filled = text.replace(line, line.removeprefix("# ").replace("VALUE", "4", 1))
    assert tomllib.loads(filled)["plant"]["substeps"] == 4
    f = tmp_path / "run.toml"
    f.write_text(filled)
    res = CliRunner().invoke(cli, ["start", "--config", str(f), "--check", "--json"])
    assert res.exit_code == 0, res.output
