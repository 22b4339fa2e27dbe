"""Admission control: before the first real command, whether the unit holds its period.

In realtime the central, after its warm-up, runs a *trial* at the requested period: the
plant ticks on its wall clock as in the run (integrating a throw-away copy of the robot at
rest, so that its CPU load is the run's) and publishes trial samples; the central runs the
real pipeline on them (every process, every exchange, the same scheduler) with positions
that follow the reference, computes each command and sends it flagged ``probe``: the
plant checks and drops it (runtime/roles/plant_node.py), so the trial carries the
command's messaging too and the robot never moves for it. A run that records does
the recording's work in its trial too, into a recorder that keeps nothing (``rehearse``):
on a slow host, the recorder on the central's thread made runs admitted without it halve
their rate within 400 intervals (docs/measurements/2026-11-27-ros2-live.md). A trial interval is
*late* when its command would have reached the plant after the tick it is due at (its
sample's time plus ``depth`` periods; the traversal counts from the sample's time stamp and
adds the command's one-way transit measured at warm-up); a skipped sample is late too. The
period is *held* when at most one trial interval in 200 is late and the 99th percentile of
the traversal, transit included, uses at most :data:`HEADROOM` of the budget; under
SCHED_FIFO, also when no CPU was busy more than ``ADMIT_BUSY_SHARE`` of the kernel's
real-time budget during the trial (runtime/host/sched.py: FIFO tasks win every CPU they want, so
a trial can hold at a load the kernel would throttle in a longer run). A period that
holds is admitted only if the task can be tracked at it (:func:`predicted_tracking`).

A trial whose late intervals all fall in one stall, and which holds without it
(``one_stall``), is run once more at the same period (``retry`` in the second rung's
figures), once per admission: a stall of the host costs about the same misses per 1000
periods at every period, so a longer period would not avoid it (docs/measurements/
2026-11-24-realtime.md, "The admission refuses too often").

When it is not held the trial goes on up :data:`LADDER_S` and stops at the first period
that holds: the refusal names the period asked, what the trial measured, and the shortest
period measured to hold. ``--period auto`` starts at 1 ms and runs at the first period that
holds; where 1 ms holds, it goes down the ladder (to 0.25 ms) while each shorter period
may hold by the figures of the last one that held (:func:`may_hold_at`) and its trial
holds, and runs at the shortest that held (in both cases the launcher starts the unit
again at it: every role derives its setup from the period). The decision and its figures
go in the report (``admission``); docs/faults-and-errors.md has the exit code.
"""

from __future__ import annotations

import math
import statistics
import time
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from ..config import EXIT_UNSUSTAINABLE
from ..host import sched
from ..host.busy_guard import ADMIT_BUSY_SHARE
from ..transport.codec import WARMUP_BASE
from .predicted import predicted_tracking, tracks
from .refusal import HEADROOM, LATE_SHARE, advice, trial_findings

if TYPE_CHECKING:
    from ..central import Central

LADDER_S = (0.25e-3, 0.32e-3, 0.4e-3, 0.5e-3, 0.64e-3, 0.8e-3, 1.0e-3, 1.25e-3, 1.6e-3,
            2.0e-3, 2.5e-3, 3.2e-3, 4.0e-3, 5.0e-3, 6.4e-3, 8.0e-3, 10.0e-3)
"""The periods ``--period auto`` chooses from, and the trial climbs after a refusal
(issue 59: down to 0.25 ms, the thesis's 0.5 ms among them)."""

TRIAL_BASE = 2 * WARMUP_BASE
"""Trial cycles are numbered from here (one block of 2**20 per rung), far from the run's
and the warm-up's, so that a straggling trial message is never taken for a real one."""

EPISODE_GAP = 10
"""Late (or skipped) intervals less than this many intervals apart belong to one episode."""

TRACKING_SHARE = 0.5
"""A period that holds is admitted only if the one-process simulation of the task at it
tracks within this share of ``--max-error`` (the run would otherwise stop mid-motion)."""


class Unsustainable(Exception):
    """The requested period cannot be held; ``info`` is the admission's report,
    ``headline`` what was refused in a clause and ``advice`` what to try (sentences, or
    empty): ``ctrlunit start`` puts those two on stderr."""

    code = EXIT_UNSUSTAINABLE

    def __init__(self, message: str, info: dict[str, Any], *, headline: str = "",
                 advice: str = "") -> None:
        super().__init__(message)
        self.info, self.headline, self.advice = info, headline or message, advice


SAY_TRIAL_S = 2.0
"""A trial longer than this is said before it runs."""


def _say_long_trial(note: Callable[[str], Any] | None, period: float) -> None:
    """Tell ``note`` of a trial at ``period`` longer than :data:`SAY_TRIAL_S` (a long
    period's: the user would wait in silence)."""
    if note is not None and (n := trial_intervals(period)) * period > SAY_TRIAL_S:
        note(f"ctrlunit: the admission's trial at {period * 1e3:g} ms: {n} intervals, "
             f"{n * period:.0f} s before the first command (--no-admission skips it)")


def trial_intervals(period_s: float, *, seconds: float = 0.3, least: int = 50,
                    most: int = 1200) -> int:
    """Trial length at ``period_s``: ``seconds`` of it, within ``[least, most]`` intervals."""
    return max(least, min(most, round(seconds / period_s)))


def rung_verdict(traversal_s: np.ndarray, *, skipped: int, budget_s: float,
                 transit_s: float, busy_share: float | None = None,
                 busy_limit: float | None = None,
                 skip_marks: Sequence[tuple[int, int]] = ()) -> dict[str, Any]:
    """The figures of one trial and whether they hold (module notes).

    Parameters
    ----------
    traversal_s : (n,) sample-to-command time of every trial interval that ran, in the
        order they ran.
    skipped : samples skipped because the central was behind.
    budget_s : the command delay's periods: from the sample to the tick it is due at.
    transit_s : one-way time of the command to the plant.
    busy_share : the busiest CPU's busy share during the trial: the unit's own CPU time
        (runtime/host/unit_load.py) or, where that is not read, every process's.
    busy_limit : under SCHED_FIFO, the busy share above which the period does not hold
        (runtime/host/sched.py: a run near the kernel's real-time budget would be throttled);
        None: no limit. A share that could not be measured (None) is judged on the
        traversal alone: the run's guard still watches.
    skip_marks : where the ``skipped`` samples were skipped, as (index into
        ``traversal_s`` of the next interval, samples skipped); skips without a mark
        count as one more episode.

    Returns
    -------
    The trial's figures; besides ``held``, ``late_episodes`` (late or skipped intervals
    grouped into runs less than :data:`EPISODE_GAP` apart) and ``one_stall``: every late
    interval in one episode, and the rest of the trial (at least half of it) would hold
    without it. Such a trial is worth repeating once (:func:`admit`): a stall of the host
    costs about the same misses per 1000 periods at any period.
    """
    t = np.asarray(traversal_s, dtype=float) + transit_s
    n = int(t.size) + skipped
    late_at = np.flatnonzero(t > budget_s)
    late = int(late_at.size) + skipped
    p99 = float(np.quantile(t, 0.99)) if t.size else math.inf
    held = n > 0 and late <= n * LATE_SHARE and p99 <= HEADROOM * budget_s
    busy_over = busy_limit is not None and busy_share is not None and busy_share > busy_limit
    if busy_over:
        held = False
    points = sorted([int(i) for i in late_at] + [int(i) for i, _ in skip_marks])
    episodes = sum(1 for a, b in zip([None, *points], points)
                   if a is None or b - a >= EPISODE_GAP)
    episodes += 1 if skipped > sum(c for _, c in skip_marks) else 0  # skips not located
    one_stall = False
    if episodes == 1 and points and not held and not busy_over:
        rest = np.concatenate([t[:points[0]], t[points[-1] + 1:]])
        one_stall = (rest.size >= n / 2
                     and float(np.quantile(rest, 0.99)) <= HEADROOM * budget_s)
    return {"intervals": n, "late": late, "skipped": skipped, "budget_s": budget_s,
            "busy_share": busy_share, "busy_limit": busy_limit,
            "traversal_p50_s": float(np.median(t)) if t.size else math.inf,
            "traversal_p99_s": p99,
            "traversal_p999_s": float(np.quantile(t, 0.999)) if t.size else math.inf,
            "traversal_max_s": float(t.max()) if t.size else math.inf, "held": held,
            "late_episodes": episodes, "one_stall": one_stall}


def ladder_from(period_s: float) -> list[float]:
    """``period_s`` then every longer period of :data:`LADDER_S`."""
    return [period_s] + [p for p in LADDER_S if p > period_s * 1.0001]


def shorter_rungs(period_s: float) -> list[float]:
    """The periods of :data:`LADDER_S` shorter than ``period_s``, longest first: where
    ``--period auto`` goes down once its start held."""
    return [p for p in reversed(LADDER_S) if p < period_s * 0.9999]


def may_hold_at(verdict: dict[str, Any], shorter_s: float) -> bool:
    """Whether a rung that held (``verdict``, at ``verdict["period_s"]``) may hold at
    ``shorter_s`` by its own figures, the unit's CPU time and its traversal per interval
    taken as they were: its busy share grows as the period shrinks and stays within its
    limit (under SCHED_FIFO), and its traversal p99 stays within the headroom of a budget
    that shrinks with the period (:func:`rung_verdict`'s rules). A trial is not run where
    the figures already say no (:func:`why_not_at` says why)."""
    return why_not_at(verdict, shorter_s) is None


def why_not_at(verdict: dict[str, Any], shorter_s: float) -> str | None:
    """Why :func:`may_hold_at` says no, in words for the summary; None where it may."""
    scale = verdict["period_s"] / shorter_s
    busy, limit = verdict.get("busy_share"), verdict.get("busy_limit")
    at = f"{shorter_s * 1e3:g} ms not tried"
    if busy is not None and limit is not None and busy * scale > limit:
        return (f"{at}: a CPU {busy:.0%} busy at {verdict['period_s'] * 1e3:g} ms would be "
                f"{busy * scale:.0%} there, over the limit of {limit:.0%}")
    if verdict["traversal_p99_s"] > HEADROOM * verdict["budget_s"] / scale:
        return (f"{at}: the traversal p99 of {verdict['traversal_p99_s'] * 1e3:.2f} ms would "
                f"pass {HEADROOM:.0%} of its {verdict['budget_s'] / scale * 1e3:.2f} ms budget")
    return None


class ShorterHeld(Unsustainable):
    """``--period auto``: the period it starts at held, and so did a shorter one of the
    ladder (``info["sustainable_period_s"]``): the unit starts again at that one."""


CpuTimes = Callable[[], list[tuple[float, float]]]
"""A reading of CPU time per CPU, as :func:`..host.sched.cpu_times` gives the machine's."""


class Rehearsal(Protocol):
    """What a run does besides the control, done in a trial and kept nowhere."""

    def on_cycle(self, progress: Any, ctx: dict) -> None: ...

    def on_message(self, direction: str, key: str, cycle: int, stage: Any, data: bytes,
                   t_ns: int) -> None: ...

    def discard(self, run: Any) -> None: ...


Rehearse = Callable[[], Rehearsal]
"""Makes a :class:`Rehearsal` for one trial (runtime/recording/recorder.py,
``Recorder.rehearsal``)."""


def admit(central: Central, *, unit_cpu: CpuTimes | None = None,
          rehearse: Rehearse | None = None, descend: bool = False,
          note: Callable[[str], Any] | None = None) -> dict[str, Any]:
    """Run the trial from the configured period up :data:`LADDER_S` until a period holds.
    Returns the admission's report when the configured period holds; raises
    :class:`Unsustainable` otherwise (with ``--period auto`` the caller starts again at
    ``info["sustainable_period_s"]``), before the plant has acted on any command (a
    trial sends its commands, flagged ``probe``, which the plant checks and drops: the
    run's messaging load without motion). ``unit_cpu`` reads the unit's own CPU time per
    CPU (runtime/host/unit_load.py), which the busy limit under FIFO judges; without it,
    the machine's. ``rehearse`` makes, for each trial, what the run does after each
    interval besides the control (its recorder, writing nowhere: :data:`Rehearse`).
    ``descend`` (``--period auto``'s first start): where the period asked holds, go down
    the ladder (:func:`descend_from`); a shorter period that held raises
    :class:`ShorterHeld`. ``note`` is told of a long trial (:func:`_say_long_trial`)."""
    rc = central.rc
    rtt = central.snapshot().times.warm_rtt_s
    transit = statistics.median(rtt) / 2 if rtt else 0.0
    asked = rc.schedule.period
    rungs: list[dict[str, Any]] = []
    held_at: float | None = None
    untrackable: tuple[float, float] | None = None
    retried = False
    for period in ladder_from(asked):
        err = predicted_tracking(central, period)
        if err > TRACKING_SHARE * rc.control.max_error:  # longer periods only track worse
            untrackable = (period, err)
            break
        _say_long_trial(note, period)
        verdict = trial(central, period, base=TRIAL_BASE + (len(rungs) << 20),
                        transit_s=transit, unit_cpu=unit_cpu, rehearse=rehearse)
        verdict["predicted_tracking_max_m"] = err
        rungs.append(verdict)
        if verdict["one_stall"] and not retried:  # one stall of the host: once more
            retried = True
            verdict = trial(central, period, base=TRIAL_BASE + (len(rungs) << 20),
                            transit_s=transit, unit_cpu=unit_cpu, rehearse=rehearse)
            verdict |= {"predicted_tracking_max_m": err, "retry": True}
            rungs.append(verdict)
        if verdict["held"]:
            held_at = period
            break
    info: dict[str, Any] = {
        "asked": "auto" if rc.schedule.period_auto else asked, "depth": rc.schedule.pipeline,
        "transit_s": transit, "headroom": HEADROOM, "late_share": LATE_SHARE,
        "tracking_share": TRACKING_SHARE, "rungs": rungs, "sustainable_period_s": held_at,
    }
    if untrackable is not None:
        info["untrackable_from_s"] = untrackable[0]
        if not rungs:
            raise Unsustainable(
                f"the task cannot be tracked at {asked * 1e3:g} ms: the one-process "
                f"simulation at it {tracks(untrackable[1], rc.control.max_error)}; refused "
                "before any motion (try a shorter --period or a slower task)", info)
    if held_at is not None and math.isclose(held_at, asked):
        shortest = descend_from(central, rungs, transit_s=transit, unit_cpu=unit_cpu,
                                rehearse=rehearse) if descend else asked
        info["period_s"] = info["sustainable_period_s"] = shortest
        if shortest < asked:
            raise ShorterHeld(f"{asked * 1e3:g} ms held, and so did {shortest * 1e3:g} ms",
                              info)
        return info
    first = rungs[0]
    if held_at is None and untrackable is not None:
        found = (f"the longer periods that might hold track the task worse than half of "
                 f"--max-error (at {untrackable[0] * 1e3:g} ms the one-process simulation "
                 f"{tracks(untrackable[1])})")
    elif held_at is None:
        found = (f"none of the ladder's periods up to {LADDER_S[-1] * 1e3:g} ms held "
                 f"either (the last: traversal p99 {rungs[-1]['traversal_p99_s'] * 1e3:.2f} "
                 f"ms of {rungs[-1]['budget_s'] * 1e3:.2f} ms)")
    else:
        found = f"the shortest period measured to hold is {held_at * 1e3:g} ms"
    headline = f"the period of {asked * 1e3:g} ms cannot be held here"
    tips = advice(rc.schedule.period_auto, first, rungs[-1] if held_at else None, LADDER_S)
    raise Unsustainable(
        f"{headline}: in a trial of {first['intervals']} intervals before any motion, "
        f"{trial_findings(first, rc.schedule.pipeline)}; {found}." + tips, info,
        headline=headline, advice=tips.strip())


def descend_from(central: Central, rungs: list[dict[str, Any]], *, transit_s: float,
                 unit_cpu: CpuTimes | None, rehearse: Rehearse | None) -> float:
    """Below the period of the last of ``rungs``, which held: a trial at each shorter
    period of the ladder, longest first, while the last that held says it may hold
    (:func:`may_hold_at`), the task is tracked at it as at any rung
    (:data:`TRACKING_SHARE`; a shorter period tracks better in the one-process loop: 0.019
    mm at 1 ms, 0.004 mm at 0.25 ms for the main job) and its trial holds (no trial is
    repeated here: a stall ends the descent). Each trial joins ``rungs``; returns the
    shortest period that held."""
    held = rungs[-1]
    for shorter in shorter_rungs(held["period_s"]):
        if (why := why_not_at(held, shorter)) is not None:
            held["shorter_not_tried"] = why  # the summary's admission line says it
            break
        err = predicted_tracking(central, shorter)
        if err > TRACKING_SHARE * central.rc.control.max_error:
            break
        verdict = trial(central, shorter, base=TRIAL_BASE + (len(rungs) << 20),
                        transit_s=transit_s, unit_cpu=unit_cpu, rehearse=rehearse)
        rungs.append(verdict | {"descent": True, "predicted_tracking_max_m": err})
        if not verdict["held"]:
            break
        held = verdict
    return float(held["period_s"])


def fifo_busy_limit() -> float | None:
    """Under SCHED_FIFO where the kernel throttles real-time tasks, the busy
    share a trial may reach (``ADMIT_BUSY_SHARE`` of the real-time budget,
    runtime/host/sched.py); None otherwise."""
    budget = sched.rt_budget()
    if budget is None or not sched.fifo_in_force():
        return None
    return ADMIT_BUSY_SHARE * budget


def trial(central: Central, period: float, *, base: int, transit_s: float,
          unit_cpu: CpuTimes | None = None, rehearse: Rehearse | None = None
          ) -> dict[str, Any]:
    """One rung: the plant ticks ``trial_intervals(period)`` trial samples at ``period``; a
    trial central (a :class:`~.central.Central` with ``trial=True`` on the same node and a
    copy of the controller) runs the pipeline on them. A fault during the trial (a silent
    peripheral or plant at this period) means the period does not hold; a dead process is
    a fault of the run. The busy share judged is the unit's own (``unit_cpu``, read before
    the plant ticks and after the trial) where given, else the machine's; the rung keeps
    the machine's too (``machine_busy_share``)."""
    from ..central import Fault
    from ..central.trial import end_trial, role_exited, trial_central

    rc = central.rc
    n = trial_intervals(period)
    late0 = central.snapshot().rejected.get("late_reply", 0)
    rehearsal = rehearse() if rehearse is not None else None
    probe = trial_central(
        central, period, ticks=n, base=base,
        on_cycle=None if rehearsal is None else rehearsal.on_cycle,
        on_message=None if rehearsal is None else rehearsal.on_message)
    unit0 = unit_cpu() if unit_cpu is not None else None  # 2-10 ms: before the ticks
    stolen0 = sched.stolen_s()
    central.say("probe", period=period, ticks=n, base=base)
    t0 = time.monotonic()
    busy0 = sched.cpu_times()
    fault = None
    try:
        probe.run()
    except Fault as exc:
        if role_exited(central):
            raise
        fault = str(exc)
    finally:
        if rehearsal is not None:  # as the run's recorder would end (within the window)
            rehearsal.discard(probe.snapshot())
    machine = sched.busy_share(busy0, sched.cpu_times())
    stolen = sched.most_stolen(stolen0, sched.stolen_s())
    busy = machine if unit_cpu is None or unit0 is None else sched.busy_share(unit0, unit_cpu())
    budget = rc.schedule.pipeline * period  # the command of sample k is due at tick k + depth
    run = probe.snapshot()  # after the readings: not the trial's work
    trav = np.asarray(run.times.traversal_ns, dtype=float) / 1e9
    out: dict[str, Any] = {"period_s": period, "machine_busy_share": machine,
                           "busy_of": "machine" if unit_cpu is None else "unit",
                           "stolen_s": stolen}
    out |= rung_verdict(trav, skipped=run.skipped, budget_s=budget, transit_s=transit_s,
                        busy_share=busy, busy_limit=fifo_busy_limit(),
                        skip_marks=list(run.times.skip_marks))
    if fault is not None:
        out["held"] = out["one_stall"] = False
        out["fault"] = fault
        out["intervals"] = n
        out["late"] = max(out["late"], n - int(trav.size))
    out["wall_s"] = time.monotonic() - t0
    # the replies of the trial's rounds it computed itself: the trial's, not the run's
    # (they once made the run's summary say 23 late replies for 1 late round)
    out["late_replies"] = end_trial(
        central, probe, late_before=late0, drain_s=min(0.2, 50 * period) if fault else 0.0)
    return out
