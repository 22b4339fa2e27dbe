"""A live view of a run in Foxglove (``ctrlunit start --foxglove [HOST:]PORT``).

A Foxglove WebSocket server (the ``foxglove-sdk`` package) offers two JSON channels:

``/signals/state``
    the message the recording holds under the same topic and schema (runtime/observe/signals.py:
    position, reference, joint angles, torques, tracking error, period, traversal), for
    one interval every ``1 / rate_hz`` seconds of command time (200 Hz by default,
    ``--foxglove-rate``; 0: every interval);
``/report/running``
    once a second, the run's figures so far (:data:`RUNNING_SCHEMA`): intervals done,
    period p50/p99, deadline misses, skipped samples, tracking error now and at most,
    and the intervals the view itself dropped.

Off the control path: the central's thread only appends a tuple to a bounded deque
(:meth:`LiveView.__call__`) when an interval is due to be shown; the view's own thread
builds the messages and hands them to the server, whose sending to each client is
asynchronous with a bounded backlog. The running figures are computed by the view's
thread from the central's own logs (command times, tracking errors), read once a second,
so that they count every interval whatever the rate. Each message shown costs the
central's process about 80 us of CPU (150 us with a reference to compare against):
every interval of a 1 kHz run would be 8-15 % of a core, hence the rate
(docs/measurements/2026-11-23-live-view.md).
A viewer that is slow, stalled or absent therefore never delays a command: at worst the
deque overflows and the view skips intervals (counted in ``dropped``).

Log times are the host's wall clock (ns since the epoch), as Foxglove's timeline expects;
the recording's are the monotonic clock.

A layout that plots the tracking error, torques and period: docs/foxglove-layout.json.
"""

from __future__ import annotations

import json
import threading
import time
from typing import TYPE_CHECKING, Any

import orjson

from ..host.sched import leave_rt
from .live import LiveStats
from .signals import SIGNALS_SCHEMA, Interval, finite_or_none, state_message
from .tap import IntervalTap

STATE_TOPIC = "/signals/state"
RUNNING_TOPIC = "/report/running"
RATE_HZ = 200.0
"""Default rate of ``/signals/state`` (``--foxglove-rate``)."""
SEND_EVERY_S = 0.02
"""The view's thread wakes this often to send what has accumulated."""
RUNNING_EVERY_S = 1.0
STOP_WAIT_S = 1.0
"""How long the end of a run waits for the server to stop."""
BACKLOG = 2048
"""Messages the server queues for one client before it drops for that client."""

if TYPE_CHECKING:
    from ..central.snapshot import Progress


RUNNING_SCHEMA: dict[str, Any] = {
    "title": "ctrlunit.Running",
    "type": "object",
    "properties": {
        "cycles": {"type": "integer", "minimum": 0, "description": "intervals done"},
        "cycles_planned": {"type": "integer", "minimum": 0},
        "period_s": {"type": "object", "properties": {
            "p50": {"type": ["number", "null"]}, "p99": {"type": ["number", "null"]}}},
        "deadline_misses": {"type": "integer", "minimum": 0},
        "skipped_samples": {"type": "integer", "minimum": 0},
        "tracking_error_m": {"type": "object", "properties": {
            "now": {"type": ["number", "null"]}, "max": {"type": ["number", "null"]}}},
        "dropped": {"type": "integer", "minimum": 0,
                    "description": "intervals due to be shown that the live view skipped "
                                   "because it fell behind (not the unit)"},
    },
    "required": ["cycles", "cycles_planned", "period_s", "deadline_misses",
                 "skipped_samples", "tracking_error_m", "dropped"],
}


class FoxgloveSink:
    """A Foxglove WebSocket server (the ``foxglove-sdk`` package) with the view's two JSON
    channels. Raises ``OSError`` naming the address when it cannot listen there."""

    listening = True
    """The server keeps what it is sent for the viewers that connect later."""

    def __init__(self, *, host: str, port: int, name: str) -> None:
        import foxglove  # only a run with --foxglove pays for the import

        self._ctx = foxglove.Context()
        try:
            self._server = foxglove.start_server(
                name=name, host=host, port=port, context=self._ctx,
                message_backlog_size=BACKLOG)
        except Exception as exc:  # the SDK raises its own error type
            raise OSError(f"--foxglove {host}:{port}: cannot listen there ({exc})") from None
        self.host, self.port = host, self._server.port
        self._state = self._channel(foxglove, STATE_TOPIC, SIGNALS_SCHEMA)
        self._running = self._channel(foxglove, RUNNING_TOPIC, RUNNING_SCHEMA)

    def _channel(self, foxglove: Any, topic: str, schema: dict) -> Any:
        return foxglove.Channel(
            topic, message_encoding="json", context=self._ctx,
            schema=foxglove.Schema(name=schema["title"], encoding="jsonschema",
                                   data=json.dumps(schema).encode()))

    @property
    def url(self) -> str:
        return f"ws://{self.host}:{self.port}"

    def state(self, payload: bytes, log_time: int) -> None:
        self._state.log(payload, log_time=log_time)

    def running(self, payload: bytes, log_time: int) -> None:
        self._running.log(payload, log_time=log_time)

    def close(self) -> None:
        """Stop the server: its stop waits for its clients to take a close frame, and one
        that stopped reading holds it for ~50 s; the run does not wait (the thread ends
        with it)."""
        stopper = threading.Thread(target=self._server.stop, name="ctrlunit-foxglove-stop",
                                   daemon=True)
        stopper.start()
        stopper.join(timeout=STOP_WAIT_S)


class LiveView:
    """The live view of one run; the central's ``on_cycle`` callback.

    Parameters
    ----------
    sink : where the messages go: ``state(payload, log_time)``, ``running(payload,
        log_time)``, ``listening`` (nothing is built while it is false), ``url`` and
        ``close()``; by default a :class:`FoxgloveSink` on ``host``, ``port`` (port 0: any
        free port) named ``name``; runtime/observe/zview.py's ``ZenohSink`` for the
        observers' keys.
    task : the task whose ``sample(t)[0]`` is the reference (``None`` in freerun).
    period_s : the nominal period (s).
    cycles : intervals planned.
    rate_hz : ``/signals/state`` messages per second of command time at most (0: every
        interval).
    name : the server's name shown in Foxglove.

    Use as a context manager, or call :meth:`close`. Raises ``OSError`` naming the
    address when the server cannot listen there.
    """

    def __init__(self, *, task: Any | None, period_s: float, cycles: int,
                 rate_hz: float = RATE_HZ, host: str = "127.0.0.1", port: int = 0,
                 name: str = "ctrlunit", sink: Any | None = None) -> None:
        self.task, self.period_s, self.cycles = task, period_s, cycles
        self.sink = sink if sink is not None else FoxgloveSink(host=host, port=port,
                                                                 name=name)
        self.tap = IntervalTap(rate_hz=rate_hz)
        self.sent = 0
        self.stats = LiveStats(cycles)
        self._progress: Progress | None = None
        self._read = 0  # intervals of the central's logs read into the running figures
        self._errors_read = 0
        self._wall_offset_ns = time.time_ns() - time.monotonic_ns()
        self._lock = threading.Lock()  # the run's figures against rerun()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="ctrlunit-foxglove",
                                        daemon=True)
        self._thread.start()

    @property
    def url(self) -> str:
        """Where the view is read (the sink's address)."""
        return str(self.sink.url)

    @property
    def port(self) -> int:
        """The Foxglove server's port."""
        return int(self.sink.port)

    # -- the central's thread ----------------------------------------------------------

    def __call__(self, progress: Progress, ctx: dict) -> None:
        """``on_cycle``: note the interval if it is due to be shown (a tuple into a bounded
        deque; nothing waits)."""
        self._progress = progress
        if self.sink.listening:  # nobody reads: nothing is built
            self.tap.offer(progress, ctx)

    # -- the view's thread -------------------------------------------------------------

    @property
    def dropped(self) -> int:
        """Intervals the view skipped because its thread fell behind."""
        return self.tap.dropped

    @property
    def appended(self) -> int:
        """Intervals noted to be shown."""
        return self.tap.appended

    def _send_pending(self) -> None:
        self.tap.drain(self._send)

    def _send(self, iv: Interval) -> None:
        msg = state_message(iv, period_s=self.period_s, task=self.task,
                            previous_cmd_ns=iv.previous_cmd_ns)
        self.sink.state(orjson.dumps(msg), iv.cmd_ns + self._wall_offset_ns)
        self.sent += 1

    def _read_logs(self) -> None:
        """Bring the running figures up to the central's logs (its thread only appends
        to them; a slice is taken under the GIL)."""
        p = self._progress
        if p is None:
            return
        cmd, self._read = p.history.commands_since(self._read)
        errors, self._errors_read = p.history.errors_since(self._errors_read)
        self.stats.add_many(done=p.done, cmd_ns=cmd, misses=p.misses, skipped=p.skipped,
                            errors=errors)

    def running(self) -> dict[str, Any]:
        """The ``/report/running`` message: the figures so far."""
        self._read_logs()
        s = self.stats
        return {"cycles": s.done, "cycles_planned": self.cycles,
                "period_s": {"p50": finite_or_none(s.percentile_s(50)),
                             "p99": finite_or_none(s.percentile_s(99))},
                "deadline_misses": s.misses, "skipped_samples": s.skipped,
                "tracking_error_m": {"now": finite_or_none(s.error),
                                     "max": finite_or_none(s.error_max)},
                "degraded": [] if self._progress is None else self._progress.history.degraded(),
                "dropped": self.dropped}

    def _send_running(self) -> None:
        self.sink.running(json.dumps(self.running()).encode(), time.time_ns())

    def _run(self) -> None:
        next_running = time.monotonic() + RUNNING_EVERY_S
        while not self._stop.wait(SEND_EVERY_S):
            # its work can wait: never at the roles' real-time priority, where a thread
            # runs until it blocks (the observers' view is made after the policy is set:
            # its thread starts under its creator's)
            leave_rt()
            with self._lock:
                self._send_pending()
                if time.monotonic() >= next_running:
                    next_running += RUNNING_EVERY_S
                    self._send_running()
        self.flush()

    def flush(self) -> None:
        """Send what is queued and the running figures now (the end of a run)."""
        with self._lock:
            self._send_pending()
            self._send_running()

    def rerun(self, *, task: Any | None, period_s: float, cycles: int) -> None:
        """The unit starts again (``--period auto``): the same server and viewers, the
        figures of the new run from zero. Call it from the central's thread between runs."""
        with self._lock:
            self.tap.clear()
            self.task, self.period_s, self.cycles = task, period_s, cycles
            self.stats = LiveStats(cycles)
            self._progress = None
            self._read = self._errors_read = 0
            self.sent = 0

    # -- end ---------------------------------------------------------------------------

    def close(self, *, linger_s: float = 0.0, join_s: float = 5.0) -> None:
        """Send what is left and the last running figures, keep serving ``linger_s``
        seconds (so that a viewer sees the end), then close the sink. Waits at most
        ``join_s`` for the view's thread (one held in a send by a reader that stopped
        reading is left behind: it ends with the process)."""
        if self._stop.is_set():
            return
        self._stop.set()
        self._thread.join(timeout=join_s)
        if linger_s > 0:
            time.sleep(linger_s)
        self.sink.close()

    def __enter__(self) -> LiveView:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
