"""How the rest of the unit sees the central: values it hands out, never its parts.

Two views, both made by :class:`~.scheduler.Central` and read by the report, the
recorder, the live views, the admission and the end of a run (docs/architecture.md,
"The central seen from outside"):

- :class:`Progress`, after each interval (the ``on_cycle`` hook): what that interval
  left and the counters at that moment; a tuple, made in a few microseconds on the
  control path.
- :class:`RunSnapshot`, at any moment between intervals and at the end: every figure the
  report needs, copied, so that nothing read from it changes afterwards.

A view that runs on a thread of its own (the live view) reads the central's growing logs
through :class:`History`, whose reads are safe from a thread that does not append.
"""

from __future__ import annotations

import copy
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from types import MappingProxyType
from typing import TYPE_CHECKING, Any, NamedTuple

from ..compute.stride import StrideSchedule
from .records import CycleLog

if TYPE_CHECKING:
    from .scheduler import Central


class History:
    """The central's logs for a reader on another thread: the command times and tracking
    errors from an index on (:meth:`~..compute.timing.BoundedSeries.since`), and the
    peripherals taken over so far."""

    def __init__(self, log: CycleLog, degraded: Callable[[], list[dict[str, Any]]]) -> None:
        self._log = log
        self._degraded = degraded

    def commands_since(self, start: int) -> tuple[Any, int]:
        """When each interval's command left (ns), from absolute index ``start``, and the
        index after the last."""
        return self._log.cmd_ns.since(start)

    def errors_since(self, start: int) -> tuple[Any, int]:
        """Tracking errors (m) from absolute index ``start``, and the index after the
        last."""
        return self._log.errors.since(start)

    def degraded(self) -> list[dict[str, Any]]:
        """The report's ``degraded`` so far: each loss of a peripheral, in order."""
        return list(self._degraded())


class Progress(NamedTuple):
    """Interval ``cycle``, just finished (its command sent), as ``on_cycle`` sees it."""

    cycle: int
    done: int
    """Intervals finished, this one included."""
    reached: int
    """Periods covered (intervals fall behind them where samples were skipped or the
    control rate was halved)."""
    planned: int
    """The cycle number after the run's last."""
    period_s: float
    """The sampling period of this central's run (an admission trial's own)."""
    cmd_ns: int
    """When this interval's command left (``time.monotonic_ns``)."""
    previous_cmd_ns: int | None
    traversal_ns: int
    """From its sample to its command."""
    true_p: tuple[float, float, float] | None
    """The plant's true end-effector position at its sample (m), where known."""
    misses: int
    """Commands late at the plant so far, as the plant last reported."""
    skipped: int
    """Samples skipped so far (realtime)."""
    rejected: Mapping[str, int]
    """Messages rejected so far, by reason (a copy)."""
    lost: tuple[int, ...]
    """Peripherals (0-based) taken over now."""
    spans: tuple[tuple[str, int, int], ...]
    """Each process's compute span for this interval, ``(process, t0_ns, t1_ns)``."""
    history: History


@dataclass(frozen=True)
class RunTimes:
    """Where the run's time went (ns of ``time.monotonic_ns`` unless named otherwise)."""

    t_start_ns: int
    t_end_ns: int
    wait_ns: int
    """Time the central's loop waited for an event."""
    cpu_s: float | None
    """The central process's CPU during the run (every thread)."""
    plant_busy_ns: int
    periph_busy_ns: tuple[int, ...]
    central_costs: dict[str, float]
    """The central's own time per request, reply, start and finish (the schedule model's)."""
    spans: tuple[tuple[str, int, int, int], ...]
    """``(process, cycle, t0, t1)`` of the first intervals (Gantt charts)."""
    cmd_ns: tuple[int, ...]
    """Command times of the intervals kept exactly (the newest)."""
    sample_ns: tuple[int, ...]
    """Their sample times."""
    traversal_ns: tuple[int, ...]
    skip_marks: tuple[tuple[int, int], ...]
    """Where samples were skipped, as (traversals logged before, samples skipped)."""
    warm_rtt_s: tuple[float, ...]
    """The warm-up's round trips (s)."""
    cost_errors_ns: tuple[int, ...]
    """The T-800 cost emulation's errors."""


@dataclass(frozen=True)
class LateFigures:
    """Late intervals and late rounds (realtime), and the control rate's changes."""

    deadline_ns: int
    work_ns: tuple[int, ...]
    late_work_ns: tuple[int, ...]
    late: int
    per_axis: tuple[int, ...]
    computed: int
    taken_over: int
    rate_changes: tuple[dict[str, Any], ...]
    halves_on_overload: bool
    grid: StrideSchedule
    """Which cycles ran at which control rate (a copy of the controller's)."""


@dataclass(frozen=True)
class RunSnapshot:
    """The central's run as the report reads it (copies: later intervals change nothing
    here; its dicts are the snapshot's own, not to be changed by a reader)."""

    done: int
    next_cycle: int
    first_cycle: int
    planned: int
    times: RunTimes
    late: LateFigures
    t1_inputs: tuple[Any, ...]
    """What ``t_1`` recomputes the first intervals from."""
    rejected: Mapping[str, int]
    role_reports: Mapping[str, dict]
    """Each role's final report, by role name."""
    timing: dict[str, Any]
    digest: str
    """SHA-256 of every command, in order (lockstep runs are compared by it)."""
    torque_max: float
    tracking: dict[str, float]
    plant_misses: int
    skipped: int
    exchanges: int
    replies_info: dict[str, Any] | None
    silences_excused: int
    degraded: tuple[dict[str, Any], ...]
    rebalanced: tuple[dict[str, Any], ...]
    """Each live re-placement (:mod:`.rebalance`), in order."""
    live_balance: dict[str, Any] | None
    """What live balance did, where it was asked (:meth:`.rebalance.LiveBalance.summary`)."""
    memory_kb: tuple[int, int, tuple[tuple[int, int], ...]]
    """The central's resident memory: when warm, at the end, and its series."""

    @property
    def periods(self) -> int:
        """Periods the run covered (0 before its first interval finished)."""
        return max(0, self.next_cycle - self.first_cycle) if self.done else 0


def progress_of(central: Central, cycle: int, history: History) -> Progress:
    """The :class:`Progress` of ``central`` right after interval ``cycle`` finished."""
    log, m, ctl = central.log, central.meters, central.ctl
    cmd = log.cmd_ns
    return Progress(
        cycle, central.done, cycle - ctl.first_cycle + ctl.hold_of(cycle), central.cycles,
        central.rc.schedule.period, cmd[-1], cmd[-2] if len(cmd) > 1 else None,
        log.traversal_ns[-1], log.true_p.get(cycle), m.plant_misses, m.skipped,
        dict(central.node.rejected), tuple(sorted(central.takeover.lost)),
        tuple(m.spans_of(cycle)), history)


def snapshot_of(central: Central) -> RunSnapshot:
    """The :class:`RunSnapshot` of ``central`` now (between intervals, or at the end)."""
    m, log, late, ov = central.meters, central.log, central.late, central.overload
    done = central.done
    times = RunTimes(
        t_start_ns=m.t_start_ns, t_end_ns=m.t_end_ns, wait_ns=m.wait_ns, cpu_s=m.cpu_s,
        plant_busy_ns=m.plant_busy_ns, periph_busy_ns=tuple(m.periph_busy_ns),
        central_costs=m.costs(done), spans=tuple(m.spans), cmd_ns=tuple(log.cmd_ns.recent),
        sample_ns=tuple(log.sample_ns), traversal_ns=tuple(log.traversal_ns.recent),
        skip_marks=tuple(m.skip_marks), warm_rtt_s=tuple(central.warmup.warm_rtt_s),
        cost_errors_ns=tuple(central.engine.cost.errors_ns))
    late_figures = LateFigures(
        deadline_ns=central.settings.deadline_ns, work_ns=tuple(log.work_ns.recent),
        late_work_ns=tuple(log.late_work_ns), late=log.late,
        per_axis=tuple(late.late_per_axis), computed=late.computed,
        taken_over=late.taken_over, rate_changes=tuple(dict(c) for c in ov.rate_changes),
        halves_on_overload=ov.enabled, grid=copy.deepcopy(central.ctl.grid))
    return RunSnapshot(
        done=done, next_cycle=central.next_cycle, first_cycle=central.ctl.first_cycle,
        planned=central.cycles, times=times, late=late_figures, t1_inputs=tuple(m.t1_inputs),
        rejected=MappingProxyType(dict(central.node.rejected)),
        role_reports=MappingProxyType(dict(central.orders.role_reports)),
        timing=log.times.figures(), digest=log.digest.hexdigest(),
        torque_max=log.torque_max, tracking=log.errors.stats(),
        plant_misses=m.plant_misses, skipped=m.skipped, exchanges=m.exchanges,
        replies_info=dict(central.warmup.replies_info), silences_excused=central.silence.excuses,
        degraded=tuple(central.takeover.report()), rebalanced=tuple(central.balance.report()),
        live_balance=central.balance.summary(),
        memory_kb=(m.rss_warm, m.rss_end, tuple(m.rss_series)))


__all__ = ["History", "LateFigures", "Progress", "RunSnapshot", "RunTimes", "progress_of",
           "snapshot_of"]
