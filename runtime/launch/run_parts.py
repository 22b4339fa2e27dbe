"""What a start of the unit (:mod:`.unit_start`) is assembled from: the central's view of
the processes it starts, its per-interval hooks (progress, status file), the live view,
and the report's parts that come from the roles' final reports."""

from __future__ import annotations

import contextlib
import os
import queue
import subprocess
import threading
from collections.abc import Callable, Collection, Iterable
from pathlib import Path
from typing import Any

from ..central import Supervision
from ..central.snapshot import Progress, RunSnapshot
from ..compute.setup import Setup
from ..config import RunConfig, parse_host_port
from ..host import sched
from ..observe.report import cpu_budget, text_or_none
from ..roles.supervise import (
    ZENOH_THREADS,
    ThreadTimes,
    machine_load,
    process_cpus,
    process_state,
    thread_times,
)
from ..transport.endpoints import default_endpoint, is_socket, loopback_endpoint, with_free_port
from ..transport.limits import Limits
from ..transport.node import Node, rss_kb
from ..transport.zsession import make_config

STOP_REPORTS_WAIT_S = 0.5
"""How long the central waits for the roles' last reports (the plant's safe stop among
them) after a fault or a stop by the user; it goes on as soon as every role reported."""


def child_names(rc: RunConfig, setup: Setup) -> list[str]:
    """The roles a start runs besides the central, in the order they are started."""
    names = [] if rc.schedule.clock == "freerun" else ["plant"]
    return names + [f"peripheral-{k + 1}" for k in range(setup.placement.peripherals)]


def raise_to_mine(pids: Iterable[int]) -> None:
    """Every thread of each process ``pids`` (roles this one started, set up) under this
    thread's policy: SCHED_FIFO at its priority, or the default one."""
    fifo = os.sched_getscheduler(0) == os.SCHED_FIFO
    sched.demote(pids, priority=os.sched_getparam(0).sched_priority if fifo else 0)


def supervision(children: list[subprocess.Popen], pids: dict[str, int],
                names: list[str], *,
                respawn: Callable[[str], subprocess.Popen] | None = None) -> Supervision:
    """What the central can learn of the role processes it starts (``children``, named
    ``names`` in order; ``pids`` by name, filled as they are started), and how it starts
    one anew (``respawn(name)``, on a thread of its own: a start forks this process and
    waits for the new program, which the central's loop must not)."""

    def check(skip: Collection[str] = ()) -> tuple[str, int] | None:
        for p, name in zip(children, names, strict=False):
            if name not in skip and p.poll() is not None:
                return name, p.returncode
        return None

    def role_state(role: str) -> str:
        if role == "central":  # its Zenoh threads: is anything in transit here?
            return process_state(os.getpid(), threads=ZENOH_THREADS)
        return process_state(pids[role]) if role in pids else "unknown"

    def last_cpus(role: str) -> set[int]:
        return process_cpus(pids[role]) if role in pids else set()

    def role_times(role: str) -> ThreadTimes:
        if role == "central":
            return thread_times(os.getpid(), threads=ZENOH_THREADS)
        return thread_times(pids[role]) if role in pids else {}

    asked: queue.SimpleQueue[str] = queue.SimpleQueue()
    started: list[threading.Thread] = []

    def restarter() -> None:  # lives as long as the process: a role started by a thread
        os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))  # dies when it ends
        while True:  # (PR_SET_PDEATHSIG); a role it starts begins at the default policy
            role = asked.get()
            p = respawn(role)  # type: ignore[misc]
            children[names.index(role)], pids[role] = p, p.pid

    def restart(role: str) -> None:
        if not started:
            started.append(threading.Thread(target=restarter, name="restarter", daemon=True))
            started[0].start()
        asked.put(role)

    def promote(role: str) -> None:
        raise_to_mine([pids[role]])

    return Supervision(check, role_state, role_times, machine_load,
                       None if respawn is None else restart, promote, last_cpus)


def relayed(rc: RunConfig) -> list[str]:
    """The ``--listen`` endpoints the observers' relay takes (runtime/observe/relay.py):
    without keys and without ``--insecure`` every one but a unix socket, where only the
    observers' keys go; none otherwise (with keys roles on other hosts share the port)."""
    t = rc.transport
    if t.keys or t.insecure:
        return []
    return [e for e in t.listen or [] if not is_socket(e)]


RELAY_READY_S = 10.0
"""How long the launcher waits for the relay to listen."""


def start_relay(rc: RunConfig, run_dir: Path) -> subprocess.Popen | None:
    """The observers' relay on :func:`relayed`'s endpoints and a socket in ``run_dir``,
    once it listens; None where there are none. Its standard input is a pipe from this
    process: it ends when this process does, SIGKILL included. Raises OSError if it does
    not start (a port taken, say), naming why."""
    listen = relayed(rc)
    if not listen:
        return None
    import sys

    from ..observe.relay import SOCKET

    proc = subprocess.Popen(
        [sys.executable, "-m", "ctrlunit.runtime.observe.relay", "--socket",
         str(run_dir / SOCKET), "--listen", *listen], stdin=subprocess.PIPE,
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    ready: list[str] = []
    reader = threading.Thread(target=lambda: ready.append(proc.stdout.readline()),  # type: ignore[union-attr]
                              daemon=True)
    reader.start()
    reader.join(RELAY_READY_S)
    if not ready or ready[0].strip() != "ready":
        proc.kill()
        proc.wait()
        why = ready[0].strip().removeprefix("error: ") if ready and ready[0].strip() else \
            f"no answer within {RELAY_READY_S:g} s"
        raise OSError(f"--listen {', '.join(listen)}: the observers' relay did not start: "
                      f"{why}")
    return proc


VIEW_CONNECT_TRIES = 15
"""How many times the view tries to reach its relay, 0.2 s apart: connections held at
the observers' port can fill the relay's pending handshakes for a while."""


def _relay_client(socket: Path) -> Any:
    """A Zenoh client session of the observers' relay at ``socket``, or the last error."""
    import time

    import zenoh

    conf = make_config(connect=[f"unixsock-stream/{socket}"], lowlatency=False)
    conf.insert_json5("mode", '"client"')
    for attempt in range(VIEW_CONNECT_TRIES):
        try:
            return zenoh.open(conf)
        except Exception as exc:  # ZError: no handshake admitted
            if attempt == VIEW_CONNECT_TRIES - 1:
                return exc
            time.sleep(0.2)
    return None


def end_relay(proc: subprocess.Popen | None) -> None:
    """End the relay: its standard input closes, then SIGKILL if it lingers."""
    if proc is None:
        return
    with contextlib.suppress(OSError):
        proc.stdin.close()  # type: ignore[union-attr]
    try:
        proc.wait(timeout=2.0)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()


def central_node(rc: RunConfig, run_dir: Path) -> tuple[Node, str]:
    """The central's node and the endpoint the children connect to. The node listens on
    that endpoint and on ``--listen`` (its ports chosen already: :func:`listen_ports`).
    Without keys the endpoint is the first unix socket of ``--listen``, else the local
    socket in the run's folder, and any other link carries the observers' keys alone
    unless ``--insecure`` (runtime/transport/security.py); with keys (links must carry
    the roles' certificates) the first ``--listen`` endpoint, else TLS on a free loopback
    port, chosen again if taken meanwhile (5 tries). ``--connect`` joins the central to
    another Zenoh network (e.g. another unit's)."""
    t = rc.transport
    socket = next(filter(is_socket, t.listen or []), None)
    for attempt in range(5):
        endpoint = (t.listen[0] if t.listen else loopback_endpoint("tls")) \
            if t.keys else socket or default_endpoint(run_dir)
        listen = [e for e in dict.fromkeys([endpoint, *(t.listen or [])])
                  if e not in relayed(rc)]  # the observers' relay listens there instead
        conf = make_config(listen=listen,
                           connect=t.connect, config_file=t.zenoh_config, keys=t.keys,
                           role="central", limits=Limits.of(t), control=not t.insecure)
        try:
            return Node(conf, t.unit, "central"), endpoint
        except Exception:  # ZError: the port was taken meanwhile
            if t.listen or not t.keys or attempt == 4:
                raise
    raise AssertionError("unreachable")


def listen_ports(rc: RunConfig) -> RunConfig:
    """``rc`` with each ``--listen`` port 0 replaced by one free now
    (runtime/transport/endpoints.py, ``with_free_port``): chosen once for the whole run,
    so that what is printed is where the central listens, and every start of ``--period
    auto`` listens there (a viewer stays connected)."""
    given = rc.transport.listen or []
    fixed = [with_free_port(e) for e in given]
    return rc if fixed == given else rc.replace(listen=fixed)


def live_view(rc: RunConfig, setup: Setup, echo: Any) -> Any:
    """``--foxglove``: the live view's server (runtime/observe/viewer.py), or ``None``."""
    if not rc.run.foxglove:
        return None
    from ..observe.viewer import LiveView

    host, port = parse_host_port(rc.run.foxglove, field_name="--foxglove")
    view = LiveView(host=host, port=port, task=view_task(rc, setup),
                    period_s=rc.schedule.period,
                    cycles=setup.cycles, rate_hz=rc.run.foxglove_rate,
                    name=f"ctrlunit {rc.transport.unit}")
    echo(f"ctrlunit: live view on {view.url} (in Foxglove: Open connection, Foxglove "
         "WebSocket)")
    return view


def observers_view(rc: RunConfig, setup: Setup, node: Any, echo: Any,
                   run_dir: Path | None = None) -> Any:
    """The observers' view on ``ctrlunit/<unit>/view/`` (runtime/observe/zview.py): built
    only while someone subscribes, in the central's session ``node``, or, where
    :func:`relayed` gives the observers' relay ports (and ``run_dir`` its socket), in a
    client session of the relay, which it starts and ends with the view. Where
    ``--listen`` gives observers a way in, ``echo`` says where, and the keys they read."""
    from ..observe.viewer import LiveView
    from ..observe.zview import ZenohSink
    from ..transport.security import tls_endpoint

    t = rc.transport
    relay = start_relay(rc, run_dir) if run_dir is not None else None
    ports = [tls_endpoint(e) if t.keys else e for e in t.listen or []
             if not is_socket(e)]
    if ports:
        echo(f"ctrlunit: unit {t.unit}: observers read {node.keys.view('**')} on "
             f"{', '.join(ports)}" + (" (the viewer's certificate)" if t.keys else ""))
    sink = ZenohSink(node.session, node.keys)
    if relay is not None and run_dir is not None:
        from ..observe.relay import SOCKET

        session = _relay_client(run_dir / SOCKET)
        if isinstance(session, Exception) or session is None:
            end_relay(relay)  # the run goes on: an observer never stops the unit
            echo(f"ctrlunit: --listen: the observers' view could not reach its relay "
                 f"({str(session).split(' at /')[0]}): no view is served this run")
        else:
            sink = ZenohSink(session, node.keys, own=lambda: end_relay(relay))
    return LiveView(sink=sink, task=view_task(rc, setup),
                    period_s=rc.schedule.period, cycles=setup.cycles,
                    rate_hz=rc.run.foxglove_rate)


def ros2_config(rc: RunConfig, *, probe: bool = True) -> Any:
    """``--ros2``: the Zenoh configuration of the session that joins the ROS 2 network
    (runtime/transport/ros2_zenoh.py), with ``probe`` once a router answers there; None
    without ``--ros2``. Raises ValueError (a link the rule refuses) or OSError (no
    router)."""
    if rc.run.ros2 is None:
        return None
    from ..transport import ros2_zenoh

    conf = ros2_zenoh.session_config(os.environ, insecure=rc.transport.insecure)
    if probe:
        ros2_zenoh.probe(conf)
    return conf


def ros2_live(rc: RunConfig, setup: Setup, echo: Any) -> Any:
    """``--ros2``: the live ROS 2 topics (runtime/recording/ros2_live.py) in a session of
    their own, or None; a session that does not open is said and the run goes on
    without them (an observer never stops the unit)."""
    if rc.run.ros2 is None:
        return None
    from ..recording.ros2_live import Ros2Live

    try:
        live = Ros2Live(ros2_config(rc, probe=False), domain=rc.run.ros2, unit=rc.transport.unit,
                        task=view_task(rc, setup), period_s=rc.schedule.period,
                        rate_hz=rc.run.foxglove_rate)
    except Exception as exc:  # ZError: the router went away since the probe
        echo(f"ctrlunit: --ros2: no ROS 2 topics this run ({exc})")
        return None
    echo(f"ctrlunit: ROS 2 topics of node /{live.node} in domain {live.domain} via "
         f"{live.router} (ros2 topic echo /joint_states)")
    return live


def view_task(rc: RunConfig, setup: Setup) -> Any:
    """The reference the live view draws (none in freerun)."""
    return setup.task if rc.schedule.clock != "freerun" else None


def status_writer(path: str | None) -> Any:
    """Every 10 intervals, write the completed count to ``path`` (atomic rename)."""
    if not path:
        return None
    tmp = path + ".tmp"

    def write(progress: Progress, _ctx: dict) -> None:
        if progress.done % 10 == 0:
            with open(tmp, "w") as fh:
                fh.write(str(progress.done))
            os.replace(tmp, path)

    return write


def chain(*fns: Any) -> Any:
    """One hook calling each of ``fns`` that is not None, in order (None: none is)."""
    fs = [f for f in fns if f is not None]
    if not fs:
        return None

    def call(*a: Any) -> None:
        for f in fs:
            f(*a)

    return call


def report_extras(rc: RunConfig, setup: Setup, run: RunSnapshot, *, cores: int | None,
                  spawn: bool) -> dict[str, Any]:
    """The report's late data, memory, CPU budget, scheduling policies and the plant's
    own word on its safe stop: from the central's run and the roles' final reports."""
    reports = run.role_reports
    names = child_names(rc, setup)
    out: dict[str, Any] = {
        "late": {"policy": rc.schedule.late_policy, "blocks": dict(rc.schedule.late),
                 "misses_per_axis": list(run.late.per_axis),
                 "computed": run.late.computed, "taken_over": run.late.taken_over},
        "degraded": [dict(d) for d in run.degraded],
        "rebalanced": [dict(d) for d in run.rebalanced], "live_balance": run.live_balance,
        "memory_kb": {"central": {"warm": run.memory_kb[0],
                                  "end": run.memory_kb[1] if run.memory_kb[1] > 0 else rss_kb(),
                                  "series": list(run.memory_kb[2])}},
    }
    for role, rep in reports.items():
        if isinstance(rep.get("rss_kb"), dict):
            out["memory_kb"][role] = rep["rss_kb"]
    out.update(cpu_budget(run, names, cores))
    out["scheduling"] = {"central": sched.policy_name()} | {
        name.replace("-", "_"): text_or_none((reports.get(name) or {}).get("sched"))
        for name in (names if spawn else [])}
    if rc.schedule.clock != "freerun":  # the plant's own word that it held and braked
        plant = reports.get("plant") or {}
        stop = plant.get("safe_stop")
        out["safe_stop"] = stop if isinstance(stop, dict) else None
        out["plant_commands"] = plant.get("commands")  # commands it took
        # the admission's trial commands it checked and dropped (none acts)
        out["plant_trial_commands"] = plant.get("trial_commands")
        # late commands it replaced with the one extrapolated the period before
        out["plant_spares"] = plant.get("spares")
    return out


def every_start(tried: list[dict[str, Any]], admission: dict[str, Any]) -> dict[str, Any]:
    """A start's ``admission`` (runtime/launch/admission.py) with every start's trials in
    its ``rungs``: ``tried``, those of the starts before it (``--period auto`` starting
    again), then its own, each marked with its ``start`` (0 for the first)."""
    start = 1 + max((r["start"] for r in tried), default=-1)
    return admission | {"rungs": [*tried, *({**r, "start": start}
                                            for r in admission.get("rungs") or [])]}


__all__ = [
    "STOP_REPORTS_WAIT_S",
    "chain",
    "child_names",
    "end_relay",
    "every_start",
    "live_view",
    "observers_view",
    "raise_to_mine",
    "relayed",
    "report_extras",
    "ros2_config",
    "ros2_live",
    "start_relay",
    "status_writer",
    "supervision",
    "view_task",
]
