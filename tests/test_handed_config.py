"""A role started by hand takes the run's configuration from the central at its handshake
(runtime/config/handed.py, runtime/central/orders.py): it needs only its unit id, where to
connect and its keys, and runs the unit's settings whatever else it was given."""

from __future__ import annotations

import json
import subprocess
import sys
from typing import Any

import msgpack
import pytest
from ctrlunit.runtime.central.fault import Fault
from ctrlunit.runtime.central.orders import HELLO_ROLES, Orders
from ctrlunit.runtime.config import ConfigError, RunConfig
from ctrlunit.runtime.config.handed import ROLE_OWN, config_message, handed
from ctrlunit.runtime.transport.codec import decode, encode
from ctrlunit.runtime.transport.node import Event
from loopback import Bus, LoopbackNode
from runner import ctrlunit, kill_unit, unit_id

CENTRAL = dict(peripherals=2, pipeline=2, clock="lockstep", law="computed-torque",
               observer="previous", plant_friction=0.5, period=2e-3, cycles=123,
               late={"ik": "hold"}, listen=["tcp/127.0.0.1:7447"], unit="u1")


def _orders(bus: Bus, rc: RunConfig, *, timeout: float = 0.3) -> Orders:
    node = LoopbackNode(bus, rc.transport.unit, "central")
    return Orders(node, peripherals=rc.schedule.peripherals, plant=True,
                  startup_timeout_s=timeout, check_children=lambda: None,
                  take_sample=lambda data, ns: None, config=config_message(rc))


def _sent(bus: Bus, unit: str, stage: str) -> list[tuple[str, dict]]:
    return [(key, decode(data, unit)) for key, data in bus.log
            if key.startswith(f"ctrlunit/{unit}/") and decode(data, unit)["stage"] == stage]


def hello(role: str) -> str:
    """``role``'s hello key in unit ``u1``."""
    return f"ctrlunit/u1/central/hello/{role}"


def said(role: str, **fields: Any) -> Event:
    """A hello-key event of ``role`` as the central's inbox gives it."""
    return Event("hello", HELLO_ROLES.index(role), encode("u1", 0, "hello", role=role, **fields),
                 0)


def _asked(*roles: str) -> tuple[RunConfig, Bus, Orders]:
    """The central's orders on a bus, and a hello asking for the configuration from each
    of ``roles`` on its own key."""
    rc = RunConfig.of(**CENTRAL)
    bus = Bus()
    orders = _orders(bus, rc)
    for role in roles:
        bus.put(hello(role), encode("u1", 0, "hello", role=role, want="config"))
    return rc, bus, orders


def test_a_role_that_asks_gets_the_configuration_and_counts_once_it_says_hello():
    rc, bus, orders = _asked("peripheral-2")
    with pytest.raises(Fault, match="no hello from"):  # asking is not its hello
        orders.handshake()
    (key, msg), = _sent(bus, "u1", "config")
    assert key == "ctrlunit/u1/peripheral/control"  # to the peripherals, not the plant
    # what the role runs: the central's settings, its own endpoints
    own = RunConfig.of(unit="u1", connect=["tcp/127.0.0.1:7447"], pipeline=1)
    got, notes = handed(msg, own, {"unit", "connect", "pipeline"})
    assert got.to_dict() == rc.replace(listen=None, connect=["tcp/127.0.0.1:7447"]).to_dict()
    assert notes == ["schedule.pipeline = 2 of the unit over 1 given"]
    assert not _sent(bus, "u1", "go")
    for role in ("plant", "peripheral-1", "peripheral-2"):
        bus.put(hello(role), encode("u1", 0, "hello", role=role))
    orders.handshake()
    assert len(_sent(bus, "u1", "go")) == 2  # to the peripherals' and the plant's key


def test_a_peripheral_the_unit_lacks_is_told_and_a_name_that_is_no_role_is_counted():
    _, bus, orders = _asked("peripheral-3", "viewer")
    with pytest.raises(Fault):
        orders.handshake()
    (_, msg), = _sent(bus, "u1", "config")  # peripheral 3 checks its index against it
    assert msg["settings"]["schedule"]["peripherals"] == 2
    assert orders.node.rejected["unexpected_key"] == 1  # a viewer has no hello key
    orders.on_hello(said("peripheral-1", want="config"))
    assert len(_sent(bus, "u1", "config")) == 1  # after the handshake: too late to join


def test_a_role_cannot_speak_for_another_on_its_hello_key():
    """A message on a role's hello key that names another role is counted and dropped: a
    peripheral's certificate once sent a ``bye`` as the plant naming a plant fault, and
    the unit stopped on it (with keys each role may publish on its own hello key alone:
    tests/test_access_policy.py)."""
    orders = _asked()[2]
    fault = {"exit": "fault", "fault": {"name": "mechanical_stop", "time": 1.234,
                                        "message": "arm 2 at its mechanical stop"}}
    forged = Event("hello", HELLO_ROLES.index("peripheral-1"),
                   encode("u1", 0, "bye", role="plant", report=fault), 0)
    orders.on_hello(forged)  # no plant fault raised
    assert orders.node.rejected["bad_value"] == 1 and "plant" not in orders.role_reports
    with pytest.raises(Fault, match="mechanical stop"):  # the plant's own, on its own key
        orders.on_hello(Event("hello", 0, encode("u1", 0, "bye", role="plant", report=fault),
                              0))


def test_a_lost_peripheral_started_again_may_join_the_running_unit():
    """Once the run has begun only a peripheral the central lost (runtime/central/
    takeover.py) gets the configuration; its hello then gets ``go`` with the blocks the
    central runs, and ``start`` (its CPU counted from then)."""
    _, bus, orders = _asked()
    for role in ("plant", "peripheral-1", "peripheral-2"):
        bus.put(hello(role), encode("u1", 0, "hello", role=role))
    orders.handshake()
    orders.central_blocks = ["ik_obs0"]
    orders.say("start")
    orders.may_join = lambda role: role == "peripheral-2"
    for role in ("peripheral-1", "peripheral-2", "plant"):
        orders.on_hello(said(role, want="config"))
    assert len(_sent(bus, "u1", "config")) == 1
    orders.on_hello(said("peripheral-2"))
    go = [m for _, m in _sent(bus, "u1", "go")][-1]
    assert go["central_blocks"] == ["ik_obs0"]
    assert [k for k, _ in _sent(bus, "u1", "start")][-1] == "ctrlunit/u1/peripheral/control"


def test_the_role_keeps_its_own_endpoints_keys_and_cpus(socket_endpoint):
    rc = RunConfig.of(**CENTRAL, keys="/central/keys", pin="0", startup_timeout=30.0)
    own = RunConfig.of(unit="u1", connect=[socket_endpoint], keys=None, pin="1",
                       insecure=True, startup_timeout=5.0, zenoh_config=None)
    got, _ = handed(config_message(rc), own, set())
    assert {f: got.option(f) for f in ROLE_OWN} == {f: own.option(f) for f in ROLE_OWN}
    assert got.replace(**{f: rc.option(f) for f in ROLE_OWN}).to_dict() == rc.to_dict()


def test_a_role_may_not_be_insecure_where_the_central_is_not(socket_endpoint):
    """A role with --insecure under a central without it would carry the control path
    over its own links (and route for a Zenoh client connected to it), where the
    central's carry the observers' keys alone (an attacker's review, 2026-11-28): refused,
    naming the option and both fixes. Without --insecure, with the socket alone, or under
    an insecure central, it runs; a message without the field (an older central) is not
    refused."""
    own = RunConfig.of(unit="u1", connect=[socket_endpoint], listen=["tcp/127.0.0.1:0"],
                       insecure=True)
    with pytest.raises(ConfigError, match=r"^--insecure: the unit's central runs without it"):
        handed(_message_through_the_codec(RunConfig.of(**CENTRAL)), own, set())
    # on the socket alone it has nothing to relay on
    handed(_message_through_the_codec(RunConfig.of(**CENTRAL)),
           own.replace(listen=None), set())
    handed(_message_through_the_codec(RunConfig.of(**CENTRAL, insecure=True)), own, set())
    handed(_message_through_the_codec(RunConfig.of(**CENTRAL)),
           own.replace(insecure=False), set())
    older = _message_through_the_codec(RunConfig.of(**CENTRAL))
    older.pop("insecure")
    handed(older, own, set())


def _message_through_codec(msg: dict) -> dict:
    return decode(encode("u1", 0, "config", **msg), "u1")


def _message_through_the_codec(rc: RunConfig) -> dict:
    return _message_through_codec(config_message(rc))


@pytest.mark.parametrize("change, error", [
    (lambda m: m.pop("settings"), "expected the sections"),
    (lambda m: m["settings"].pop("plant"), "expected the sections"),
    (lambda m: m["settings"].update(plant=[1, 2]), r"\[plant\] is not a table"),
    (lambda m: m["settings"]["plant"].update(pipeline=2), r"\[plant\] has no 'pipeline'"),
    (lambda m: m["settings"]["schedule"].update(pipeline="two"), "pipeline = 'two'"),
    (lambda m: m["settings"]["schedule"].update(pipeline=7), "pipeline"),
    (lambda m: m["settings"]["schedule"].pop("command_delay"), "missing command_delay"),
    (lambda m: m["settings"]["run"].update(report="r.json"), r"\[run\] has no 'report'"),
    (lambda m: m["settings"]["transport"].update(unit="u2"), "has no 'unit'"),
    (lambda m: m.clear() or m.update(error="why"), "cannot hand this role .*: why"),
    (lambda m: m.update(files=[1]), "'files' is not a table"),
    (lambda m: m.update(files={"record": "ab"}), "files has 'record'"),
])
def test_a_malformed_configuration_is_refused_naming_what(change, error):
    msg = _message_through_the_codec(RunConfig.of(**CENTRAL))
    change(msg)
    with pytest.raises(ConfigError, match=error):
        handed(msg, RunConfig.of(unit="u1"), set())


def test_the_unit_s_files_must_be_on_the_role_s_host_with_the_central_s_contents(tmp_path):
    params, mine = tmp_path / "central.toml", tmp_path / "params.toml"
    params.write_text("# the robot's parameters (only their bytes matter here)\n")
    mine.write_bytes(params.read_bytes())
    msg = config_message(RunConfig.of(**CENTRAL, params=str(params)))
    assert set(msg["files"]) == {"params"}
    own = RunConfig.of(unit="u1", params=str(mine))
    assert handed(msg, own, {"params"})[0].control.params == str(mine)  # its own copy
    assert handed(msg, own, set())[0].control.params == str(params)  # the central's path
    mine.write_bytes(params.read_bytes() + b"\n# changed\n")
    with pytest.raises(ConfigError, match="--params .*differs from the central's file"):
        handed(msg, own, {"params"})
    gone = RunConfig.of(unit="u1", params=str(tmp_path / "none.toml"))
    with pytest.raises(ConfigError, match="--params .*not on this host; give --params"):
        handed(msg, gone, {"params"})
    # a central without a parameters file: the role's is replaced, and it is told
    plain = config_message(RunConfig.of(**CENTRAL))
    got, notes = handed(plain, own, {"params"})
    assert got.control.params is None
    assert notes == [f"control.params = None of the unit over {str(mine)!r} given"]


def test_a_text_longer_than_the_messages_carry_is_refused_by_name():
    msg = config_message(RunConfig.of(**CENTRAL, task="/" + "t" * 300 + ".json"))
    assert set(msg) == {"error"} and "control.task is longer than 256 bytes" in msg["error"]
    with pytest.raises(ConfigError, match="cannot hand this role .*control.task"):
        handed(_message_through_codec(msg), RunConfig.of(unit="u1"), set())
    # what only the central uses does not travel
    long_report = RunConfig.of(**CENTRAL, report="/" + "r" * 300 + ".json")
    assert "report" not in config_message(long_report)["settings"]["run"]


def test_the_message_fits_the_codec_s_bounds():
    msg = config_message(RunConfig.of(**CENTRAL))
    data = encode("u1", 0, "config", **msg)
    assert _message_through_the_codec(RunConfig.of(**CENTRAL))["settings"] == \
        msgpack.unpackb(data)["settings"]


@pytest.mark.zenoh
def test_roles_started_by_hand_with_only_their_links_run_the_central_s_commands(
        tmp_path, socket_endpoint):
    unit, endpoint = unit_id("hand"), socket_endpoint
    options = ["--clock", "lockstep", "--peripherals", "2", "--pipeline", "2", "--law",
               "computed-torque", "--cycles", "200", "--placement", "axes"]
    py = [sys.executable, "-m", "ctrlunit.runtime.cli"]
    link = ["--unit", unit, "--connect", endpoint]
    procs = [subprocess.Popen([*py, "central", *options, "--unit", unit, "--listen", endpoint,
                               "--report", str(tmp_path / "hand.json")],
                              stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)]
    roles = [["plant"], ["peripheral", "--index", "1", "--pipeline", "1"],
             ["peripheral", "--index", "2"]]
    procs += [subprocess.Popen([*py, *r, *link], stdout=subprocess.DEVNULL,
                               stderr=subprocess.PIPE, text=True) for r in roles]
    try:
        out, _ = procs[0].communicate(timeout=120)
        errs = [p.communicate(timeout=30)[1] for p in procs[1:]]
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
                p.wait()
    assert [p.returncode for p in procs] == [0, 0, 0, 0], (out, errs)
    assert f"start the other roles with --unit {unit} --connect {endpoint}" in out
    assert "schedule.pipeline = 2 of the unit over 1 given" in errs[1]
    assert ctrlunit("start", *options, "--report", str(tmp_path / "start.json")).returncode == 0
    hand, start = (json.loads((tmp_path / f"{n}.json").read_text()) for n in ("hand", "start"))
    assert hand["command_digest"] == start["command_digest"]


def test_a_role_by_hand_needs_the_unit_id_and_its_help_shows_what_it_keeps():
    from click.testing import CliRunner
    from ctrlunit.runtime.cli import cli

    res = CliRunner().invoke(cli, ["plant", "--connect", "tcp/127.0.0.1:9"])
    assert res.exit_code == 1 and "needs --unit ID" in res.output
    shown = CliRunner().invoke(cli, ["peripheral", "--help"]).output
    flags = {w.split()[0] for w in shown.splitlines() if w.strip().startswith("--")}
    assert flags == {"--pin", "--unit", "--listen", "--connect", "--zenoh-config", "--keys",
                     "--insecure", "--check", "--help-all", "--index", "--task", "--params",
                     "--placement"}
    every = CliRunner().invoke(cli, ["peripheral", "--help-all"]).output
    assert "--pipeline" in every and "--late-policy" in every


@pytest.mark.zenoh
def test_a_role_the_unit_does_not_have_is_told_at_once(socket_endpoint):
    unit, endpoint = unit_id("nohand"), socket_endpoint
    py = [sys.executable, "-m", "ctrlunit.runtime.cli"]
    central = subprocess.Popen([*py, "central", "--unit", unit, "--listen", endpoint,
                                "--clock", "freerun", "--peripherals", "1", "--cycles", "50"],
                               stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        for role, error in ((["peripheral", "--index", "2"],
                             "--index = 2: allowed 1 to 1 (the unit's peripherals)"),
                            (["plant"], "the unit runs --clock freerun, which has no plant")):
            res = subprocess.run([*py, *role, "--unit", unit, "--connect", endpoint],
                                 capture_output=True, text=True, timeout=60)
            assert res.returncode == 1 and error in res.stderr, res.stderr
    finally:
        central.kill()
        central.wait(timeout=10)


def test_a_central_whose_roles_never_come_reports_no_run_length(tmp_path):
    """The run never started: its report says 0 s, not the time since the host booted."""
    unit = unit_id("nohello")
    report = tmp_path / "r.json"
    try:
        res = ctrlunit("central", "--unit", unit, "--peripherals", "1", "--clock", "lockstep",
                       "--listen", f"unixsock-stream/{tmp_path}/{unit}.sock",
                       "--set", "transport.startup_timeout=1", "--report", str(report),
                       timeout=60)
    finally:
        kill_unit(unit)
    assert res.returncode == 6, res.stdout + res.stderr
    rep = json.loads(report.read_text())
    assert rep["cycles"] == 0 and rep["wall_s"] == 0.0
