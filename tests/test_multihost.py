"""Multi-host: plant, central and peripherals each in its own network namespace, joined by
veth links in a star (as the Transputers), over TCP; then with tc/netem delay and a
20 Mbit/s rate on every link. Skips where network namespaces cannot be made."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys

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


def run_star(tmp_path, central: str, hosts: list[str], tag: str) -> dict:
    unit = f"mh-{tag}-{os.getpid()}"
    report = tmp_path / f"{tag}.json"
    common = ["--unit", unit, "--clock", "lockstep", "--cycles", "300", "--peripherals", "3",
              "--timeout", "5s"]
    py = [sys.executable, "-m", "ctrlunit.runtime.cli"]
    procs = [subprocess.Popen(["ip", "netns", "exec", central, *py, "central", *common,
                               "--listen", "tcp/0.0.0.0:7447", "--report", str(report)],
                              stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)]
    for k, (ns, role) in enumerate(zip(hosts, ROLES), start=1):
        args = ["plant"] if role == "plant" else ["peripheral", "--index", role[-1]]
        procs.append(subprocess.Popen(
            ["ip", "netns", "exec", ns, *py, *args, *common, "--connect",
             f"tcp/10.77.{k}.1:7447"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
    try:
        out, _ = procs[0].communicate(timeout=300)
        for p in procs[1:]:
            p.wait(timeout=15)
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
    assert procs[0].returncode == 0, out
    return json.loads(report.read_text())


def test_each_role_on_its_own_host_with_and_without_link_limits(tmp_path, star):
    central, hosts, links = star
    plain = run_star(tmp_path, central, hosts, "plain")
    # a Transputer-like link: 20 Mbit/s, and 1 ms each way where the kernel has netem
    # (where it has only tbf, the rate alone)
    netem = True
    for ns_c, a, ns_r, b in links:
        for ns, dev in ((ns_c, a), (ns_r, b)):
            res = sh("ip", "netns", "exec", ns, "tc", "qdisc", "add", "dev", dev, "root",
                     "netem", "delay", "1ms", "rate", "20mbit", check=False)
            if res.returncode != 0:
                netem = False
                sh("ip", "netns", "exec", ns, "tc", "qdisc", "add", "dev", dev, "root", "tbf",
                   "rate", "20mbit", "burst", "4kbit", "latency", "100ms")
    limit = "netem 1 ms + 20 Mbit/s" if netem else "tbf 20 Mbit/s (no netem in this kernel)"
    slow = run_star(tmp_path, central, hosts, "limited")
    if not netem:
        # 20 Mbit/s alone hardly shows (a few hundred bytes per message, far below the
        # rate): 256 kbit/s makes the serialisation time of every message count
        for ns_c, a, ns_r, b in links:
            for ns, dev in ((ns_c, a), (ns_r, b)):
                sh("ip", "netns", "exec", ns, "tc", "qdisc", "replace", "dev", dev, "root",
                   "tbf", "rate", "256kbit", "burst", "1600", "latency", "500ms")
        slow_1m = run_star(tmp_path, central, hosts, "256kbit")
        print(f"tbf 256 kbit/s: period p50 {slow_1m['period_s']['p50'] * 1e3:.2f} ms, "
              f"efficiency {slow_1m['efficiency'] * 100:.2f} %")
    for name, r in (("plain veth", plain), (limit, slow)):
        print(f"{name}: period p50 {r['period_s']['p50'] * 1e3:.2f} ms, traversal p50 "
              f"{r['traversal_s']['p50'] * 1e3:.2f} ms, efficiency "
              f"{r['efficiency'] * 100:.2f} % (N = {r['efficiency_n']})")
    assert plain["cycles"] == slow["cycles"] == 300
    assert plain["command_digest"] == slow["command_digest"]  # lockstep: same arithmetic
    # two round trips and the plant's exchange cross the limited links: with netem each
    # crossing adds 2 ms; with the rate alone (256 kbit/s), each message waits its
    # serialisation time (a few hundred bytes: several ms per crossing)
    limited = slow if netem else slow_1m
    assert limited["command_digest"] == plain["command_digest"]
    assert limited["period_s"]["p50"] > plain["period_s"]["p50"] + 2e-3
    assert limited["efficiency"] < plain["efficiency"]
