"""``ctrlunit start``: plant, central and peripherals on this host, and the roles one by one.

The launcher runs the central in its own process and starts the plant and the peripherals
as children. Every child dies with the launcher (``PR_SET_PDEATHSIG``), exits on the
central's ``stop``, and has a watchdog on the central's silence; on completion, Ctrl-C or
any failure the launcher says stop, waits briefly, then terminates and kills what is left.
"""

from __future__ import annotations

import contextlib
import ctypes
import json
import math
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..kernels.laws import Gains
from ..kernels.params import DELTA_IA, DeltaParams, load_params
from ..kernels.trajectory import Task, get_task
from ..kernels.workspace import require_path
from ..plant.simulator import Plant, PlantConfig
from ..topology.graph import stage_graph
from ..topology.placement import Placement, default_placement, load_placement
from ..topology.plan import ExchangePlan, exchange_plan
from . import sched
from .blocks import BlockConfig
from .central import Central, Fault, measure_t1
from .config import (
    EXIT_CONFIG,
    EXIT_INTERRUPTED,
    EXIT_LINK,
    EXIT_OK,
    ConfigError,
    RunConfig,
)
from .controller import Controller, initial_angles, initial_command
from .engine import CostModel, Engine
from .node import Node, rss_kb
from .report import build_report, gantt_window
from .zsession import default_endpoint, make_config


@dataclass
class Setup:
    """Everything a role derives from the run configuration."""

    rc: RunConfig
    params: DeltaParams
    task: Task
    placement: Placement
    plan: ExchangePlan
    cycles: int

    def engine(self, *, peripherals_plan: bool = True, cost: str | None = None) -> Engine:
        plan = self.plan if peripherals_plan else exchange_plan(self.plan.graph,
                                                                default_placement(0))
        lead_depth = self.rc.pipeline + (1 if self.rc.clock == "realtime" else 0)
        cfg = BlockConfig.build(self.params, model=self.rc.model,
                                gains=Gains.from_bandwidth(self.rc.bandwidth),
                                task=self.task, period=self.rc.period,
                                observer=self.rc.observer, depth=lead_depth)
        return Engine(plan, cfg, cost=CostModel(cost or self.rc.cost_model,
                                                scale=self.rc.cost_scale))


def make_setup(rc: RunConfig) -> Setup:
    """Validate a run configuration and derive the plan.

    Raises
    ------
    ConfigError
        Naming the field at fault; a task outside the usable workspace is refused here,
        before any motion.
    """
    rc.validate()
    params = DELTA_IA if rc.params is None else load_params(rc.params)
    try:
        task = get_task(rc.task).align(rc.period / 2.0)
    except ValueError as exc:
        raise ConfigError(f"task: {exc}") from None
    pts = np.array([task.sample_path(t)[0] for t in np.linspace(0.0, task.duration, 400)])
    try:
        require_path(params, pts, what=f"task {task.name}")
    except ValueError as exc:
        raise ConfigError(str(exc)) from None
    graph = stage_graph(rc.law, rc.model, observer=rc.observer)
    if rc.placement:
        placement = load_placement(rc.placement,
                                   block_names={b.name for b in graph.axis_blocks})
        if placement.peripherals != rc.peripherals:
            raise ConfigError(
                f"placement {rc.placement} has {placement.peripherals} peripherals but "
                f"--peripherals is {rc.peripherals}")
    else:
        placement = default_placement(rc.peripherals)
    plan = exchange_plan(graph, placement)
    return Setup(rc, params, task, placement, plan, rc.total_cycles(task.period))


# -- children -------------------------------------------------------------------------

_PR_SET_PDEATHSIG = 1


def _die_with_parent() -> None:  # runs in the child between fork and exec
    with contextlib.suppress(Exception):
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(_PR_SET_PDEATHSIG, signal.SIGTERM)


def _child_setup(cpus: set[int] | None) -> Callable[[], None]:
    """What a role's process does between fork and exec: die with its parent, and take
    its CPUs before its first instruction (threads it starts later, numpy's and Zenoh's,
    inherit them)."""
    def setup() -> None:
        _die_with_parent()
        if cpus:
            os.sched_setaffinity(0, cpus)

    return setup


def spawn_role(spec: Path, role: str, index: int | None, endpoint: str, log: Path, *,
               cpus: set[int] | None = None) -> subprocess.Popen:
    """Start one role as a child process (``ctrlunit plant|peripheral --spec``), on
    ``cpus`` (see :func:`role_cpus`) if given."""
    run = json.loads(spec.read_text())["run"]
    args = [sys.executable, "-m", "ctrlunit.runtime.cli", role, "--spec", str(spec),
            "--connect", endpoint, "--unit", run["unit"]]  # the unit id names it in ps
    if index is not None:
        args += ["--index", str(index)]
    out = open(log, "wb")
    return subprocess.Popen(args, stdout=out, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                            preexec_fn=_child_setup(cpus))


def role_cpus(rc: RunConfig) -> tuple[set[int] | None, set[int] | None]:
    """``(central, others)``: the CPUs the launcher pins itself (the central) and the roles
    it starts to, or None to leave an affinity alone.

    ``--cpus same``: every role on CPU 0; ``--cpus split``: the central on 0, the others
    on 1; ``--pin`` alone pins the central only. Read before the central pins itself: the
    children are given their CPUs explicitly, since they would otherwise inherit the
    central's. A CPU this process may not use is replaced by every CPU it may use.
    """
    pin = {int(c) for c in rc.pin.split(",") if c.strip()} if rc.pin else None
    try:
        mine = set(os.sched_getaffinity(0))
    except OSError:
        return pin, None

    def only(cpu: int) -> set[int]:
        return {cpu} if cpu in mine else mine

    if rc.cpus == "same":
        return pin or only(0), only(0)
    if rc.cpus == "split":
        return pin or only(0), only(1)
    return pin, (mine if pin else None)


def end_children(children: list[subprocess.Popen], *, grace: float = 1.0) -> None:
    """Wait up to ``grace`` s for children to exit, then terminate, then kill."""
    deadline = time.monotonic() + grace
    for p in children:
        with contextlib.suppress(subprocess.TimeoutExpired):
            p.wait(timeout=max(0.0, deadline - time.monotonic()))
    for p in children:
        if p.poll() is None:
            p.terminate()
    for p in children:
        try:
            p.wait(timeout=0.3)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait(timeout=1.0)


# -- roles ----------------------------------------------------------------------------


def run_peripheral(setup: Setup, index: int, conf: Any) -> int:
    from .peripheral import declare, serve

    node = Node(conf, setup.rc.unit, f"peripheral-{index}")
    try:
        reply = declare(node, index - 1)
        node.wait_for_go(timeout=setup.rc.startup_timeout)
        res = serve(node, setup.engine(), index - 1, reply,
                    watchdog=max(5.0, 3 * setup.rc.timeout), trace=setup.rc.trace)
        res["sched"] = sched.policy_name()
        _bye(node, res)
        return EXIT_OK if res["exit"] == "stop" else EXIT_LINK
    except TimeoutError as exc:
        print(f"ctrlunit peripheral {index}: {exc}", file=sys.stderr)
        return EXIT_LINK
    finally:
        node.close()


def run_plant(setup: Setup, conf: Any) -> int:
    from .plant_node import PlantServer, serve

    rc = setup.rc
    plant = Plant(setup.params, PlantConfig(period=rc.period, substeps=rc.plant_substeps,
                                           lag=rc.plant_lag, friction=rc.plant_friction,
                                           belt=rc.belt),
                  q0=initial_angles(setup.params, setup.task),
                  p_guess=tuple(setup.task.start()))
    node = Node(conf, rc.unit, "plant")
    try:
        server = PlantServer(node, plant, depth=rc.pipeline,
                             initial=initial_command(setup.params, setup.task))
        node.wait_for_go(timeout=rc.startup_timeout)
        res = serve(node, server, clock=rc.clock, period=rc.period, cycles=setup.cycles,
                    watchdog=max(5.0, 3 * rc.timeout))
        hold = (node.stop_msg or {}).get("hold")
        if isinstance(hold, list) and len(hold) == 3 and all(
                isinstance(x, float) and math.isfinite(x) for x in hold):
            plant.set_command(hold)
        res["safe_stop"] = safe_stop(plant)
        res["sched"] = sched.policy_name()
        _bye(node, res)
        return EXIT_OK if res["exit"] in ("stop", "done") else EXIT_LINK
    except TimeoutError as exc:
        print(f"ctrlunit plant: {exc}", file=sys.stderr)
        return EXIT_LINK
    finally:
        node.close()


def safe_stop(plant: Plant, *, hold_s: float = 0.05, damping: float = 5.0,
              drive_period: float = 2.5e-4) -> dict[str, Any]:
    """The documented stop: for ``hold_s``, gravity compensation (the torques the central
    sent with its stop order, computed at its last estimate; the last command if the
    central is gone) plus drive-level damping ``-damping * qdot`` (N m s/rad, updated
    every ``drive_period`` as a drive's own loop would, whatever the control period) so
    that a moving robot brakes instead of coasting; then zero torque.

    At the fastest point of pick & place (3.75 m/s) the platform travels 34 mm and is
    left at under 2 mm/s; the damping of 1 N m s/rad used before left it at 0.39 m/s.
    Returns the hold time, the distance moved and the platform speed at the end of it."""
    p0 = list(plant.state.p)
    hold = list(plant.command)
    # integrated with sub-steps no longer than the plant's own (the belt needs 0.1 ms)
    inner = max(1, math.ceil(drive_period * plant.config.n_substeps / plant.config.period
                             - 1e-9))
    for _ in range(max(1, round(hold_s / drive_period))):
        # a drive damps what its encoder sees: the motor, behind a belt
        qd = plant.state.motor_d if plant.config.belt else plant.state.qd
        plant.set_command([hold[i] - damping * qd[i] for i in range(3)])
        for _ in range(inner):
            plant.substep(drive_period / inner)
        plant.project()
    plant.set_command([0.0, 0.0, 0.0])
    return {"hold_s": hold_s, "drift_m": math.dist(p0, plant.state.p),
            "speed_m_s": math.hypot(*plant.state.pd)}


def _bye(node: Node, report: dict[str, Any]) -> None:
    from .codec import encode

    pub = node.publisher(node.keys.hello)
    for _ in range(3):
        pub.put(encode(node.unit, 0, "bye", role=node.role, report=report))
        time.sleep(0.02)


# -- the whole unit ---------------------------------------------------------------------


def central_only(rc: RunConfig) -> tuple[int, dict]:
    """Run the central alone (the other roles are started by hand)."""
    return start(rc, spawn=False)


def start(rc: RunConfig, *, echo: Any = print, progress: Any = None, spawn: bool = True,
          inspect: dict | None = None) -> tuple[int, dict]:
    """Run a whole unit on this host; returns ``(exit code, report)``. ``inspect``, if
    given, receives the central (spans, logs) for benchmarks. This process's scheduling
    policy is what it was before when it returns (see :mod:`.sched`)."""
    saved = sched.current()
    try:
        return _start(rc, echo=echo, progress=progress, spawn=spawn, inspect=inspect)
    finally:
        sched.restore(saved)


def _start(rc: RunConfig, *, echo: Any, progress: Any, spawn: bool,
           inspect: dict | None) -> tuple[int, dict]:
    try:
        setup = make_setup(rc)
        # before zenoh.open and the children: Zenoh's threads and the roles inherit it
        policy = sched.apply_rt(rc.rt_priority)
    except (ConfigError, ValueError, sched.RtPermissionError) as exc:
        return EXIT_CONFIG, {"fault": {"process": "configuration", "message": str(exc),
                                       "code": EXIT_CONFIG}}
    rc.trace = bool(rc.record)
    run_dir = Path(tempfile.mkdtemp(prefix="ctrlunit-"))
    spec = run_dir / "spec.json"
    spec.write_text(json.dumps({"run": rc.to_dict()}))
    endpoint = rc.listen[0] if rc.listen else default_endpoint(run_dir)
    connect_ep = endpoint  # the children always connect to their own central
    central_cpus, child_cpus = role_cpus(rc)  # before this process pins itself
    cores = _unit_cores(central_cpus, child_cpus) if spawn else None
    if central_cpus:
        os.sched_setaffinity(0, central_cpus)  # before zenoh.open: its threads inherit it
    # --connect joins the central to another Zenoh network (e.g. another unit's)
    node = Node(make_config(listen=[endpoint], connect=rc.connect,
                            config_file=rc.zenoh_config), rc.unit, "central")
    engine = setup.engine()
    ctl = Controller(engine, rc.period, setup.params.increment, tuple(setup.task.start()))
    recorder = None
    if rc.record:
        from .recorder import Recorder

        recorder = Recorder(rc.record, setup)
    central = Central(node, rc, engine, ctl, setup.cycles,
                      on_cycle=_chain(recorder.on_cycle if recorder else None, progress,
                                      _status_writer(rc.status_file)),
                      on_message=recorder.on_message if recorder else None)
    children: list[subprocess.Popen] = []
    code, fault = EXIT_OK, None
    old_int = signal.getsignal(signal.SIGINT)
    try:
        if not spawn:
            pass
        elif rc.clock != "freerun":
            children.append(spawn_role(spec, "plant", None, connect_ep, run_dir / "plant.log",
                                       cpus=child_cpus))
        for k in range(setup.placement.peripherals if spawn else 0):
            children.append(spawn_role(spec, "peripheral", k + 1, connect_ep,
                                       run_dir / f"peripheral-{k + 1}.log", cpus=child_cpus))
        names = _child_names(rc, setup) if spawn else []

        def check() -> tuple[str, int] | None:
            for p, name in zip(children, names, strict=False):
                if p.poll() is not None:
                    return name, p.returncode
            return None

        central.child_check = check
        central.handshake()
        central.warm_up()
        central.choose_replies()
        central.say("start")
        central.run()
    except Fault as exc:
        code = exc.code
        fault = {"process": exc.process, "message": str(exc), "code": exc.code}
    except KeyboardInterrupt:
        code = EXIT_INTERRUPTED
        fault = {"process": "user", "message": "interrupted", "code": code}
    finally:
        signal.signal(signal.SIGINT, signal.SIG_IGN)  # finish cleaning up
        central.t_end_ns = central.t_end_ns or time.monotonic_ns()
        try:
            zenoh_ids = central.zenoh_identity()
        except Exception:
            zenoh_ids = {}
        interrupted = code == EXIT_INTERRUPTED
        try:
            central.stop(reason="done" if fault is None else fault["message"],
                         wait=5.0 if fault is None else (0.1 if interrupted else 0.5))
        finally:
            end_children(children, grace=0.3 if interrupted else 1.0)
            node.close()
            if recorder is not None:
                recorder.close(central)
            signal.signal(signal.SIGINT, old_int)
    for p, name in zip(children, _child_names(rc, setup), strict=False):
        if p.returncode not in (0, None) and fault is None and p.returncode != -15:
            log = (run_dir / f"{name}.log").read_text(errors="replace")[-2000:]
            echo(f"ctrlunit: {name} exited with {p.returncode}:\n{log}")
    if code == EXIT_OK:  # the run directory (spec, socket, role logs) is for diagnosis
        shutil.rmtree(run_dir, ignore_errors=True)
    else:
        echo(f"ctrlunit: the roles' logs are kept in {run_dir}")
    report = finish_report(setup, central, fault)
    report["zenoh"] = zenoh_ids
    report["late"] = {"policy": rc.late_policy, "blocks": dict(rc.late),
                      "misses_per_axis": list(central.late_per_axis)}
    report["memory_kb"] = {"central": {"warm": central.rss_warm,
                                       "end": central.rss_end if central.rss_end > 0
                                       else rss_kb(), "series": central.rss_series}}
    for role, rep in central.role_reports.items():
        if isinstance(rep.get("rss_kb"), dict):
            report["memory_kb"][role] = rep["rss_kb"]
    report.update(cpu_budget(central, _child_names(rc, setup), cores))
    report["scheduling"] = {"central": policy} | {
        name.replace("-", "_"): _text_or_none((central.role_reports.get(name) or {}).get("sched"))
        for name in (_child_names(rc, setup) if spawn else [])}
    if rc.clock != "freerun":  # the plant's own word that it held and braked
        stop = (central.role_reports.get("plant") or {}).get("safe_stop")
        report["safe_stop"] = stop if isinstance(stop, dict) else None
    if inspect is not None:
        inspect["central"] = central
        inspect["setup"] = setup
    if recorder is not None:
        recorder.write_report(report)
    return code, report


def _text_or_none(x: Any) -> str | None:
    """A role's word as text, or None when it said nothing usable."""
    return x if isinstance(x, str) else None


def _unit_cores(central: set[int] | None, others: set[int] | None) -> int:
    """How many CPUs the roles started on this host can use together, given
    :func:`role_cpus` (read before the central pins itself)."""
    try:
        mine = set(os.sched_getaffinity(0))
    except OSError:
        return os.cpu_count() or 1
    return len((central or mine) | (others or mine))


def cpu_budget(central: Central, roles: list[str], cores: int | None) -> dict[str, Any]:
    """CPU time per interval of every process (all its threads, Zenoh's included) between
    the central's ``start`` and ``stop``, and what it implies: on ``cores`` CPUs, the
    freerun period cannot be shorter than the total divided by ``cores``, whatever the
    schedule. ``total`` and ``cpu_bound_period_s`` are there only when every role ran on
    this host and reported (not after a fault, nor for ``ctrlunit central`` alone).

    The CPU is averaged over every interval of the run, its first ones included (the
    period's figures leave those out), so a short run shows a higher figure. When units
    run inside another program (``ctrlunit bench``), the central's share also counts
    that program's other threads."""
    done = max(1, central.done)
    per: dict[str, float] = {}
    if central.cpu_s is not None:
        per["central"] = central.cpu_s / done
    for role in roles:
        cpu = (central.role_reports.get(role) or {}).get("cpu_s")
        if isinstance(cpu, (int, float)) and not isinstance(cpu, bool) and cpu >= 0:
            per[role.replace("-", "_")] = cpu / done
    complete = len(per) == len(roles) + 1
    total = sum(per.values())
    if complete:  # a total of the roles that reported would pass for the unit's
        per["total"] = total
    return {"cpu_per_interval_s": per,
            "cpu_cores": cores,
            "cpu_bound_period_s": total / cores if cores and complete and central.done
            else None}


def _child_names(rc: RunConfig, setup: Setup) -> list[str]:
    names = [] if rc.clock == "freerun" else ["plant"]
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


def finish_report(setup: Setup, central: Central, fault: dict | None) -> dict[str, Any]:
    rc = setup.rc
    wall = max(1, central.t_end_ns - central.t_start_ns)
    business = {"central": max(0.0, 1.0 - central.wait_ns / wall)}
    for k in range(setup.placement.peripherals):
        business[f"peripheral_{k + 1}"] = central.periph_busy_ns[k] / wall
    if rc.clock != "freerun":
        business["plant"] = central.plant_busy_ns / wall
    t1, per_block = math.nan, {}
    t1_engines: list[Engine] = []

    def t1_engine() -> Engine:
        t1_engines.append(setup.engine(peripherals_plan=False))
        return t1_engines[-1]

    if central.t1_inputs:
        t1, per_block = measure_t1(t1_engine,
                                   central.t1_inputs[: (50 if rc.cost_model == "t800" else None)])
    cost_err = None
    if rc.cost_model == "t800":
        # block costs are the emulated T-800 times; the emulation's error is measured
        per_block = {b.name: b.t800_s(rc.cost_scale) for b in setup.plan.graph.blocks}
        errs = sorted(central.engine.cost.errors_ns + [e for g in t1_engines
                                                       for e in g.cost.errors_ns])
        if errs:
            cost_err = {"p50": errs[len(errs) // 2] / 1e9,
                        "p99": errs[int(len(errs) * 0.99)] / 1e9, "max": errs[-1] / 1e9,
                        "method": "sleep to twice the mean sleep overshoot (50 us to 1 ms) "
                                  "before the T-800 deadline, then spin; "
                                  "one settle per message sent"}
    rejected = dict(central.node.rejected)
    for role, rep in central.role_reports.items():
        for k, v in (rep.get("rejected") or {}).items():
            rejected[f"{role}:{k}"] = v
    return build_report(
        rc=rc, plan=setup.plan, task=setup.task, cmd_ns=list(central.log.cmd_ns),
        sample_ns=list(central.log.sample_ns), digest=central.log.digest.hexdigest(),
        torque_max=central.log.torque_max, tracking_errors=central.log.errors,
        business=business,
        deadline_misses=central.plant_misses, skipped=central.skipped, rejected=rejected,
        t1_s=t1, per_block_s=per_block, fault=fault,
        wall_s=(central.t_end_ns - central.t_start_ns) / 1e9, cost_error_s=cost_err,
        exchanges=central.exchanges if setup.placement.peripherals else None,
        replies=central.replies_info if setup.placement.peripherals else None,
        central_costs=central.costs(), gantt=gantt_window(central.spans),
    )


def load_spec(path: str) -> RunConfig:
    data = json.loads(Path(path).read_text())["run"]
    return RunConfig(**data)


os.environ.setdefault("RUST_LOG", "error")  # keep Zenoh's own logging quiet
