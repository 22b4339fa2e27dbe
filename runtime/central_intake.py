"""The central's intake: every message it receives (replies, samples, hellos and the
roles' final reports) checked field by field before use, then merged into the interval it
belongs to. A message that fails a check is counted under its reason and dropped.

:class:`CentralIntake` is a part of :class:`~.central.Central` (a mixin).
"""

from __future__ import annotations

import math
import time

from ..topology.pipeline import (
    finishes_after_next_request,
)
from .central_guard import role_report
from .codec import (
    BadMessage,
    check_span,
    check_vals,
    check_vector,
    parts_of,
)
from .engine import Engine


class CentralIntake:
    """Message intake of :class:`~.central.Central`."""

    def _handle(self, ev: tuple[str, int, bytes, int]) -> None:
        kind, index, data, rx = ev
        if kind == "reply":
            self._on_reply(index, data, rx)
        elif kind == "sample":
            self._on_sample(data, rx)
        elif kind == "hello":
            msg = self.node.decode(data)
            if msg is None:
                return
            stage = msg.get("stage")
            if stage == "hello":
                self.say("go")  # a role that missed go asks again
            elif stage == "bye":
                report = msg.get("report")
                if msg.get("role") not in self.expected_roles() or type(report) is not dict:
                    self.node.reject("bad_value")
                    return
                self.role_reports[msg["role"]] = role_report(report)
            elif stage != "placed":  # a late acknowledgement of a place order is no fault
                self.node.reject("bad_stage")
        else:
            self.node.reject("unexpected_key")

    def _on_sample(self, data: bytes, rx: int) -> None:
        msg = self.node.decode(data)
        if msg is None:
            return
        if msg["stage"] != "sample":
            self.node.reject("bad_stage")
            return
        if (msg.get("probe") is True) != self.trial:
            return  # the admission trial's samples are its own (a stray one is no fault)
        try:
            counts = msg.get("counts")
            if not isinstance(counts, list) or len(counts) != 3 or not all(
                isinstance(c, int) and not isinstance(c, bool) and abs(c) < 10**9
                for c in counts
            ):
                raise BadMessage("bad_value", "counts")
            t_ns = msg.get("t_ns")
            if isinstance(t_ns, bool) or not isinstance(t_ns, int):
                raise BadMessage("bad_value", "t_ns")
            p = check_vector(msg.get("p"), 3, "p")
            span = check_span(msg.get("span"))
        except BadMessage as exc:
            self.node.reject(exc.reason)
            return
        cycle = msg["cycle"]
        if not self.ctl.on_grid(cycle):
            return  # the rate is halved and the plant has yet to hear it: not taken
        if cycle < self.next_cycle or cycle >= self.cycles + self.depth + 1:
            self.node.reject("stale_cycle" if cycle < self.next_cycle else "future_cycle")
            return
        if self.last_sample_ns and rx - self.last_sample_ns > 2 * self.period_ns * self.ctl.stride:
            self.plant_gaps.append((self.last_sample_ns, rx))  # the plant silent too
        self.last_sample_ns = rx
        self.newest_sample = max(self.newest_sample, cycle)
        self.samples[cycle] = (counts, t_ns)
        if len(self.samples) > 64:  # realtime and far behind: keep the newest
            del self.samples[min(self.samples)]
        true_p = self.log.true_p
        here = true_p[cycle] = (p[0], p[1], p[2])
        if len(true_p) > 64:  # the oldest goes, even the one just taken (samples ahead)
            del true_p[min(true_p)]
        if cycle < self.cycles:  # the run's samples only: the plant may publish one more
            ref = self.engine.cfg.task.position(self.ctl.time_of(cycle))  # type: ignore[union-attr]
            self.log.errors.append(math.dist(here, ref))
        self.plant_busy_ns += span[1] - span[0]
        misses = msg.get("misses")
        if isinstance(misses, int) and not isinstance(misses, bool):
            self.plant_misses = misses
        self._span("plant", cycle, span[0], span[1])
        if self.on_message is not None:
            self.on_message("in", self.node.keys.sample, cycle, "sample", data, rx)

    def _on_reply(self, k: int, data: bytes, rx: int) -> None:
        t_in = time.perf_counter_ns()
        msg = self.node.decode(data)
        if msg is None:
            return
        try:
            parts = parts_of(msg)
        except BadMessage as exc:
            self.node.reject(exc.reason)
            return
        axes = self.plan.placement.axes[k]
        complete = []
        accepted = False
        for part in parts:
            f = self.inflight.get(part["cycle"])
            if (f is None or f.round is None or part["stage"] != f.round.index
                    or k not in f.waiting):
                key = (part["cycle"], part["stage"], k)
                if key in self.held:  # its values were replaced by the last ones (hold)
                    self.held.discard(key)
                    self.last_reply_ns[k] = rx
                    self.node.reject("late_reply")
                else:
                    self.node.reject("unexpected_reply")
                continue
            try:
                vals = check_vals(part.get("vals"), f.round.recv, len(axes))
                if "trace" in part and not isinstance(part["trace"], dict):
                    raise BadMessage("bad_value", "trace")
                span = check_span(part.get("span"))
            except BadMessage as exc:
                self.node.reject(exc.reason)
                continue
            accepted = True
            Engine.merge(f.ctx, vals, axes)
            Engine.merge(self.last_vals, vals, axes)  # replies hold per-axis values only
            self.periph_busy_ns[k] += span[1] - span[0]
            f.work_ns = max(f.work_ns, min(span[1] - span[0], 2**31 - 1))
            self._span(f"peripheral_{k + 1}", f.cycle, span[0], span[1])
            f.waiting.discard(k)
            if not f.waiting:
                complete.append(f)
        if not accepted:
            return
        self.reply_ns += time.perf_counter_ns() - t_in
        self.reply_msgs += 1
        self.last_reply_ns[k] = rx
        if self.on_message is not None:
            self.on_message("in", self.node.keys.reply(k + 1), msg["cycle"], msg["stage"],
                            data, rx)
        # depth 2: intervals with more rounds first; those whose last round this was
        # finish after the next request is out (their last central blocks, command,
        # recording and progress overlap the peripherals' work)
        finishing = [f for f in complete if f.round is not None
                     and f.round.index >= self.ahead_rounds
                     and finishes_after_next_request(depth=self.depth,
                                                     round_index=f.round.index,
                                                     last_round=self.last_round)]
        for f in complete:
            if f not in finishing:
                self._advance(f)
        if finishing:
            for f in finishing:
                f.finishing = True
            self._start_ready()
            self._flush(time.monotonic_ns())
            for f in finishing:
                self._advance(f)
