"""--zenoh-config passes a Zenoh configuration through: with user/password authentication,
a peer without credentials cannot publish commands into the unit."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from typing import Any

import pytest
import zenoh
from ctrlunit.runtime.transport.codec import encode
from ctrlunit.runtime.transport.zsession import Keys, make_config
from runner import kill_unit, start_json, unit_id
from test_fuzz import free_port

pytestmark = pytest.mark.zenoh


def auth_config(tmp_path) -> str:
    users = tmp_path / "users.txt"
    users.write_text("ctrl:s3cret\n")
    conf = tmp_path / "auth.json5"
    conf.write_text(json.dumps({
        "mode": "peer",
        "scouting": {"multicast": {"enabled": False}, "gossip": {"enabled": False}},
        "transport": {"auth": {"usrpwd": {"user": "ctrl", "password": "s3cret",
                                          "dictionary_file": str(users)}}},
    }))
    return str(conf)


def test_peer_without_credentials_cannot_publish_commands(tmp_path):
    conf, port = auth_config(tmp_path), free_port()
    unit = unit_id("auth")
    report, status = tmp_path / "r.json", tmp_path / "status"
    common = ["--clock", "lockstep", "--cycles", "1500"]
    proc = subprocess.Popen(
        [sys.executable, "-m", "ctrlunit.runtime.cli", "start", "--unit", unit,
         "--zenoh-config", conf, "--listen", f"tcp/127.0.0.1:{port}", "--report", str(report),
         "--status-file", str(status), *common, "--peripherals", "3"],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        deadline = time.monotonic() + 60
        while not status.exists() and time.monotonic() < deadline:
            time.sleep(0.05)
        keys = Keys(unit)
        with zenoh.open(make_config(connect=[f"tcp/127.0.0.1:{port}"])) as intruder:
            time.sleep(1.0)
            refused = len(list(intruder.info.peers_zid())) == 0
            pub = intruder.declare_publisher(keys.command)
            for k in range(2000):  # well-formed commands for the coming cycles
                pub.put(encode(unit, k, "command", tau=[20.0, -20.0, 20.0]))
        out, _ = proc.communicate(timeout=300)
    finally:
        kill_unit(unit)
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, out
    assert refused, "the unauthenticated peer was admitted"
    rep = json.loads(report.read_text())
    # undisturbed: the one-process unit (the star's commands equal its bit for bit)
    _, clean, _ = start_json(tmp_path, *common, "--peripherals", "0", tag="authclean")
    assert rep["command_digest"] == clean["command_digest"]
    assert rep["tracking_error_m"] == clean["tracking_error_m"]
    print(f"intruder refused; {rep['cycles']} intervals as without it, rejections "
          f"{rep['rejected_messages']}")


# -- mutual TLS and access control (runtime/transport/security.py) ---------------------------------


@pytest.fixture(scope="module")
def unit_keys(tmp_path_factory):
    from ctrlunit.runtime.transport.security import make_keys

    d = tmp_path_factory.mktemp("keys") / "unit"
    make_keys(d, peripherals=3)
    return d


def peer_config(port: int, keys_dir=None, role: str | None = None) -> zenoh.Config:
    """A plain Zenoh peer connecting to the unit: over TCP without credentials, or over
    TLS with the unit's keys as ``role`` (the authority's certificate alone when
    ``role`` is None: it trusts the unit, the unit cannot trust it)."""
    if keys_dir is None:
        return make_config(connect=[f"tcp/127.0.0.1:{port}"])
    if role is not None:
        return make_config(connect=[f"tcp/127.0.0.1:{port}"], keys=str(keys_dir), role=role)
    conf = make_config(connect=[f"tls/127.0.0.1:{port}"])
    conf.insert_json5("transport/link/tls", json.dumps(
        {"root_ca_certificate": str(keys_dir / "ca.pem"), "verify_name_on_connect": False}))
    return conf


CYCLES = "6000"
"""Long enough (a few seconds in lockstep) for every attacker to have its turn."""


def forged_samples(unit: str, first: int, n: int) -> list[bytes]:
    """Well-formed samples for cycles ``first`` .. ``first + n - 1``, the joint counts
    displaced by 2000 increments from the robot's start."""
    from ctrlunit.kernels.kinematics import inverse_kinematics
    from ctrlunit.kernels.params import DELTA_IA as P
    from ctrlunit.kernels.trajectory import pick_place_task

    q = inverse_kinematics(P, pick_place_task().start())
    counts = [round(float(x) / P.increment) + 2000 for x in q]
    now = time.monotonic_ns()
    return [encode(unit, k, "sample", counts=counts, t_ns=now, span=[now, now],
                   p=[0.0, 0.0, -0.35], misses=0, applied=-1) for k in range(first, first + n)]


def attacked_run(tmp_path, tag: str, attackers: Any, *options: str
                 ) -> tuple[int, dict, str, dict[str, dict[str, int]]]:
    """A lockstep unit listening on a loopback TCP port while each attacker
    (``attackers(port) -> [(name, zenoh.Config)]``) connects, subscribes to all of the
    unit's keys and publishes forged samples for the coming cycles, forged replies and
    forged commands. Returns the run's exit code, report and output, and per attacker how
    many of the unit's messages it received and how many peers it saw."""
    port, unit = free_port(), unit_id(tag)
    report, status = tmp_path / f"{tag}.json", tmp_path / f"{tag}.status"
    proc = subprocess.Popen(
        [sys.executable, "-m", "ctrlunit.runtime.cli", "start", "--unit", unit,
         "--listen", f"tcp/127.0.0.1:{port}", "--clock", "lockstep", "--cycles", CYCLES,
         "--peripherals", "3", "--pipeline", "2", "--report", str(report),
         "--status-file", str(status), *options],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True)
    seen: dict[str, dict[str, int]] = {}
    try:
        deadline = time.monotonic() + 60
        while not status.exists() and time.monotonic() < deadline:
            time.sleep(0.02)
        keys = Keys(unit)
        for name, conf in attackers(port):
            got = [0]
            with zenoh.open(conf) as peer:
                # what the central sends the peripherals (the attacker sends nothing there)
                sub = peer.declare_subscriber(f"{keys.root}/peripheral/**",
                                              lambda s, got=got: got.__setitem__(0, got[0] + 1))
                time.sleep(0.3)
                done = int(status.read_text() or 0) if status.exists() else 0
                for data in forged_samples(unit, done, 300):
                    peer.put(keys.sample, data)
                for k in range(done, done + 300):
                    peer.put(keys.reply(1), encode(unit, k, 0, parts=[]))
                    peer.put(keys.command, encode(unit, k, "command", tau=[20.0, -20.0, 20.0]))
                time.sleep(0.3)
                # the port's Zenoh: the central's session with keys, else the observers'
                # relay (a router: runtime/observe/relay.py)
                seen[name] = {"received": got[0], "peers": len(list(peer.info.peers_zid()))
                              + len(list(peer.info.routers_zid()))}
                sub.undeclare()
        out, _ = proc.communicate(timeout=300)
    finally:
        kill_unit(unit)
        if proc.poll() is None:
            proc.kill()
    rep = json.loads(report.read_text()) if report.exists() else {}
    return proc.returncode, rep, out, seen


def test_with_keys_a_peer_without_them_cannot_connect_and_a_viewer_cannot_write(
        tmp_path, unit_keys):
    """The attack of the issue, three times: on a loopback TCP port without keys under
    ``--insecure`` the forged samples reach the central and change its commands (the
    attack works); without ``--insecure`` the port carries the observers' keys alone (the
    roles meet on the local socket): the intruder connects, reads nothing of the
    control path, and its samples, replies and commands are dropped; with --keys the same
    port is mutual TLS, a peer without a certificate is never admitted (it reads
    nothing), and a peer with the viewer's certificate reads none of the control path
    (the observers' keys alone: tests/test_observers.py) and its samples, replies and
    commands are dropped by the access control: the commands are the undisturbed run's
    bit for bit. (Zenoh drops what the policy denies before the unit sees it: the unit's
    own rejection counters stay empty.)"""
    _, clean, _ = start_json(tmp_path, "--clock", "lockstep", "--cycles", CYCLES,
                             "--peripherals", "0", "--pipeline", "2", tag="tlsclean")
    code, open_rep, out, open_seen = attacked_run(
        tmp_path, "tlsopen", lambda port: [("anyone", peer_config(port))], "--insecure")
    print(f"without keys, --insecure: exit {code}, the intruder read "
          f"{open_seen['anyone']['received']} messages, rejected "
          f"{open_rep.get('rejected_messages')}")
    assert open_seen["anyone"]["received"] > 0, out  # it read the traffic
    assert open_rep.get("command_digest") != clean["command_digest"], out
    assert open_rep["links"] == "insecure" and "INSECURE" in out
    code, rep, out, seen = attacked_run(
        tmp_path, "loopback", lambda port: [("anyone", peer_config(port))])
    print(f"without keys: exit {code}, {seen}")
    assert code == 0, out
    assert "observers read ctrlunit/" in out and "/view/** on tcp/127.0.0.1:" in out
    assert seen["anyone"] == {"received": 0, "peers": 1}  # connected, denied the requests
    assert rep["command_digest"] == clean["command_digest"]
    assert rep["links"] == "loopback"
    code, rep, out, seen = attacked_run(
        tmp_path, "tlskeys", lambda port: [("no certificate", peer_config(port, unit_keys)),
                                           ("viewer", peer_config(port, unit_keys, "viewer"))],
        "--keys", str(unit_keys))
    print(f"with keys: {seen}; rejected by the unit itself: {rep.get('rejected_messages')}")
    assert code == 0, out
    assert not rep.get("degraded"), rep.get("degraded")  # no peripheral was taken over
    assert "links       TLS with mutual authentication" in out and rep["links"] == "tls"
    assert rep["command_digest"] == clean["command_digest"]
    assert rep["tracking_error_m"] == clean["tracking_error_m"]
    assert seen["no certificate"] == {"received": 0, "peers": 0}
    assert seen["viewer"] == {"received": 0, "peers": 1}  # connected, denied the requests


def test_a_link_beyond_the_host_without_keys_is_refused_and_names_the_fix(tmp_path):
    port = free_port()
    for args in (["start", "--listen", f"tcp/0.0.0.0:{port}"],
                 ["plant", "--connect", f"tcp/192.0.2.1:{port}"],
                 ["start", "--listen", f"tcp/0.0.0.0:{port}", "--check"]):
        res = subprocess.run([sys.executable, "-m", "ctrlunit.runtime.cli", *args,
                              "--clock", "lockstep", "--cycles", "10"],
                             capture_output=True, text=True, timeout=60)
        assert res.returncode == 1, (args, res.stdout, res.stderr)
        err = res.stderr.strip().splitlines()
        assert len(err) == 1 and err[0].startswith("ctrlunit: error: "), res.stderr
        assert "can be reached from other hosts" in err[0]
        assert "ctrlunit keys init DIR" in err[0] and "--keys DIR" in err[0]
        assert "--insecure" in err[0]


def test_a_role_by_hand_without_keys_on_a_tcp_link_alone_is_refused_and_names_the_fix():
    """Without keys a TCP port carries the observers' keys alone: a central that listens,
    or a role that connects, on nothing else could never reach the control path (the
    central's roles would say no hello). Refused before anything starts, naming the
    socket, the keys and ``--insecure``, each of which the check then lets pass."""
    port, cli = free_port(), [sys.executable, "-m", "ctrlunit.runtime.cli"]
    for args, way in ((["central", "--listen", f"tcp/127.0.0.1:{port}"], "listen"),
                      (["plant", "--unit", "u", "--connect", f"tcp/127.0.0.1:{port}"],
                       "connect")):
        res = subprocess.run([*cli, *args, "--check"], capture_output=True, text=True,
                             timeout=60)
        assert res.returncode == 1, (args, res.stdout, res.stderr)
        err = res.stderr.strip().splitlines()
        assert len(err) == 1 and err[0].startswith(f"ctrlunit: error: --{way} tcp/127"), err
        assert "unixsock-stream/PATH" in err[0] and "--keys DIR" in err[0]
        assert "--insecure" in err[0]
        ok = subprocess.run([*cli, *args, "--check", "--insecure"], capture_output=True,
                            text=True, timeout=60)
        assert ok.returncode == 0, (args, ok.stderr)


def test_keys_init_writes_an_authority_and_a_certificate_per_role(tmp_path):
    from cryptography import x509
    from cryptography.x509.oid import NameOID
    from ctrlunit.runtime.transport.security import access_control, credentials, role_names

    d = tmp_path / "k"
    res = subprocess.run([sys.executable, "-m", "ctrlunit.runtime.cli", "keys", "init",
                          str(d), "--peripherals", "2"], capture_output=True, text=True,
                         timeout=60)
    assert res.returncode == 0, res.stderr
    assert role_names(2) == ["central", "plant", "peripheral-1", "peripheral-2", "viewer"]
    ca = x509.load_pem_x509_certificate((d / "ca.pem").read_bytes())
    for role in role_names(2):
        cert = x509.load_pem_x509_certificate((d / f"{role}.pem").read_bytes())
        assert cert.subject.get_attributes_for_oid(NameOID.COMMON_NAME)[0].value == role
        assert cert.issuer == ca.subject
        cert.verify_directly_issued_by(ca)
        assert (d / f"{role}.key").stat().st_mode & 0o077 == 0  # the owner's alone
        assert set(credentials(d, role)) == {"ca", "key", "cert"}
    assert not (d / "peripheral-3.pem").exists()
    again = subprocess.run([sys.executable, "-m", "ctrlunit.runtime.cli", "keys", "init",
                            str(d)], capture_output=True, text=True, timeout=60)
    assert again.returncode == 1 and "never overwritten" in again.stderr
    with pytest.raises(FileNotFoundError, match="peripheral-3.key is missing"):
        credentials(d, "peripheral-3")
    acl = access_control(3)
    assert acl["default_permission"] == "deny"
    writers = {p["id"]: p["subjects"] for p in acl["policies"]}
    assert writers["plant"] == ["plant"] and writers["central"] == ["central"]
    assert writers["peripheral-2"] == ["peripheral-2"]
    assert all(writers[f"hello-{r}"] == [r] for r in ("plant", "peripheral-1"))
    assert not any("viewer" in who for pid, who in writers.items() if pid != "inbox-viewer")
