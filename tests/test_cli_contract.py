"""The commands' contract on edge inputs, driven through the real entry point (click's
runner on ``ctrlunit``'s group) with generated arguments and files:

- exit 0 only with an answer that is finite (no ``nan``/``inf`` printed);
- otherwise the documented exit code and a one-line error on stderr
  (``ctrlunit: error: ...``, or click's usage error naming the option, exit 2);
- never a traceback.

CTRLUNIT_CLI_EXAMPLES sets the examples per command: 100 by default, a bounded run that
keeps the whole suite inside CI's 10 minutes on a slow day (200 took 45 s of it), the same
examples each run (derandomized). ``-m slow`` runs the module again with 100 others
(CTRLUNIT_CLI_SEED: Hypothesis's random generation from that seed), 200 in all."""

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
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st
from runner import ctrlunit, kill_unit, unit_id

pytestmark = pytest.mark.filterwarnings("ignore::hypothesis.errors.HypothesisWarning")
EXAMPLES = int(os.environ.get("CTRLUNIT_CLI_EXAMPLES", "100"))
SLOW_EXAMPLES = 100
SLOW_SEED = 20261128
SEED = os.environ.get("CTRLUNIT_CLI_SEED")
DOCUMENTED = {0, 1, 2, 3, 4, 5, 6, 7, 130}
NON_FINITE = re.compile(r"\b(nan|-?inf(inity)?)\b", re.IGNORECASE)
QUOTED_TASK = re.compile(r'\btask(?:": | )"(?:[^"\\]|\\.)*"')
"""A task file's name as a summary quotes it (``task "INF"``, ``"task": "INF"`` in
``--json``): not a figure. Only that is skipped; a string "nan" anywhere else (a figure
in ``--json``) still fails."""
SETTINGS = settings(max_examples=EXAMPLES, deadline=None, derandomize=SEED is None,
                    suppress_health_check=[HealthCheck.too_slow])


def invoke(*args: str) -> Result:
    return CliRunner().invoke(cli, list(args), prog_name="ctrlunit", catch_exceptions=True)


def check_contract(res: Result, args: tuple[str, ...], *, generated: bool = True) -> None:
    if generated:
        event(f"exit {res.exit_code}")  # pytest --hypothesis-show-statistics: how often each
    if res.exception is not None and not isinstance(res.exception, SystemExit):
        raise AssertionError(f"ctrlunit {' '.join(map(repr, args))} raised "
                             f"{type(res.exception).__name__}: {res.exception}") \
            from res.exception
    assert "Traceback" not in res.stdout + res.stderr, args
    assert res.exit_code in DOCUMENTED, (args, res.exit_code)
    if res.exit_code == 0:
        assert not NON_FINITE.search(QUOTED_TASK.sub("task", res.stdout)), (args, res.stdout)
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


def test_a_task_named_like_a_non_finite_figure_keeps_the_contract(work):
    """Found at 2000 examples: a task file named INF printed ``task INF``."""
    f = work / "inf.json"
    for name in ("INF", "-inf", "NaN"):
        f.write_text(json.dumps({**TASK, "name": name}))
        for extra in ((), ("--json",)):
            args = ("trajectory", str(f), *extra)
            res = invoke(*args)
            assert res.exit_code == 0 and name in res.stdout, (args, res.stdout)
            check_contract(res, args, generated=False)
    assert NON_FINITE.search(QUOTED_TASK.sub("task", '{"task": "t", "min_eig": "nan"}'))


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


class Recorded(tuple):
    """(recording bytes, report): shown by name only in a failing example's report."""

    def __repr__(self) -> str:
        return "<the 40-interval recording and its report>"


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
    return Recorded((rec.read_bytes(), json.loads(rep.read_text())))


def _slow_rate(text: str) -> bool:
    """A valid --rate under 1 replays the 0.2 s recording for up to 200 s."""
    try:
        return 1e-3 <= float(text) < 1.0
    except ValueError:
        return False


REPLAY_OPTIONS = {
    "--cycles": st.one_of(st.tuples(numbers_as_text, numbers_as_text).map(":".join),
                          st.sampled_from(["10:20", "0:1", "39:40", "100:200", ":5", "5:",
                                           "3:3"]), numbers_as_text),
    "--start-offset": st.one_of(numbers_as_text, st.sampled_from(["0", "0.05", "0.3"])),
    "--rate": st.one_of(numbers_as_text.filter(lambda t: not _slow_rate(t)),
                        st.sampled_from(["10", "1000"])),
    "--topics": st.one_of(st.text(max_size=8),
                          st.sampled_from(["/plant/command", "/central/sample", "/x"])),
    "--unit": st.one_of(st.text(max_size=8), st.just("contract-replay")),
    "--connect": st.deferred(lambda: ENDPOINTS),
}


@SETTINGS
@given(data=st.data())
def test_report_and_replay_keep_the_contract_on_recordings(work, recorded, data):
    """Files cut, emptied or garbled (export to rosbag2 too); and the whole recording with
    replay's options (``--loop`` aside: it republishes until stopped)."""
    good, _ = recorded
    f = work / "cut.mcap"
    intact = data.draw(st.booleans())
    f.write_bytes(good if intact else data.draw(file_contents(good=good)))
    bag = Path(tempfile.mkdtemp(dir=work)) / "bag"  # new for each example: export writes it
    command = data.draw(st.sampled_from([("report",), ("replay", "--verify"),
                                         ("replay", "--csv", str(work / "csv")),
                                         ("replay",), ("export", "--rosbag2", str(bag))]))
    args: list[str] = [*command, str(f)]
    if intact and command[0] == "replay":
        for opt in data.draw(st.lists(st.sampled_from(sorted(REPLAY_OPTIONS)), max_size=3,
                                      unique=True)):
            args += [opt, data.draw(REPLAY_OPTIONS[opt])]
    check_contract(invoke(*args), tuple(args))


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


@SETTINGS
@given(data=st.data())
def test_balance_keeps_the_contract_on_reports(work, recorded, data):
    _, report = recorded
    f = work / "report.json"
    f.write_bytes(data.draw(file_contents(doc=json.loads(json.dumps(report)))))
    args = ("balance", str(f), "--write", str(work / "placement.json"), "--json")
    check_contract(invoke(*args), args)


BAD_REPORTS = [  # (change to the run's report, words the one-line error must hold)
    (lambda r: None, "must be a JSON object, got null"),
    (lambda r: [r], "must be a JSON object, got a list"),
    (lambda r: r | {"law": ["pd"]}, "law = ['pd']; allowed: resolved-acceleration"),
    (lambda r: r | {"pipeline": 3}, "pipeline = 3; allowed: 1 or 2"),
    (lambda r: r | {"model_state": "later"}, "model_state = 'later'; allowed: acting, sample"),
    (lambda r: r | {"block_cost_s": {}}, "block_cost_s = {}"),
    (lambda r: r | {"block_cost_s": r["block_cost_s"] | {"ik": "7e-6"}},
     "block_cost_s.ik = '7e-6'; allowed: a number of seconds in [0, 10]"),
    (lambda r: r | {"block_cost_s": r["block_cost_s"] | {"ik": 1e308}}, "block_cost_s.ik"),
    (lambda r: r | {"block_cost_s": r["block_cost_s"] | {"warp": 1e-6}},
     "a key of block_cost_s = 'warp'"),
    (lambda r: r | {"business": {"central": True}}, "business.central = True"),
    (lambda r: r | {"placement": {"peripherals": 1, "axes": [[0, 1]]}}, "placement"),
    (lambda r: r | {"period_s": {"p50": -1.0}, "period_mean_s": None}, "period_s.p50 = -1.0"),
    (lambda r: r | {"gantt_ms": [["central", 1, "a", 2]]}, "gantt_ms"),
]


@pytest.mark.parametrize("change,words", BAD_REPORTS,
                         ids=[w.split(" ")[0] for _, w in BAD_REPORTS])
def test_balance_names_the_field_of_a_bad_report(work, recorded, change, words):
    _, report = recorded
    f = work / "bad-report.json"
    f.write_text(json.dumps(change(json.loads(json.dumps(report)))))
    out = work / "bad-placement.json"
    out.unlink(missing_ok=True)
    res = invoke("balance", str(f), "--write", str(out))
    assert res.exit_code == 1, res.output
    assert words in res.stderr and res.stderr.count("\n") == 1, res.stderr
    assert not out.exists()  # nothing written from a report it could not read


def test_balance_reads_a_report_of_the_observer_that_starts_from_the_previous_estimate(
        work, recorded):
    """Found with the contract test: a run with ``--observer previous`` has the second
    Newton-Raphson iteration's blocks (``ik_obs1``, ...); balance once knew only the
    default observer's blocks and stopped on them. Reports name their observer now; one
    written before says it by those blocks."""
    _, report = recorded
    assert report["observer"] == "predict"
    older = {k: v for k, v in report.items() if k != "observer"}
    costs = older["block_cost_s"]
    older["block_cost_s"] = costs | {f"{b}1": costs[f"{b}0"]
                                     for b in ("ik_obs", "jinv_obs", "residual", "observer")}
    for doc in (older, older | {"observer": "previous"}):
        f = work / "previous.json"
        f.write_text(json.dumps(doc))
        res = invoke("balance", str(f), "--write", str(work / "p.json"), "--json")
        assert res.exit_code == 0, res.output
        a = json.loads(res.stdout)
        assert "ik_obs1" in a["block_cost_s"]
        assert a["t_s_s"] == pytest.approx(sum(older["block_cost_s"].values()), rel=1e-12)


def test_balance_reads_a_report_written_before_the_model_state(work, recorded):
    """A report names where its model was evaluated; one written before says it by the
    block ``ahead`` (absent: the model at the sample, the thesis's graph)."""
    _, report = recorded
    assert report["model_state"] == "acting" and "ahead" in report["block_cost_s"]
    older = {k: v for k, v in report.items() if k != "model_state"}
    thesis = older | {"block_cost_s": {k: v for k, v in older["block_cost_s"].items()
                                       if k not in ("ahead", "inflight")}}
    for doc, state in ((older, "acting"), (thesis, "sample")):
        f = work / "older.json"
        f.write_text(json.dumps(doc))
        res = invoke("balance", str(f), "--write", str(work / "p.json"), "--json")
        assert res.exit_code == 0, res.output
        a = json.loads(res.stdout)
        assert (a["model_state"], a["block_cost_s"]) == (state, doc["block_cost_s"])


def documented_errors() -> list[tuple[list[str], str, int]]:
    """The rows of docs/faults-and-errors.md whose first cell is a whole ``ctrlunit``
    command: (arguments, message, exit code)."""
    doc = Path(__file__).resolve().parents[1] / "docs" / "faults-and-errors.md"
    rows = []
    for line in doc.read_text().splitlines():
        m = re.match(r"^\| `ctrlunit ([^`]*)` \| (``?)(.*?)\2 \| (\d+) \|$", line)
        if m:
            rows.append((m[1].split(), m[3], int(m[4])))
    return rows


DOCUMENTED_ERRORS = documented_errors()
ROLE_COMMANDS = {"start", "central", "plant", "peripheral"}


def test_the_error_table_is_read():
    assert len(DOCUMENTED_ERRORS) >= 20
    assert {args[0] for args, _, _ in DOCUMENTED_ERRORS} >= {
        "ik", "fk", "trajectory", "workspace", "start", "central", "peripheral", "latency",
        "bench"}


@pytest.mark.parametrize("args,message,code", DOCUMENTED_ERRORS,
                         ids=[" ".join(a) for a, _, _ in DOCUMENTED_ERRORS])
def test_each_documented_error_is_what_the_command_says(args, message, code):
    """The message (its pieces around ``...``, in order) and the exit code of each command
    docs/faults-and-errors.md lists. The roles get ``--check``: a regression that made one
    valid starts nothing."""
    if args[0] in ROLE_COMMANDS:
        args = [args[0], "--check", *args[1:]]
    res = invoke(*args)
    check_contract(res, tuple(args), generated=False)
    assert res.exit_code == code, (args, res.exit_code, res.stderr)
    at = 0
    for piece in (p.strip() for p in message.split("...")):
        found = res.stderr.find(piece, at)
        assert found >= 0, (args, piece, res.stderr)
        at = found + len(piece)


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
PLAUSIBLE = {  # a value each option accepts, so that examples reach past the first check
    "--period": "2ms", "--cycles": "50", "--duration": "1s", "--peripherals": "2",
    "--pipeline": "2", "--max-error": "0.01", "--bandwidth": "10", "--fault-periods": "5",
    "--timeout": "3", "--cost-scale": "2", "--plant-substeps": "4", "--plant-lag": "0.001",
    "--plant-friction": "0.1", "--rt-priority": "0", "--foxglove-rate": "50",
    "--clock": "lockstep", "--law": "pd", "--model": "simplified", "--task": "circle",
    "--observer": "previous", "--late-policy": "hold", "--late": "ik=hold",
    "--replies": "each", "--cpus": "split", "--unit": "contract-x", "--foxglove": "0",
    "--cost-model": "t800", "--record-compression": "lz4", "--command-delay": "short",
    "--hold-rounds": "never", "--listen": "tcp/127.0.0.1:0", "--connect": "tcp/127.0.0.1:9"}
TEXT_OPTIONS = ["--clock", "--law", "--model", "--task", "--observer", "--late-policy",
                "--late", "--replies", "--cpus", "--unit", "--foxglove", "--cost-model",
                "--record-compression", "--command-delay", "--hold-rounds"]
PLACEMENT = {"peripherals": 3, "axes": [[0], [1], [2]]}


ENDPOINTS = st.one_of(
    st.text(max_size=12),
    st.sampled_from(["tcp/127.0.0.1:0", "tcp/127.0.0.1:99999", "tcp/[::1]:7447", "tcp/:80",
                     "udp/127.0.0.1:x", "unixsock-stream//tmp/ctrlunit-x.sock", "garbage",
                     "tcp/127.0.0.1:7447?x=1", "/tcp/1.2.3.4:5"]),
    st.integers(-2, 70000).map(lambda p: f"tcp/127.0.0.1:{p}"))
ZENOH_CONFIG = {"mode": "peer", "scouting": {"multicast": {"enabled": False}}}
SPEC = {"run": {"peripherals": 1, "pipeline": 1, "clock": "lockstep", "period": 0.001}}
ROLES = [("start",), ("central", "--listen", "tcp/127.0.0.1:0"), ("plant",),
         ("peripheral", "--index", "1")]


@SETTINGS
@given(data=st.data())
def test_start_and_the_roles_keep_the_contract_on_options_and_files(work, data):
    """``start`` and the single roles (``central``, ``plant``, ``peripheral``) share their
    options; with ``--check`` each checks them and the files and starts nothing."""
    role = data.draw(st.sampled_from(ROLES))
    args: list[str] = [*role, "--check"]
    # plausible values, of which at most one is spoiled: each error path on its own
    options = data.draw(st.lists(st.sampled_from([*NUMERIC_OPTIONS, *TEXT_OPTIONS,
                                                  "--listen", "--connect"]),
                                 max_size=4, unique=True))
    spoiled = data.draw(st.one_of(st.none(), st.sampled_from(options))) if options else None
    for opt in options:
        value = PLAUSIBLE[opt]
        if opt == spoiled:
            value = data.draw(numbers_as_text if opt in NUMERIC_OPTIONS else ENDPOINTS
                              if opt in ("--listen", "--connect") else st.one_of(
                                  st.text(max_size=10), st.sampled_from(
                                      ["auto", "x=hold", "8765", "0.0.0.0:99999", "ik=",
                                       "nosuchblock=hold"])))
        args += [opt, value]
    which = data.draw(st.sampled_from(["none", "task", "placement", "params", "zenoh",
                                       "spec"]))
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
    elif which == "zenoh":
        f = work / "zenoh.json5"
        f.write_bytes(data.draw(file_contents(doc=ZENOH_CONFIG)))
        args += ["--zenoh-config", str(f)]
    elif which == "spec" and role[0] != "start":
        f = work / "role.spec"
        f.write_bytes(data.draw(file_contents(doc=SPEC)))
        args += ["--spec", str(f)]
    if role[0] in ("start", "central"):
        args += data.draw(st.sampled_from([[], ["--json"]]))
    res = invoke(*args)
    check_contract(res, tuple(args))
    if res.exit_code == 0:  # --check never starts a run
        assert "nothing was started" in res.stdout or '"valid": true' in res.stdout


# -- workspace, latency, bench ----------------------------------------------------------

def _not_a_slow_grid(text: str) -> bool:
    """A valid --grid above 15 draws maps for seconds (401: 25 s); the range is click's."""
    try:
        return not 15 < int(text) <= 401
    except ValueError:
        return True


@SETTINGS
@given(grid=st.one_of(numbers_as_text.filter(_not_a_slow_grid),
                     st.integers(11, 15).map(str)),
       as_json=st.booleans())
def test_workspace_keeps_the_contract(grid, as_json):
    args = ("workspace", "--grid", grid, *(["--json"] if as_json else []))
    check_contract(invoke(*args), args)


with_unit = st.one_of(numbers_as_text, st.tuples(numbers_as_text, st.sampled_from(
    ["s", "ms", "us", "ns", "min", "h"])).map("".join))


@SETTINGS
@given(period=st.one_of(with_unit, st.sampled_from(["1ms", "500us", "20us", "19us"])),
       duration=st.one_of(st.sampled_from(["1ms", "5ms", "20ms", "0", "-1ms", "1e308",
                                           "nan", "inf", "x", ""]),
                          numbers_as_text.filter(lambda s: not _short(s))),
       as_json=st.booleans(),
       priority=st.sampled_from(["auto", "0", "100", "-1", "fifo", ""]))
def test_latency_keeps_the_contract(work, period, duration, as_json, priority):
    """Valid durations are kept under 20 ms (the command measures for that long)."""
    args = ("latency", "--period", period, "--duration", duration, "--plot",
            str(work / "latency.png"), "--rt-priority", priority,
            *(["--json"] if as_json else []))
    check_contract(invoke(*args), args)


def _short(text: str) -> bool:
    """A bare number of seconds that latency would accept and measure for long."""
    try:
        return float(text) > 0.02
    except ValueError:
        return False


@SETTINGS
@given(periods=st.lists(st.one_of(with_unit, st.sampled_from(["3ms", "1ms", "10us"])),
                       max_size=2),
       repeats=st.one_of(numbers_as_text, st.sampled_from(["1", "2", "20"])),
       scale=st.one_of(numbers_as_text, st.sampled_from(["1", "30", "1000"])),
       quick=st.booleans(),
       stages=st.one_of(st.text(max_size=12),
                        st.sampled_from(["all", "thesis,floor", "realtime", "sweep, thesis",
                                         "thesis,bogus", ","])))
def test_bench_keeps_the_contract(work, periods, repeats, scale, quick, stages):
    """``bench --check`` checks the options and lists the runs; it starts none."""
    args = ["bench", "--check", "--out", str(work / "bench-out"), "--repeats", repeats,
            "--thesis-scale", scale, "--stages", stages, *(["--quick"] if quick else [])]
    for p in periods:
        args += ["--realtime-period", p]
    res = invoke(*args)
    check_contract(res, tuple(args))
    if res.exit_code == 0:
        assert not (work / "bench-out").exists()
        assert res.stdout.rstrip().endswith("nothing was run")
    if stages in ("thesis,bogus", ","):
        assert res.exit_code in (1, 2)  # 2: another option was refused first


@pytest.mark.slow
def test_every_command_keeps_the_contract_on_two_hundred_examples():
    """``pytest -m slow``: this module again with 100 examples per command other than the
    fast suite's 100 (generated from a seed of their own), 200 in all (2000 took 147-383 s
    on the 2-core reference machine, 1000 took 182-216 s, 500 took 121 s of a CI run that a
    slow hour of the host brought within 93 s of its 30 minutes on 2026-11-28; 300 of them
    again, the fast suite's 100 among them, 75-97 s, and on 2026-11-29 a slow day took CI
    past its 30 minutes with them; docs/measurements/ has the dated runs)."""
    import subprocess
    import sys

    env = os.environ | {"CTRLUNIT_CLI_EXAMPLES": str(SLOW_EXAMPLES),
                        "CTRLUNIT_CLI_SEED": str(SLOW_SEED)}
    res = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider",
                          f"--hypothesis-seed={SLOW_SEED}", "-m", "not slow", __file__],
                         env=env, timeout=3600, capture_output=True, text=True)
    assert res.returncode == 0, res.stdout[-4000:]
