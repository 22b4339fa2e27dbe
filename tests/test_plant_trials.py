"""The plant's admission trials: a trial order that comes during a trial supersedes it.

The central gives a trial up early (a fault in it) and orders the next rung at once; the
plant, still ticking the old trial, used to drop that order, so the next rung's trial
found the plant silent and failed without being measured.
"""

from __future__ import annotations

import queue
import time
from collections import Counter

from ctrlunit.runtime.roles.plant_node import serve
from ctrlunit.runtime.transport.node import Event

ORDERS = {
    b"A": {"stage": "probe", "period": 1e-3, "ticks": 200, "base": 1000},
    b"B": {"stage": "probe", "period": 1e-3, "ticks": 5, "base": 2000},
    b"start": {"stage": "start"},
    b"stop": {"stage": "stop"},
}


class ScriptedInbox:
    """Hands out each scripted event once ``published()`` reaches its threshold."""

    def __init__(self, script: list[tuple[int, bytes]], published) -> None:
        self.script = list(script)
        self.published = published

    def _next(self) -> Event:
        if self.script and self.published() >= self.script[0][0]:
            return Event("control", 0, self.script.pop(0)[1], time.monotonic_ns())
        raise queue.Empty

    def get(self, timeout: float | None = None) -> Event:
        try:
            return self._next()
        except queue.Empty:
            time.sleep(min(timeout or 0.0, 0.005))
            raise

    def get_nowait(self) -> Event:
        return self._next()


class FakeNode:
    def __init__(self) -> None:
        self.rejected: Counter[str] = Counter()
        self.last_heard_ns = time.monotonic_ns()
        self.stop_msg = None
        self.cpu_start_s = None
        self.events: ScriptedInbox | None = None

    def decode(self, data: bytes) -> dict:
        return dict(ORDERS[data])

    def reject(self, reason: str) -> None:
        self.rejected[reason] += 1


class FakeSim:
    def step(self) -> None:
        pass


class FakeServer:
    """What :func:`serve` reads of a :class:`PlantServer` up to the run's start."""

    def __init__(self, node: FakeNode) -> None:
        self.node = node
        self.trial_plant = lambda period: FakeSim()
        self.next_trial = None
        self.samples: list[int] = []
        self.sample_no = self.misses = self.busy_ns = self.commands_taken = 0
        self.trial_commands = 0
        self.spares_applied = 0
        self.rss_warm = -1
        self.depth = 2
        self.fault = None

    def publish_sample(self, span, *, trial=None) -> None:
        self.samples.append(-1 if trial is None else trial[1])  # -1: the run's own

    def simulate(self) -> tuple[int, int]:
        return 0, 0


def run(script: list[tuple[int, bytes]]) -> tuple[FakeServer, dict]:
    node = FakeNode()
    server = FakeServer(node)
    node.events = ScriptedInbox(script, lambda: len(server.samples))
    result = serve(node, server, clock="realtime", period=1e-3, cycles=0, watchdog=5.0,
                   delay=2)
    return server, result


def test_a_trial_order_during_a_trial_ends_it_and_runs_next() -> None:
    server, result = run([(0, b"A"), (10, b"B"), (15, b"stop")])
    a = [s for s in server.samples if s < 2000]
    b = [s for s in server.samples if s >= 2000]
    assert 10 <= len(a) < 200, len(a)  # A ended soon after B came
    assert b == list(range(2000, 2005))  # B ran whole, right after A
    assert result["exit"] == "stop"


def test_the_start_order_during_a_trial_ends_it(monkeypatch) -> None:
    # a role's, not ours
    monkeypatch.setattr("ctrlunit.runtime.transport.node.freeze_heap", lambda: None)
    server, result = run([(0, b"A"), (10, b"start"), (11, b"stop")])
    assert 10 <= server.samples.index(-1) < 200  # the run began soon after the start
    assert result["exit"] == "done"
