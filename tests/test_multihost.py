"""Multi-host: plant, central and peripherals each in its own network namespace, joined by
veth links in a star (as the Transputers), over TCP; then with a 1 ms delay each way and a
20 Mbit/s rate on every link: tc netem where the kernel has it, else a tc tbf rate and the
user-space delay line of ``ctrlunit.bench.linkdelay`` on each link. Skips where network
namespaces cannot be made."""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import subprocess
import sys
import time

import pytest

pytestmark = pytest.mark.zenoh

ROLES = ["plant", "peripheral-1", "peripheral-2", "peripheral-3"]


def sh(*args: str, check: bool = True) -> subprocess.CompletedProcess:
    return subprocess.run(args, capture_output=True, text=True, timeout=30, check=check)


def netns_available() -> str | None:
    if os.geteuid() != 0:
        return "needs root to create network namespaces"
    if not shutil.which("ip") or not shutil.which("tc"):
        return "needs iproute2 (ip, tc)"
    probe = f"cuprobe{os.getpid()}"
    res = sh("ip", "netns", "add", probe, check=False)
    if res.returncode != 0:
        return f"ip netns unavailable: {res.stderr.strip()}"
    sh("ip", "netns", "del", probe, check=False)
    return None


@pytest.fixture
def star():
    """Namespaces c (central) and r1..r4 (plant, peripherals), a veth link c<->rk each."""
    why = netns_available()
    if why:
        pytest.skip(why)
    tag = f"cu{os.getpid() % 100000}"
    central = f"{tag}c"
    hosts = [f"{tag}r{k}" for k in range(1, 5)]
    links = []
    try:
        for ns in [central, *hosts]:
            sh("ip", "netns", "add", ns)
            sh("ip", "netns", "exec", ns, "ip", "link", "set", "lo", "up")
        for k, ns in enumerate(hosts, start=1):
            a, b = f"{tag}a{k}", f"{tag}b{k}"
            sh("ip", "link", "add", a, "type", "veth", "peer", "name", b)
            sh("ip", "link", "set", a, "netns", central)
            sh("ip", "link", "set", b, "netns", ns)
            sh("ip", "netns", "exec", central, "ip", "addr", "add", f"10.77.{k}.1/24", "dev", a)
            sh("ip", "netns", "exec", ns, "ip", "addr", "add", f"10.77.{k}.2/24", "dev", b)
            sh("ip", "netns", "exec", central, "ip", "link", "set", a, "up")
            sh("ip", "netns", "exec", ns, "ip", "link", "set", b, "up")
            links.append((central, a, ns, b))
        yield central, hosts, links
    finally:
        for ns in [central, *hosts]:
            pids = sh("ip", "netns", "pids", ns, check=False).stdout.split()
            for pid in pids:
                try:
                    os.kill(int(pid), 9)
                except (ProcessLookupError, ValueError):
                    pass
            sh("ip", "netns", "del", ns, check=False)


def run_star(tmp_path, central: str, hosts: list[str], tag: str,
             endpoints: list[str] | None = None, *, keys: str | None = None) -> dict:
    """One lockstep session across the namespaces; ``endpoints[k]`` is what role k connects
    to (default: the central's address on its veth link). With ``keys`` every link is
    mutual TLS under the unit's access control; without, ``--insecure``."""
    unit = f"mh-{tag}-{os.getpid()}"
    report = tmp_path / f"{tag}.json"
    # the thesis's placement: two round trips per interval to each peripheral, whatever
    # --placement auto would choose on these links
    # the roles take the run's configuration from the central at the handshake: each is
    # given only its unit, its link and its keys
    link = ["--unit", unit, *(["--keys", keys] if keys else ["--insecure"])]
    py = [sys.executable, "-m", "ctrlunit.runtime.cli"]
    procs = [subprocess.Popen(["ip", "netns", "exec", central, *py, "central", *link,
                               "--clock", "lockstep", "--cycles", "300", "--peripherals", "3",
                               "--timeout", "5s", "--placement", "axes",
                               "--listen", "tcp/0.0.0.0:7447", "--report", str(report)],
                              stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)]
    logs = contextlib.ExitStack()  # each role's stderr, for the failure's message
    for k, (ns, role) in enumerate(zip(hosts, ROLES), start=1):
        args = ["plant"] if role == "plant" else ["peripheral", "--index", role[-1]]
        procs.append(subprocess.Popen(
            ["ip", "netns", "exec", ns, *py, *args, *link, "--connect",
             endpoints[k - 1] if endpoints else f"tcp/10.77.{k}.1:7447"],
            stdout=subprocess.DEVNULL,
            stderr=logs.enter_context((tmp_path / f"{tag}-{role}.err").open("w"))))
    try:
        out, _ = procs[0].communicate(timeout=300)
        for p in procs[1:]:
            p.wait(timeout=15)
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
                p.wait(timeout=10)
        logs.close()
    errs = {f.name: f.read_text()[-400:] for f in sorted(tmp_path.glob(f"{tag}-*.err"))}
    assert procs[0].returncode == 0, (out, errs)
    return json.loads(report.read_text())


def delay_lines(hosts: list[str], delay: str) -> tuple[list[subprocess.Popen], list[str]]:
    """A delay line in each role's namespace, from 127.0.0.1:7600 to the central."""
    relays, endpoints = [], []
    for k, ns in enumerate(hosts, start=1):
        relays.append(subprocess.Popen(
            ["ip", "netns", "exec", ns, sys.executable, "-m", "ctrlunit.bench.linkdelay",
             "--listen", "127.0.0.1:7600", "--to", f"10.77.{k}.1:7447", "--delay", delay],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
        endpoints.append("tcp/127.0.0.1:7600")
    for ns in hosts:  # listening before any role connects
        for _ in range(100):
            if "127.0.0.1:7600" in sh("ip", "netns", "exec", ns, "ss", "-ltn",
                                      check=False).stdout:
                break
            time.sleep(0.05)
    return relays, endpoints


def test_each_role_on_its_own_host_with_and_without_link_limits(tmp_path, star):
    from ctrlunit.runtime.transport.security import make_keys

    central, hosts, links = star
    plain = run_star(tmp_path, central, hosts, "plain")
    make_keys(tmp_path / "keys")
    secure = run_star(tmp_path, central, hosts, "tls", keys=str(tmp_path / "keys"))
    assert plain["links"] == "insecure" and secure["links"] == "tls"
    assert secure["command_digest"] == plain["command_digest"]
    for name, r in (("insecure", plain), ("TLS + access control", secure)):
        print(f"{name}: period p50 {r['period_s']['p50'] * 1e3:.3f} ms, p99 "
              f"{r['period_s']['p99'] * 1e3:.3f} ms, traversal p50 "
              f"{r['traversal_s']['p50'] * 1e3:.3f} ms, misses {r['deadline_misses']}, "
              f"CPU per interval {(r.get('cpu_per_interval_s') or {}).get('total', 0) * 1e6:.0f}"
              " us")
    # a Transputer-like link: 20 Mbit/s and 1 ms each way
    netem = True
    for ns_c, a, ns_r, b in links:
        for ns, dev in ((ns_c, a), (ns_r, b)):
            res = sh("ip", "netns", "exec", ns, "tc", "qdisc", "add", "dev", dev, "root",
                     "netem", "delay", "1ms", "rate", "20mbit", check=False)
            if res.returncode != 0:
                netem = False
                sh("ip", "netns", "exec", ns, "tc", "qdisc", "add", "dev", dev, "root", "tbf",
                   "rate", "20mbit", "burst", "1600", "latency", "100ms")
    relays: list[subprocess.Popen] = []
    try:
        endpoints = None
        if not netem:
            relays, endpoints = delay_lines(hosts, "1ms")
        limit = ("netem 1 ms + 20 Mbit/s" if netem else
                 "tbf 20 Mbit/s + 1 ms delay line each way (no netem in this kernel)")
        slow = run_star(tmp_path, central, hosts, "limited", endpoints)
    finally:
        for r in relays:
            r.kill()
            r.wait(timeout=5)
    # 20 Mbit/s alone hardly shows (a few hundred bytes per message): 256 kbit/s makes the
    # serialisation time of every message count
    for ns_c, a, ns_r, b in links:
        for ns, dev in ((ns_c, a), (ns_r, b)):
            sh("ip", "netns", "exec", ns, "tc", "qdisc", "replace", "dev", dev, "root",
               "tbf", "rate", "256kbit", "burst", "1600", "latency", "500ms")
    narrow = run_star(tmp_path, central, hosts, "256kbit")
    for name, r in (("plain veth", plain), (limit, slow), ("tbf 256 kbit/s", narrow)):
        print(f"{name}: period p50 {r['period_s']['p50'] * 1e3:.2f} ms, traversal p50 "
              f"{r['traversal_s']['p50'] * 1e3:.2f} ms, efficiency "
              f"{r['efficiency'] * 100:.2f} % (N = {r['efficiency_n']})")
    assert plain["cycles"] == slow["cycles"] == narrow["cycles"] == 300
    # lockstep: the links change the timing, never the arithmetic
    assert plain["command_digest"] == slow["command_digest"] == narrow["command_digest"]
    # lockstep depth 1: each interval crosses the plant's link twice (command, sample) and
    # a peripheral's link four times (two round trips): 6 one-way delays of 1 ms
    assert slow["period_s"]["p50"] > plain["period_s"]["p50"] + 4e-3
    assert narrow["period_s"]["p50"] > plain["period_s"]["p50"] + 2e-3
    assert slow["efficiency"] < plain["efficiency"]
    assert narrow["efficiency"] < plain["efficiency"]


def test_delay_line_holds_each_direction_for_its_delay():
    """The user-space delay line (for kernels without netem) on loopback: an echo through
    it takes two delays, and the bytes come back unchanged."""
    import socket
    import threading

    from ctrlunit.bench.linkdelay import serve

    echo = socket.create_server(("127.0.0.1", 0))
    echo_port = echo.getsockname()[1]

    def run_echo() -> None:
        conn, _ = echo.accept()
        with conn:
            while data := conn.recv(4096):
                conn.sendall(data)

    threading.Thread(target=run_echo, daemon=True).start()
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    ready, stop = threading.Event(), threading.Event()
    threading.Thread(target=serve, args=(f"127.0.0.1:{port}", f"127.0.0.1:{echo_port}", 0.005),
                     kwargs={"ready": ready, "stop": stop}, daemon=True).start()
    assert ready.wait(5)
    try:
        with socket.create_connection(("127.0.0.1", port), timeout=5) as c:
            rtts = []
            for k in range(10):
                msg = bytes([k]) * 100
                t0 = time.monotonic()
                c.sendall(msg)
                got = b""
                while len(got) < len(msg):
                    got += c.recv(4096)
                rtts.append(time.monotonic() - t0)
                assert got == msg
        rtts.sort()
        print(f"delay line 5 ms each way: echo round trip p50 {rtts[5] * 1e3:.2f} ms")
        assert 0.010 <= rtts[0] and rtts[5] < 0.030
    finally:
        stop.set()
        echo.close()
