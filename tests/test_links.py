"""Every link of a unit is checked before it starts, whichever way it was given: a
``--zenoh-config`` file's endpoints and multicast scouting as ``--listen`` and
``--connect`` are (nothing another host can reach without keys, unless ``--insecure``),
and with ``--keys`` every link, the default one too, carries the roles' certificates.
The report's ``link_list`` and the summary's ``links`` lines say what protects each
(issue 56, items 4 and 5). No address beyond the host is ever contacted: those runs are
refused before anything starts."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from ctrlunit.runtime.transport.zsession import file_links, make_config
from runner import ctrlunit, start_json

pytestmark = pytest.mark.zenoh

SHORT = ("--clock", "lockstep", "--cycles", "300")


def zenoh_file(tmp_path: Path, name: str, conf: dict) -> str:
    path = tmp_path / f"{name}.json5"
    path.write_text(json.dumps(conf))
    return str(path)


REFUSED = {
    "connects beyond": ({"connect": {"endpoints": ["tcp/192.0.2.1:7447"]}},
                        "connect/endpoints tcp/192.0.2.1:7447 can be reached from other hosts"),
    "listens everywhere": ({"listen": {"endpoints": ["tcp/0.0.0.0:0"]}},
                           "listen/endpoints tcp/0.0.0.0:0 can be reached from other hosts"),
    "listens everywhere, per mode": (
        {"listen": {"endpoints": {"router": ["tcp/127.0.0.1:0"], "peer": ["tcp/0.0.0.0:0"]}}},
        "listen/endpoints tcp/0.0.0.0:0 can be reached from other hosts"),
    "multicast scouting": ({"scouting": {"multicast": {"enabled": True}}},
                           "scouting/multicast/enabled is true"),
    # gossip passes a peer's address on: a reader of the observers' port that gossips its
    # own listener would have the plant connect to it, past the central's rule (an
    # attacker's review, 2026-11-28)
    "gossip scouting": ({"scouting": {"gossip": {"enabled": True}}},
                        "scouting/gossip/enabled is true"),
}


@pytest.mark.parametrize("case", sorted(REFUSED))
def test_a_zenoh_file_reaching_beyond_the_host_without_keys_is_refused(tmp_path, case):
    conf, says = REFUSED[case]
    path = zenoh_file(tmp_path, "z", conf)
    for extra in (("--check",), ("--peripherals", "1")):  # checked, and refused at start
        res = ctrlunit("start", "--zenoh-config", path, *SHORT, *extra, timeout=120)
        assert res.returncode == 1, (case, extra, res.stdout, res.stderr)
        err = res.stderr.strip().splitlines()
        assert len(err) == 1 and err[0].startswith(f"ctrlunit: error: --zenoh-config {path}: ")
        assert says in err[0], err[0]
        assert "--keys DIR" in err[0] and "--insecure" in err[0], err[0]
    # a lab bench may (the run would then say INSECURE)
    res = ctrlunit("start", "--zenoh-config", path, *SHORT, "--check", "--insecure",
                   timeout=120)
    assert res.returncode == 0, res.stderr


def test_a_run_file_naming_such_a_zenoh_file_is_refused_too(tmp_path):
    path = zenoh_file(tmp_path, "z", REFUSED["connects beyond"][0])
    run = tmp_path / "run.toml"
    run.write_text(f'[transport]\nzenoh_config = "{path}"\n')
    for how in (("--config", str(run)), ("--set", f'transport.zenoh_config="{path}"')):
        res = ctrlunit("start", *how, *SHORT, "--check", timeout=120)
        assert res.returncode == 1, (how, res.stdout, res.stderr)
        assert f"--zenoh-config {path}: connect/endpoints tcp/192.0.2.1:7447" in res.stderr


@pytest.mark.parametrize(("conf", "says"), [
    ({"plugins_loading": {"enabled": True}, "plugins": {"rest": {"http_port": "0.0.0.0:8000"}}},
     "it loads Zenoh plugins (rest)"),
    ({"plugins_loading": {"enabled": True}}, "it loads Zenoh plugins (plugins_loading)"),
    ({"adminspace": {"enabled": True, "permissions": {"read": True, "write": True}}},
     "adminspace/permissions/write is true"),
    ({"namespace": "ctrlunit/x/view"}, "namespace 'ctrlunit/x/view'")])
def test_a_zenoh_file_that_loads_plugins_or_opens_its_admin_space_is_refused(tmp_path, conf,
                                                                             says):
    """A plugin opens ports of its own (the REST plugin's HTTP port on every interface, in
    an attacker's review that --check passed), past the link rule and the keys; a writable
    admin space lets a peer change the session. Refused, --insecure or not."""
    path = zenoh_file(tmp_path, "z", conf)
    for extra in ((), ("--insecure",)):
        res = ctrlunit("start", "--zenoh-config", path, *SHORT, "--check", *extra, timeout=120)
        err = res.stderr.strip().splitlines()
        assert res.returncode == 1 and len(err) == 1, (extra, res.stderr)
        assert err[0].startswith(f"ctrlunit: error: --zenoh-config {path}: {says}"), err[0]


def test_a_unix_socket_in_a_folder_others_may_write_is_refused_without_insecure(tmp_path):
    """In /tmp (or any folder others may write) another user could bind the socket's path
    first and pose as the central to every role that connects there: refused, naming the
    folder, for start, a role by hand and replay alike; a folder of one's own will do."""
    shared = tmp_path / "shared"
    shared.mkdir()
    shared.chmod(0o1777)
    endpoint = f"unixsock-stream/{shared}/c.sock"
    for args in (("start", "--listen", endpoint, *SHORT, "--check"),
                 ("central", "--listen", endpoint, *SHORT, "--check"),
                 ("plant", "--unit", "u", "--connect", endpoint, "--check")):
        res = ctrlunit(*args, timeout=120)
        err = res.stderr.strip().splitlines()
        assert res.returncode == 1 and len(err) == 1, (args, res.stderr)
        assert f"its folder {shared} may be written by others (mode 1777)" in err[0], err[0]
        assert "mkdir -m 700" in err[0] and "--insecure" in err[0], err[0]
        assert ctrlunit(*args, "--insecure", timeout=120).returncode == 0, args
    own = tmp_path / "own"
    own.mkdir(mode=0o700)
    res = ctrlunit("start", "--listen", f"unixsock-stream/{own}/c.sock", *SHORT, "--check",
                   timeout=120)
    assert res.returncode == 0, res.stderr


def test_a_socket_folder_another_user_owns_will_not_do(tmp_path):
    """Owned by another user, a folder closed to others is still theirs to bind in."""
    import os

    from ctrlunit.runtime.transport.security import shared_folder

    theirs = tmp_path / "theirs"
    theirs.mkdir(mode=0o755)
    assert shared_folder(f"unixsock-stream/{theirs}/c.sock") is None  # ours
    if os.geteuid() != 0:
        pytest.skip("giving a folder to another user needs root")
    os.chown(theirs, 65534, 65534)
    why = shared_folder(f"unixsock-stream/{theirs}/c.sock")
    assert why is not None and "is another user's (uid 65534)" in why, why


@pytest.mark.parametrize("endpoint", ["unixsock-stream/tmp/c.sock",
                                      "unixsock-stream//no/such/folder/c.sock",
                                      "unixsock-stream//tmp/" + "c" * 110 + ".sock"])
def test_a_unix_socket_needs_an_absolute_path_in_a_folder_that_exists(endpoint):
    """``unixsock-stream/tmp/x`` is a path relative to where the role starts: it passed
    --check, then the run ended in Zenoh's traceback (a new user's review, 2026-11-28)."""
    res = ctrlunit("central", "--listen", endpoint, *SHORT, "--check", timeout=120)
    err = res.stderr.strip().splitlines()
    assert res.returncode == 1 and len(err) == 1, res.stderr
    assert "expected unixsock-stream//FOLDER/NAME, an absolute path" in err[0], err[0]


def test_a_zenoh_file_in_another_mode_than_peer_is_refused(tmp_path):
    path = zenoh_file(tmp_path, "z", {"mode": "router"})
    res = ctrlunit("start", "--zenoh-config", path, *SHORT, "--check", timeout=120)
    assert res.returncode == 1 and "mode 'router'" in res.stderr, res.stderr


def test_a_loopback_zenoh_file_runs_and_its_links_are_reported(tmp_path):
    path = zenoh_file(tmp_path, "z", {"listen": {"endpoints": ["tcp/127.0.0.1:0"]}})
    code, rep, out = start_json(tmp_path, "--zenoh-config", path, "--peripherals", "1",
                                *SHORT, tag="loopfile")
    assert code == 0, out
    assert rep["links"] == "loopback", rep.get("link_list")
    ways = {(ln["endpoint"], ln["protection"]) for ln in rep["link_list"]}
    assert ("tcp/127.0.0.1:0", "loopback") in ways  # the file's
    assert any(p == "local" and e.startswith("unixsock-stream/") for e, p in ways)  # default
    assert "links       TCP on a loopback address without keys" in out
    assert f"tcp/127.0.0.1:0 (listen, --zenoh-config {path})" in out


def test_with_a_file_scouting_stays_off_unless_it_turns_it_on(tmp_path):
    quiet = zenoh_file(tmp_path, "quiet", {"connect": {"endpoints": ["tcp/127.0.0.1:9"]}})
    conf = make_config(config_file=quiet)
    assert conf.get_json("scouting/multicast/enabled") == "false"
    assert conf.get_json("scouting/gossip/enabled") == "false"
    assert json.loads(conf.get_json("connect/endpoints")) == ["tcp/127.0.0.1:9"]
    assert json.loads(conf.get_json("listen/endpoints")) == []  # not Zenoh's default
    loud = zenoh_file(tmp_path, "loud", {"scouting": {"multicast": {"enabled": True},
                                                      "gossip": {"enabled": True}}})
    conf = make_config(config_file=loud)
    assert conf.get_json("scouting/multicast/enabled") == "true"
    assert conf.get_json("scouting/gossip/enabled") == "true"
    both = zenoh_file(tmp_path, "both", {"listen": {"endpoints": {"peer": ["tcp/127.0.0.1:0"]}}})
    assert file_links(both).listen == ["tcp/127.0.0.1:0"]
    conf = make_config(listen=["tcp/127.0.0.1:7"], config_file=both)
    assert json.loads(conf.get_json("listen/endpoints")) == ["tcp/127.0.0.1:7",
                                                             "tcp/127.0.0.1:0"]


def test_keys_with_the_default_link_run_over_tls(tmp_path):
    keys = tmp_path / "keys"
    init = ctrlunit("keys", "init", str(keys), timeout=120)
    assert init.returncode == 0, init.stderr
    code, rep, out = start_json(tmp_path, "--peripherals", "3", "--pipeline", "2", *SHORT,
                                "--keys", str(keys), tag="keysdefault", timeout=180)
    assert code == 0, out
    assert rep["links"] == "tls" and rep["cycles"] == 300
    (link,) = rep["link_list"]
    assert link["endpoint"].startswith("tls/127.0.0.1:") and link["from"] == "default"
    assert "links       TLS with mutual authentication" in out
    assert "safe stop   NOT confirmed" not in out
    # a link that carries no certificate would drop everything: refused before start
    res = ctrlunit("start", "--listen", f"unixsock-stream/{tmp_path / 'c.sock'}",
                   "--keys", str(keys), *SHORT, "--check", timeout=120)
    assert res.returncode == 1 and "carries none" in res.stderr, res.stderr


def test_a_listen_port_0_becomes_a_port_listened_on_and_named(tmp_path):
    """``--listen PROTO/HOST:0`` asks for any port: the run listens on one the system had
    free, and the summary and the report name it. With keys that endpoint is the one the
    roles connect to: before, they were sent to port 0, and the run waited 30 s for their
    hello and ended with exit 6 (a review found port 0 in the summary)."""
    keys = tmp_path / "keys"
    assert ctrlunit("keys", "init", str(keys), "--peripherals", "1",
                    timeout=120).returncode == 0
    for proto, extra in (("tcp", ()), ("tls", ("--keys", str(keys)))):
        code, rep, out = start_json(tmp_path, "--peripherals", "1", *SHORT, "--listen",
                                    f"{proto}/127.0.0.1:0", *extra, tag=f"port0{proto}",
                                    timeout=180)
        assert code == 0, out
        (link,) = [ln for ln in rep["link_list"] if ln["endpoint"].startswith(proto)]
        port = int(link["endpoint"].rsplit(":", 1)[1])
        assert 0 < port <= 65535 and f"{proto}/127.0.0.1:{port} (listen)" in out, out


def test_a_central_started_by_hand_names_the_port_it_listens_on():
    """``ctrlunit central --listen tcp/127.0.0.1:0`` tells the user which endpoint to give
    the other roles: it named port 0 (a new user's review), where nobody can connect."""
    import re

    from runner import unit_id

    res = ctrlunit("central", "--unit", unit_id("central0"), "--clock", "lockstep",
                   "--peripherals", "0", "--listen", "tcp/127.0.0.1:0", "--insecure",
                   "--set", "transport.startup_timeout=1", timeout=120)
    said = re.search(r"--connect tcp/127\.0\.0\.1:(\d+)", res.stderr)
    assert said and said[1] != "0", res.stderr
    assert f"tcp/127.0.0.1:{said[1]} (listen)" in res.stdout + res.stderr, res.stdout


def test_a_port_0_is_chosen_once_for_every_start_of_the_run():
    """``--period auto`` may start the unit again; each start listened on a port of its
    own, and a viewer connected to the first lost the run (a new user's review). The
    launcher chooses the port once: choosing again keeps it."""
    from ctrlunit.runtime.config import RunConfig
    from ctrlunit.runtime.launch.run_parts import listen_ports

    rc = RunConfig.of(listen=["tcp/127.0.0.1:0", "unixsock-stream//tmp/x.sock"])
    once = listen_ports(rc)
    port = once.transport.listen[0].rsplit(":", 1)[1]
    assert port != "0" and once.transport.listen[1] == "unixsock-stream//tmp/x.sock"
    assert listen_ports(once).transport.listen == once.transport.listen
