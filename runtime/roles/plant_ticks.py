"""The plant's wall clock before and during motion: sleeping to a tick with the inbox read
(commands taken at the tick), and, before the central's start order, the admission's
trials (runtime/launch/admission.py), which tick a throw-away robot at the run's period
and check and drop the trial's commands."""

from __future__ import annotations

import queue
import time
from typing import TYPE_CHECKING

from ..transport.node import Node, control_order, is_stop
from .plant_orders import trial_order

if TYPE_CHECKING:
    from .plant_node import PlantServer

SLEEP_SLICE_S = 0.02
"""Longest the realtime plant sleeps before it reads its inbox (a stop order waits at most
this long)."""


def sleep_to_tick(node: Node, server: PlantServer, tick_ns: int, *,
                  take_commands: bool) -> bool:
    """Sleep to the monotonic time ``tick_ns``, reading the inbox every
    :data:`SLEEP_SLICE_S` and once at the tick (commands are taken then, all at once, when
    ``take_commands``: a wake-up per command and a ticker hop per tick cost more CPU than
    the simulation; otherwise, during a trial, the trial's commands are checked and
    dropped as they come and a new trial order is kept in :attr:`PlantServer.next_trial`).
    Returns False on a stop order."""
    while True:
        ahead = tick_ns - time.monotonic_ns()
        if ahead > 0:
            time.sleep(min(ahead / 1e9, SLEEP_SLICE_S))
        while True:
            try:
                ev = node.events.get_nowait()
            except queue.Empty:
                break
            if take_commands:
                if ev.kind == "command":
                    server.take_command(ev.data)
                    continue
                order = control_order(node, ev)
                if order is not None and order["stage"] == "stop":
                    return False
                if order is not None and order["stage"] == "stride":
                    server.take_stride(order)
            elif ev.kind == "command":
                server.take_command(ev.data, trial=True)
            elif is_stop(node, ev):
                return False
            elif (trial := trial_order(node, ev)) is not None:
                server.next_trial = trial
        if time.monotonic_ns() >= tick_ns:
            return True


def tick_after(tick_ns: int, period_ns: int) -> int:
    """The tick after ``tick_ns``; a period from now when the plant fell more than a period
    behind (the ticks missed are skipped, not caught up)."""
    nxt = tick_ns + period_ns
    now = time.monotonic_ns()
    return now + period_ns if now > nxt else nxt


def trial_ticks(node: Node, server: PlantServer, period: float, ticks: int, base: int, *,
                causal: bool) -> bool:
    """An admission trial (runtime/launch/admission.py): tick ``ticks`` times at ``period`` on the
    wall clock, integrating a throw-away robot at rest (the run's load) and publishing its
    samples, numbered from ``base`` and flagged ``probe``, in the run's order (``causal``:
    at the tick, then integrate). The trial's commands are checked and dropped
    (:meth:`PlantServer.take_command`), none is applied. The trial ends early when a new
    trial order comes (the central gave this one up, e.g. on a fault: the new one runs at
    once, where it used to be dropped and its trial found the plant silent) or the start
    order. Returns False on a stop order."""
    if server.trial_plant is None:
        return True
    sim = server.trial_plant(period)
    tick_ns = int(period * 1e9)
    next_tick = time.monotonic_ns() + tick_ns
    span = (0, 0)

    for j in range(ticks):
        if not sleep_to_tick(node, server, next_tick, take_commands=False):
            return False
        if server.next_trial is not None or node.cpu_start_s is not None:
            break
        next_tick = tick_after(next_tick, tick_ns)
        if causal:
            server.publish_sample(span, trial=(sim, base + j))
        t0 = time.monotonic_ns()
        sim.step()
        span = (t0, time.monotonic_ns())
        if not causal:
            server.publish_sample(span, trial=(sim, base + j))
    node.last_heard_ns = time.monotonic_ns()
    return True


def await_start(node: Node, server: PlantServer, *, causal: bool, watchdog: float
                ) -> str | None:
    """Before the run: tick each admission trial the central orders (:func:`trial_ticks`)
    and check and drop the commands that come after a trial's last tick, until the start
    order (None) or a stop order or ``watchdog`` seconds of silence (the reason)."""
    while True:
        try:
            ev = node.events.get(timeout=0.2)
        except queue.Empty:
            if (time.monotonic_ns() - node.last_heard_ns) / 1e9 > watchdog:
                return "watchdog"
            continue
        if is_stop(node, ev):
            return "stop"
        if node.cpu_start_s is not None:  # is_stop noted the start order
            return None
        if ev.kind == "command":  # a trial's last ones, after its last tick
            server.take_command(ev.data, trial=True)
            continue
        order = trial_order(node, ev)
        while order is not None:  # a trial, or the one that superseded it
            if not trial_ticks(node, server, *order, causal=causal):
                return "stop"
            order, server.next_trial = server.next_trial, None
        if node.cpu_start_s is not None:  # the start came during a trial
            return None


__all__ = ["SLEEP_SLICE_S", "await_start", "sleep_to_tick", "tick_after", "trial_ticks"]
