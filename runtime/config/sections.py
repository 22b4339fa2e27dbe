"""The sections of a run's configuration, each frozen: what the unit computes, how it is
scheduled, the plant's options, the transport, and the run's length and outputs.

A :class:`~ctrlunit.runtime.config.RunConfig` holds one of each; it is built and validated
once from the options of ``ctrlunit start`` (their flat names, e.g. ``--plant-lag`` is
``plant.lag``) and never changed: a derived configuration (``--period auto``, a replay) is
a new one. Every role derives its plan and engine from ``control`` and ``schedule``;
beyond that the peripheral reads ``transport`` and ``run.trace``, the plant ``plant``,
``schedule`` (clock, period, delay) and ``transport``; the central every section.

Each field is a :func:`~.setting.setting`: its help, the values it may take and its flag
are written there once (module notes of :mod:`.setting`).
"""

from __future__ import annotations

import os
import secrets
from dataclasses import dataclass

from ...plant.substeps import MAX_SUBSTEP_BELT_S, MAX_SUBSTEP_S
from ...topology.graph import LAWS, MODEL_STATES
from ...topology.pipeline import HOLD_RULES
from ..host.idle import IDLE_CHOICES
from ..transport import limits as lim
from .choices import (
    BALANCES,
    CLOCKS,
    COMMAND_DELAYS,
    COMPRESSIONS,
    CPU_SPREADS,
    LATE_POLICIES,
    MISSED_COMMANDS,
    OVERLOAD_ACTIONS,
    PERIPHERAL_LOSSES,
    REPLY_MODES,
)
from .setting import Flag, setting


@dataclass(frozen=True)
class ControlConfig:
    """What the unit computes: the task, the law and its model (Ch. V, § IV.7), the
    robot's parameters and the cost model of the blocks."""

    task: str = setting("pick-place", flag=Flag(everyday=True),
                        help="pick-place, circle, or a JSON task file.")
    law: str = setting(
        "resolved-acceleration", flag=Flag(everyday=True), choices=(*LAWS, "kinematics"),
        help="Control law; 'kinematics' runs the kinematics part alone (benchmarks: its "
        "commands are joint accelerations, not torques).")
    model: str = setting("complete", flag=Flag(), choices=("complete", "simplified"),
                         allowed="complete or simplified",
                         help="The robot's model in the law: complete or simplified (Ch. V).")
    observer: str = setting(
        "predict", flag=Flag(), choices=("predict", "previous"), allowed="predict or previous",
        help="Newton-Raphson start: prediction (1 iteration) or previous (2).")
    model_state: str = setting(
        "auto", flag=Flag(), choices=("auto", *MODEL_STATES),
        help="Resolved acceleration: servo the state predicted for the period in which the "
        "command acts (carried forward at the commands in flight) and evaluate the model "
        "(second round's kinematics, dynamics) there, from a velocity taken from the "
        "observed positions (acting); the same with the model's kinematics at that state "
        "foreseen from the previous interval, so that at depth 2 the peripherals compute "
        "them before the sample (foreseen); the same from the estimate of two intervals "
        "back, the observer's prediction too, so that two intervals' rounds go in one "
        "exchange (foreseen2); or servo and evaluate at the sample's estimate with pdot = J "
        "qdot as the thesis (sample); auto: foreseen2 in realtime at depth 2, acting "
        "otherwise.")
    bandwidth_hz: float | None = setting(
        None, flag=Flag(name="bandwidth"), bounds=(0.1, 200.0), allowed="0.1 to 200, in Hz",
        help="Closed-loop bandwidth of the gains in Hz (default: 20, at most 1/(25 "
        "period) with resolved acceleration at the acting state, so that the margin holds "
        "a period more than designed, 1/(50 period) otherwise).")
    params: str | None = setting(None, flag=Flag(kind="file"),
                                 help="TOML file of Delta parameters (a role started by "
                                 "hand: this host's copy of the central's).")
    max_error: float = setting(
        0.02, flag=Flag(), bounds=(1e-5, 1.0), allowed="1e-05 to 1, in metres (10 um to 1 m)",
        help="Tracking error (m) beyond which the unit stops the robot (a fault).")
    cost_model: str = setting(
        "native", flag=Flag(), choices=("native", "t800"), allowed="native or t800",
        help="t800: every block also occupies its process for its 1994 T-800 time.")
    cost_scale: float = setting(
        1.0, flag=Flag(), bounds=(0.01, 1000.0),
        help="Multiply the T-800 block times (t800 cost model): reproduce the 1994 ratio "
        "of arithmetic to communication.")


@dataclass(frozen=True)
class ScheduleConfig:
    """How the work is spread and timed: peripherals, pipeline depth, clock and period,
    placement, the pipeline's rules (topology/pipeline.py), late data, admission, and the
    operating system's scheduling of the processes."""

    peripherals: int = setting(3, flag=Flag(everyday=True), bounds=(0, 3),
                               allowed="0, 1, 2 or 3",
                               help="Number of peripheral processes (0 = single processor).")
    pipeline: int = setting(1, flag=Flag(everyday=True), bounds=(1, 2), allowed="1 or 2",
                            help="Pipeline depth (§ IV.7.2).")
    clock: str = setting("realtime", flag=Flag(everyday=True), choices=CLOCKS,
                         help="Virtual time, the wall clock, or no plant.")
    period: float = setting(
        1e-3, flag=Flag(kind="period", default="auto", everyday=True), bounds=(20e-6, 1.0),
        allowed="20us to 1s",
        help="Sampling period: 500us, 1ms, or seconds; auto: in realtime the shortest period "
        "of the admission ladder (0.25 to 10 ms) that its trials hold here (1 ms in the other "
        "clocks).")
    period_auto: bool = setting(
        False, internal=True, help="`--period auto`: realtime runs at the shortest period of the "
        "admission ladder that holds (runtime/launch/admission.py); `period` is where the "
        "admission starts, to climb or, where it holds, to go down.")
    command_delay: str = setting(
        "full", flag=Flag(), choices=COMMAND_DELAYS,
        help="When the plant applies the command of sample k: full (causal) in the period "
        "that begins at tick k + depth; short: the earlier convention, one period sooner, "
        "on physics that began before the command was due.")
    placement: str | None = setting(
        None, flag=Flag(kind="placement", default="auto", metavar="auto|axes|FILE",
                        everyday=True),
        allowed="auto, axes or a placement file (ctrlunit balance)",
        help="Which process runs which block: axes (each peripheral all of its axes' "
        "blocks, § IV.7), auto (at warm-up, a round cheaper than its round trip moves to "
        "the central) or a FILE from ctrlunit balance.")
    placement_auto: bool = setting(
        False, internal=True,
        help="`--placement auto`: the warm-up chooses which rounds the central "
        "runs itself (topology/balance.py, `auto_central_blocks`); the central then tells "
        "the peripherals (a `place` order) and runs with them in `central_blocks`.")
    central_blocks: list[str] | None = setting(
        None, internal=True,
        help="Per-axis blocks the central runs for every axis, with the default "
        "spread of the axes (the placement's `central_blocks`); None: none, or not chosen "
        "yet (auto).")
    replies: str = setting(
        "auto", flag=Flag(), choices=REPLY_MODES,
        help="Depth 2: peripherals answer a fused request in one reply (fused), or each "
        "round as soon as it is computed, first rounds first, so the central works on one "
        "interval while they work on the other (each); auto: each when the central's work "
        "between two rounds exceeds a round trip measured at warm-up.")
    hold_rounds: str = setting(
        "auto", flag=Flag(), choices=HOLD_RULES,
        help="Depth 2: a lone round ready early waits to travel with the next interval's "
        "first round (always: one exchange per interval), or goes at once (never: two "
        "exchanges, no wait for the next sample); auto: never in realtime (a held round "
        "waits up to a period for the next sample), always otherwise.")
    late_policy: str = setting(
        "compute", flag=Flag(), choices=LATE_POLICIES,
        help="Realtime: a peripheral's late reply is waited for, computed by the central "
        "itself (compute: the same arithmetic, so the same commands), replaced by its last "
        "values (hold), or a fault.")
    missed_command: str = setting(
        "extrapolate", flag=Flag(), choices=MISSED_COMMANDS,
        help="Realtime: in a period whose command is late the plant applies the command the "
        "central extrapolated for it and sent with the one before (at the full control "
        "rate); hold: none is sent. Past it the plant follows the trend of its last "
        "commands (16 ms), then holds it.")
    late: dict[str, str] = setting(
        flag=Flag(kind="late", metavar="BLOCK=POLICY"), factory=dict,
        help="Late-data policy for one block (overrides --late-policy).")
    fault_periods: float = setting(
        3.0, flag=Flag(), bounds=(1.0, 1000.0), allowed="1 to 1000 periods",
        help="Realtime: a peripheral, the plant or a link silent for this many periods is a "
        "fault (the robot is stopped).")
    peripheral_loss: str = setting(
        "takeover", flag=Flag(), choices=PERIPHERAL_LOSSES,
        help="A peripheral whose process exited, or that stayed silent past the silence "
        "rule, is taken over: the central computes its rounds itself from then on (the "
        "same arithmetic, so the same commands; the report's degraded says which and from "
        "when), until one whose process exited, started again by ctrlunit start, keeps up; "
        "fault: stop the robot safely (exit 3).")
    balance: str = setting(
        "off", flag=Flag(), choices=BALANCES,
        help="live: the central judges windows of 40 intervals (the first after interval 48, "
        "then after each move or when the period moved 5 %) with the model of ctrlunit "
        "balance and, where a placement of its blocks is predicted 5 % faster, moves them "
        "at an interval boundary (the commands do not change; the summary's placement "
        "lines and the report's rebalanced say when and why); freerun and lockstep only; "
        "off by default: the placement chosen at the start is kept (where nothing moves, "
        "live costs no measurable time: its judge is a process of its own at nice 19, "
        "started before the warm-up).")
    overload: str = setting(
        "auto", flag=Flag(), choices=OVERLOAD_ACTIONS,
        help="Realtime: when 10 of the last 100 intervals were late (their command left "
        "after its deadline, or their sample was skipped; late ones in a row count once), "
        "or 10 in a row were, halve the control rate: the unit "
        "takes every second sample and the plant holds each command two periods, still "
        "ticking at --period (the report's overload says from where); continue: go on as "
        "it is; auto: halve with the admission on where the gains keep their margin at "
        "twice the period, else continue.")
    admission: bool = setting(
        True, flag=Flag(kind="switch"),
        help="Realtime: a trial at the period before the first command; a period that does "
        "not hold is refused (exit 7) before any motion.")
    trial_only: bool = setting(
        False, internal=True,
        help="Run the admission trial and stop before the first command (`ctrlunit "
        "latency --unit`).")
    rt_priority: int | str = setting(
        "auto", flag=Flag(kind="priority", metavar="auto|0-99"),
        allowed="auto, 0 (leave the policy as it is) or 1 to 99 (SCHED_FIFO priority)",
        help="SCHED_FIFO priority of every role of the unit (the roles inherit it from "
        "start); 0: leave the policy as it is (1-99 needs root, CAP_SYS_NICE or ulimit -r). "
        "auto: FIFO at 10 in realtime with the admission, where permitted and the kernel "
        "throttles real-time tasks; the admission then refuses a period that keeps a CPU "
        "over 75 % of the kernel's real-time budget, and the run goes back to the default "
        "policy if it stays over 95 % of it for a second or passes it (the report says "
        "which and why).")
    idle: str = setting(
        "auto", flag=Flag(), choices=IDLE_CHOICES,
        allowed="auto (poll in realtime where permitted), poll or default",
        help="poll holds the kernel's CPU latency request at 0 us while this process runs "
        "(/dev/cpu_dma_latency), so that idle CPUs spin instead of halting and every "
        "wake-up is quicker, at the cost of the CPUs spinning while idle (needs root); "
        "auto: poll in realtime where permitted and a deeper idle state exists; default: "
        "leave them alone.")
    pin: str | None = setting(None, flag=Flag(),
                              help="CPUs for this process, e.g. 0 or 0,1.")
    cpus: str | None = setting(
        None, flag=Flag(), choices=CPU_SPREADS,
        allowed="same (every role on CPU 0) or split (central on 0, the rest on 1)",
        help="start: pin every role on CPU 0 (same), or the central on 0 and the others on "
        "1 (split); default: no pinning.")


@dataclass(frozen=True)
class PlantOptions:
    """The simulated robot's options (plant/simulator.py)."""

    substeps: int | None = setting(
        None, flag=Flag(), bounds=(1, 1000),
        help="RK4 sub-steps of the plant per period; default: the fewest of at most "
        f"{MAX_SUBSTEP_S * 1e3:g} ms ({MAX_SUBSTEP_BELT_S * 1e3:g} ms with --belt), more "
        "while an arm turns fast.")
    lag: float = setting(0.0, flag=Flag(kind="duration", default="0s"), bounds=(0.0, 1.0),
                         allowed="0 to 1 s",
                         help="Actuator time constant (Eq. IV.6).")
    friction: float = setting(0.0, flag=Flag(), bounds=(0.0, 100.0),
                              help="Viscous friction on each joint (N m s/rad).")
    belt: bool = setting(False, flag=Flag(kind="flag"),
                         help="Simulate the elastic belt (§ V.6.3).")


@dataclass(frozen=True)
class TransportConfig:
    """The unit's Zenoh session: its id, endpoints and time-outs."""

    unit: str = setting(factory=lambda: "u" + secrets.token_hex(4), flag=Flag(),
                        help="Unit id (keys ctrlunit/<unit>/...); default: a random one (a "
                        "role started by hand: give the central's).")
    listen: list[str] | None = setting(
        None, flag=Flag(kind="many"),
        help="Zenoh endpoint to listen on. Without --keys the roles meet on a unix socket, "
        "and a TCP port carries the observers' keys (view/) alone.")
    connect: list[str] | None = setting(None, flag=Flag(kind="many"),
                                        help="Zenoh endpoint to connect to.")
    zenoh_config: str | None = setting(
        None, flag=Flag(kind="file"),
        help="A Zenoh configuration file (JSON5); its endpoints are checked as --listen "
        "and --connect, and scouting stays off unless it turns it on.")
    keys: str | None = setting(
        None, flag=Flag(kind="dir"),
        help="The unit's credentials (ctrlunit keys init DIR): every link is mutual TLS "
        "under the unit's access control (the default one too: TLS on a loopback port).")
    insecure: bool = setting(False, flag=Flag(kind="flag"),
                             help="Without --keys, let links beyond this host, and any "
                             "link other than a unix socket, carry the control path (a lab "
                             "bench).")
    timeout: float = setting(
        2.0, flag=Flag(kind="duration", default="2s"), bounds=(0.01, 600.0),
        allowed="0.01 to 600 s",
        help="Reply timeout in lockstep and freerun (realtime: --fault-periods).")
    startup_timeout: float = setting(
        30.0, bounds=(0.1, 3600.0), allowed="0.1 to 3600 s", duration=True,
        help="How long (30s, 2min, or seconds) the roles may take to say hello or confirm "
        "an order.")
    max_message_size: int = setting(
        lim.MAX_MESSAGE_SIZE, bounds=(lim.MAX_MESSAGE_SIZE_MIN, 2**30),
        allowed=f"{lim.MAX_MESSAGE_SIZE_MIN} to 1073741824 bytes",
        help="Largest message in bytes this process's Zenoh takes from a link (Zenoh's "
        "transport/link/rx/max_message_size; the unit's largest is 1-2 KB, and its codec "
        "drops anything over 65536 whatever Zenoh delivers). Zenoh 1.10.2 drops only some "
        "messages over it (docs/faults-and-errors.md, Security).")
    max_sessions: int = setting(
        lim.MAX_SESSIONS, bounds=(5, 64), allowed="5 to 64 peers",
        help="Most Zenoh peers this process holds at once (transport/unicast/max_sessions): "
        "the plant, the peripherals and a few observers. A central listening on TCP or TLS "
        "runs one Zenoh worker thread per peer plus two, so that peers that all stop "
        "reading at once cannot hold every one.")
    accept_pending: int = setting(
        lim.ACCEPT_PENDING, bounds=(1, 1000), allowed="1 to 1000 handshakes",
        help="Most Zenoh handshakes under way at once on this process's listeners "
        "(transport/unicast/accept_pending).")
    accept_timeout: float = setting(
        lim.ACCEPT_TIMEOUT_S, bounds=(0.1, 60.0), allowed="0.1 to 60 s", duration=True,
        help="How long (5s, 500ms, or seconds) a peer may take to complete its Zenoh "
        "handshake before it is dropped (transport/unicast/accept_timeout).")
    reject_limit: int = setting(
        lim.REJECT_LIMIT, bounds=(1, 10**6), allowed="1 to 1000000 messages a second",
        help="The central: a peripheral or the plant that sends more than this many "
        "malformed messages (too large, undecodable, ill-formed) on its own key within a "
        "second is a fault by name (exit 3 or 4); a role of the unit sends none.")


def _ros_domain() -> str:
    """``--ros2`` alone: ``ROS_DOMAIN_ID``'s domain, or 0 (as ROS 2 does; the flag reads
    and checks it as a domain given)."""
    return os.environ.get("ROS_DOMAIN_ID", "").strip() or "0"


@dataclass(frozen=True)
class RunOptions:
    """How long the run lasts and what it writes."""

    cycles: int | None = setting(None, flag=Flag(everyday=True), bounds=(1, 10**9),
                                 allowed="1 to 1000000000",
                                 help="Intervals to run (default: one loop of the task).")
    duration: float | None = setting(None, flag=Flag(kind="duration", everyday=True),
                                     bounds=(1e-6, 1e7), allowed="1 us to 1e7 s",
                                     help="Run length instead of --cycles (e.g. 30s).")
    t1_cycles: int = setting(500, bounds=(0, 10**6),
                             help="Intervals of the one-process run that measures t_1 "
                             "(Eq. IV.23) before the run.")
    record: str | None = setting(None, flag=Flag(kind="file", everyday=True),
                                 help="Record every interval to an MCAP file.")
    record_compression: str = setting(
        "zstd", flag=Flag(), choices=COMPRESSIONS,
        help="MCAP chunk compression of --record, done on a writer thread off the control "
        "path (zstd: about 3x smaller).")
    trace: bool = setting(False, internal=True,
                          help="Keep every role's spans of every interval for the report's "
                          "Gantt chart (the launcher: with --record).")
    report: str | None = setting(None, flag=Flag(kind="file", everyday=True),
                                 help="Write the report as JSON.")
    progress: bool = setting(False, internal=True,
                             help="Show the live line on the terminal (start's --progress; "
                             "default: when stdout is a terminal).")
    status_file: str | None = setting(
        None, flag=Flag(kind="file", hidden=True), internal=True,
        help="Write the completed-interval count every 10.")
    foxglove: str | None = setting(
        None, flag=Flag(metavar="[HOST:]PORT", everyday=True),
        help="Serve a live view to Foxglove (WebSocket; host 127.0.0.1 unless given; port "
        "0: any free one), off the control path.")
    foxglove_rate: float = setting(
        200.0, flag=Flag(metavar="HZ"), allowed="0 (every interval) or 1 to 100000 Hz",
        help="/signals/state messages per second of the live view; 0: every interval (each "
        "costs the central ~0.1 ms of CPU).")
    ros2: int | None = setting(
        None, flag=Flag(metavar="[DOMAIN]", bare=_ros_domain),
        bounds=(0, 232), allowed="0 to 232",
        help="Publish /joint_states, /platform/pose, /platform/reference and "
        "/ctrlunit/diagnostics as ROS 2 topics over rmw_zenoh in this domain (alone: "
        "ROS_DOMAIN_ID, or 0), through the ROS 2 router tcp/localhost:7447 "
        "(ZENOH_CONFIG_OVERRIDE changes it, as for rmw_zenoh), at --foxglove-rate, off "
        "the control path.")


SECTIONS: dict[str, type] = {"control": ControlConfig, "schedule": ScheduleConfig,
                             "plant": PlantOptions, "transport": TransportConfig,
                             "run": RunOptions}
"""The sections of a RunConfig, by attribute name."""

RENAMED = {"plant_substeps": "substeps", "plant_lag": "lag", "plant_friction": "friction"}
"""Options whose flat name (``--plant-lag``) differs from their field in the section."""


__all__ = [
    "RENAMED",
    "SECTIONS",
    "ControlConfig",
    "PlantOptions",
    "RunOptions",
    "ScheduleConfig",
    "TransportConfig",
]
