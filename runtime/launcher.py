"""``ctrlunit start``: plant, central and peripherals on this host.

The launcher runs the central in its own process and starts the plant and the peripherals
as children (:mod:`.supervise`; each role's entry point is in its own module). Every
child dies with the launcher (``PR_SET_PDEATHSIG``), exits on the central's ``stop``, and
has a watchdog on the central's silence; on completion, Ctrl-C or any failure the
launcher says stop, waits briefly, then terminates and kills what is left. SIGTERM (``kill``,
``timeout``, a service manager) and SIGHUP (the terminal closed) end a run as Ctrl-C does:
the robot stopped safely, the report written, the recording closed.
"""

from __future__ import annotations

import contextlib
import gc
import json
import os
import shutil
import signal
import subprocess
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

from . import sched
from .admission import LADDER_S, Unsustainable, admit
from .central import Central, Fault, Supervision
from .config import (
    EXIT_CONFIG,
    EXIT_OK,
    EXIT_UNSUSTAINABLE,
    ConfigError,
    RunConfig,
    parse_host_port,
)
from .idle import IdlePermissionError, idle_request
from .node import Node, freeze_heap, rss_kb
from .report import cpu_budget, finish_report, text_or_none
from .setup import Setup, make_setup
from .stopping import STOP_SIGNALS, not_ignored, stop_of, stop_signals, stopped_by_user
from .supervise import (
    ZENOH_THREADS,
    ThreadTimes,
    end_children,
    machine_load,
    process_state,
    role_cpus,
    spawn_role,
    thread_times,
    unit_cores,
)
from .zsession import default_endpoint, make_config

STOP_REPORTS_WAIT_S = 0.5
"""How long the central waits for the roles' last reports (the plant's safe stop among
them) after a fault or a stop by the user; it goes on as soon as every role reported."""


def central_only(rc: RunConfig) -> tuple[int, dict]:
    """Run the central alone (the other roles are started by hand)."""
    return start(rc, spawn=False)


def start(rc: RunConfig, *, echo: Any = print, progress: Any = None, spawn: bool = True,
          inspect: dict | None = None) -> tuple[int, dict]:
    """Run a whole unit on this host; returns ``(exit code, report)``. ``inspect``, if
    given, receives the central (spans, logs) for benchmarks. This process's scheduling
    policy is what it was before when it returns (see :mod:`.sched`). SIGTERM and SIGHUP
    end the run as Ctrl-C does (:func:`stop_of`)."""
    with stop_signals():
        return _climb(rc, echo=echo, progress=progress, spawn=spawn, inspect=inspect)


def _climb(rc: RunConfig, *, echo: Any, progress: Any, spawn: bool,
           inspect: dict | None) -> tuple[int, dict]:
    """:func:`start`'s starts: under ``--period auto`` each start climbs the ladder."""
    saved = sched.current()
    tried: list[dict] = []
    view: list[Any] = []  # the live view, kept across starts (its viewers stay connected)
    affinity = os.sched_getaffinity(0)  # a start pins this process (--cpus, --pin)
    idle_hold = contextlib.ExitStack()  # --idle: held over every start, the trials among them
    try:
        try:
            idle_choice = idle_hold.enter_context(idle_request(rc.schedule.idle,
                                                          clock=rc.schedule.clock))
        except (ValueError, IdlePermissionError) as exc:
            return EXIT_CONFIG, {"fault": {"process": "configuration", "message": str(exc),
                                           "code": EXIT_CONFIG}}
        # --period auto: each start climbs the ladder
        for attempt in range(len(LADDER_S)):
            os.sched_setaffinity(0, affinity)  # each start chooses the roles' CPUs afresh
            code, report = _start(rc, echo=echo, progress=progress, spawn=spawn,
                                  inspect=inspect, view=view, idle=idle_choice)
            adm = report.get("admission") or {}
            tried += [r | {"start": attempt} for r in adm.get("rungs") or []]
            held = adm.get("sustainable_period_s")
            if not (code == EXIT_UNSUSTAINABLE and rc.schedule.period_auto and held
                    and held > rc.schedule.period and not rc.schedule.trial_only):
                break
            echo(f"ctrlunit: --period auto: {rc.schedule.period * 1e3:g} ms was not held in the "
                 f"trial, {held * 1e3:g} ms was; starting again at {held * 1e3:g} ms")
            rc = rc.replace(period=held)
        if adm:
            report["admission"]["rungs"] = tried
        return code, report
    except KeyboardInterrupt as exc:  # between two starts: no role is running
        code, fault = stop_of(exc)
        return code, {"fault": fault}
    finally:
        for v in view:
            v.close()
        idle_hold.close()
        os.sched_setaffinity(0, affinity)
        sched.restore(saved)


def _supervision(children: list[subprocess.Popen], pids: dict[str, int],
                 names: list[str]) -> Supervision:
    """What the central can learn of the role processes it starts (``children``, named
    ``names`` in order; ``pids`` by name, filled once they are started)."""

    def check() -> tuple[str, int] | None:
        for p, name in zip(children, names, strict=False):
            if p.poll() is not None:
                return name, p.returncode
        return None

    def role_state(role: str) -> str:
        if role == "central":  # its Zenoh threads: is anything in transit here?
            return process_state(os.getpid(), threads=ZENOH_THREADS)
        return process_state(pids[role]) if role in pids else "unknown"

    def role_times(role: str) -> ThreadTimes:
        if role == "central":
            return thread_times(os.getpid(), threads=ZENOH_THREADS)
        return thread_times(pids[role]) if role in pids else {}

    return Supervision(check, role_state, role_times, machine_load)


def _start(rc: RunConfig, *, echo: Any, progress: Any, spawn: bool,
           inspect: dict | None, view: list[Any], idle: dict[str, Any]) -> tuple[int, dict]:
    """One start of the unit; ``view`` holds the live view across starts (made at the
    first, closed by the caller); ``idle`` the caller's CPU idle request (runtime/idle.py),
    for the report."""
    viewer = None
    try:
        setup = make_setup(rc)
        # before the real-time policy: the view's threads stay at normal priority
        if view:
            viewer = view[0]
            viewer.rerun(task=_view_task(rc, setup), period_s=rc.schedule.period,
                         cycles=setup.cycles)
        else:
            viewer = _live_view(rc, setup, echo)
            view += [viewer] if viewer is not None else []
        # before zenoh.open and the children: Zenoh's threads and the roles inherit it
        sched_choice = sched.apply_choice(
            rc.schedule.rt_priority, clock=rc.schedule.clock,
            admission=rc.schedule.admission or rc.schedule.trial_only)[1]
    except (ConfigError, ValueError, OSError, sched.RtPermissionError) as exc:
        return EXIT_CONFIG, {"fault": {"process": "configuration", "message": str(exc),
                                       "code": EXIT_CONFIG}, "idle": idle}
    rc = rc.replace(trace=bool(rc.run.record))
    run_dir = Path(tempfile.mkdtemp(prefix="ctrlunit-"))
    spec = run_dir / "spec.json"
    spec.write_text(json.dumps({"run": rc.to_dict()}))
    endpoint = rc.transport.listen[0] if rc.transport.listen else default_endpoint(run_dir)
    connect_ep = endpoint  # the children always connect to their own central
    central_cpus, child_cpus = role_cpus(rc)  # before this process pins itself
    cores = unit_cores(central_cpus, child_cpus) if spawn else None
    if central_cpus:
        os.sched_setaffinity(0, central_cpus)  # before zenoh.open: its threads inherit it
    # --connect joins the central to another Zenoh network (e.g. another unit's)
    node = Node(make_config(listen=[endpoint], connect=rc.transport.connect,
                            config_file=rc.transport.zenoh_config, keys=rc.transport.keys,
                            role="central"), rc.transport.unit, "central")
    engine = setup.engine()
    ctl = setup.controller(engine)
    children: list[subprocess.Popen] = []
    guard = None  # under FIFO: back to the default policy before the kernel throttles
    if sched.fifo_in_force() and sched_choice["budget"] is not None:
        guard = sched.BusyGuard(
            lambda: [os.getpid()] + [p.pid for p in children if p.poll() is None],
            sched_choice["budget"], priority=sched_choice["priority"], say=echo)
    recorder = None
    if rc.run.record:
        from .recorder import Recorder

        recorder = Recorder(rc.run.record, setup)
    pids: dict[str, int] = {}  # the roles' processes, once started
    central = Central(node, rc, engine, ctl, setup.cycles,
                      on_cycle=_chain(recorder.on_cycle if recorder else None, progress,
                                      viewer, _status_writer(rc.run.status_file), guard),
                      on_message=recorder.on_message if recorder else None,
                      supervision=_supervision(children, pids, _child_names(rc, setup))
                      if spawn else Supervision())
    code, fault = EXIT_OK, None
    admission: dict | None = None
    placement_choice: dict | None = None
    ctrl_c: list[int] = []  # signals during the clean-up: they end the run, no start again
    old_handlers = {s: signal.getsignal(s) for s in not_ignored((signal.SIGINT, *STOP_SIGNALS))}
    try:
        if not spawn:
            pass
        elif rc.schedule.clock != "freerun":
            children.append(spawn_role(spec, "plant", None, connect_ep, run_dir / "plant.log",
                                       cpus=child_cpus))
        for k in range(setup.placement.peripherals if spawn else 0):
            children.append(spawn_role(spec, "peripheral", k + 1, connect_ep,
                                       run_dir / f"peripheral-{k + 1}.log", cpus=child_cpus))
        names = _child_names(rc, setup) if spawn else []
        pids.update({name: p.pid for p, name in zip(children, names, strict=False)})
        central.orders.handshake()
        central.warmup.run()
        central.choose_replies()
        if (rc.schedule.placement_auto and rc.schedule.central_blocks is None
                and setup.placement.peripherals):
            placement_choice = central.warmup.choose_placement()
            if placement_choice["central_blocks"] != sorted(setup.placement.central_blocks):
                # the roles take the new plan where they are: no start again
                setup = setup.with_central_blocks(placement_choice["central_blocks"])
                rc = rc.replace(central_blocks=setup.rc.schedule.central_blocks)
                engine = setup.engine()
                central.place(rc, engine, setup.controller(engine))
                echo(f"ctrlunit: --placement auto: {placement_choice['why']}")
                central.warmup.run()  # the new plan's path, and its round trip
                central.choose_replies()
        if rc.schedule.clock == "realtime" and (rc.schedule.admission or rc.schedule.trial_only):
            admission = admit(central)
        if not rc.schedule.trial_only:
            freeze_heap(collect=True)  # this process may host many runs (bench, tests)
            if recorder is not None:
                recorder.begin(setup)
            central.orders.zenoh_identity()  # the peers now (others may leave before the end)
            central.orders.say("start")
            central.run()
    except Fault as exc:
        code = exc.code
        fault = {"process": exc.process, "message": str(exc), "code": exc.code}
    except Unsustainable as exc:
        code, admission = exc.code, exc.info
        fault = {"process": "admission", "message": str(exc), "code": exc.code}
    except KeyboardInterrupt as exc:  # Ctrl-C, or SIGTERM / SIGHUP (Terminated)
        code, fault = stop_of(exc)
    finally:
        # finish cleaning up; a Ctrl-C or stop signal meanwhile is kept (it ends the run,
        # no start again)
        if threading.current_thread() is threading.main_thread():
            for s in old_handlers:
                signal.signal(s, lambda signum, _f: ctrl_c.append(signum))
        gc.unfreeze()  # what the run kept alive may be collected again
        central.meters.t_end_ns = central.meters.t_end_ns or time.monotonic_ns()
        try:
            zenoh_ids = central.orders.zenoh_identity()
        except Exception:
            zenoh_ids = {}
        interrupted = stopped_by_user({"fault": fault})
        try:
            # after a fault or a stop the roles' reports come within a few tens of ms; a
            # role that a signal of its own reached as the order came lost that order, and
            # takes the next (every 0.1 s), so a stop waits for the reports as long as a
            # fault does
            central.stop(reason="done" if fault is None else fault["message"],
                         wait=5.0 if fault is None else STOP_REPORTS_WAIT_S)
        finally:
            end_children(children, grace=0.3 if interrupted else 1.0)
            node.close()
            if recorder is not None:
                recorder.close(central)
            if viewer is not None:
                viewer.flush()
            if threading.current_thread() is threading.main_thread():
                for s, h in old_handlers.items():
                    signal.signal(s, h)
    if ctrl_c and not stopped_by_user({"fault": fault}):
        code, fault = stop_of(ctrl_c[0])
    for p, name in zip(children, _child_names(rc, setup), strict=False):
        if p.returncode not in (0, None, -signal.SIGTERM, 128 + signal.SIGTERM) and fault is None:
            log = (run_dir / f"{name}.log").read_text(errors="replace")[-2000:]
            echo(f"ctrlunit: {name} exited with {p.returncode}:\n{log}")
    # the run directory (spec, socket, role logs) is for diagnosing a fault; a refusal's
    # figures are all in the report's admission
    if code in (EXIT_OK, EXIT_UNSUSTAINABLE):
        shutil.rmtree(run_dir, ignore_errors=True)
    else:
        echo(f"ctrlunit: the roles' logs are kept in {run_dir}")
    report = finish_report(setup, central, fault)
    if admission is not None:
        report["admission"] = admission
    if placement_choice is not None:
        report["placement_choice"] = placement_choice
    report["scheduling_choice"] = sched_choice
    report["idle"] = idle
    report["scheduling_fallback"] = guard.report() if guard is not None else None
    report["zenoh"] = zenoh_ids
    report["late"] = {"policy": rc.schedule.late_policy, "blocks": dict(rc.schedule.late),
                      "misses_per_axis": list(central.late.late_per_axis),
                      "computed": central.late.computed}
    m = central.meters
    report["memory_kb"] = {"central": {"warm": m.rss_warm,
                                       "end": m.rss_end if m.rss_end > 0 else rss_kb(),
                                       "series": m.rss_series}}
    for role, rep in central.orders.role_reports.items():
        if isinstance(rep.get("rss_kb"), dict):
            report["memory_kb"][role] = rep["rss_kb"]
    report.update(cpu_budget(central, _child_names(rc, setup), cores))
    reports = central.orders.role_reports
    report["scheduling"] = {"central": sched.policy_name()} | {
        name.replace("-", "_"): text_or_none((reports.get(name) or {}).get("sched"))
        for name in (_child_names(rc, setup) if spawn else [])}
    if rc.schedule.clock != "freerun":  # the plant's own word that it held and braked
        plant = central.orders.role_reports.get("plant") or {}
        stop = plant.get("safe_stop")
        report["safe_stop"] = stop if isinstance(stop, dict) else None
        report["plant_commands"] = plant.get("commands")  # commands it took
        # late commands it replaced with the one extrapolated the period before
        report["plant_spares"] = plant.get("spares")
    if inspect is not None:
        inspect["central"] = central
        inspect["setup"] = setup
    if recorder is not None:
        recorder.write_report(report)
    if viewer is not None:
        report["live_view"] = {"url": viewer.url, "sent": viewer.sent,
                               "dropped": viewer.dropped}
    return code, report


def _live_view(rc: RunConfig, setup: Setup, echo: Any) -> Any:
    """``--foxglove``: the live view's server (runtime/viewer.py), or ``None``."""
    if not rc.run.foxglove:
        return None
    from .viewer import LiveView

    host, port = parse_host_port(rc.run.foxglove, field_name="--foxglove")
    view = LiveView(host=host, port=port, task=_view_task(rc, setup),
                    period_s=rc.schedule.period,
                    cycles=setup.cycles, rate_hz=rc.run.foxglove_rate,
                    name=f"ctrlunit {rc.transport.unit}")
    echo(f"ctrlunit: live view on {view.url} (in Foxglove: Open connection, Foxglove "
         "WebSocket)")
    return view


def _view_task(rc: RunConfig, setup: Setup) -> Any:
    """The reference the live view draws (none in freerun)."""
    return setup.task if rc.schedule.clock != "freerun" else None


def _child_names(rc: RunConfig, setup: Setup) -> list[str]:
    names = [] if rc.schedule.clock == "freerun" else ["plant"]
    return names + [f"peripheral-{k + 1}" for k in range(setup.placement.peripherals)]


def _status_writer(path: str | None) -> Any:
    """Every 10 intervals, write the completed count to ``path`` (atomic rename)."""
    if not path:
        return None
    tmp = path + ".tmp"

    def write(central: Central, _cycle: int, _ctx: dict) -> None:
        if central.done % 10 == 0:
            with open(tmp, "w") as fh:
                fh.write(str(central.done))
            os.replace(tmp, path)

    return write


def _chain(*fns: Any) -> Any:
    fs = [f for f in fns if f is not None]
    if not fs:
        return None

    def call(*a: Any) -> None:
        for f in fs:
            f(*a)

    return call
