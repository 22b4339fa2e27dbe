"""A peripheral's reply at the central: the gather of § IV.7.2 (Fig. 24).

Each part of a reply (one per round it answers, where rounds of consecutive intervals
were fused) is checked against the interval that waits for it, merged into that
interval's values and counted; a part that comes after its round was computed without it
(runtime/central/late.py) or that nobody waits for is counted and dropped. The intervals
whose round is then complete go on, in the pipeline's order
(:func:`ctrlunit.topology.pipeline.finishes_after_next_request`)."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

from ...topology.pipeline import finishes_after_next_request
from ..compute.engine import Engine
from ..transport.zsession import Keys
from .intake import Intake
from .intervals import Intervals
from .late import LateData
from .meters import Meters
from .records import InFlight
from .silence import SilenceWatch
from .takeover import TakeOver


class Replies:
    """The central's handling of replies; given its collaborators at construction."""

    def __init__(self, *, intervals: Intervals, intake: Intake, takeover: TakeOver,
                 late: LateData, silence: SilenceWatch, meters: Meters, keys: Keys,
                 on_message: Callable[[str, str, int, Any, bytes, int], None] | None) -> None:
        self.intervals, self.intake, self.takeover = intervals, intake, takeover
        self.late, self.silence, self.meters = late, silence, meters
        self.keys, self.on_message = keys, on_message

    def take(self, k: int, data: bytes, rx: int) -> None:
        """Take a reply of peripheral ``k`` (0-based) received at ``rx``: each of its
        parts merged into the interval that waits for it (a late or unexpected one
        counted and dropped), then the intervals whose round it completed go on."""
        t_in = time.perf_counter_ns()
        iv = self.intervals
        got = self.intake.reply(data)
        if got is None:
            return
        msg, parts = got
        parts = self.takeover.sift(k, parts, next_cycle=iv.next_cycle, done=iv.done, rx=rx)
        axes = iv.engine.plan.placement.axes[k]
        complete = []
        accepted = False
        for part in parts:
            f = iv.inflight.get(part["cycle"])
            if (f is None or f.round is None or part["stage"] != f.round.index
                    or k not in f.waiting):
                if self.late.came_late(part["cycle"], part["stage"], k):
                    self.silence.heard_reply(k, rx)  # its values were held: alive, late
                    self.intake.reject("late_reply")
                else:
                    self.intake.unexpected_reply(part["cycle"])
                continue
            checked = self.intake.reply_part(part, f.round.recv, len(axes))
            if checked is None:
                continue
            vals, span = checked
            accepted = True
            Engine.merge(f.ctx, vals, axes)
            self.late.remember(vals, axes)  # replies hold per-axis values only
            self.meters.periph_busy_ns[k] += span[1] - span[0]
            self.meters.span(f"peripheral_{k + 1}", f.cycle, span[0], span[1])
            if f.answered(k, min(span[1] - span[0], 2**31 - 1)):
                complete.append(f)
        if not accepted:
            return
        self.meters.reply_ns += time.perf_counter_ns() - t_in
        self.meters.reply_msgs += 1
        self.silence.heard_reply(k, rx)
        if self.on_message is not None:
            self.on_message("in", self.keys.reply(k + 1), msg["cycle"], msg["stage"],
                            data, rx)
        self._complete(complete)

    def _complete(self, complete: list[InFlight]) -> None:
        """Go on with the intervals whose round is complete. Depth 2: intervals with more
        rounds first; those whose last round this was finish after the next request is
        out (their last central blocks, command, recording and progress overlap the
        peripherals' work)."""
        finishing = [f for f in complete if f.round is not None
                     and f.round.index >= self.intervals.shape.ahead_rounds
                     and finishes_after_next_request(depth=self.intervals.settings.depth,
                                                     round_index=f.round.index,
                                                     last_round=self.intervals.shape.last_round)]
        for f in complete:
            if f not in finishing:
                self.intervals.advance(f)
        if finishing:
            for f in finishing:
                f.finish_after_request()
            self.intervals.start_ready()
            self.intervals.flush(time.monotonic_ns())
            for f in finishing:
                self.intervals.advance(f)


__all__ = ["Replies"]
