"""What the commands leave behind and say where: no file written that was not asked for,
a faulted run's kept folder named, the exit code of each class of error the same for
every command, warnings on stderr, the command balance's prediction assumes, and the
profile ``main-job`` equal to README's main job (docs/faults-and-errors.md)."""

from __future__ import annotations

import json
import os
import re
import shlex
import shutil
import signal
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
from click.testing import CliRunner, Result
from ctrlunit.runtime.cli import cli
from ctrlunit.runtime.config import RunConfig
from ctrlunit.runtime.config.run_file import read_run_file
from runner import kill_unit, pids_of, unit_id, wait_status

README = Path(__file__).resolve().parent.parent / "README.md"


def invoke(*args: str) -> Result:
    return CliRunner().invoke(cli, list(args), prog_name="ctrlunit", catch_exceptions=True)


def listing(d: Path) -> list[str]:
    return sorted(str(p.relative_to(d)) for p in d.rglob("*"))


def run_in(cwd: Path, tmpdir: Path, *args: str, timeout: float = 120
           ) -> subprocess.CompletedProcess:
    """``ctrlunit ARGS`` in ``cwd``, its temporary files under ``tmpdir``."""
    env = os.environ | {"TMPDIR": str(tmpdir)}
    return subprocess.run([sys.executable, "-m", "ctrlunit.runtime.cli", *args], cwd=cwd,
                          env=env, capture_output=True, text=True, timeout=timeout)


@pytest.fixture(scope="module")
def made(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """A 40-interval lockstep run started in an empty folder, recorded and reported
    elsewhere: what it left in that folder and in its temporary directory."""
    root = tmp_path_factory.mktemp("outputs")
    cwd, tmp, out = root / "cwd", root / "t", root / "out"
    for d in (cwd, tmp, out):
        d.mkdir()
    unit = unit_id("outputs")
    try:
        res = run_in(cwd, tmp, "start", "--unit", unit, "--clock", "lockstep",
                     "--peripherals", "1", "--cycles", "40", "--record", str(out / "run.mcap"),
                     "--report", str(out / "run.json"))
    finally:
        kill_unit(unit)
    assert res.returncode == 0, res.stderr
    return {"cwd": listing(cwd), "tmp": listing(tmp), "stderr": res.stderr,
            "record": out / "run.mcap", "report": out / "run.json"}


def test_a_run_leaves_only_the_files_asked_for(made):
    assert made["cwd"] == [] and made["tmp"] == [], made
    assert "logs are kept" not in made["stderr"]


def test_no_command_writes_a_file_it_was_not_asked_for(made, tmp_path, monkeypatch):
    """Each command run in an empty folder (the commands that write by README's word,
    ``plot`` and ``bench``'s runs, aside) leaves it empty."""
    cwd = tmp_path / "cwd"
    cwd.mkdir()
    monkeypatch.chdir(cwd)
    rec, rep = str(made["record"]), str(made["report"])
    for args in (["ik", "0", "0", "-0.35"], ["ik", "0", "0", "0.35", "--json"],
                 ["fk", "0", "0", "0"], ["trajectory", "pick-place"],
                 ["workspace", "--grid", "11"], ["config"], ["start", "--check"],
                 ["start", "--profile", "main-job", "--check", "--json"],
                 ["bench", "--check", "--stages", "floor"], ["bench", "--check", "--quick"],
                 ["latency", "--period", "1ms", "--duration", "20ms", "--rt-priority", "0",
                  "--idle", "default"],
                 ["balance", rep], ["balance", rec, "--json"],
                 ["replay", rec, "--verify"], ["report", rec]):
        res = invoke(*args)
        assert res.exit_code == 0, (args, res.output)
        assert listing(cwd) == [], (args, listing(cwd))


def test_balance_of_a_lockstep_run_warns_that_its_prediction_does_not_hold(made):
    """The plant's simulation paces a lockstep interval; the model takes that pace for the
    exchanges (a new user's: 97 us predicted with fewer exchanges, 1072 us measured)."""
    res = invoke("balance", str(made["report"]))
    assert res.exit_code == 0 and "is a lockstep run" in res.stderr, res.stderr
    assert "balance a freerun or realtime run" in res.stderr
    res = invoke("balance", str(made["report"]), "--json")  # stdout stays the answer alone
    assert json.loads(res.stdout)["run"]["clock"] == "lockstep" and "lockstep run" in res.stderr


def test_a_faulted_run_names_the_folder_it_keeps(tmp_path):
    """A peripheral killed mid-run under ``--peripheral-loss fault``: exit 3, and the
    run's folder (spec, the roles' logs), the only thing left in the temporary directory,
    is named in the summary, on stderr after it and in the report; the logs say what each
    role saw (runtime/roles/rolelog.py)."""
    cwd, tmp = tmp_path / "cwd", tmp_path / "t"
    cwd.mkdir()
    tmp.mkdir()
    unit = unit_id("kept")
    status, report = tmp_path / "status", tmp_path / "run.json"
    proc = subprocess.Popen(
        [sys.executable, "-m", "ctrlunit.runtime.cli", "start", "--unit", unit, "--clock",
         "lockstep", "--peripherals", "1", "--cycles", "1000000", "--timeout", "300ms",
         "--peripheral-loss", "fault", "--status-file", str(status), "--report", str(report)],
        cwd=cwd, env=os.environ | {"TMPDIR": str(tmp)}, stdout=subprocess.PIPE,
        stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        assert wait_status(status, 20) >= 20
        for pid in pids_of(unit):
            cmd = Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()
            if " peripheral " in cmd:
                os.kill(pid, signal.SIGKILL)
        out, err = proc.communicate(timeout=30)
    finally:
        kill_unit(unit)
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 3, err
    kept = [tmp / name for name in os.listdir(tmp)]
    try:
        assert len(kept) == 1 and kept[0].name.startswith("ctrlunit-"), kept
        assert err.splitlines()[-1] == f"ctrlunit: the roles' logs are kept in {kept[0]}"
        assert json.loads(report.read_text())["logs_kept"] == str(kept[0])
        # each role's log says what it saw: the killed peripheral got its go, and the
        # plant ended with its final report
        killed = (kept[0] / "peripheral-1.log").read_text()
        assert "peripheral-1[" in killed and ": go" in killed, killed
        plant = (kept[0] / "plant.log").read_text().splitlines()
        assert plant and ": ended (stop): {" in plant[-1], plant
        assert listing(cwd) == [] and out.strip()
        assert any(line.startswith(f"  logs        kept in {kept[0]} (")
                   for line in out.splitlines())  # the summary names it too
    finally:
        for d in kept:
            shutil.rmtree(d, ignore_errors=True)


# -- exit codes by class ------------------------------------------------------------------

def missing_files(d: Path, existing: str) -> list[list[str]]:
    """Commands naming a file that does not exist, or a folder where a file is wanted."""
    nope = str(d / "nosuch")
    return [["replay", nope + ".mcap"], ["replay", nope + ".mcap", "--verify"],
            ["report", nope + ".mcap"], ["plot", nope + ".mcap"], ["report", str(d)],
            ["balance", nope + ".json"], ["balance", existing, "--compare", nope + ".json"],
            ["trajectory", nope + ".json"], ["ik", "0", "0", "-0.35", "--params", nope],
            ["fk", "0", "0", "0", "--params", str(d)],
            ["start", "--check", "--placement", nope + ".json"],
            ["start", "--check", "--task", nope + ".json"],
            ["start", "--check", "--params", nope + ".toml"],
            ["start", "--check", "--config", nope + ".toml"],
            ["start", "--check", "--zenoh-config", nope + ".json5"],
            ["start", "--check", "--record", str(d)],
            ["central", "--check", "--listen", "tcp/127.0.0.1:0", "--placement", nope],
            ["peripheral", "--check", "--index", "1", "--params", nope],
            ["latency", "--plot", str(d)], ["workspace", "--png", str(d)]]


def test_a_missing_file_is_an_input_error_for_every_command(tmp_path):
    existing = tmp_path / "exists.json"
    existing.write_text("{}")
    for args in missing_files(tmp_path, str(existing)):
        res = invoke(*args)
        err = res.stderr.strip().splitlines()
        assert res.exit_code == 1, (args, res.exit_code, res.stderr)
        assert len(err) == 1 and err[0].startswith("ctrlunit: error: "), (args, res.stderr)
        assert "nosuch" in err[0] or str(tmp_path) in err[0], (args, err)  # names the file
    err = invoke("start", "--check", "--task", str(tmp_path / "nosuch.json")).stderr
    assert "--task: no such file" in err, err  # named as the user gives it


def test_an_output_file_that_cannot_be_written_is_refused_before_the_run(tmp_path):
    """``--report`` or ``--record`` in a directory that does not exist, or under a file:
    refused before anything starts, ``--check`` too (a new user's run went to its end,
    then ended in a traceback and printed no summary)."""
    a_file = tmp_path / "afile"
    a_file.write_text("")
    dangling = tmp_path / "link.json"  # an attacker's review: the run wrote its target
    dangling.symlink_to(tmp_path / "elsewhere.json")
    for option, path, why in (("--report", tmp_path / "nosuch" / "r.json", "does not exist"),
                              ("--record", a_file / "x.mcap", "is not a directory"),
                              ("--record", tmp_path / "nosuch" / "x.mcap", "does not exist"),
                              ("--report", Path(os.devnull), "is not a regular file"),
                              ("--record", Path("/proc/version"), "is a kernel interface file"),
                              ("--report", dangling, "is a symbolic link to")):
        for check in (["--check"], ["--clock", "lockstep", "--cycles", "10"]):
            res = invoke("start", *check, option, str(path))
            err = res.stderr.strip().splitlines()
            assert res.exit_code == 1 and len(err) == 1, (option, res.stderr)
            assert err[0].startswith(f"ctrlunit: error: {option}: ") and why in err[0], err
            assert str(path) in err[0], err
            assert not res.stdout.strip(), res.stdout  # nothing ran
    assert not (tmp_path / "elsewhere.json").exists()


@pytest.mark.parametrize("command", sorted(cli.commands))
def test_a_command_line_that_does_not_parse_is_a_usage_error(command):
    args = [command, "init"] if command == "keys" else [command]
    res = invoke(*args, "--no-such-option")
    if command in ("fk", "ik"):  # they take -0.35 as a number: here a value refused, exit 1
        assert res.exit_code == 1 and "'--no-such-option' is not a valid float" in res.stderr
        return
    assert res.exit_code == 2, (command, res.output)
    assert res.stderr.strip().splitlines()[-1].startswith("Error: ")


def test_warnings_go_to_stderr():
    """A point outside the usable workspace has angles (exit 0); the warning is not part
    of the answer."""
    res = invoke("ik", "0", "0", "0.35")
    assert res.exit_code == 0
    assert re.fullmatch(r"q = \[[^\]]+\] rad\n", res.stdout), res.stdout
    assert res.stderr.startswith("ctrlunit: warning: ") and "beta_min" in res.stderr
    res = invoke("ik", "0", "0", "0.35", "--json")
    assert json.loads(res.stdout)["usable"] is False
    assert invoke("ik", "0", "0", "-0.35").stderr == ""


# -- names ----------------------------------------------------------------------------------

VARIANTS = {  # a change to the recorded run's report: the run balance reads
    "as recorded": {},
    "freerun at depth 2": {"clock": "freerun", "pipeline": 2},
    "realtime at 2 ms": {"clock": "realtime", "pipeline": 2, "nominal_period_s": 0.002},
    "t800, replies and rounds asked": {"cost_model": "t800", "cost_scale": 60.0,
                                       "replies": {"asked": "each", "mode": "each"},
                                       "hold_rounds": {"asked": "never", "held": False},
                                       "cycles": 500},
    "the circle": {"task": "circle"},
}


@pytest.mark.parametrize("change", VARIANTS.values(), ids=list(VARIANTS))
def test_balance_prints_the_command_its_prediction_assumes(made, tmp_path, change):
    """The command balance prints resolves to the run its model was calibrated on, with
    the placement it wrote: every setting the prediction depends on."""
    src = json.loads(made["report"].read_text()) | change
    f, placement = tmp_path / "run.json", tmp_path / "placement.json"
    f.write_text(json.dumps(src))
    res = invoke("balance", str(f), "--write", str(placement), "--json")
    assert res.exit_code == 0, res.output
    a = json.loads(res.stdout)
    text = invoke("balance", str(f), "--write", str(placement)).stdout
    assert a["command"] in text and a["written"] == str(placement)
    words = shlex.split(a["command"])
    assert words[:2] == ["ctrlunit", "start"]
    toml = tmp_path / "resolved.toml"
    resolved = invoke("config", *words[2:])
    assert resolved.exit_code == 0, resolved.output
    toml.write_text(resolved.stdout)
    rc = RunConfig.of(**read_run_file(str(toml)))
    s, c = rc.schedule, rc.control
    # the model plays free-running intervals: a realtime run's prediction is freerun's
    clock = "freerun" if src["clock"] == "realtime" else src["clock"]
    assert (s.clock, s.pipeline, s.placement, s.placement_auto) == (
        clock, src["pipeline"], str(placement), False)
    if s.clock != "freerun":
        assert s.period == src["nominal_period_s"] and not s.period_auto
    assert (c.law, c.model, c.observer, rc.resolved_model_state) == (
        src["law"], src["model"], src["observer"], src["model_state"])
    assert (c.cost_model, c.cost_scale) == (src["cost_model"], src["cost_scale"])
    asked = {k: (src.get(k) or {}).get("asked", "auto") for k in ("replies", "hold_rounds")}
    assert (s.replies, s.hold_rounds) == (asked["replies"], asked["hold_rounds"])
    assert rc.run.cycles == src["cycles"]
    assert c.task == src["task"]
    assert json.loads(placement.read_text())["peripherals"] == a["placement"]["peripherals"]


def test_balance_of_a_realtime_run_calibrates_on_its_traversal_and_predicts_freerun(
        made, tmp_path):
    """A new user's: balance of a realtime run at 2.5 ms predicted 712 us, and its command
    re-ran at the clock's 2.5 ms (measured 2519 us, '+253.6 %'). The clock pads a realtime
    period, so the model is fitted to the traversal (one interval alone), and the period
    it predicts is measured free-running; a realtime re-run is refused by name."""
    src = json.loads(made["report"].read_text()) | {"clock": "realtime",
                                                    "nominal_period_s": 0.0025}
    f = tmp_path / "run.json"
    f.write_text(json.dumps(src))
    res = invoke("balance", str(f), "--json")
    assert res.exit_code == 0, res.output
    a = json.loads(res.stdout)
    assert "is a realtime run" in res.stderr and "--clock freerun" in res.stderr
    assert "traversal" in a["model_costs_s"]["latency_is"]
    assert "--clock freerun" in a["command"] and "--period" not in a["command"]
    lock = invoke("balance", str(made["report"]), "--json")  # the same costs, not paced
    assert json.loads(lock.stdout)["model_costs_s"]["latency_is"] == \
        "fitted to the run's mean period"
    placement = tmp_path / "p.json"
    invoke("balance", str(f), "--write", str(placement))
    rerun = tmp_path / "rerun.json"
    rerun.write_text(json.dumps(src | {"placement": a["placement"]}))
    res = invoke("balance", str(f), "--compare", str(rerun))
    assert res.exit_code == 1 and "whose period is its clock's" in res.stderr, res.output


def test_balance_names_the_cpu_floor_under_a_prediction_below_it(made, tmp_path):
    """A new user's: balance predicted a period below the CPU floor it printed, and said
    nothing of it. It says so now, without promising the floor: the floor is the source
    run's CPU, and a re-run with the new placement measured a mean period below it."""
    src = json.loads(made["report"].read_text())
    a = json.loads(invoke("balance", str(made["report"]), "--json").stdout)
    predicted = a["predicted"][f"depth{a['pipeline']}"]["period_s"]
    for floor, said in ((3 * predicted, True), (predicted / 3, False)):
        f = tmp_path / "run.json"
        f.write_text(json.dumps(src | {"cpu_per_interval_s": {"total": 2 * floor,
                                                              "central": floor},
                                       "cpu_cores": 2, "cpu_bound_period_s": floor}))
        res = invoke("balance", str(f))
        assert res.exit_code == 0, res.output
        line = f"below this run's CPU floor ({floor * 1e6:.0f} us on 2 core(s))"
        assert (line in res.stdout) == said, res.stdout


def test_balance_without_write_says_it_wrote_nothing(made, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    res = invoke("balance", str(made["report"]))
    assert res.exit_code == 0 and "not written (--write FILE writes it)" in res.stdout
    assert "--placement FILE" in res.stdout and listing(tmp_path) == []


def readme_main_job() -> list[str]:
    """The options of README's first command, the main job."""
    m = re.search(r"&& ctrlunit start ([^\n`]*)\n", README.read_text())
    assert m, "README's set-up runs the main job"
    return m[1].split()


def test_the_main_job_profile_is_readmes_main_job():
    main = readme_main_job()
    assert "--pipeline" in main
    for check in (["--check", "--unit", "u1"], ["--check", "--json", "--unit", "u1"]):
        profiled = invoke("start", "--profile", "main-job", *check)
        assert profiled.exit_code == 0, profiled.output
        assert profiled.stdout == invoke("start", *main, *check).stdout
    assert invoke("config", "--profile", "main-job").stdout == invoke("config", *main).stdout
    assert "pipeline depth 2" in invoke("start", "--profile", "main-job", "--check").stdout


def test_stderr_names_what_was_refused_and_what_to_try():
    """stdout may go to a file: a refusal's stderr line says what was refused and what to
    try; a fault's names the process and what happened (its whole message with
    ``--json``); a stop the
    user asked for is no fault."""
    from ctrlunit.runtime.cli.base import exit_line as _exit_line

    refusal = {"process": "admission", "message": "the period of 0.5 ms cannot be held here: "
               "in a trial of 300 intervals ... Try --period auto; or --period 2.5ms.",
               "headline": "the period of 0.5 ms cannot be held here",
               "advice": "Try --period auto; or --period 2.5ms."}
    line = _exit_line(refusal, 7, as_json=False)
    assert line == ("ctrlunit: refused before any motion: the period of 0.5 ms cannot be "
                    "held here (exit 7). Try --period auto; or --period 2.5ms."), line
    assert "in a trial of" not in line  # the figures are the summary's
    assert _exit_line(refusal, 7, as_json=True).endswith("--period 2.5ms. (exit 7)")
    fault = {"process": "central", "message": "cycle 9: tracking error 21 mm; 55 commands "
             "missed their deadline"}
    assert _exit_line(fault, 5, as_json=False) == \
        "ctrlunit: fault in central: cycle 9: tracking error 21 mm (exit 5)"  # a new user's
    assert "55 commands" in _exit_line(fault, 5, as_json=True)
    assert _exit_line({"process": "plant"}, 4, as_json=False) == "ctrlunit: fault in plant (exit 4)"
    assert _exit_line({"process": "user", "message": "interrupted (Ctrl-C)"}, 130,
                      as_json=False).startswith("ctrlunit: stopped on request")


def test_a_file_the_system_refuses_is_one_line_for_every_command(tmp_path):
    """An attacker's review: ``plot --out``, ``replay --csv`` and ``export --rosbag2``
    under a path the system refuses ended in a traceback. Any such refusal is one line
    naming the path, exit 1."""
    a_file = tmp_path / "afile"
    a_file.write_text("")
    rec = tmp_path / "run.mcap"
    assert invoke("start", "--clock", "lockstep", "--cycles", "30", "--peripherals", "0",
                  "--record", str(rec)).exit_code == 0
    for args in (("plot", str(rec), "--out", str(a_file / "plots")),
                 ("replay", str(rec), "--csv", str(a_file / "csv")),
                 ("export", str(rec), "--rosbag2", str(a_file / "bag"))):
        res = invoke(*args)
        err = res.stderr.strip().splitlines()
        assert res.exit_code == 1 and len(err) == 1, (args, res.stderr)
        assert err[0].startswith("ctrlunit: error: ") and str(a_file) in err[0], err


def test_nan_and_a_device_are_refused_where_a_range_or_a_file_is_asked(tmp_path):
    """An attacker's review: ``replay --rate nan`` replayed unpaced and ``--wait-subscribers
    nan`` was taken (NaN compares with no bound); ``start --check --config /dev/zero``
    never returned. Each is one line, exit 1."""
    rec = tmp_path / "run.mcap"
    assert invoke("start", "--clock", "lockstep", "--cycles", "20", "--peripherals", "0",
                  "--record", str(rec)).exit_code == 0
    for args, said in ((("replay", str(rec), "--rate", "nan"), "'nan' is not a number"),
                       (("replay", str(rec), "--wait-subscribers", "nan"),
                        "'nan' is not a number"),
                       (("start", "--check", "--config", "/dev/zero"), "not a regular file")):
        res = invoke(*args)
        err = res.stderr.strip().splitlines()
        assert res.exit_code == 1 and len(err) == 1 and said in err[0], (args, res.stderr)


def test_replay_verify_with_csv_makes_both(tmp_path):
    """An attacker's review: ``replay --verify --csv DIR`` verified and ignored ``--csv``
    without a word. Each output asked for is made."""
    rec = tmp_path / "run.mcap"
    assert invoke("start", "--clock", "lockstep", "--cycles", "30", "--peripherals", "0",
                  "--record", str(rec)).exit_code == 0
    res = invoke("replay", str(rec), "--verify", "--csv", str(tmp_path / "csv"))
    assert res.exit_code == 0, res.output
    assert "verified 30 intervals" in res.stdout and "wrote " in res.stdout, res.stdout
    assert any((tmp_path / "csv").iterdir())


def test_an_output_through_a_link_to_nothing_is_refused(made, tmp_path):
    """An attacker's review: ``report --report LINK`` wrote the file LINK pointed to,
    wherever that was. Any output path that is a link to nothing is refused by name."""
    link = tmp_path / "out.json"
    link.symlink_to(tmp_path / "target.json")
    for args in (("report", str(made["record"]), "--report", str(link)),
                 ("balance", str(made["report"]), "--write", str(link))):
        res = invoke(*args)
        assert res.exit_code == 1 and "is a symbolic link to" in res.stderr, (args, res.output)
    assert not (tmp_path / "target.json").exists()


def test_replay_verify_of_no_interval_fails_and_a_range_past_the_recording_is_said(
        made, tmp_path):
    """A new user's: a run stopped during its admission left a recording that ``replay
    --verify`` passed ("verified 0 intervals"), and ``--cycles 100:500`` over intervals
    0 to 395 was cut to what the file held without a word."""
    from mcap.reader import make_reader
    from mcap.writer import Writer

    empty = tmp_path / "empty.mcap"
    with open(made["record"], "rb") as src, open(empty, "wb") as dst:
        r, w = make_reader(src), Writer(dst)
        w.start(profile="ros2", library="a run stopped before its first interval")
        for m in r.iter_metadata():
            w.add_metadata(m.name, dict(m.metadata))
        w.finish()
    res = invoke("replay", str(empty), "--verify")
    assert res.exit_code == 1 and "no interval to verify" in res.stderr, res.output
    res = invoke("replay", str(made["record"]), "--verify", "--cycles", "5:100000000")
    assert res.exit_code == 0 and "reaches past the recording" in res.stderr, res.output
    res = invoke("plot", str(made["record"]), "--out", str(tmp_path / "p"), "--cycles",
                 "5:100000000")
    assert res.exit_code == 0 and "reaches past the recording" in res.stderr, res.output
    res = invoke("replay", str(made["record"]), "--verify", "--cycles", "5:10")
    assert res.exit_code == 0 and "reaches past" not in res.stderr, res.output


def test_listen_on_a_path_that_holds_something_is_refused(tmp_path):
    """An attacker's review: ``--listen unixsock-stream//DIR/notes`` deleted ``notes`` (Zenoh
    removes what is at the path before it binds), and took another program's live socket
    away. A socket left behind, which nobody answers on, may go."""
    import socket

    folder = tmp_path / "own"
    folder.mkdir(mode=0o700)
    notes = folder / "notes.txt"
    notes.write_text("precious")
    live = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    live.bind(str(folder / "live.sock"))
    live.listen(1)
    stale = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    stale.bind(str(folder / "stale.sock"))
    stale.close()  # left behind: nobody answers
    try:
        for name, why in (("notes.txt", "exists and is not a socket"),
                          ("live.sock", "another program listens")):
            res = invoke("start", "--check", "--clock", "lockstep", "--listen",
                         f"unixsock-stream/{folder / name}")
            assert res.exit_code == 1 and why in res.stderr, (name, res.output)
        res = invoke("start", "--check", "--clock", "lockstep", "--listen",
                     f"unixsock-stream/{folder / 'stale.sock'}")
        assert res.exit_code == 0, res.output
    finally:
        live.close()
    assert notes.read_text() == "precious"


def test_a_live_view_other_hosts_reach_needs_insecure():
    """An attacker's review: ``--foxglove 0.0.0.0:PORT`` served the samples, commands and
    positions on every interface with no key, where the link rule refuses any other
    endpoint beyond the host."""
    for host in ("0.0.0.0:0", "[::]:0"):
        res = invoke("start", "--check", "--clock", "lockstep", "--foxglove", host)
        assert res.exit_code == 1 and "--insecure" in res.stderr, (host, res.output)
        res = invoke("start", "--check", "--clock", "lockstep", "--foxglove", host,
                     "--insecure")
        assert res.exit_code == 0, (host, res.output)
    for host in ("127.0.0.1:0", "8765", "[::1]:0"):
        assert invoke("start", "--check", "--clock", "lockstep", "--foxglove",
                      host).exit_code == 0, host


def test_one_path_for_two_outputs_or_for_the_input_is_refused(made, tmp_path):
    """An attacker's review: ``--record F --report F`` left the report where the recording
    was, and ``report R --report R`` overwrote the recording it read."""
    same = tmp_path / "same.out"
    res = invoke("start", "--check", "--clock", "lockstep", "--record", str(same),
                 "--report", str(same))
    assert res.exit_code == 1 and "--record and --report: both are" in res.stderr, res.output
    copy = tmp_path / "copy.mcap"
    copy.write_bytes(made["record"].read_bytes())
    res = invoke("report", str(copy), "--report", str(copy))
    assert res.exit_code == 1 and "it is the recording read" in res.stderr, res.output
    assert copy.read_bytes() == made["record"].read_bytes()


def test_a_task_whose_loop_never_ends_is_refused(tmp_path):
    """An attacker's review: an acceleration of 1e-300 (inside its range) planned 1e153
    intervals, and the run never ended on its own."""
    task = tmp_path / "tiny.json"
    task.write_text(json.dumps({"name": "tiny", "dwell": 0.05, "segments": [
        {"type": "half-ellipse", "start": [0.125, 0.0, -0.35], "top": [0.0, 0.0, -0.31],
         "end": [-0.125, 0.0, -0.35], "accel": 1e-300}]}))
    res = invoke("start", "--check", "--clock", "lockstep", "--task", str(task))
    assert res.exit_code == 1 and "allowed at most 1e9" in res.stderr, res.output
    assert invoke("start", "--check", "--clock", "lockstep", "--task", str(task),
                  "--cycles", "100").exit_code == 0
