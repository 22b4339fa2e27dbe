"""The human summary of a run's report (:mod:`.report`), printed at the end of a run and by
``ctrlunit report``: one line a figure, and a line for each thing that happened (a fault,
a change of the control rate, late data, the links' protection)."""

from __future__ import annotations

import math
from typing import Any

from .report import quoted


def _overload_lines(r: dict[str, Any]) -> list[str]:
    """Each change of the control rate (``--overload``)."""
    o = r.get("overload") or {}
    lines = []
    for c in o.get("changes") or []:
        at = f" at interval {c['at_interval']}" if "at_interval" in c else ""
        if c["stride"] == 2:
            why = f"{c['late']} of the last {c['window']} intervals late" if "late" in c \
                else "late intervals"
            if "after_return" in c:
                why += f", {c['after_return']} intervals after going back (on trial)"
            lines.append(f"  overload    {why}{at}: from sample {c['from_cycle']} on every "
                         "second sample taken, each command held two periods (the control rate "
                         "halved; the plant still ticks at the period)")
        else:
            why = f"{c['calm']} intervals without a late one" if "calm" in c else "calm"
            lines.append(f"  overload    {why}{at}: from sample {c['from_cycle']} on every "
                         "sample taken again (the full control rate)")
    if lines and o.get("halved_periods") is not None:
        lines.append(f"              {o['halved_periods']} period(s) at the halved rate")
    return lines


def _late_lines(r: dict[str, Any]) -> list[str]:
    """The late rounds the central computed itself (``--late-policy compute``), the late
    intervals and where their time went (:func:`late_work_figures`)."""
    out = []
    computed = (r.get("late") or {}).get("computed")
    if computed:
        out.append(f"  late data   {computed} late peripheral round(s) computed by the central "
                   "(the same arithmetic: the commands are unchanged)")
    late = r.get("late_intervals")
    if not late or not late["intervals"] or not late["work_stretch"]:
        return out
    st = late["work_stretch"]
    why = {True: ": the machine itself ran slower",
           False: ": the time went to waiting, not to the work"}.get(late["machine_slower"], "")
    return [*out, f"  late        {late['intervals']} command(s) left after their deadline; "
            f"there the peripherals' work took {st['median']:.1f}x its median of "
            f"{late['work_median_s'] * 1e6:.0f} us (max {st['max']:.1f}x){why}"]


def _cpu_lines(r: dict[str, Any]) -> list[str]:
    """CPU per interval of each process and the period it allows (when measured)."""
    cpu = dict(r.get("cpu_per_interval_s") or {})
    if not cpu:
        return []
    total = cpu.pop("total", None)
    line = ("  CPU / interval " + "  ".join(f"{k} {v * 1e6:.0f} us" for k, v in cpu.items())
            + (f"  total {total * 1e6:.0f} us" if total is not None
               else "  (no total: not every role reported)"))
    bound = r.get("cpu_bound_period_s")
    if bound is not None and r.get("cpu_cores"):
        mean = r.get("period_mean_s", math.nan)
        line += (f"; on {r['cpu_cores']} core(s) no period below {bound * 1e6:.0f} us"
                 + (f" (the mean period is {mean / bound:.2f}x that)"
                    if r.get("clock") == "freerun" and mean and math.isfinite(mean) else ""))
    return [line]


def _sched_lines(r: dict[str, Any]) -> list[str]:
    """The scheduling policy of each role: one phrase when they share it."""
    pol = r.get("scheduling") or {}
    if not pol:
        return []
    values = set(pol.values())
    if len(values) == 1:
        lines = [f"  scheduling  {next(iter(values))}, every role"]
    else:
        lines = ["  scheduling  " + "  ".join(f"{k} {v or 'not reported'}"
                                             for k, v in pol.items())]
    choice, fell = r.get("scheduling_choice") or {}, r.get("scheduling_fallback")
    if choice.get("asked") == "auto" and choice.get("why"):
        lines.append(f"              auto: {choice['why']}")
    if fell:
        lines.append(f"              back to the default policy at interval {fell['cycle']}: "
                     f"a CPU {fell['busy_share']:.0%} busy over "
                     f"{fell.get('over_s', fell['window_s']):g} s "
                     f"(limit {fell['limit']:.0%})")
        if fell.get("restored"):
            lines.append(f"              under SCHED_FIFO again {fell['restored']} time(s), "
                         f"{'under it' if fell.get('fifo_at_end') else 'not'} at the end")
    idle = r.get("idle") or {}
    if idle.get("in_force") == "poll":
        lines.append("  idle CPUs   poll (CPU latency request 0 us)"
                     + (f": {idle['why']}" if idle.get("asked") == "auto" else ""))
    elif idle.get("asked") in ("auto", "poll") and r.get("clock") == "realtime":
        lines.append(f"  idle CPUs   as they are: {idle.get('why')}")
    return lines


def _safe_stop_line(stop: Any) -> str:
    """What the plant reported of its safe stop (gravity hold with braking, then zero
    torque), or that it reported nothing."""
    try:
        return (f"  safe stop   the plant held and braked for {stop['hold_s'] * 1e3:.0f} ms "
                f"(moved {stop['drift_m'] * 1e3:.1f} mm, left at "
                f"{stop['speed_m_s'] * 1e3:.1f} mm/s), then zero torque")
    except (TypeError, KeyError, ValueError):
        return "  safe stop   NOT confirmed: the plant did not report one"


LINK_LINES = {
    "tls": "TLS with mutual authentication, under the unit's access control (--keys)",
    "local": "a unix socket: who may enter its directory may connect (the default's: "
             "this user alone)",
    "loopback": "TCP on a loopback address without keys: any process on this host may "
                "connect (--keys DIR makes it TLS)",
    "insecure": "INSECURE: links beyond this host without keys (--insecure): anyone who "
                "reaches them may read the unit's traffic and move the robot",
}
"""The summary's line on what protects a run's links, by protection
(runtime/transport/security.py, ``PROTECTIONS``)."""


def _link_lines(r: dict[str, Any]) -> list[str]:
    """One line per protection among the report's ``link_list``, the weakest first, with
    the endpoints it covers; a report without the list (an older one): its ``links``."""
    listed = r.get("link_list")
    if not isinstance(listed, list) or not listed:
        line = LINK_LINES.get(r.get("links", "local"))
        return [f"  links       {line}"] if line and r.get("links", "local") != "local" else []
    lines = []
    for prot in ("insecure", "loopback", "local", "tls"):
        eps = [f"{ln['endpoint']} ({ln['way']}"
               + (f", {ln['from']})" if ln["from"].startswith("--zenoh") else ")")
               for ln in listed if ln.get("protection") == prot]
        if eps:
            lines.append(f"  links       {LINK_LINES[prot]}: {', '.join(eps)}")
    return lines


def summary(r: dict[str, Any]) -> str:
    """The human summary printed at the end of a run."""

    def us(x: float) -> str:
        return "   n/a" if x is None or not math.isfinite(x) else f"{x * 1e6:8.1f} us"

    def mm(x: float) -> str:
        return "n/a" if x is None or not math.isfinite(x) else f"{x * 1e3:.3f} mm"

    lines = [
        f"ctrlunit: {r['cycles']} intervals, {r['peripherals']} peripheral(s), pipeline depth "
        f"{r['pipeline']}, clock {r['clock']}, {r['law']} + {r['model']} model, task "
        f"{quoted(r['task'])}, cost model {r['cost_model']}",
        *_delay_lines(r),
        f"  round trips per interval  {r['round_trips']}" + (
            f" ({r['rounds_ahead']} before the sample, off its path to the command)"
            if r.get("rounds_ahead") else "") + (
            f"   exchanges per interval {r['exchanges_per_interval']:.2f}" + (
                " (rounds of consecutive intervals fused)"
                if r["exchanges_per_interval"] < r["round_trips"] - 0.01 else "")
            if r.get("exchanges_per_interval") else "") + (
            "; replies per round" if (r.get("replies") or {}).get("mode") == "each" else "") + (
            "; lone rounds go at once" if (r.get("hold_rounds") or {}).get("held") is False
            else ""),
        f"  period      p50 {us(r['period_s']['p50'])}  p99 {us(r['period_s']['p99'])}  "
        f"max {us(r['period_s']['max'])}  mean {us(r.get('period_mean_s', math.nan))}",
        f"  traversal   p50 {us(r['traversal_s']['p50'])}  p99 {us(r['traversal_s']['p99'])}  "
        f"max {us(r['traversal_s']['max'])}",
        f"  jitter      std {us(r['jitter_s']['std'])}",
        f"  deadline misses {r['deadline_misses']}"
        + (f" ({r['plant_spares']} covered by the command extrapolated the period before)"
           if r.get("plant_spares") else "")
        + f"   skipped samples {r['skipped_samples']}"
        + (f"   silences excused {r['silences_excused']} (the machine, not the process, was slow)"
           if r.get("silences_excused") else ""),
        *_late_lines(r),
        *_overload_lines(r),
        "  business    " + "  ".join(f"{k} {v * 100:.0f} %" for k, v in r["business"].items()),
        *_cpu_lines(r),
        *_sched_lines(r),
        f"  t_1 (one process, no exchange) {us(r['t1_s'])}   t_s {us(r['t_s_model_s'])}   "
        f"t_p {us(r['t_p_model_s'])}",
        f"  efficiency (Eq. IV.23, N = {r['efficiency_n']}, t_parallel = {r['t_parallel_is']}) "
        f"{r['efficiency'] * 100:.1f} %   speedup {r['speedup']:.2f}"
        if math.isfinite(r["efficiency"]) else "  efficiency n/a",
        f"  tracking error max {mm(r['tracking_error_m']['max'])}   rms "
        f"{mm(r['tracking_error_m']['rms'])}   peak torque {r['torque_nm']['max']:.2f} N m",
    ]
    if not r["cycles"]:  # refused or failed before the first interval: nothing measured
        lines = lines[:2] if r.get("command_delay") else lines[:1]
    choice = r.get("placement_choice")
    if choice:
        lines.append(f"  placement   auto: {choice['why']}")
    lines += _link_lines(r)
    adm = r.get("admission")
    if adm and adm.get("period_s"):
        lines.append(f"  admission   {adm['period_s'] * 1e3:g} ms held in a trial of "
                     f"{adm['rungs'][-1]['intervals']} intervals before motion (asked: "
                     + ("auto" if adm["asked"] == "auto" else f"{adm['asked'] * 1e3:g} ms")
                     + ")" + (f"; the first trial at it had one stall ({adm['rungs'][-2]['late']}"
                              " intervals late), so it ran again"
                              if adm["rungs"][-1].get("retry") else ""))
    rejected = dict(r["rejected_messages"])
    late = rejected.pop("late_reply", 0)  # not malformed: a round already held or computed
    if late:
        lines.append(f"  late replies {late} (dropped: their rounds were held or computed "
                     "by the central)")
    if rejected:
        lines.append("  rejected messages " + ", ".join(
            f"{k}: {v}" for k, v in sorted(rejected.items())))
    if r.get("fault"):
        f = r["fault"]
        code = f" (exit {f['code']})" if f.get("code") is not None else ""
        lines.append(f"  FAULT in {f['process']}: {f['message']}{code}")
        if "safe_stop" in r:
            lines.append(_safe_stop_line(r["safe_stop"]))
    return "\n".join(lines)


def _delay_lines(r: dict[str, Any]) -> list[str]:
    d = r.get("command_delay")
    if not d:
        return []
    where = {"acting": "; model at the state where it acts",
             "foreseen": "; model at the state where it acts, foreseen a period ahead",
             "foreseen2": "; model at the state where it acts, foreseen two periods ahead",
             "sample": "; model at the sample"}.get(str(r.get("model_state")), "")
    return [f"  command delay {d['periods']} period(s) from sample to the period it acts in "
            f"({d['convention']}){where}"]


__all__ = ["LINK_LINES", "summary"]
