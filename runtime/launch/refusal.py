"""What a refusal of the admission says (runtime/launch/admission.py): what its first
trial measured against each rule, with the limit it missed, and only the advice the
trial showed would help."""

from __future__ import annotations

from typing import Any

from ..host import sched
from ..host.busy_guard import ADMIT_BUSY_SHARE

HEADROOM = 0.95
"""The trial's traversal p99 (command transit included) may use at most this share of the
budget: the rest is for the run's longer tail (a few hundred trial intervals see fewer
of the machine's stalls than a run of thousands)."""

LATE_SHARE = 1 / 200
"""At most this share of the trial's intervals may be late (or skipped)."""

NEAR_LIMIT = 0.9
"""A refusal suggests a period that held in its trial within this share of a limit (the
traversal p99 of its headroom, the busy share of its limit) one rung higher: on a busy
host the next start's trial refused such a period as often as not
(docs/measurements/2026-11-27-newcomer.md)."""


def busy_over(rung: dict[str, Any]) -> bool:
    """Whether the rung's busy share passed its limit."""
    limit, share = rung.get("busy_limit"), rung.get("busy_share")
    return limit is not None and share is not None and share > limit


def trial_findings(rung: dict[str, Any], depth: int) -> str:
    """What a trial measured, each figure against its rule, in clauses joined by ``;``;
    a rule it broke says its limit ("over the 2.85 ms allowed"): a new user read "the
    traversal p99 was 2.86 ms of a 3.00 ms budget" as a pass."""
    n, late = rung["intervals"], rung["late"]
    allowed = int(n * LATE_SHARE)
    found = [f"{late} were late" + (f", more than the {allowed} allowed" if late > allowed
                                    else "")]
    p99, budget = rung["traversal_p99_s"], rung["budget_s"]
    limit = HEADROOM * budget
    over = p99 > limit
    found.append(f"the traversal p99 was {p99 * 1e3:.2f} ms, "
                 + (f"over the {limit * 1e3:.2f} ms allowed" if over else "within the "
                    f"{limit * 1e3:.2f} ms allowed")
                 + f" ({HEADROOM:.0%} of a {budget * 1e3:.2f} ms budget: {depth} period(s))")
    if rung.get("fault"):
        found.append(f"the trial faulted ({rung['fault']})")
    if busy_over(rung):
        whose = "the unit kept a CPU" if rung.get("busy_of") == "unit" else "a CPU was"
        found.append(f"{whose} {rung['busy_share']:.0%} busy under SCHED_FIFO, over the "
                     f"limit of {rung['busy_limit']:.0%} of the CPU ({ADMIT_BUSY_SHARE:.0%} "
                     "of the kernel's real-time budget)")
    if rung.get("stolen_s"):  # a stall of the whole machine, which no option of ours undoes
        found.append(f"the hypervisor took up to {rung['stolen_s'] * 1e3:.0f} ms from one of "
                     "this machine's CPUs meanwhile (steal: what ran there stood still)")
    return "; ".join(found)


def suggested(held: dict[str, Any], ladder: tuple[float, ...]) -> str:
    """The period to try after a refusal, from the rung that held: its own, or the next
    of the ladder where it held near a limit (:data:`NEAR_LIMIT`)."""
    period, limit, share = held["period_s"], held.get("busy_limit"), held.get("busy_share")
    near = (held["traversal_p99_s"] > NEAR_LIMIT * HEADROOM * held["budget_s"]
            or (limit is not None and share is not None and share > NEAR_LIMIT * limit))
    above = [p for p in ladder if p > period * 1.0001]
    if near and above:
        return f"--period {above[0] * 1e3:g}ms ({period * 1e3:g} ms held, near its limit)"
    return f"--period {period * 1e3:g}ms (measured to hold)"


def advice(period_auto: bool, first: dict[str, Any], held: dict[str, Any] | None,
           ladder: tuple[float, ...]) -> str:
    """The refusal's advice: only what the trial showed would help. ``--period auto`` and
    a period measured to hold (``held``: its rung); FIFO where the unit ran without it and
    may use it (other programs then wait for the unit); a lighter placement where the
    unit's own load was the limit."""
    if held is not None and period_auto:
        return ""  # the launcher starts again at the period that held
    tries: list[str] = []
    if held is not None:
        tries += ["--period auto (it climbs to a period that holds at each start)",
                  suggested(held, ladder)]
    if not sched.fifo_in_force() and sched.fifo_permitted():
        tries.append(f"--rt-priority {sched.AUTO_PRIORITY} (SCHED_FIFO: other programs "
                     "then wait for the unit)")
    if busy_over(first):
        tries.append("a placement from ctrlunit balance (less of the unit's CPU time)")
    if not tries:
        return " ctrlunit latency --unit measures what this machine holds for the unit."
    return (" Try " + "; or ".join(tries)
            + ". ctrlunit latency --unit measures what this machine holds for the unit.")


__all__ = ["HEADROOM", "LATE_SHARE", "NEAR_LIMIT", "advice", "busy_over", "suggested",
           "trial_findings"]
