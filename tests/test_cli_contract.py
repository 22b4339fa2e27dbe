"""The commands' contract on edge inputs, driven through the real entry point (click's
runner on ``ctrlunit``'s group) with generated arguments and files:

- exit 0 only with an answer that is finite (no ``nan``/``inf`` printed);
- otherwise the documented exit code and a one-line error on stderr
  (``ctrlunit: error: ...``, or click's usage error naming the option, exit 2);
- never a traceback.

CTRLUNIT_CLI_EXAMPLES sets the examples per command (200 by default; more under
``-m slow``)."""

from __future__ import annotations

import json
import math
import os
import re
import tempfile
from pathlib import Path
from typing import Any

import pytest
from click.testing import CliRunner, Result
from ctrlunit.runtime.cli import cli
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from runner import ctrlunit, kill_unit, unit_id

pytestmark = pytest.mark.filterwarnings("ignore::hypothesis.errors.HypothesisWarning")
EXAMPLES = int(os.environ.get("CTRLUNIT_CLI_EXAMPLES", "200"))
DOCUMENTED = {0, 1, 2, 3, 4, 5, 6, 7, 130}
NON_FINITE = re.compile(r"\b(nan|-?inf(inity)?)\b", re.IGNORECASE)
SETTINGS = settings(max_examples=EXAMPLES, deadline=None, derandomize=True,
                    suppress_health_check=[HealthCheck.too_slow])


def invoke(*args: str) -> Result:
    return CliRunner().invoke(cli, list(args), prog_name="ctrlunit", catch_exceptions=True)


def check_contract(res: Result, args: tuple[str, ...]) -> None:
    if res.exception is not None and not isinstance(res.exception, SystemExit):
        raise AssertionError(f"ctrlunit {' '.join(map(repr, args))} raised "
                             f"{type(res.exception).__name__}: {res.exception}") \
            from res.exception
    assert "Traceback" not in res.stdout + res.stderr, args
    assert res.exit_code in DOCUMENTED, (args, res.exit_code)
    if res.exit_code == 0:
        assert not NON_FINITE.search(res.stdout), (args, res.stdout)
        return
    err = res.stderr.strip().splitlines()
    assert err, (args, res.exit_code, "no error message")
    if res.exit_code == 2:  # click's usage error: names the option or argument
        assert err[-1].startswith("Error: "), (args, res.stderr)
    else:
        assert len(err) == 1 and err[0].startswith("ctrlunit: error: "), (args, res.stderr)


# -- generated values -------------------------------------------------------------------

doubles = st.floats(allow_nan=True, allow_infinity=True, allow_subnormal=True)
numbers_as_text = st.one_of(
    doubles.map(repr),
    st.sampled_from(["nan", "-nan", "inf", "-inf", "-0", "-0.0", "5e-324", "1e308",
                     "-1e308", "1e-320", "0x10", "1_000", " 1", "1e", ""]),
    st.integers(min_value=-10**40, max_value=10**40).map(str),
    st.text(max_size=8),
    st.just("\udcff\udcfe"),  # the bytes of a non-UTF-8 argument, as Python sees them
)
plausible = st.floats(min_value=-0.5, max_value=0.5, allow_nan=False)
coordinates = st.one_of(numbers_as_text, plausible.map(repr))


@SETTINGS
@given(xyz=st.tuples(coordinates, coordinates, coordinates), as_json=st.booleans())
def test_ik_keeps_the_contract(xyz, as_json):
    args = ("ik", *xyz, *(["--json"] if as_json else []))
    check_contract(invoke(*args), args)


@SETTINGS
@given(q=st.tuples(coordinates, coordinates, coordinates), as_json=st.booleans())
def test_fk_keeps_the_contract(q, as_json):
    args = ("fk", *q, *(["--json"] if as_json else []))
    check_contract(invoke(*args), args)


# -- files ------------------------------------------------------------------------------

json_values = st.recursive(
    st.one_of(st.none(), st.booleans(), st.integers(min_value=-2**70, max_value=2**70),
              doubles, st.text(max_size=6)),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=6), inner,
                                                                 max_size=4),
    max_leaves=12)


def spoil(doc: Any, draw: Any) -> Any:
    """A copy of ``doc`` with one value somewhere replaced (wrong type, out of range,
    non-finite), or a key removed."""
    if isinstance(doc, dict) and doc:
        key = draw(st.sampled_from(sorted(doc)))
        out = dict(doc)
        if draw(st.integers(0, 5)) == 0:
            del out[key]
        else:
            out[key] = spoil(doc[key], draw) if draw(st.booleans()) else draw(json_values)
        return out
    if isinstance(doc, list) and doc:
        i = draw(st.integers(0, len(doc) - 1))
        out = list(doc)
        out[i] = spoil(doc[i], draw) if draw(st.booleans()) else draw(json_values)
        return out
    return draw(json_values)


def dump(doc: Any) -> bytes:
    return json.dumps(doc, allow_nan=True).encode()


TASK = {"name": "t", "dwell": 0.05, "segments": [
    {"type": "line", "start": [0.0, 0.0, -0.35], "end": [0.1, 0.0, -0.35], "accel": 10},
    {"type": "half-ellipse", "start": [0.1, 0.0, -0.35], "top": [0.05, 0.0, -0.3],
     "end": [0.0, 0.0, -0.35], "accel": 10}]}


@st.composite
def file_contents(draw: Any, good: bytes | None = None, doc: Any = None) -> bytes:
    """Empty, garbage, a truncated good file, JSON of the wrong type, or a good JSON
    document with one field spoiled."""
    kinds = ["empty", "garbage", "json"]
    if good:
        kinds.append("truncated")
    if doc is not None:
        kinds += ["spoiled", "spoiled"]
    kind = draw(st.sampled_from(kinds))
    if kind == "empty":
        return b""
    if kind == "garbage":
        return draw(st.binary(max_size=300))
    if kind == "json":
        return dump(draw(json_values))
    if kind == "truncated":
        assert good is not None
        return good[:draw(st.integers(0, len(good) - 1))]
    return dump(spoil(doc, draw))


@pytest.fixture(scope="module")
def work() -> Any:
    with tempfile.TemporaryDirectory(prefix="ctrlunit-contract-") as d:
        yield Path(d)


@SETTINGS
@given(data=st.data())
def test_trajectory_keeps_the_contract_on_task_files(work, data):
    f = work / "task.json"
    f.write_bytes(data.draw(file_contents(doc=TASK)))
    args = ("trajectory", str(f), *(["--json"] if data.draw(st.booleans()) else []))
    check_contract(invoke(*args), args)


PARAMS = b"[delta]\nm_c = 0.5\nl_a = 0.2\n"


@SETTINGS
@given(data=st.data())
def test_parameter_files_keep_the_contract(work, data):
    f = work / "robot.toml"
    kind = data.draw(st.sampled_from(["toml", "garbage", "truncated"]))
    if kind == "toml":
        key = data.draw(st.sampled_from(["m_c", "l_a", "l_b", "r_a", "r_b", "m_b", "x"]))
        value = data.draw(st.one_of(numbers_as_text.filter(lambda s: "\n" not in s
                                                           and "\udcff" not in s),
                                    st.just('"text"'), st.just("[1, 2]")))
        f.write_text(f"[delta]\n{key} = {value}\n")
    elif kind == "garbage":
        f.write_bytes(data.draw(st.binary(max_size=200)))
    else:
        f.write_bytes(PARAMS[:data.draw(st.integers(0, len(PARAMS) - 1))])
    args = ("ik", "0", "0", "-0.35", "--params", str(f))
    check_contract(invoke(*args), args)


@pytest.fixture(scope="module")
def recorded(work) -> tuple[bytes, Any]:
    """A 40-interval lockstep recording and its report, made once."""
    unit = unit_id("contract")
    rec, rep = work / "run.mcap", work / "run.json"
    try:
        res = ctrlunit("start", "--unit", unit, "--clock", "lockstep", "--peripherals", "1",
                       "--cycles", "40", "--record", str(rec), "--report", str(rep),
                       timeout=120)
    finally:
        kill_unit(unit)
    assert res.returncode == 0, res.stderr
    return rec.read_bytes(), json.loads(rep.read_text())


@SETTINGS
@given(data=st.data())
def test_report_and_replay_keep_the_contract_on_recordings(work, recorded, data):
    good, _ = recorded
    f = work / "cut.mcap"
    f.write_bytes(data.draw(file_contents(good=good)))
    command = data.draw(st.sampled_from([("report",), ("replay", "--verify")]))
    args = (*command, str(f))
    check_contract(invoke(*args), args)


@SETTINGS
@given(data=st.data())
def test_plot_keeps_the_contract_on_recordings(work, recorded, data):
    good, _ = recorded
    f = work / "plot.mcap"
    # a cut before the first chunk, or garbage: a prefix that holds intervals draws six
    # figures (seconds each), which tests/test_plots.py covers
    content = data.draw(st.one_of(st.binary(max_size=300),
                                  st.integers(0, 200).map(lambda n: good[:n])))
    f.write_bytes(content)
    args = ("plot", str(f), "--out", str(work / "plots"))
    check_contract(invoke(*args), args)


@pytest.mark.xfail(reason="balance reads a report's fields without checking their types: "
                   "a report that is JSON null or a list ends in an AttributeError "
                   "(found by this test, 2026-11-23; issue 16)", strict=True,
                   raises=AssertionError)
@SETTINGS
@given(data=st.data())
def test_balance_keeps_the_contract_on_reports(work, recorded, data):
    _, report = recorded
    f = work / "report.json"
    f.write_bytes(data.draw(file_contents(doc=json.loads(json.dumps(report)))))
    args = ("balance", str(f), "--write", str(work / "placement.json"), "--json")
    check_contract(invoke(*args), args)


def test_the_generators_reach_the_edges():
    """The strategies above do produce the edge values the contract is about."""
    seen = set()

    @settings(max_examples=300, derandomize=True)
    @given(numbers_as_text)
    def collect(s):
        seen.add(s)

    collect()
    floats = set()
    for s in seen:
        try:
            floats.add(float(s))
        except ValueError:
            pass
    assert any(math.isnan(x) for x in floats) and math.inf in floats
    assert any(0 < abs(x) < 2.3e-308 for x in floats)  # a subnormal
    assert any(abs(x) > 1e300 for x in floats)


# -- start: every option and file, checked without starting anything (--check) ----------

NUMERIC_OPTIONS = ["--period", "--cycles", "--duration", "--peripherals", "--pipeline",
                   "--max-error", "--bandwidth", "--fault-periods", "--timeout",
                   "--cost-scale", "--plant-substeps", "--plant-lag", "--plant-friction",
                   "--rt-priority", "--foxglove-rate"]
TEXT_OPTIONS = ["--clock", "--law", "--model", "--task", "--observer", "--late-policy",
                "--late", "--replies", "--cpus", "--unit", "--foxglove", "--cost-model",
                "--record-compression", "--command-delay", "--hold-rounds"]
PLACEMENT = {"peripherals": 3, "axes": [[0], [1], [2]]}


@SETTINGS
@given(data=st.data())
def test_start_keeps_the_contract_on_options_and_files(work, data):
    args: list[str] = ["start", "--check"]
    for opt in data.draw(st.lists(st.sampled_from(NUMERIC_OPTIONS), max_size=3,
                                  unique=True)):
        args += [opt, data.draw(numbers_as_text)]
    for opt in data.draw(st.lists(st.sampled_from(TEXT_OPTIONS), max_size=2, unique=True)):
        args += [opt, data.draw(st.one_of(st.text(max_size=10), st.sampled_from(
            ["auto", "lockstep", "pd", "circle", "x=hold", "8765", "0.0.0.0:99999"])))]
    which = data.draw(st.sampled_from(["none", "task", "placement", "params"]))
    if which == "task":
        f = work / "start-task.json"
        f.write_bytes(data.draw(file_contents(doc=TASK)))
        args += ["--task", str(f)]
    elif which == "placement":
        f = work / "start-placement.json"
        f.write_bytes(data.draw(file_contents(doc=PLACEMENT)))
        args += ["--placement", str(f)]
    elif which == "params":
        f = work / "start-params.toml"
        f.write_bytes(data.draw(st.binary(max_size=100)))
        args += ["--params", str(f)]
    args += data.draw(st.sampled_from([[], ["--json"]]))
    res = invoke(*args)
    check_contract(res, tuple(args))
    if res.exit_code == 0:  # --check never starts a run
        assert "nothing was started" in res.stdout or '"valid": true' in res.stdout
