"""The central's own accounting: where its time went, what the other processes reported
as their compute spans, and what it sampled of its memory; for the report, the schedule
model (:mod:`ctrlunit.topology.schedule`) and the Gantt charts. Nothing here decides."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field


@dataclass
class Meters:
    """Counters and spans of one central's run (times in ns from ``time.monotonic_ns``
    or ``time.perf_counter_ns``, as each field says)."""

    peripherals: int
    keep_cycle_spans: bool = False
    """Keep each interval's spans until it is finished (for the per-interval hook)."""
    exchanges: int = 0
    """Requests sent (each may carry several rounds)."""
    send_ns: int = 0
    """Time spent sending requests (encode, put)."""
    reply_ns: int = 0
    """Time spent on replies (decode, check, merge), not on what follows them."""
    reply_msgs: int = 0
    admit_ns: int = 0
    """Starting intervals (sample, context), not their steps."""
    finish_ns: int = 0
    """Finishing intervals (checks, command, logs, progress)."""
    wait_ns: int = 0
    """Time the loop waited for an event."""
    plant_busy_ns: int = 0
    periph_busy_ns: list[int] = field(default_factory=list)
    t_start_ns: int = 0
    t_end_ns: int = 0
    cpu_s: float | None = None
    """CPU of this process (all threads) during the run."""
    rss_warm: int = -1
    rss_end: int = -1
    rss_series: list[tuple[int, int]] = field(default_factory=list)
    spans: list[tuple[str, int, int, int]] = field(default_factory=list)
    """(process, cycle, t0, t1) of the first intervals, at most :attr:`max_spans`."""
    max_spans: int = 4_000
    cycle_spans: dict[int, list[tuple[str, int, int]]] = field(default_factory=dict)
    t1_inputs: list[tuple] = field(default_factory=list)
    """What ``t_1`` recomputes the first intervals from (runtime/compute/engine.py)."""
    plant_misses: int = 0
    """Commands that missed their deadline at the plant, as the plant last reported."""
    skipped: int = 0
    """Samples skipped: the central started behind the plant's clock (realtime)."""
    skip_marks: list[tuple[int, int]] = field(default_factory=list)
    """In a trial: where samples were skipped, as (traversals logged before, samples
    skipped), so that the admission can tell one stall from a steady lag."""

    def __post_init__(self) -> None:
        if not self.periph_busy_ns:
            self.periph_busy_ns = [0] * self.peripherals

    def span(self, proc: str, cycle: int, t0: int, t1: int) -> None:
        """Note that ``proc`` computed for ``cycle`` from ``t0`` to ``t1``."""
        if len(self.spans) < self.max_spans:
            self.spans.append((proc, cycle, t0, t1))
        if self.keep_cycle_spans:
            self.cycle_spans.setdefault(cycle, []).append((proc, t0, t1))

    def plant_sample(self, cycle: int, span: Sequence[int], misses: int | None) -> None:
        """Note the plant's compute ``span`` for sample ``cycle`` and its count of late
        commands (None: not reported)."""
        self.plant_busy_ns += span[1] - span[0]
        if misses is not None:
            self.plant_misses = misses
        self.span("plant", cycle, span[0], span[1])

    def spans_of(self, cycle: int) -> list[tuple[str, int, int]]:
        """The spans kept for ``cycle`` (each process's compute time)."""
        return self.cycle_spans.get(cycle, [])

    def finished(self, cycle: int) -> None:
        """Forget the spans of ``cycle`` and of intervals more than 8 before it."""
        self.cycle_spans.pop(cycle, None)
        for c in [c for c in self.cycle_spans if c < cycle - 8]:
            del self.cycle_spans[c]

    def costs(self, done: int) -> dict[str, float]:
        """The central's own time after ``done`` intervals, for the schedule model: per
        request sent, per reply message handled, per interval to start and to finish it,
        and busy (not waiting) per interval."""
        wall = max(1, self.t_end_ns - self.t_start_ns)
        done = max(1, done)
        return {
            "start": self.admit_ns / done / 1e9,
            "finish": self.finish_ns / done / 1e9,
            "send": self.send_ns / max(1, self.exchanges) / 1e9,
            "reply": self.reply_ns / max(1, self.reply_msgs) / 1e9,
            "replies_per_interval": self.reply_msgs / max(1, done),
            "busy_per_interval": (wall - self.wait_ns) / done / 1e9,
        }


__all__ = ["Meters"]
