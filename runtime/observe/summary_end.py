"""The summary's last lines (:mod:`.summary`): messages dropped or refused, how the run
ended (as planned, what it gave up on the way, a stop asked for, or a fault with the
plant's safe stop) and the folder kept for a fault's diagnosis."""

from __future__ import annotations

from typing import Any


def safe_stop_line(stop: Any) -> str:
    """What the plant reported of its safe stop (gravity hold with braking, then zero
    torque), or that it reported nothing."""
    try:
        return (f"  safe stop   the plant held and braked for {stop['hold_s'] * 1e3:.0f} ms "
                f"(moved {stop['drift_m'] * 1e3:.1f} mm, left at "
                f"{stop['speed_m_s'] * 1e3:.1f} mm/s), then zero torque")
    except (TypeError, KeyError, ValueError):
        return "  safe stop   NOT confirmed: the plant did not report one"


def _result_line(r: dict[str, Any]) -> str:
    """How a run that was not stopped ended: as planned, or what it gave up on the way (a
    peripheral taken over, the halved rate, late commands), each said above."""
    given_up = []
    lost = sorted({d["peripheral"] for d in r.get("degraded") or []
                   if not str(d.get("why", "")).startswith("stands by")})
    if lost:
        given_up.append("degraded: the central computed the rounds of peripheral(s) "
                        + ", ".join(map(str, lost)))
    halved = (r.get("overload") or {}).get("halved_periods")
    if halved:
        given_up.append(f"{halved} period(s) at the halved rate")
    periods = r.get("periods") or r.get("cycles") or 0
    if r["clock"] == "realtime" and r.get("deadline_misses") and periods:
        given_up.append(f"{r['deadline_misses']} of {periods} commands late "
                        f"({r['deadline_misses'] / periods:.1%})")
    return ("  result      completed" + (": " + "; ".join(given_up) if given_up
                                         else " as planned"))


def end_lines(r: dict[str, Any]) -> list[str]:
    """Messages dropped or refused; how the run ended when not as planned: a stop the
    user asked for (Ctrl-C, SIGTERM, SIGHUP: not a fault, docs/faults-and-errors.md) or a
    fault, with the plant's safe stop, and the folder kept for its diagnosis; and what a
    recording could not tell."""
    lines = []
    rejected = dict(r["rejected_messages"])
    late = rejected.pop("late_reply", 0)  # not malformed: a round already held or computed
    if late and not (r.get("late") or {}).get("computed"):  # else on the late data line
        lines.append(f"  late replies {late} (dropped: their rounds were held or computed "
                     "by the central)")
    stragglers = rejected.pop("straggler", 0)  # not malformed: the unit's own, late
    if stragglers:
        lines.append(f"  stragglers  {stragglers} replies to the warm-up's or the admission "
                     "trials' throw-away intervals came after them (dropped)")
    if rejected:
        lines.append("  rejected messages " + ", ".join(
            f"{k}: {v}" for k, v in sorted(rejected.items())))
    f = r.get("fault")
    if f:
        code = f" (exit {f['code']})" if f.get("code") is not None else ""
        if f.get("process") == "user":
            lines.append(f"  stopped     on request: {f['message']}{code}, after {r['cycles']} "
                         "intervals (a stop asked for, not a fault)")
        elif f.get("process") == "admission":  # nothing moved: a refusal, not a fault
            lines.append(f"  refused     before any motion: {f['message']}{code}")
        else:
            lines.append(f"  FAULT in {f['process']}: {f['message']}{code}")
        if "safe_stop" in r:
            lines.append(safe_stop_line(r["safe_stop"]))
    else:
        lines.append(_result_line(r))
    if r.get("recording_failed"):
        lines.append(f"  recording   {r['recording_failed']}; the run went on, the file holds "
                     "what came before (ctrlunit report reads it)")
    if r.get("logs_kept"):
        lines.append(f"  logs        kept in {r['logs_kept']} (the run's spec and each role's "
                     "log, for the diagnosis; delete it when done)")
    unknown = r.get("not_recorded")
    if unknown:
        lines.append(f"  not in the recording: {', '.join(unknown['lines'])} "
                     f"({unknown['why']})")
    return lines


def how_it_ended(fault: dict[str, Any]) -> tuple[str, str]:
    """A run's end as a figure marks it and says it in its title, as :func:`end_lines` does:
    a stop the user asked for and the admission's refusal are no fault."""
    return {"user": ("stopped on request", "was stopped on request"),
            "admission": ("refused", "was refused before any motion")}.get(
        str(fault.get("process")), ("fault", "ended in a fault"))


__all__ = ["end_lines", "how_it_ended", "safe_stop_line"]
