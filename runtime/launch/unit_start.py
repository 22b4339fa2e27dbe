"""One start of a unit on this host (``ctrlunit start``), as a lifecycle: *configure*
(the setup, the live view, the scheduling policy), *activate* (the run directory, the
central's node and the central, the roles' processes, the handshake, the warm-up, the
placement and reply choices, the admission), *run* (the intervals), *deactivate* (the
stop order and the roles' reports, the processes ended, the node and the recording
closed) and the report (docs/architecture.md, processes and their lifecycle).

:func:`~.launcher.start` makes one :class:`UnitStart` a start (``--period auto`` may
start again at a longer period) and calls it.
"""

from __future__ import annotations

import gc
import json
import os
import shutil
import signal
import subprocess
import threading
from pathlib import Path
from typing import Any

from ..central import Central, Fault, Supervision
from ..compute.setup import make_setup
from ..config import EXIT_CONFIG, EXIT_OK, EXIT_UNSUSTAINABLE, ConfigError, RunConfig
from ..host import sched
from ..host.busy_guard import BusyGuard
from ..host.unit_load import UnitLoad
from ..observe.report import finish_report
from ..roles.stopping import STOP_SIGNALS, held_stops, not_ignored, stop_of, stopped_by_user
from ..roles.supervise import end_children, role_cpus, spawn_role, unit_cores
from ..transport.node import freeze_heap
from .admission import Unsustainable, admit
from .run_dir import keep, make_run_dir
from .run_parts import (
    STOP_REPORTS_WAIT_S,
    central_node,
    chain,
    child_names,
    every_start,
    live_view,
    observers_view,
    raise_to_mine,
    report_extras,
    ros2_config,
    ros2_live,
    status_writer,
    supervision,
    view_task,
)

OBSERVERS_JOIN_S = 0.5
"""How long the end of a run waits for the observers' view to send its last messages."""


class UnitStart:
    """One start of the unit of ``rc``; calling it runs the lifecycle and returns
    ``(exit code, report)``.

    Parameters
    ----------
    rc : the run's configuration.
    echo, progress : where messages go; the progress line's hook (or None).
    spawn : start the plant and the peripherals here (else they are started by hand).
    inspect : receives the central and the setup (benchmarks), or None.
    view : the live view across starts (made at the first start, closed by the caller).
    idle : the caller's CPU idle request (runtime/host/idle.py), for the report.
    """

    def __init__(self, rc: RunConfig, *, echo: Any, progress: Any, spawn: bool,
                 inspect: dict | None, view: list[Any], idle: dict[str, Any]) -> None:
        self.rc = rc
        self.echo, self.progress, self.spawn, self.inspect = echo, progress, spawn, inspect
        self.view, self.idle = view, idle
        self.children: list[subprocess.Popen] = []
        self.pids: dict[str, int] = {}  # the roles' processes, once started
        self.code = EXIT_OK
        self.fault: dict[str, Any] | None = None
        self.kept: Path | None = None  # the run directory, kept after a fault
        self.decided: dict[str, Any] = {}
        self.ros2: Any = None  # --ros2's topics, once the node is open
        """What the start decided on the way: admission, placement choice, Zenoh ids."""

    def __call__(self, *, descend: bool = False,
                 tried: list[dict[str, Any]] | None = None) -> tuple[int, dict]:
        """Start the unit and run it; ``descend``: ``--period auto``'s first start, whose
        admission may go down the ladder (runtime/launch/admission.py); ``tried``: the
        admission trials of the starts before this one, which its report (and recording)
        give before its own."""
        refused = self.configure()
        if refused is not None:
            return refused
        self.open()
        ctrl_c: list[int] = []  # signals during the clean-up: they end the run
        handlers = {s: signal.getsignal(s) for s in not_ignored((signal.SIGINT, *STOP_SIGNALS))}
        try:
            with held_stops(self.node.events):  # a stop signal: raised between two turns
                self.activate(descend=descend)
                self.run()
        except Fault as exc:
            self.code = exc.code
            self.fault = {"process": exc.process, "message": str(exc), "code": exc.code}
        except Unsustainable as exc:
            self.code, self.decided["admission"] = exc.code, exc.info
            self.fault = {"process": "admission", "message": str(exc), "code": exc.code,
                          "headline": exc.headline, "advice": exc.advice}
        except KeyboardInterrupt as exc:  # Ctrl-C, or SIGTERM / SIGHUP (Terminated)
            self.code, self.fault = stop_of(exc)
        finally:
            self.deactivate(handlers, ctrl_c)
        if ctrl_c and not stopped_by_user({"fault": self.fault}):
            self.code, self.fault = stop_of(ctrl_c[0])
        self.leave()
        report = self.report(tried or [])
        if self.kept is not None:  # after the recording's copy: a path on this host only
            report["logs_kept"] = str(self.kept)
        return self.code, report

    # -- configure --------------------------------------------------------------------

    def configure(self) -> tuple[int, dict] | None:
        """The setup, the live view and the scheduling policy; a refusal of the
        configuration as ``(exit code, report)``, else None."""
        rc = self.rc
        self.viewer = None
        try:
            self.setup = setup = make_setup(rc)
            ros2_config(rc)  # --ros2: a router answers, else the start is refused here
            # before the real-time policy: the view's threads stay at normal priority
            if self.view:
                self.viewer = self.view[0]
                self.viewer.rerun(task=view_task(rc, setup), period_s=rc.schedule.period,
                                  cycles=setup.cycles)
            else:
                self.viewer = live_view(rc, setup, self.echo)
                self.view += [self.viewer] if self.viewer is not None else []
            # before zenoh.open and the children: Zenoh's threads and the roles inherit it
            self.sched_choice = sched.apply_choice(
                rc.schedule.rt_priority, clock=rc.schedule.clock,
                admission=rc.schedule.admission or rc.schedule.trial_only,
                pinned=bool(rc.schedule.cpus or rc.schedule.pin))[1]
        except (ConfigError, ValueError, OSError, sched.RtPermissionError) as exc:
            return EXIT_CONFIG, {"fault": {"process": "configuration", "message": str(exc),
                                           "code": EXIT_CONFIG}, "idle": self.idle}
        self.rc = rc.replace(trace=bool(rc.run.record))
        return None

    # -- activate ---------------------------------------------------------------------

    def open(self) -> None:
        """The run directory, the CPUs, the central's node, the recorder and the
        central."""
        rc, setup = self.rc, self.setup
        self.run_dir = make_run_dir()
        (self.run_dir / "spec.json").write_text(json.dumps({"run": rc.to_dict()}))
        self.cpus = role_cpus(rc)  # (the central's, the children's): before pinning
        if self.cpus[0]:
            sched.pin_all(self.cpus[0])  # before zenoh.open: its threads inherit it
        self.node, self.endpoint = central_node(rc, self.run_dir)
        self.guard = self._busy_guard()
        self.observers = observers_view(rc, setup, self.node, self.echo, self.run_dir)
        # after the node's session: Zenoh's threads, shared, are made under the RT policy
        self.ros2 = ros2_live(rc, setup, self.echo)
        self.recorder = None
        if rc.run.record:
            from ..recording.recorder import Recorder

            self.recorder = Recorder(rc.run.record, setup)
        engine = setup.engine()
        self.central = Central(
            self.node, rc, engine, setup.controller(engine), setup.cycles,
            on_cycle=chain(self.recorder.on_cycle if self.recorder else None, self.progress,
                           self.viewer, self.observers, self.ros2,
                           status_writer(rc.run.status_file), self.guard),
            on_message=self.recorder.on_message if self.recorder else None,
            supervision=supervision(self.children, self.pids, child_names(rc, setup),
                                    respawn=self._spawn_one)
            if self.spawn else Supervision())

    def _busy_guard(self) -> BusyGuard | None:
        """Under FIFO: back to the default policy before the kernel throttles. The guard
        and the admission judge the unit's own CPU time (runtime/host/unit_load.py), read
        by a thread of its own, not the machine's."""
        choice = self.sched_choice
        if not (sched.fifo_in_force() and choice["budget"] is not None):
            return None
        children = self.children

        def pids() -> list[int]:
            return [os.getpid()] + [p.pid for p in children if p.poll() is None]

        return BusyGuard(pids, choice["budget"], priority=choice["priority"], say=self.echo,
                         load=UnitLoad(pids).__enter__())

    def activate(self, *, descend: bool = False) -> None:
        """Start the roles' processes, then the handshake, the warm-up, the reply mode,
        the placement (``auto``) and the admission (realtime)."""
        self._spawn()
        central, rc = self.central, self.rc
        central.handshake()
        raise_to_mine(self.pids.values())  # each set up: as a role started again is raised
        central.warm_up()
        central.choose_replies()
        if (rc.schedule.placement_auto and rc.schedule.central_blocks is None
                and self.setup.placement.peripherals):
            self._place()
        if rc.schedule.clock == "realtime" and (rc.schedule.admission or rc.schedule.trial_only):
            self.decided["admission"] = admit(
                central, unit_cpu=self.guard.load.sample if self.guard and self.guard.load
                else None, rehearse=self._rehearsal if self.recorder else None,
                descend=descend and rc.schedule.period_auto and not rc.schedule.trial_only,
                note=self.echo)

    def _rehearsal(self) -> Any:
        """The recorder of one admission trial: the run's work after each interval, kept
        nowhere."""
        from ..recording.recorder import Recorder

        return Recorder.rehearsal(self.setup)

    def _spawn(self) -> None:
        """The roles' processes, started under the default policy (set up, it is raised)."""
        if not self.spawn:
            return
        with sched.thread_at_default():
            for name in child_names(self.rc, self.setup):
                self.children.append(self._spawn_one(name))
                self.pids[name] = self.children[-1].pid

    def _spawn_one(self, name: str) -> subprocess.Popen:
        """Start role ``name`` (``plant``, ``peripheral-K``) from the run's spec file; its
        output goes to ``name.log`` in the run's directory (appended: a role started
        again during the run keeps its first process's log)."""
        role, _, k = name.partition("-")
        return spawn_role(self.run_dir / "spec.json", role, int(k) if k else None,
                          self.endpoint, self.run_dir / f"{name}.log", cpus=self.cpus[1])

    def _place(self) -> None:
        """``--placement auto``: the warm-up's choice; if it differs, the roles take the
        new plan where they are (no start again), warmed up anew."""
        choice = self.decided["placement_choice"] = self.central.choose_placement()
        if choice["central_blocks"] == sorted(self.setup.placement.central_blocks):
            return
        self.setup = setup = self.setup.with_central_blocks(choice["central_blocks"])
        self.rc = self.rc.replace(central_blocks=setup.rc.schedule.central_blocks)
        engine = setup.engine()
        self.central.place(self.rc, engine, setup.controller(engine))
        self.echo(f"ctrlunit: --placement auto: {choice['why']}")
        self.central.warm_up()  # the new plan's path, and its round trip
        self.central.choose_replies()

    # -- run --------------------------------------------------------------------------

    def run(self) -> None:
        """The intervals (not after a trial only)."""
        if self.rc.schedule.trial_only:
            return
        freeze_heap(collect=True)  # this process may host many runs (bench, tests)
        if self.recorder is not None:
            self.recorder.begin(self.setup)
        self.central.zenoh_identity()  # the peers now (others may leave before the end)
        stolen0 = sched.stolen_s()  # before the plant ticks: off the timed path
        self.central.say("start")
        try:
            self.central.run()
        finally:  # a fault's report too: the host's stall may be its cause
            self.decided["host_stolen_s"] = sched.most_stolen(stolen0, sched.stolen_s())

    # -- deactivate -------------------------------------------------------------------

    def deactivate(self, handlers: dict, ctrl_c: list[int]) -> None:
        """Stop the roles (the plant's safe stop) and collect their reports, end their
        processes, close the node, the recording and the view; a Ctrl-C or stop signal
        meanwhile is kept in ``ctrl_c`` (it ends the run, no start again)."""
        main = threading.current_thread() is threading.main_thread()
        if main:
            for s in handlers:
                signal.signal(s, lambda signum, _f: ctrl_c.append(signum))
        gc.unfreeze()  # what the run kept alive may be collected again
        central = self.central
        try:
            self.decided["zenoh"] = central.zenoh_identity()
        except Exception:
            self.decided["zenoh"] = {}
        interrupted = stopped_by_user({"fault": self.fault})
        try:
            # after a fault or a stop the roles' reports come within a few tens of ms; a
            # role that a signal of its own reached as the order came lost that order, and
            # takes the next (every 0.1 s), so a stop waits for the reports as long as a
            # fault does
            central.stop(reason="done" if self.fault is None else self.fault["message"],
                         wait=5.0 if self.fault is None else STOP_REPORTS_WAIT_S)
        finally:
            end_children(self.children, grace=0.3 if interrupted else 1.0)
            if self.guard is not None:
                self.guard.close()
            self.observers.close(join_s=OBSERVERS_JOIN_S)
            if self.ros2 is not None:
                self.ros2.close(join_s=OBSERVERS_JOIN_S)
            self.node.close()
            if self.recorder is not None:
                self.recorder.close(central.snapshot())
            if self.viewer is not None:
                self.viewer.flush()
            if main:
                for s, h in handlers.items():
                    signal.signal(s, h)

    def leave(self) -> None:
        """Say which role exited with an error, and remove the run directory unless the
        run failed (its spec, socket and logs diagnose a fault; a refusal's figures are in
        the report, and a stop the user asked for is no fault): then it is kept
        (runtime/launch/run_dir.py), the report's ``logs_kept``, named after the summary."""
        central = getattr(self, "central", None)  # None: the start failed before it
        taken = ({f"peripheral-{d['peripheral']}" for d in central.snapshot().degraded}
                 if central else set())
        for p, name in zip(self.children, child_names(self.rc, self.setup), strict=False):
            if (p.returncode not in (0, None, -signal.SIGTERM, 128 + signal.SIGTERM)
                    and self.fault is None):
                if name in taken:  # the summary's degraded lines say what became of it
                    self.echo(f"ctrlunit: {name} exited with {p.returncode}; the central had "
                              "taken its rounds over")
                    continue
                log = (self.run_dir / f"{name}.log").read_text(errors="replace")[-2000:]
                self.echo(f"ctrlunit: {name} exited with {p.returncode}"
                          + (f":\n{log}" if log.strip() else " (its log is empty)"))
        if self.code in (EXIT_OK, EXIT_UNSUSTAINABLE) or stopped_by_user({"fault": self.fault}):
            shutil.rmtree(self.run_dir, ignore_errors=True)
        else:
            keep(self.run_dir)
            self.kept = self.run_dir

    # -- report -----------------------------------------------------------------------

    def report(self, tried: list[dict[str, Any]]) -> dict[str, Any]:
        """The run's report (runtime/observe/report.py) with what this start decided."""
        rc, central = self.rc, self.central
        run = central.snapshot()
        report = finish_report(self.setup, run, self.fault)
        for key in ("admission", "placement_choice"):
            if self.decided.get(key) is not None:
                report[key] = self.decided[key]
        if report.get("admission"):
            report["admission"] = every_start(tried, report["admission"])
        report["scheduling_choice"] = self.sched_choice
        report["host_stolen_s"] = self.decided.get("host_stolen_s")
        report["idle"] = self.idle
        report["scheduling_fallback"] = self.guard.report() if self.guard is not None else None
        report["zenoh"] = self.decided.get("zenoh", {})
        report["link_list"] = rc.links(central=self.endpoint)  # the central's, the default's too
        report["links"] = rc.link_security(check_files=False, central=self.endpoint)
        cores = unit_cores(*self.cpus) if self.spawn else None
        report.update(report_extras(rc, self.setup, run, cores=cores, spawn=self.spawn))
        if self.inspect is not None:
            self.inspect["central"] = central
            self.inspect["setup"] = self.setup
        if self.recorder is not None:
            self.recorder.write_report(report)
            if self.recorder.failed:
                report["recording_failed"] = self.recorder.failed
        if self.viewer is not None:
            report["live_view"] = {"url": self.viewer.url, "sent": self.viewer.sent,
                                   "dropped": self.viewer.dropped}
        report["observers"] = {"keys": self.observers.url, "sent": self.observers.sent,
                               "dropped": self.observers.dropped}
        if self.ros2 is not None:
            report["ros2"] = self.ros2.report()
        if self.node.close_error is not None:
            report["zenoh"]["close_error"] = self.node.close_error
        return report


__all__ = ["UnitStart"]
