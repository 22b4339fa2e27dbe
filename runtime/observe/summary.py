"""The human summary of a run's report (:mod:`.report`), printed at the end of a run and by
``ctrlunit report``: one line a figure, and a line for each thing that happened (a fault,
a change of the control rate, late data, the links' protection)."""

from __future__ import annotations

import math
from typing import Any

from .efficiency import EFFICIENCY_BASIS, efficiency_unmeasured
from .report import quoted
from .summary_end import end_lines


def _overload_lines(r: dict[str, Any]) -> list[str]:
    """Each change of the control rate (``--overload``)."""
    o = r.get("overload") or {}
    lines = []
    for c in o.get("changes") or []:
        at = f" at interval {c['at_interval']}" if "at_interval" in c else ""
        if c["stride"] == 2:
            why = (f"late {c['late']} times in the last {c['window']} intervals" if "late" in c
                   else f"{c['in_a_row']} intervals late in a row" if "in_a_row" in c
                   else "late intervals")
            if "after_return" in c:
                why += f", {c['after_return']} intervals after going back (on trial)"
            lines.append(f"  overload    {why}{at}: from sample {c['from_cycle']} on every "
                         "second sample taken, each command held two periods (the control rate "
                         "halved; the plant still ticks at the period)")
        else:
            period = r.get("nominal_period_s") or 0.0  # a halved interval covers two
            why = (f"{c['calm']} intervals without a late one"
                   f" ({c['calm'] * 2 * period:.3g} s)" if "calm" in c else "calm")
            lines.append(f"  overload    {why}{at}: from sample {c['from_cycle']} on every "
                         "sample taken again (the full control rate)")
    if lines and o.get("halved_periods") is not None:
        lines.append(f"              {o['halved_periods']} period(s) at the halved rate")
    late = (r.get("late_intervals") or {}).get("intervals") or 0
    if not lines and o.get("policy") == "halve" and late:
        lines.append(f"  overload    not halved: {late} interval(s) late, never 10 of the last "
                     "100 (late ones in a row counting once) nor 10 in a row")
    return lines


def _late_lines(r: dict[str, Any]) -> list[str]:
    """The late rounds the central computed itself (``--late-policy compute``), the late
    intervals and where their time went (:func:`late_work_figures`)."""
    out = []
    computed = (r.get("late") or {}).get("computed")
    if computed:
        replies = dict(r.get("rejected_messages") or {}).get("late_reply", 0)
        out.append(f"  late data   {computed} peripheral round(s) late for their deadline, "
                   "computed by the central (the same arithmetic: the commands are "
                   "unchanged)" + (f"; the {replies} late repl"
                                   f"{'y was' if replies == 1 else 'ies were'} dropped"
                                   if replies else ""))
    out += _degraded_lines(r)
    late = r.get("late_intervals")
    if not late or not late["intervals"] or not late["work_stretch"]:
        return out
    st = late["work_stretch"]
    why = {True: ": the machine itself ran slower",
           False: ": the time went to waiting, not to the work"}.get(late["machine_slower"], "")
    out.append(f"  late        {late['intervals']} command(s) left after their deadline; "
               f"there the peripherals' work took {st['median']:.1f}x its median of "
               f"{late['work_median_s'] * 1e6:.0f} us (max {st['max']:.1f}x){why}")
    if late["intervals"] != r.get("deadline_misses", late["intervals"]):
        out.append(f"{' ' * 14}(late: the central's count, from each sample's time at the "
                   "plant to its command's leaving; deadline misses: the plant's, commands "
                   "not there at their tick, the command's transit included)")
    return out


def _degraded_lines(r: dict[str, Any]) -> list[str]:
    """The peripherals lost and taken over (runtime/central/takeover.py), and those that
    stood by with them."""
    out = []
    for i, d in enumerate(r.get("degraded") or []):
        head = "  degraded    " if i == 0 else " " * 14
        why = str(d["why"])
        why = why if len(why) <= 600 else why[:597] + "..."  # whole: it is the diagnosis
        if why.startswith("stands by"):
            out.append(f"{head}peripheral {d['peripheral']} stands by from cycle "
                       f"{d['from_cycle']}{why[len('stands by'):]}")
        else:
            out.append(f"{head}peripheral {d['peripheral']} lost at interval {d['at_interval']}"
                       f" ({why}): the central computes its rounds from cycle "
                       f"{d['from_cycle']}")
        if "requests_again_at_interval" in d:
            out.append(f"{' ' * 14}peripheral {d['peripheral']} answered after all: requests "
                       f"out again at interval {d['requests_again_at_interval']}")
        if "requests_stopped_again" in d:
            out.append(f"{' ' * 14}peripheral {d['peripheral']}: requests stopped for good "
                       f"({d['requests_stopped_again']})")
        if "back_from_cycle" in d:
            out.append(f"{' ' * 14}peripheral {d['peripheral']} back at interval "
                       f"{d['back_at_interval']}: it serves its rounds again from cycle "
                       f"{d['back_from_cycle']}")
    if out:
        out.append(f"{' ' * 14}{(r.get('late') or {}).get('taken_over', 0)} round(s) of lost "
                   "peripherals computed by the central (the same arithmetic: the commands "
                   "are unchanged)")
    return out


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


LINK_LINES = {
    "tls": "TLS with mutual authentication, under the unit's access control (--keys)",
    "local": "a unix socket: who may enter its directory may connect (the default's: "
             "this user alone)",
    "loopback": "TCP on a loopback address without keys: any process on this host may "
                "connect and read the observers' keys (view/) alone; the roles use the "
                "local socket (--keys DIR makes it TLS)",
    "insecure": "INSECURE: links without keys that carry the control path (--insecure): "
                "anyone who reaches them may read the unit's traffic and move the robot",
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


def _us(x: float | None) -> str:
    return "   n/a" if x is None or not math.isfinite(x) else f"{x * 1e6:8.1f} us"


def _mm(x: float | None) -> str:
    return "n/a" if x is None or not math.isfinite(x) else f"{x * 1e3:.3f} mm"


def _timing_lines(r: dict[str, Any]) -> list[str]:
    """Period, traversal and jitter where the clock gives them a meaning: in lockstep
    (virtual time, no deadline) only the wall time each interval took; in realtime the
    deadline and the margin the traversal leaves (:func:`_deadline_lines`)."""
    pq, tq = r["period_s"], r["traversal_s"]
    if r["clock"] == "lockstep":
        return [f"  wall time   per interval mean {_us(r.get('period_mean_s')).strip()}, "
                f"sample to command p50 {_us(tq['p50']).strip()} (lockstep keeps virtual "
                "time:", "              no deadline; this is how fast the processes ran)"]
    return [
        f"  period      p50 {_us(pq['p50'])}  p99 {_us(pq['p99'])}  "
        f"max {_us(pq['max'])}  mean {_us(r.get('period_mean_s', math.nan))}",
        f"  traversal   p50 {_us(tq['p50'])}  p99 {_us(tq['p99'])}  max {_us(tq['max'])}",
        f"  jitter      std {_us(r['jitter_s']['std'])}",
        *_deadline_lines(r),
    ]


def _deadline_lines(r: dict[str, Any]) -> list[str]:
    """Realtime: the time from a sample to the tick its command is due at (the command
    delay's periods, at least one), and what the traversal's p99 leaves of it."""
    period, p99 = r.get("nominal_period_s"), r["traversal_s"]["p99"]
    if r["clock"] != "realtime" or not period or p99 is None or not math.isfinite(p99):
        return []
    due = max(int((r.get("command_delay") or {}).get("periods") or 1), 1)
    budget = due * period
    margin = budget - p99
    left = (f"leaves a margin of {margin * 1e6:.1f} us ({margin / budget:.0%})" if margin >= 0
            else f"passes it by {-margin * 1e6:.1f} us")
    return [f"  deadline    {budget * 1e6:.1f} us from a sample to its command (due at tick "
            f"k + {due}): the traversal p99 {left}"]


def _efficiency_lines(r: dict[str, Any]) -> list[str]:
    """Eq. IV.23's efficiency and the speedup ``t_1 / t_parallel`` where the run measures
    them (:func:`efficiency_unmeasured`), with their terms and basis; else why not."""
    why = efficiency_unmeasured(r)
    if why is not None:
        return [f"  efficiency  not measured here: {why}"
                + ("" if why.startswith(("t_1", "one")) else
                   " (Eq. IV.23 is measured with --clock freerun)")]
    lines = [f"  efficiency  Eq. IV.23: t_1 / (t_parallel x N) = {r['t1_s'] * 1e6:.1f} us / "
             f"({r['t_parallel_s'] * 1e6:.1f} us x {r['efficiency_n']}) = "
             f"{r['efficiency'] * 100:.1f} %   speedup {r['speedup']:.2f}",
             f"              {EFFICIENCY_BASIS}"]
    if r["speedup"] < 1:
        lines.append("              a speedup below 1: the exchanges cost more than the "
                     "arithmetic they share" + (" (--cost-model t800 gives the blocks the "
                                                "thesis's costs)"
                                                if r.get("cost_model") != "t800" else ""))
    return lines


def _misses_lines(r: dict[str, Any]) -> list[str]:
    """Deadline misses, skipped samples and excused silences: in realtime, and in the
    other clocks (which have no deadline) only when one of them is not 0."""
    if r["clock"] != "realtime" and not (r["deadline_misses"] or r["skipped_samples"]
                                         or r.get("silences_excused")):
        return []
    return [f"  deadline misses {r['deadline_misses']}"
            + (f" ({r['plant_spares']} covered by the command extrapolated the period before)"
               if r.get("plant_spares") else "")
            + f"   skipped samples {r['skipped_samples']}"
            + (f"   silences excused {r['silences_excused']} (the machine, not the process, "
               "was slow)" if r.get("silences_excused") else "")]


def _host_lines(r: dict[str, Any]) -> list[str]:
    """Realtime: the most CPU time the hypervisor took from one of this machine's CPUs
    during the run, where it took any (what ran there stood still, whatever its
    priority: misses and skipped samples the unit could not have avoided)."""
    stolen = r.get("host_stolen_s")
    if r["clock"] != "realtime" or not stolen:
        return []
    return [f"  host        the hypervisor took up to {stolen:.2f} s from one of this "
            "machine's CPUs during the run (steal: what ran there stood still, whatever its "
            "priority)"]


def _tracking_line(r: dict[str, Any]) -> str:
    torque = f"peak torque {r['torque_nm']['max']:.2f} N m"
    if r["clock"] == "freerun":
        return f"  {torque} (no tracking error: freerun has no plant)"
    err = r["tracking_error_m"]
    line = f"  tracking error max {_mm(err['max'])}   rms {_mm(err['rms'])}   {torque}"
    if r.get("cycles") and not all(isinstance(err[k], (int, float)) and math.isfinite(err[k])
                                   for k in ("max", "rms")):
        line += ("\n              (n/a: a sample's error is not a number: a position NaN or "
                 "infinite, or none measured)")
    return line


def _exchange_line(r: dict[str, Any]) -> str:
    return (f"  round trips per interval  {r['round_trips']}" + (
        f" ({r['rounds_ahead']} before the sample, off its path to the command)"
        if r.get("rounds_ahead") else "") + (
        f"   exchanges per interval {r['exchanges_per_interval']:.2f}" + (
            " (rounds of consecutive intervals fused)"
            if r["exchanges_per_interval"] < r["round_trips"] - 0.01 else "")
        if r.get("exchanges_per_interval") else "") + (
        "; replies per round" if (r.get("replies") or {}).get("mode") == "each" else "") + (
        "; lone rounds go at once" if (r.get("hold_rounds") or {}).get("held") is False
        else ""))


def _admission_lines(r: dict[str, Any]) -> list[str]:
    adm = r.get("admission")
    if not (adm and adm.get("period_s")):
        return []
    rungs = adm["rungs"]
    at = [k for k, x in enumerate(rungs) if x["held"] and x["period_s"] == adm["period_s"]]
    k = at[-1] if at else len(rungs) - 1  # the trial that held the period run (not a
    rung = rungs[k]  # shorter one tried after it, on the way down the ladder)
    return [f"  admission   {adm['period_s'] * 1e3:g} ms held in a trial of "
            f"{rung['intervals']} intervals before motion (asked: "
            + ("auto" if adm["asked"] == "auto" else f"{adm['asked'] * 1e3:g} ms")
            + ")" + (f"; the first trial at it had one stall ({rungs[k - 1]['late']}"
                     " intervals late), so it ran again"
                     if rung.get("retry") and k > 0 else "") + _descent(rungs)]


def _descent(rungs: list[dict[str, Any]]) -> str:
    """``--period auto``'s way down the ladder in its first start: which shorter periods
    held, the first that did not, and whether the start again at the shortest held."""
    down = [x for x in rungs if x.get("descent")]
    why = next((x["shorter_not_tried"] for x in rungs if x.get("shorter_not_tried")), None)
    if not down:
        return f"; {why}" if why else ""
    held = [f"{x['period_s'] * 1e3:g} ms" for x in down if x["held"]]
    not_held = [f"{x['period_s'] * 1e3:g} ms" for x in down if not x["held"]]
    again = next((x for x in rungs if x.get("start") == 1), None)
    return (f"; below {rungs[0]['period_s'] * 1e3:g} ms the first start's trials held "
            f"{', '.join(held) or 'none'}" + (f", not {not_held[0]}" if not_held else "")
            + (f"; started again at {again['period_s'] * 1e3:g} ms, its trial did not hold"
               if again is not None and not again["held"] else "") + (f"; {why}" if why else ""))


def summary(r: dict[str, Any]) -> str:
    """The human summary printed at the end of a run: each figure where the run's clock
    gives it a meaning (:func:`_timing_lines`, :func:`efficiency_unmeasured`)."""
    lines = [
        f"ctrlunit: {r['cycles']} intervals, {r['peripherals']} peripheral(s), pipeline depth "
        f"{r['pipeline']}, clock {r['clock']}, {r['law']} + {r['model']} model, task "
        f"{quoted(r['task'])}, cost model {r['cost_model']}",
        *_delay_lines(r),
        _exchange_line(r),
        *_timing_lines(r),
        *_misses_lines(r),
        *_host_lines(r),
        *_late_lines(r),
        *_overload_lines(r),
        "  business    " + "  ".join(f"{k} {v * 100:.0f} %" for k, v in r["business"].items()),
        *_cpu_lines(r),
        *_sched_lines(r),
        f"  t_1 (one process, no exchange) {_us(r['t1_s'])}   the blocks as this run timed "
        f"them: in series t_s {_us(r['t_s_model_s'])}, the per-axis ones split t_p "
        f"{_us(r['t_p_model_s'])}",
        *_efficiency_lines(r),
        _tracking_line(r),
    ]
    if not r["cycles"]:  # refused or failed before the first interval: nothing measured
        lines = lines[:2] if r.get("command_delay") else lines[:1]
    choice = r.get("placement_choice")
    if choice:
        lines.append(f"  placement   auto: {choice['why']}")
    lines += _live_balance_lines(r, first=not choice)
    lines += _link_lines(r)
    lines += _admission_lines(r)
    lines += end_lines(r)
    return "\n".join(lines)


def _live_balance_lines(r: dict[str, Any], *, first: bool) -> list[str]:
    """``--balance live``: each move, and what the figures above then cover; or why
    there was none (runtime/central/rebalance.py)."""
    moves, live = r.get("rebalanced") or [], r.get("live_balance")
    out = [f"live, from interval {m['from_cycle']}: {m['why']}: predicted "
           f"{_us(m['predicted_period_s']).strip()} against "
           f"{_us(m['measured_period_s']).strip()} measured" for m in moves]
    if moves and live is not None:
        now = ", ".join(live["central_blocks"]) or "none"
        out.append(f"live: central blocks now {now} (a placement file: peripherals and "
                   "central_blocks); the figures above span the placements before and after")
    elif live is not None:
        out.append(f"live: {live['ended']}" if live["ended"] else
                   f"live: {live['judged']} judgement(s), no move (none predicted 5 % "
                   "faster)" if live["judged"] else "live: no verdict, the run ended while "
                   "the judge (a process at nice 19: it waits for an idle CPU) was at its "
                   "first" if live.get("under_way") else "live: no judgement, the run "
                   f"ended before its first (after interval {live['first_judged_after']})")
    return [("  placement   " if i == 0 and first else " " * 14) + x
            for i, x in enumerate(out)]


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


__all__ = ["EFFICIENCY_BASIS", "LINK_LINES", "efficiency_unmeasured", "summary"]
