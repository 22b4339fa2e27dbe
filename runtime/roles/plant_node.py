"""The plant role: the simulated Delta as a Zenoh node.

It publishes each sample (encoder counts, sample number, the host monotonic time of the
sample, the plant's compute span) and takes commands (three torques and the cycle they
answer). A command is rejected and counted when it is malformed (NaN, inf, wrong length
or type), stale or from the future; the last valid command stays applied.

Plant faults: when an arm reaches a mechanical stop, or the simulated robot stops on a
singular or unreachable configuration (plant/limits.py), the plant stops ticking, sends
its report with the ``fault`` by name at once (the central stops the unit on it), waits
for the stop order, makes its safe stop and exits with code 4.

Clocks
------
``delay`` is the number of periods from sample k to the start of the period in which the
command of interval k acts: the pipeline depth d with ``--command-delay full`` (causal,
the default), d - 1 with ``short``.

``lockstep``: after sample k the plant waits for the command of cycle ``k - delay``
(before the first one it holds the initial command), applies it, advances one period and
publishes sample k+1.

``realtime``: the plant ticks on its own wall clock. ``full``: at tick j it publishes
sample j (the state at jT, integrated ahead during the previous period), then applies the
command of cycle ``j - d`` if it has arrived (else a deadline miss is counted and the
command extrapolated for it, or the trend of the last ones, acts: runtime/roles/
plant_hold.py) and integrates the period [jT, (j+1)T) while the controller works: the
sample leaves at the tick, and a command acts only on physics after it was due.
``short``: at tick j it applies the command of cycle ``j - d``, integrates the period that
ended at the tick, [(j-1)T, jT), and then publishes sample j.
"""

from __future__ import annotations

import math
import queue
import sys
import time
from collections.abc import Callable
from typing import Any

from ...plant.simulator import Plant, PlantConfig
from ..compute.controller import initial_angles, initial_command
from ..compute.setup import Setup
from ..compute.stride import StrideSchedule
from ..config import EXIT_LINK, EXIT_OK, EXIT_PLANT
from ..host import sched
from ..transport.codec import BadMessage, check_vector, encode
from ..transport.node import WARM_RSS_AT, Node, cpu_used, is_stop, rss_kb, say_bye
from .plant_hold import CommandHold
from .plant_orders import STOP_ORDER_WAIT_S, announce_fault, safe_stop, wait_for_stop
from .plant_ticks import await_start, sleep_to_tick, tick_after
from .rolelog import role_log, role_log_end
from .stopping import stop_of, stop_signals


class PlantServer:
    """State of the plant role between messages. ``trial_plant(period)`` builds the
    throw-away robot of an admission trial at ``period`` (:func:`.plant_ticks.trial_ticks`)."""

    def __init__(self, node: Node, plant: Plant, *, depth: int, initial: list[float],
                 period_s: float,
                 trial_plant: Callable[[float], Plant] | None = None) -> None:
        self.node = node
        self.trial_plant = trial_plant
        self.commands_taken = 0
        self.trial_commands = 0
        """Commands of the admission's trials checked and dropped (:meth:`take_command`)."""
        self.plant = plant
        self.depth = depth
        self.pub = node.publisher(node.keys.sample)
        node.route(node.keys.command, "command")
        self.commands: dict[int, list[float]] = {}
        self.spares: dict[int, list[float]] = {}
        """Cycle -> the command the central extrapolated for it, sent with the command of
        the cycle before (``next``): applied if that cycle's own command is late."""
        self.spares_applied = 0
        self.hold = CommandHold(period_s)
        """The last commands applied: what a period without one holds."""
        self.applied_cycle = -1
        self.plant.set_command(initial)
        self.misses = 0
        self.busy_ns = 0
        self.sample_no = 0
        self.rss_warm = -1
        self.grid = StrideSchedule()
        """The samples published and the commands due: every one until the central halves
        its control rate (``stride`` orders; then every second one, each command held two
        periods), runtime/compute/stride.py."""
        self.next_trial: tuple[float, int, int] | None = None
        """A trial order that came during a trial: it ends that trial and runs next."""
        self.fault: dict[str, Any] | None = None
        """The plant fault that ends the run (``name``, ``message``, ``time``): the first
        arm that reached its mechanical stop (a real robot hit its end stop), or the fault
        that stopped the simulated robot (plant/limits.py)."""

    def take_command(self, data: bytes, *, trial: bool = False) -> None:
        """Check a command and keep it for the period it acts in. An admission trial's
        (flagged ``probe``) is checked as the run's are, counted, and never kept: the trial
        carries the run's messaging load, the robot never moves for it. During a trial
        (``trial``) only those are taken; a command of the run is dropped there."""
        msg = self.node.decode(data)
        if msg is None:
            return
        if msg["stage"] != "command":
            self.node.reject("bad_stage")
            return
        probe = msg.get("probe") is True
        if trial and not probe:
            return
        try:
            tau = check_vector(msg.get("tau"), 3, "tau")
            nxt = None if msg.get("next") is None else check_vector(msg["next"], 3, "next")
        except BadMessage as exc:
            self.node.reject(exc.reason)
            return
        if probe:
            self.trial_commands += 1
            return
        cycle = msg["cycle"]
        if cycle <= self.applied_cycle:
            self.node.reject("stale_cycle")
            return
        if cycle >= self.sample_no + 1:  # no sample of that number was published yet
            self.node.reject("future_cycle")
            return
        if len(self.commands) > 64:
            self.commands.pop(min(self.commands))
        self.commands[cycle] = tau
        if nxt is not None:
            self.spares[cycle + 1] = nxt
            if len(self.spares) > 64:
                self.spares.pop(min(self.spares))
        self.commands_taken += 1
        self.node.last_heard_ns = time.monotonic_ns()

    def take_stride(self, msg: dict[str, Any]) -> None:
        """The central's ``stride`` order (it halved its control rate, or went back to the
        full one), checked field by field: one that cannot be the next change is
        rejected (``bad_value``) and changes nothing."""
        stride, start = msg.get("stride"), msg.get("start")
        if self.grid.check(stride, start) is not None:
            self.node.reject("bad_value")
            return
        self.grid.change(stride, start)  # type: ignore[arg-type]

    def on_grid(self, cycle: int) -> bool:
        """Whether sample ``cycle`` is published and its command due."""
        return self.grid.on_grid(cycle)

    def apply(self, cycle: int) -> bool:
        """Apply the command of ``cycle``; if it is not here (a deadline miss), apply the
        command the central extrapolated for it with the command before (``next``, sent
        in realtime at the full rate), else the newest earlier command that arrived late,
        else the trend of the last commands (:class:`.plant_hold.CommandHold`). Returns
        whether the due command was here. Off the control rate's grid (halved) no command
        is due: a late one that came is applied, else the acting one holds its second
        period, as the central's model has it (the trend there had the halved rate track
        1.1 mm where it tracks 0.02: docs/measurements/2026-11-29-late-runs.md).

        A late command left the last one acting a period longer; a burst of them, each
        the next period's, held a command ever older: at 1.6 ms four in a row cost up to
        0.47 mm of tracking, and 0.12 mm with the extrapolated ones (bench/missed.py;
        docs/measurements/2026-11-25-realtime.md)."""
        ready = [c for c in self.commands if c <= cycle]
        spare = self.spares.pop(cycle, None)
        for c in [c for c in self.spares if c < cycle]:
            del self.spares[c]
        newest = max(ready) if ready else None
        due = self.grid.on_grid(cycle)
        if due and newest != cycle and spare is not None:
            self.plant.set_command(spare)
            self.spares_applied += 1
        elif newest is not None:
            self.plant.set_command(self.commands[newest])
        elif due and (held := self.hold.held(cycle)) is not None:
            self.plant.set_command(held)
        if newest is not None:
            self.hold.note(newest, self.commands[newest])
            self.applied_cycle = newest
            for c in ready:
                del self.commands[c]
        return newest == cycle

    def publish_sample(self, span: tuple[int, int], *,
                       trial: tuple[Plant, int] | None = None) -> None:
        """Publish the robot's sample now; ``trial``: an admission trial's robot and
        sample number instead (flagged ``probe``, no misses, nothing applied)."""
        plant, cycle = trial or (self.plant, self.sample_no)
        extra = {"misses": 0, "applied": -1, "probe": True} if trial else {
            "misses": self.misses, "applied": self.applied_cycle}
        self.pub.put(encode(
            self.node.unit, cycle, "sample", counts=plant.encoder_counts(),
            t_ns=time.monotonic_ns(), span=list(span), p=[float(x) for x in plant.state.p],
            **extra))

    def simulate(self) -> tuple[int, int]:
        t0 = time.monotonic_ns()
        if self.sample_no == WARM_RSS_AT:
            self.rss_warm = rss_kb()
        self.plant.step()
        t1 = time.monotonic_ns()
        self.busy_ns += t1 - t0
        if self.plant.event_count:  # the first: an arm at its stop, or a fault that stopped
            self.fault = self.plant.events[0].as_dict()  # the robot (plant/limits.py)
        return t0, t1


def serve(node: Node, server: PlantServer, *, clock: str, period: float, cycles: int,
          watchdog: float, delay: int) -> dict[str, Any]:
    """Run the plant until ``cycles`` samples are out, a stop, or the watchdog.

    ``delay``: periods from a sample to the period its command acts in (module notes).
    The clock starts on the central's ``start`` order (after its warm-up)."""
    causal = clock == "realtime" and delay == server.depth
    ended = await_start(node, server, causal=causal, watchdog=watchdog)
    if ended is not None:
        return _result(server, ended, time.monotonic_ns())
    t_start = time.monotonic_ns()
    server.publish_sample((t_start, t_start))
    span = server.simulate() if causal else (t_start, t_start)  # the state at T, ahead
    tick_ns = int(period * 1e9)
    next_tick = time.monotonic_ns() + tick_ns
    while server.sample_no < cycles and server.fault is None:  # a fault: the robot stopped
        if clock == "lockstep":
            due = server.sample_no - delay
            if due >= 0:
                # wait for the awaited command
                while due not in server.commands:
                    try:
                        ev = node.events.get(timeout=0.2)
                    except queue.Empty:
                        if (time.monotonic_ns() - node.last_heard_ns) / 1e9 > watchdog:
                            return _result(server, "watchdog", t_start)
                        continue
                    if is_stop(node, ev):
                        return _result(server, "stop", t_start)
                    if ev.kind == "command":
                        server.take_command(ev.data)
                server.apply(due)
            span = server.simulate()
            server.sample_no += 1
            server.publish_sample(span)
        else:  # realtime
            if not sleep_to_tick(node, server, next_tick, take_commands=True):
                return _result(server, "stop", t_start)
            next_tick = tick_after(next_tick, tick_ns)
            server.sample_no += 1
            due = server.sample_no - server.depth
            grid = server.on_grid(server.sample_no)
            if causal and grid:  # the sample leaves at the tick; the period is integrated after
                server.publish_sample(span)
            if due >= 0 and not server.apply(due) and server.on_grid(due):
                server.misses += 1  # off the grid no command is due: the last one holds
            if server.sample_no < cycles or not causal:
                span = server.simulate()
            if not causal and grid:
                server.publish_sample(span)
            if (time.monotonic_ns() - node.last_heard_ns) / 1e9 > watchdog:
                return _result(server, "watchdog", t_start)
    # keep answering until the central says stop (it may still be finishing); a fault
    # is reported at once (run_plant)
    deadline = time.monotonic() + (0.0 if server.fault else watchdog)
    while time.monotonic() < deadline:
        try:
            ev = node.events.get(timeout=0.1)
        except queue.Empty:
            continue
        if is_stop(node, ev):
            break
        if ev.kind == "command":
            server.take_command(ev.data)
    return _result(server, "fault" if server.fault else "done", t_start)


def _result(server: PlantServer, reason: str, t_start: int) -> dict[str, Any]:
    return {"exit": reason, "samples": server.sample_no, "misses": server.misses,
            "busy_ns": server.busy_ns, "wall_ns": time.monotonic_ns() - t_start,
            "rejected": dict(server.node.rejected), "commands": server.commands_taken,
            "trial_commands": server.trial_commands,
            "spares": server.spares_applied,
            "rss_kb": {"warm": server.rss_warm, "end": rss_kb()},
            "cpu_s": cpu_used(server.node)} | ({"fault": server.fault} if server.fault else {})


def run_plant(setup: Setup, conf: Any) -> int:
    rc = setup.rc
    initial = initial_command(setup.params, setup.task)

    def make_plant(period: float) -> Plant:
        return Plant(setup.params, PlantConfig(period=period, substeps=rc.plant.substeps,
                                               lag=rc.plant.lag, friction=rc.plant.friction,
                                               belt=rc.plant.belt),
                     q0=initial_angles(setup.params, setup.task),
                     p_guess=tuple(setup.task.start()))

    def trial_plant(period: float) -> Plant:
        sim = make_plant(period)
        sim.set_command(initial)  # at rest at the task's start, held against gravity
        return sim

    plant = make_plant(rc.schedule.period)
    with Node(conf, rc.transport.unit, "plant") as node:
        server = PlantServer(node, plant, depth=rc.schedule.pipeline, initial=initial,
                             period_s=rc.schedule.period, trial_plant=trial_plant)
        role_log("plant", f"connected to unit {rc.transport.unit}; waiting for the go")
        try:
            node.wait_for_go(timeout=rc.transport.startup_timeout)
        except TimeoutError as exc:
            print(f"ctrlunit plant: {exc}", file=sys.stderr)
            return EXIT_LINK
        role_log("plant", f"go: {rc.schedule.clock} at {rc.schedule.period * 1e3:g} ms")
        t_serve = time.monotonic_ns()
        code = EXIT_OK
        try:
            with stop_signals():
                res = serve(node, server, clock=rc.schedule.clock, period=rc.schedule.period,
                            cycles=setup.cycles, watchdog=max(5.0, 3 * rc.transport.timeout),
                            delay=rc.delay_periods)
        except KeyboardInterrupt as exc:  # Ctrl-C, SIGTERM or SIGHUP to the plant itself
            code, _ = stop_of(exc)  # the robot brakes all the same
            res = _result(server, "interrupted", t_serve)
            wait_for_stop(node, STOP_ORDER_WAIT_S)
        if res["exit"] == "fault":  # named at once; the central's stop order brings the hold
            announce_fault(node, res)
            wait_for_stop(node, STOP_ORDER_WAIT_S)
        hold = (node.stop_msg or {}).get("hold")
        if isinstance(hold, list) and len(hold) == 3 and all(
                isinstance(x, float) and math.isfinite(x) for x in hold):
            plant.set_command(hold)
        res["safe_stop"] = safe_stop(plant)
        res["sched"] = sched.policy_name()
        say_bye(node, res)
        role_log_end("plant", res)
        if code != EXIT_OK:
            return code
        if res["exit"] == "fault":
            return EXIT_PLANT
        return EXIT_OK if res["exit"] in ("stop", "done") else EXIT_LINK
