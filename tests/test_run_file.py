"""Profiles, the run file and --set (runtime/config/run_file.py): each layer over the one
before, the flags given over all of them; ``ctrlunit config`` prints what they resolve
to and ``start --config`` reads it back."""

from __future__ import annotations

import pytest
from click.testing import CliRunner
from ctrlunit.runtime.cli import cli
from ctrlunit.runtime.config import ConfigError, RunConfig
from ctrlunit.runtime.config.run_file import PROFILES, parse_set, read_run_file, to_toml
from ctrlunit.runtime.config.spellings import to_fields


def config(*args: str) -> str:
    res = CliRunner().invoke(cli, ["config", *args])
    assert res.exit_code == 0, res.output
    return res.output


def resolved(*args: str) -> RunConfig:
    """What ``ctrlunit config ARGS`` prints, read back."""
    import tempfile

    with tempfile.NamedTemporaryFile("w", suffix=".toml", delete=False) as fh:
        fh.write(config(*args))
    return RunConfig.of(**to_fields(read_run_file(fh.name)))


def test_the_defaults_are_the_main_job():
    rc = resolved()
    assert (rc.schedule.clock, rc.schedule.period_auto, rc.schedule.placement_auto) == (
        "realtime", True, True)
    assert rc.control.model_state == "auto" and rc.transport.unit != ""


def test_each_layer_overrides_the_one_before_and_the_flags_given_override_all(tmp_path):
    run = tmp_path / "run.toml"
    run.write_text('[control]\nobserver = "predict"\n[schedule]\npipeline = 2\n'
                   'late_policy = "wait"\nfault_periods = 4\n')
    rc = resolved("--profile", "thesis")
    assert (rc.control.model_state, rc.control.observer, rc.schedule.placement_auto) == (
        "sample", "previous", False)
    rc = resolved("--profile", "thesis", "--config", str(run))
    assert rc.control.observer == "predict" and rc.control.model_state == "sample"
    assert (rc.schedule.pipeline, rc.schedule.late_policy) == (2, "wait")
    rc = resolved("--profile", "thesis", "--config", str(run), "--set",
                  "schedule.fault_periods=6", "--set", "schedule.late_policy=hold")
    assert (rc.schedule.fault_periods, rc.schedule.late_policy) == (6.0, "hold")
    rc = resolved("--config", str(run), "--set", "schedule.pipeline=1", "--pipeline", "2",
                  "--placement", "axes", "--late-policy", "fault")
    assert rc.schedule.pipeline == 2 and rc.schedule.late_policy == "fault"
    rc = resolved("--profile", "thesis", "--placement", "auto")  # a flag equal to default
    assert rc.schedule.placement_auto is True


def test_a_resolved_file_runs_as_asked(tmp_path):
    run = tmp_path / "resolved.toml"
    run.write_text(config("--profile", "thesis", "--clock", "lockstep", "--pipeline", "2"))
    assert "# unit =" in run.read_text()  # a fresh id per run, not pinned by the file
    res = CliRunner().invoke(cli, ["start", "--check", "--json", "--config", str(run)])
    assert res.exit_code == 0, res.output
    assert '"pipeline": 2' in res.output and '"clock": "lockstep"' in res.output
    assert '"placement_auto": false' in res.output


@pytest.mark.parametrize("item, message", [
    ("pipeline=2", "expected SECTION.KEY=VALUE"),
    ("schedule.nope=1", "[schedule] has no 'nope'"),
    ("sched.pipeline=1", "no section [sched]"),
    ("schedule.pipeline=two", "--set schedule.pipeline = 'two': allowed 1 or 2"),
    ("schedule.late_policy=waitt",
     "--set schedule.late_policy = 'waitt': allowed wait, compute, hold, fault"),
    ("schedule.period=2 ms!", "--set schedule.period = '2 ms!': allowed auto, or 20us to 1s"),
    ("schedule.period_auto=false", "period_auto is the run's own state, not a setting; give "
     "period"),
    ("schedule.admission=1", "allowed true or false"),
])
def test_a_bad_setting_is_refused_by_name(item, message):
    with pytest.raises(ConfigError, match=message.replace("[", r"\[").replace("]", r"\]")):
        parse_set([item])


def test_set_reads_toml_values_and_bare_words():
    assert parse_set(["schedule.late_policy=wait", "schedule.fault_periods=2.5",
                      "schedule.admission=false", "transport.listen=[\"tcp/127.0.0.1:1\"]",
                      'schedule.late={ik="hold"}']) == {
        "late_policy": "wait", "fault_periods": 2.5, "admission": False,
        "listen": ["tcp/127.0.0.1:1"], "late": {"ik": "hold"}}


def test_a_bad_run_file_names_the_file_and_the_key(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text("[schedule]\npipeline = \n")
    with pytest.raises(ConfigError, match="--config .*bad.toml"):
        read_run_file(str(bad))
    bad.write_text('[schedule]\nlate_policy = 3\n')
    with pytest.raises(ConfigError, match=r"\[schedule\] late_policy = 3: allowed wait, "):
        read_run_file(str(bad))
    bad.write_text('pipeline = 2\n')
    with pytest.raises(ConfigError, match="must be a section"):
        read_run_file(str(bad))
    res = CliRunner().invoke(cli, ["start", "--check", "--config", str(tmp_path / "none")])
    assert res.exit_code == 1


def test_to_toml_writes_every_section_and_reads_back():
    import tomllib

    rc = RunConfig.of(pipeline=2, late={"ik": "hold"}, listen=["tcp/127.0.0.1:9"])
    data = tomllib.loads(to_toml(rc.to_dict()))
    assert list(data) == ["control", "schedule", "plant", "transport", "run"]
    back = {k: v for k, v in rc.to_dict().items() if v is not None}
    assert RunConfig.of(**to_fields(read_back(data))).to_dict() == RunConfig.of(**back).to_dict()
    assert set(PROFILES) == {"main-job", "thesis"}


def read_back(data: dict) -> dict:
    from ctrlunit.runtime.config import FLAT

    by_field = {v: k for k, v in FLAT.items()}
    return {by_field[(sec, k)]: v for sec, table in data.items() for k, v in table.items()}


@pytest.mark.parametrize("command", ["start", "config"])
def test_a_refusal_of_settings_together_says_where_a_setting_came_from(tmp_path, command):
    """A check across settings names the flag (``--balance live: not with --clock
    realtime``); where the run file or ``--set`` gave it, it says so, and the flag given
    on the command line is named as it is."""
    run_file = tmp_path / "run.toml"
    run_file.write_text('[schedule]\nbalance = "live"\n')

    def refused(*args: str) -> str:
        res = CliRunner().invoke(cli, [command, *args])
        assert res.exit_code == 1, res.output
        return res.output.strip().splitlines()[-1]

    said = refused("--config", str(run_file))
    assert said.startswith("ctrlunit: error: --balance live: not with --clock realtime")
    assert said.endswith(f"(--balance given as schedule.balance by --config {run_file})")
    assert refused("--set", "schedule.balance=live").endswith(
        "(--balance given as schedule.balance by --set)")
    assert refused("--config", str(run_file), "--balance", "live").endswith(
        "allowed with --clock freerun or lockstep")


@pytest.mark.parametrize(("line", "hint"), [
    ("clock = lockstep", 'text goes in quotes: clock = "lockstep"'),
    ("period = 2ms", 'text goes in quotes: period = "2ms"'),
    ("pipeline = [", None),
])
def test_a_run_file_that_is_no_toml_names_the_line_and_how_to_quote_text(tmp_path, line, hint):
    path = tmp_path / "run.toml"
    path.write_text(f"[schedule]\n{line}\n")
    with pytest.raises(ConfigError) as err:
        read_run_file(str(path))
    said = str(err.value)
    assert said.startswith(f"--config {path}: ")
    assert (said.endswith(hint) and "line 2" in said) if hint else "quotes" not in said


@pytest.mark.parametrize(("text", "said"), [
    ('clock = "lockstep"\n', "'clock' must be a section ([clock]) holding keys; clock is a key "
     "of [schedule]"),
    ('[control]\nclock = "lockstep"\n', "; clock is a key of [schedule]"),
    ('[control]\nbalanc = "live"\n', "params, task)"),  # no setting's name: nothing more
])
def test_a_key_in_the_wrong_place_names_its_section(tmp_path, text, said):
    path = tmp_path / "run.toml"
    path.write_text(text)
    with pytest.raises(ConfigError) as err:
        read_run_file(str(path))
    assert str(err.value).endswith(said), str(err.value)


def test_a_period_without_a_unit_says_it_was_read_as_seconds(tmp_path):
    """``period = 2`` (meant as 2 ms) is 2 s, out of range: the refusal says so, in the
    run file, ``--set`` and the flag alike; in range, or with a unit, nothing is added."""
    path = tmp_path / "run.toml"
    path.write_text("[schedule]\nperiod = 2\n")
    with pytest.raises(ConfigError) as err:
        read_run_file(str(path))
    assert str(err.value).endswith('2 was read as 2 s (milliseconds: "2ms")'), str(err.value)
    with pytest.raises(ConfigError, match=r'500 was read as 500 s \(milliseconds: "500ms"\)'):
        parse_set(["schedule.period=500"])
    res = CliRunner().invoke(cli, ["start", "--check", "--period", "3"])
    assert res.exit_code == 1 and 'read as 3 s (milliseconds: "3ms")' in res.output, res.output
    for item in ("schedule.period=2s", "schedule.period=1e-6"):
        with pytest.raises(ConfigError) as err:
            parse_set([item])
        assert "without a unit" not in str(err.value)
    assert parse_set(["schedule.period=0.002"]) == {"period": 0.002}


def test_one_run_length_counts_the_one_given_last(tmp_path):
    """``--cycles`` and ``--duration`` are one setting given two ways: both in one layer
    are refused, naming them; a flag's replaces a run file's, whichever it is."""
    run = tmp_path / "run.toml"
    run.write_text('[run]\nduration = "5s"\n')

    def check(*args: str) -> tuple[int, str]:
        res = CliRunner().invoke(cli, ["start", "--check", "--json", *args])
        return res.exit_code, res.output

    code, out = check("--clock", "lockstep", "--cycles", "100", "--duration", "5s")
    assert code == 1 and "--cycles and --duration: give one" in out, out
    code, out = check("--config", str(run), "--cycles", "100")
    assert code == 0 and '"cycles": 100, "duration": null' in out, out
    code, out = check("--config", str(run), "--set", "run.cycles=7")
    assert code == 0 and '"cycles": 7, "duration": null' in out, out
    code, out = check("--config", str(run))
    assert code == 0 and '"cycles": null, "duration": 5.0' in out, out
    run.write_text('[run]\nduration = "5s"\ncycles = 7\n')
    code, out = check("--config", str(run))
    assert code == 1 and "give one" in out and f"by --config {run}" in out, out
