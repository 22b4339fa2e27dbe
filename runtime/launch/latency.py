"""``ctrlunit latency``: this machine's timer wake-up latency at a period (the analogue of
LinuxCNC's latency-test), and with ``--unit`` the unit's own sample-to-command traversal
from the admission trial (runtime/launch/admission.py).

The wake-up test sleeps to absolute ticks ``t0 + j T`` the way the realtime plant does,
under the policy the unit's roles would run under, and
records, for each tick, how late it woke. A tick woken later than the next tick is a
period lost whatever the unit does; the realtime unit needs the rest of the period for
its own work. :func:`sustainable_from_wakeup` turns that into a period from the admission
ladder: the shortest whose period, less the wake-up latency's p99.9, leaves at least half
the period for the work.
"""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np

from ..compute.timing import quantiles
from ..config import RunConfig
from ..config.spellings import to_fields
from ..host import sched
from ..host.idle import idle_request
from ..roles.plant_ticks import SLEEP_SLICE_S
from .admission import LADDER_S


def wakeup_latencies(period_s: float, duration_s: float) -> np.ndarray:
    """Sleep to ``duration_s / period_s`` consecutive absolute ticks of ``period_s``;
    returns how late each wake-up was (s), shape ``(ticks,)``. Ticks missed entirely (the
    process woke more than a period late) are skipped, as the plant skips them, and the
    late wake-up that skipped them is the one recorded."""
    if not 20e-6 <= period_s <= 1.0:
        raise ValueError(f"--period = {period_s:g} s: allowed 20us to 1s")
    if not period_s <= duration_s <= 3600.0:
        raise ValueError(f"--duration = {duration_s:g} s: allowed one period to 3600 s")
    ticks = int(duration_s / period_s)
    tick_ns = int(period_s * 1e9)
    out = np.empty(ticks, dtype=float)
    next_tick = time.monotonic_ns() + tick_ns
    n = 0
    end = next_tick + ticks * tick_ns
    while n < ticks and next_tick <= end:
        while (ahead := next_tick - time.monotonic_ns()) > 0:
            time.sleep(min(ahead / 1e9, SLEEP_SLICE_S))
        woke = time.monotonic_ns()
        out[n] = (woke - next_tick) / 1e9
        n += 1
        next_tick += tick_ns
        if woke > next_tick:  # more than a period late: the next tick is already gone
            next_tick += ((woke - next_tick) // tick_ns + 1) * tick_ns
    return out[:n]


def sustainable_from_wakeup(p999_s: float) -> float | None:
    """The shortest period of the admission ladder whose wake-up p99.9 leaves at least half
    of it for the unit's work; None when none does."""
    for p in LADDER_S:
        if p999_s <= 0.5 * p:
            return p
    return None


def histogram_png(lat_s: np.ndarray, path: str, *, period_s: float, title: str) -> None:
    """The wake-up latencies as a log-count histogram, with the period marked."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 3.5))
    us = lat_s * 1e6
    top = max(float(us.max()) if us.size else 1.0, period_s * 1e6) * 1.05
    ax.hist(us, bins=np.linspace(0.0, top, 120).tolist(), color="#3465a4")
    ax.set_yscale("log")
    ax.axvline(period_s * 1e6, color="#cc0000", lw=1, label=f"period {period_s * 1e3:g} ms")
    for q, ls in (("p99", "--"), ("p999", ":")):
        v = float(np.quantile(lat_s, 0.99 if q == "p99" else 0.999)) * 1e6 if us.size else 0
        ax.axvline(v, color="k", lw=1, ls=ls, label=f"{q} {v:.0f} us")
    ax.set_xlabel("wake-up latency (us)")
    ax.set_ylabel("ticks")
    ax.set_title(title, fontsize=10)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def latency_lines(rep: dict[str, Any], *, period_s: float, peripherals: int,
                  pipeline: int) -> list[str]:
    """The lines ``ctrlunit latency`` prints for ``rep`` (:func:`latency_report`, with
    ``unit`` for ``--unit``): each figure with what it was measured on."""
    q = rep["wakeup_latency_s"]

    def us(x: float | None) -> str:
        return "n/a" if x is None or not math.isfinite(x) else f"{x * 1e6:.0f} us"

    def ms(x: float | None) -> str:
        return "none of the ladder" if x is None else f"{x * 1e3:g} ms"

    polling = ", idle CPUs poll" if rep["idle"]["in_force"] == "poll" else ""
    lines = [f"wake-up latency at {period_s * 1e3:g} ms over {rep['ticks']} ticks "
             f"({rep['scheduling']}{polling}): p50 "
             f"{us(q['p50'])}  p99 {us(q['p99'])}  p99.9 {us(q['p999'])}  max "
             f"{us(q['max'])}; {rep['ticks_lost']} tick(s) woken more than a period late"]
    if "unit" in rep:
        u = rep["unit"]
        t = u["traversal_s"]
        lines.append(f"unit (n = {peripherals}, depth {pipeline}) traversal, command transit "
                     f"included: p50 {us(t['p50'])}  p99 {us(t['p99'])}  p99.9 "
                     f"{us(t['p999'])}  max {us(t['max'])}; {u['late']} of {u['intervals']} "
                     "trial intervals late")
    held = rep["sustainable_period_s"]
    tail = ("; the timer alone, not the unit's work: --unit tries the unit" if "unit" not in rep
            else "; shorter periods not tried: give a shorter --period to try one"
            if held is not None and math.isclose(held, period_s) else "")
    lines.append(f"shortest sustainable period ({rep['sustainable_period_from']}): "
                 f"{ms(held)}{tail}")
    if rep.get("plot"):
        lines.append(f"histogram: {rep['plot']}")
    return lines


def trial_config(*, peripherals: int, pipeline: int, period_s: float, idle: str) -> RunConfig:
    """The unit ``latency --unit`` tries: ``ctrlunit start``'s at its defaults (read as
    its flags read them: ``--placement auto`` among them) with these settings, stopped
    after the admission trial. Built with :meth:`RunConfig.of` alone it was the thesis's
    placement (``axes``), whose trial at 1 ms measured a traversal p50 of 1.8-2.0 ms where
    the main job's own trial measured 0.19 ms (a review: latency advised 1.25-2 ms while
    ``start`` held 0.64-1 ms)."""
    settings = {"peripherals": peripherals, "pipeline": pipeline, "clock": "realtime",
                "period": period_s, "idle": idle, "placement": "auto"}
    return RunConfig.of(**to_fields(settings), trial_only=True)


def latency_report(period_s: float, duration_s: float, *, rt_priority: int | str = sched.AUTO,
                   idle: str = "auto") -> tuple[dict[str, Any], np.ndarray]:
    """Measure and summarise; the report's keys are those of ``ctrlunit latency --json``.

    The test runs under the scheduling policy a realtime unit with the admission would get
    for ``rt_priority`` (runtime/host/sched.py: ``auto`` is SCHED_FIFO 10 where permitted and
    the kernel throttles); the process's policy is what it was before on return. The
    policy matters: on the reference machine the p50 was 20-26 us under SCHED_FIFO and
    about 70 us under the default policy, whose 50 us timer slack FIFO does not have.
    Likewise the idle CPUs for ``idle`` (runtime/host/idle.py): where they poll instead of
    halting, the p50 was 30-45 us against 78 us the same hour (under FIFO).

    Raises
    ------
    RtPermissionError
        ``rt_priority`` 1-99 and this process may not use SCHED_FIFO.
    IdlePermissionError
        ``idle`` is ``poll`` and the CPU latency request cannot be made.
    """
    saved = sched.current()
    try:
        with idle_request(idle, clock="realtime") as idle_choice:
            policy, choice = sched.apply_choice(rt_priority, clock="realtime", admission=True)
            lat = wakeup_latencies(period_s, duration_s)
    finally:
        sched.restore(saved)
    q = quantiles(lat)
    return {
        "scheduling": policy,
        "scheduling_choice": choice,
        "idle": idle_choice,
        "period_s": period_s,
        "duration_s": duration_s,
        "ticks": int(lat.size),
        "ticks_lost": int(np.sum(lat > period_s)),
        "wakeup_latency_s": q,
        "sustainable_period_s": sustainable_from_wakeup(q["p999"]),
        "sustainable_period_from": "timer wake-up (p99.9 at most half the period)",
    }, lat
