"""Every interval to MCAP (``ctrlunit start --record FILE.mcap``).

Channels
--------
``msgpack`` (raw bytes exactly as on the wire; log time = send or receive time, ns), named
  by their Zenoh key without ``ctrlunit/<unit>`` (keys are addressed by destination):
  ``/central/sample``, ``/plant/command``, ``/peripheral/request``, ``/central/reply/K``,
  ``/plant/control`` for the orders that change the control rate (``--overload``), and
  ``/central/primed`` for an interval whose sample-free steps ran before its sample was
  skipped (replay runs them too: they fill the task's cache), and ``/central/placement``
  for each live re-placement (``--balance live``: the interval it starts at, the blocks
  on the central, why, the figures that justified it; replay changes plans there).
``msgpack``: ``/timing/spans`` (per interval: ``[[process, t0, t1], ...]``),
  ``/faults/rejected`` (rejection counters, every 500 intervals and at the end),
  ``/faults/deadline`` (deadline misses and skipped samples as they change),
  ``/faults/held`` (a late round's values replaced by the last ones, ``--late-policy
  hold``: cycle, stage, peripheral and the values used, which replay uses too),
  ``/faults/computed`` (a late round the central computed itself for a peripheral,
  ``--late-policy compute``, or a lost peripheral's round: cycle, stage, peripheral;
  replay expects no reply there), ``/faults/degraded`` (a peripheral lost and taken over:
  which, from which cycle, why; runtime/central/takeover.py).
``json`` with ``jsonschema`` schemas (open in Foxglove): ``/signals/state`` (p, reference,
  q, torque, tracking error, period, traversal). NaN and infinities are written as null.
``cdr`` with ``ros2msg`` schemas (ROS 2's tools; the file's profile is ``ros2``):
  ``/joint_states``, ``/platform/pose``, ``/platform/reference``,
  ``/ctrlunit/diagnostics`` (:mod:`.ros2`).

A metadata record ``ctrlunit`` holds the configuration, placement, package version, host,
core count and clock, and the wall clock's offset from the log times
(``epoch_offset_ns``); ``ctrlunit.files`` the text of the task, parameters and placement
files the run read (:mod:`.recorded_config`); ``ctrlunit.result`` (at the end) holds
``t_1``, the block costs and what else only the live run knew (``live``: scheduling,
admission, placement choice, late data, excused silences, the safe stop, the links;
``cpu``: the CPU budget), so that
``ctrlunit report`` prints every line of the live summary.

Chunks are compressed (``--record-compression``, zstd by default) and written on the
writer's own thread: the central's thread only appends to the open chunk.

Crash safety: a chunk is closed at 256 KiB (about 75 intervals) or 100 ms after its first
message, whichever comes first, and the file is flushed at least every 20 ms, so a file cut
off by ``kill -9`` loses at most the open chunk (100 ms of the run at most) and those the
writer thread had not yet written; :func:`ctrlunit.runtime.recording.reader.read` salvages such a
file with a non-seeking pass. Larger chunks compress better (a 10 000-interval freerun
recording: 2.92x at 64 KiB, 3.02x at 256 KiB; docs/measurements/2026-11-22-recording.md).
"""

from __future__ import annotations

import contextlib
import json
import os
import platform
import socket
import time
from importlib.metadata import version
from typing import Any

import msgpack
import orjson

from ..central.snapshot import Progress, RunSnapshot
from ..host import sched
from ..observe.report import CPU_KEYS, RESULT_KEYS
from ..observe.signals import SIGNALS_SCHEMA, capture, state_message
from .mcap_writer import LeanWriter
from .recorded_config import FILES_RECORD, files_of
from .ros2 import PROFILE, Ros2Channels

FLUSH_EVERY_NS = 20_000_000
CHUNK_SIZE = 256 * 1024
CHUNK_AGE_NS = 100_000_000


class Recorder:
    """Writes the run to an MCAP file as it goes.

    Parameters
    ----------
    path : output file.
    setup : the run's :class:`~ctrlunit.runtime.compute.setup.Setup` (the header is written by
        :meth:`begin`, with the set-up the run starts with).
    """

    def __init__(self, path: str, setup: Any) -> None:
        self.path = path
        self.setup = setup
        self.fh = open(path, "wb")
        self.w = LeanWriter(self.fh, chunk_size=CHUNK_SIZE, chunk_age=CHUNK_AGE_NS,
                            compression=setup.rc.run.record_compression, background=True,
                            before_job=sched.leave_rt)
        self.w.start(profile=PROFILE, library=f"ctrlunit {version('ctrlunit')}")
        self.channels: dict[str, int] = {}
        self.seq = 0
        self.last_flush = time.monotonic_ns()
        self.last_cmd_ns: int | None = None
        self.last_misses = -1
        self.closed = False
        self.failed: str | None = None
        """Why writing stopped, if it did (a full disk, a file that takes no writes): the
        run goes on, the file holds what came before (:meth:`_lost`)."""
        self.done = 0  # intervals recorded
        self.pending: list[tuple[str, int, bytes]] = []
        self.topics: dict[str, str] = {}  # Zenoh key -> topic
        self.began = False
        self.raw_schema = self.w.register_schema("", "", b"")
        self.central_outputs = [o for b in setup.plan.graph.blocks if not b.per_axis
                                for o in b.outputs]
        self.json_schema = self.w.register_schema(
            "ctrlunit.State", "jsonschema", json.dumps(SIGNALS_SCHEMA).encode())
        self.ros2 = Ros2Channels(self._ros2_channel, self._add_ros2, setup.rc.transport.unit)

    @classmethod
    def rehearsal(cls, setup: Any) -> Recorder:
        """A recorder writing to ``/dev/null``: the admission's trial does the recording's
        work on the same threads without keeping it (runtime/launch/admission.py); end it
        with :meth:`discard`."""
        return cls(os.devnull, setup)

    def discard(self, run: RunSnapshot) -> None:
        """End a :meth:`rehearsal` of ``run`` (its last records and footer go nowhere)."""
        self.close(run)
        self.write_report({})

    def _ros2_channel(self, topic: str, msgtype: str, definition: bytes) -> int:
        cid = self.w.register_channel(
            topic, "cdr", self.w.register_schema(msgtype, "ros2msg", definition))
        self.channels[topic] = cid
        return cid

    def _add_ros2(self, cid: int, t_ns: int, data: bytes) -> None:
        if self.closed:
            return
        self.seq += 1
        self.w.add_message(cid, t_ns, data, t_ns, self.seq)

    def begin(self, setup: Any) -> None:
        """Write the header (metadata ``ctrlunit``) of the run about to start: its
        configuration and the placement it runs (``--placement auto`` chooses it at
        warm-up, after this recorder noted the first exchanges)."""
        if self.began or self.closed:
            return
        self.began = True
        self.setup = setup
        rc = setup.rc
        meta = {
            # the model state as it runs: what ``auto`` resolves to may change
            "config": json.dumps(rc.replace(model_state=rc.resolved_model_state).to_dict()),
            "placement": json.dumps(setup.placement.to_dict()),
            "plan": setup.plan.describe(),
            "round_trips": str(setup.plan.round_trips),
            "cycles_planned": str(setup.cycles),
            "version": version("ctrlunit"),
            "host": socket.gethostname(),
            "platform": platform.platform(),
            "cores": str(os.cpu_count()),
            "clock": rc.schedule.clock,
            "time_unit": "ns (host monotonic clock)",
            # a log time plus this is ns since the epoch (for tools that want dates)
            "epoch_offset_ns": str(time.time_ns() - time.monotonic_ns()),
        }
        try:
            self.w.add_metadata("ctrlunit", meta)
            if (files := files_of(rc)):  # what the setup read: a reader takes it from here
                self.w.add_metadata(FILES_RECORD, files)
        except (OSError, RuntimeError) as exc:
            self._lost(exc)

    def channel(self, topic: str, *, json_signals: bool = False) -> int:
        cid = self.channels.get(topic)
        if cid is None:
            if json_signals:
                cid = self.w.register_channel(topic, "json", self.json_schema)
            else:
                cid = self.w.register_channel(topic, "msgpack", self.raw_schema)
            self.channels[topic] = cid
        return cid

    def _add(self, topic: str, t_ns: int, data: bytes, *, json_signals: bool = False) -> None:
        if self.closed:
            return
        self.seq += 1
        self.w.add_message(self.channel(topic, json_signals=json_signals), t_ns, data, t_ns,
                           self.seq)
        if t_ns - self.last_flush > FLUSH_EVERY_NS:
            self.w.flush()
            self.last_flush = t_ns

    # -- callbacks from the central -----------------------------------------------------

    def on_message(self, direction: str, key: str, cycle: int, stage: Any, data: bytes,
                   t_ns: int) -> None:
        """Every exchange, raw (``key`` is the Zenoh key; the topic drops the unit id).
        Only noted here, on the central's critical path; written at the interval's end."""
        self.pending.append((key, t_ns, data))

    def _drain(self) -> None:
        topics = self.topics
        for key, t_ns, data in self.pending:
            topic = topics.get(key)
            if topic is None:
                topic = topics[key] = "/" + key.split("/", 2)[2]
            self._add(topic, t_ns, data)
        self.pending.clear()

    def _lost(self, exc: BaseException) -> None:
        """Writing failed (in the writer's thread, or here): stop recording, keep the run
        going. The file holds the chunks written before; :func:`.reader.read` salvages
        it."""
        cause = exc.__cause__ if isinstance(exc.__cause__, OSError) else exc
        self.failed = f"stopped after {self.done} interval(s): {cause}"
        self.closed = True
        with contextlib.suppress(Exception):
            self.fh.close()

    def on_cycle(self, progress: Progress, ctx: dict) -> None:
        """After each interval (at depth 2 once the next request is out): the exchanges
        noted since the last one, spans, signals, deadline and rejection events; a write
        that fails ends the recording, never the run (:meth:`_lost`)."""
        if self.closed:
            return
        try:
            self._cycle(progress, ctx)
            self.done += 1
        except (OSError, RuntimeError) as exc:
            self._lost(exc)

    def _cycle(self, progress: Progress, ctx: dict) -> None:
        self._drain()
        p, cycle = progress, progress.cycle
        iv = capture(p, ctx)
        now = iv.cmd_ns
        spans = list(p.spans)
        self._add("/timing/spans", now, msgpack.packb({"cycle": cycle, "spans": spans}))
        sch = self.setup.rc.schedule
        sig = state_message(iv, period_s=p.period_s,
                            task=self.setup.task if sch.clock != "freerun" else None,
                            previous_cmd_ns=self.last_cmd_ns)
        self.last_cmd_ns = now
        self._add("/signals/state", now, orjson.dumps(sig), json_signals=True)
        ros2 = self.ros2
        ros2.interval(now, sig, ctx.get("qdmeas_i"))
        if ros2.due(now):
            ros2.status(now, misses=p.misses, skipped=p.skipped,
                        rejected=sum(p.rejected.values()))
        self._add("/trace/central", now, msgpack.packb(
            {"cycle": cycle, "vals": {n: ctx[n] for n in self.central_outputs
                                      if n in ctx}}, use_single_float=False))
        misses = p.misses + p.skipped
        if misses != self.last_misses:
            self._add("/faults/deadline", now, msgpack.packb(
                {"cycle": cycle, "deadline_misses": p.misses, "skipped_samples": p.skipped}))
            self.last_misses = misses
        if p.done % 500 == 0:
            self._add("/faults/rejected", now, msgpack.packb(dict(p.rejected)))

    # -- end ------------------------------------------------------------------------------

    def close(self, run: RunSnapshot) -> None:
        """Write the last counters of ``run`` (the central's at the end; the report
        follows in :meth:`write_report`)."""
        if self.closed:
            return
        try:
            self._close(run)
        except (OSError, RuntimeError) as exc:
            self._lost(exc)

    def _close(self, run: RunSnapshot) -> None:
        self.begin(self.setup)  # a run that ended before its first interval: still a header
        self._drain()
        now = time.monotonic_ns()
        self._add("/faults/rejected", now, msgpack.packb(dict(run.rejected)))
        self._add("/faults/deadline", now, msgpack.packb(
            {"cycle": run.next_cycle, "deadline_misses": run.plant_misses,
             "skipped_samples": run.skipped}))
        self.ros2.status(now, misses=run.plant_misses, skipped=run.skipped,
                         rejected=sum(run.rejected.values()))
        t = run.times
        self.t_end_ns, self.t_start_ns = t.t_end_ns, t.t_start_ns
        self.busy = {"central_wait_ns": t.wait_ns, "periph_busy_ns": list(t.periph_busy_ns),
                     "plant_busy_ns": t.plant_busy_ns}

    def write_report(self, report: dict[str, Any]) -> None:
        """Store what only the live run knows (t_1, block costs, wall times, and under
        ``live`` the report's :data:`~..observe.report.RESULT_KEYS`), then finish."""
        if self.closed:
            return
        try:
            self._result(report)
        except (OSError, RuntimeError) as exc:
            self._lost(exc)

    def _result(self, report: dict[str, Any]) -> None:
        self.w.add_metadata("ctrlunit.result", {
            "t1_s": repr(report.get("t1_s")),
            "block_cost_s": json.dumps(report.get("block_cost_s") or {}),
            "t_start_ns": str(getattr(self, "t_start_ns", 0)),
            "t_end_ns": str(getattr(self, "t_end_ns", 0)),
            "busy": json.dumps(getattr(self, "busy", {})),
            "fault": json.dumps(report.get("fault")),
            "rejected": json.dumps(report.get("rejected_messages") or {}),
            "cpu": json.dumps({k: report.get(k) for k in CPU_KEYS}),
            "live": json.dumps({k: report[k] for k in RESULT_KEYS if k in report},
                               default=_plain),
        })
        self.w.finish()
        self.fh.close()
        self.closed = True


def _plain(x: Any) -> Any:
    """A value JSON has no type for (a numpy number): as a plain number, else as text."""
    item = getattr(x, "item", None)
    return item() if callable(item) else str(x)
