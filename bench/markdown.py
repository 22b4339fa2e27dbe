"""``report.md`` of a benchmark run."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

from .realtime import markdown_lines


def _us(x: Any) -> str:
    return "n/a" if x is None or (isinstance(x, float) and not math.isfinite(x)) else (
        f"{x * 1e6:.0f}")


def _pct(x: Any, *, sign: bool = False) -> str:
    return "n/a" if x is None or (isinstance(x, float) and not math.isfinite(x)) else (
        f"{x * 100:+.1f} %" if sign else f"{x * 100:.1f} %")


def _idle_phrase(idle: dict[str, Any] | None) -> str:
    """How the idle CPUs were during the paced rounds (runtime/host/idle.py)."""
    if (idle or {}).get("in_force") == "poll":
        return "Idle CPUs polling, as a realtime unit's (`--idle`)."
    return f"Idle CPUs as they are (`--idle`: {(idle or {}).get('why', 'not recorded')})."


def write_markdown(path: Path, r: dict[str, Any]) -> None:
    """``report.md`` of the stages that ran (``r["stages"]``), one section each."""
    m = r["machine"]
    stages = ", ".join(r.get("stages") or ["all"])
    lines = [
        "# ctrlunit benchmark",
        "",
        f"Machine: {m['platform']}, {m['cores']} cores, Python {m['python']}. "
        f"{'Quick' if r['quick'] else 'Full'} bench, {r['repeats']} repeat(s), stages "
        f"{stages}; {r['wall_s']:.0f} s.",
        "",
        "Method: " + "; ".join(f"{k}: {v}" for k, v in r["method"].items()) + ".",
    ]
    for section in (_floor, _sweep, _thesis, _recording, _target, _balance):
        lines += section(r)
    if r.get("realtime"):
        lines += ["", *markdown_lines(r["realtime"])]
    lines += ["", "## Figures", ""]
    for f in r.get("figures", []):
        lines.append(f"![{f}]({f})")
    path.write_text("\n".join(lines) + "\n")


def _floor(r: dict[str, Any]) -> list[str]:
    fl = r.get("floor")
    if not fl:
        return []
    lines = [
        "",
        "## Transport floor (same scatter/gather pattern, 64-byte payloads)",
        "",
        "| n | pipes p50 (us) | Zenoh p50 (us) | Zenoh p99 (us) | Zenoh / pipes |",
        "|---|---|---|---|---|",
    ]
    for n, f in fl["by_n"].items():
        lines.append(f"| {n} | {_us(f['pipe_s']['p50'])} | {_us(f['zenoh_s']['p50'])} | "
                     f"{_us(f['zenoh_s']['p99'])} | {f['ratio_p50']:.1f} |")
    paced = fl.get("paced")
    if paced:
        lines += [
            "",
            f"At the unit's cadence: one request and one reply of 250 bytes every "
            f"{paced['period_s'] * 1e3:g} ms between two processes, the caller sleeping to "
            f"each tick as the realtime plant does ({paced['rounds']} rounds). CPU time per "
            "round of each process, every thread counted: what the plant's sample and "
            "command, or a peripheral's request and reply, cost per interval. "
            + _idle_phrase(paced.get("idle")),
            "",
            "| link | CPU caller (us) | CPU echo (us) | round trip p50 / p99 (us) |",
            "|---|---|---|---|",
        ]
        for kind in ("pipe", "zenoh"):
            x = paced[kind]
            lines.append(f"| {kind} | {_us(x['cpu_caller_s'])} | {_us(x['cpu_echo_s'])} | "
                         f"{_us(x['round_trip_s']['p50'])} / {_us(x['round_trip_s']['p99'])} |")
    return lines


def _exits(codes: list[Any]) -> str:
    """The exit codes of a configuration's runs, named (docs/faults-and-errors.md)."""
    names = {7: "refused before any motion (exit 7)", None: "no report"}
    return ", ".join(names.get(c, f"exit {c}") for c in codes if c != 0) or "no run"


def _sweep(r: dict[str, Any]) -> list[str]:
    rows = [x for x in r.get("runs", []) if x["tag"] in ("sweep", "realtime", "live")]
    if not rows:
        return []
    lines = [
        "",
        "## Sweep (freerun unless stated; medians over repeats)",
        "",
        "CPU per interval / cores: the CPU time every process of the unit spent per "
        "interval (all threads, Zenoh's included), divided by the cores they share: no "
        "schedule can make the freerun period shorter.",
        "",
        "| n | N | depth | cost | clock | round trips | period p50 / p99 / mean (us) | "
        "CPU per interval, all processes (us) / cores | traversal p50 (us) | t_1 (us) | "
        "efficiency (spread) | speedup | misses | business |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for x in rows:
        head = (f"| {x['peripherals']} | {x['processors'] or 'n/a'} | {x['pipeline']} | "
                f"{x['cost_model']} | {x['clock']} {x['nominal_period_s'] * 1e3:g} ms |")
        codes = x.get("exit_codes") or []
        if not x.get("repeats"):  # no run moved: its figures would read as measured
            lines.append(f"{head} not run: {_exits(codes)} |" + " |" * 8)
            continue
        busy = ", ".join(f"{k.replace('peripheral_', 'p')} {v * 100:.0f}%"
                         for k, v in x["business"].items() if v is not None)
        busy += f" ({x['repeats']} of {len(codes)} runs: {_exits(codes)})" \
            if len(codes) > x["repeats"] else ""
        sp = x["efficiency_spread"]
        lines.append(
            f"{head} {x['round_trips']} | "
            f"{_us(x['period_s']['p50'])} / {_us(x['period_s']['p99'])} / "
            f"{_us(x.get('period_mean_s'))} | {_us(x.get('cpu_bound_period_s'))} | "
            f"{_us(x['traversal_s']['p50'])} | {_us(x['t1_s'])} | {_pct(x['efficiency'])} "
            f"({_pct(sp[0])}..{_pct(sp[1])}) | {x['speedup']:.2f} | {x['deadline_misses']} |"
            f" {busy} |")
    return lines


def _thesis(r: dict[str, Any]) -> list[str]:
    """The 1994 comparison and its guarded figures (:mod:`.thesis`)."""
    th = r.get("thesis")
    if not th:
        return []
    from .thesis import guard_lines

    by = {(x["law"], x["pipeline"]): x for x in r["runs"] if x["tag"] == "thesis"}
    kin, whole1, whole2 = (by.get(("kinematics", 1)), by.get(("resolved-acceleration", 1)),
                           by.get(("resolved-acceleration", 2)))
    f = th["figures"]
    lines = [
        "",
        f"## Against the 1994 unit (t800 cost model x {r['cost_scale_thesis_runs']:g}, "
        "so that arithmetic outweighs messages as on the Transputers)",
        "",
        f"{th['config']}.",
        "",
        "| what | 1994 | ctrlunit |",
        "|---|---|---|",
    ]
    if kin:
        lines.append(f"| all kinematics, N = 4, depth 1 | 57 % (1320 us / (582 us x 4)) | "
                     f"{_pct(f['kinematics_efficiency'])} (t_1 {_us(kin['t1_s'])} us, "
                     f"traversal {_us(kin['traversal_s']['p50'])} us, "
                     f"N = {kin['processors']}) |")
    if whole1:
        lines.append(f"| whole cycle, N = 4, depth 1 | 46 % by Eq. IV.23 (54 % printed) | "
                     f"{_pct(f['whole_cycle_efficiency'])} (t_1 {_us(whole1['t1_s'])} us, "
                     f"traversal {_us(whole1['traversal_s']['p50'])} us) |")
    if whole1 and whole2:
        busy = f.get("depth2_business_peripherals")
        lines.append(f"| depth-2 period / depth-1 period (mean: the throughput) | 0.5 "
                     f"designed, not run reliably | {f['depth_ratio']:.2f} "
                     f"({_us(f['depth2_period_mean_s'])} / {_us(f['depth1_period_mean_s'])} "
                     f"us; peripherals {_pct(busy)} busy at depth 2) |")
        lines.append(f"| depth-2 period from the model calibrated at depth 1 | n/a | "
                     f"{_us(f['model_depth2_period_s'])} us predicted, "
                     f"{_pct(f['model_depth2_error'], sign=True)} measured against it |")
    t = r["thesis_1994"]
    lines.append(f"| sampling period | {t['period_1_us']} us on 1, {t['period_4_us']} us on 4"
                 " | see the sweep |")
    lines += ["", "Guarded figures (a regression fails CI):", "",
              *(f"- {g}" for g in guard_lines(th))]
    return lines


def _recording(r: dict[str, Any]) -> list[str]:
    lines: list[str] = []
    rc_ = r.get("recording_cost")
    if rc_:
        lines += ["", "## What recording costs", "",
                  f"{rc_['config']}: period p50 {_us(rc_['period_p50_without_s'])} us without "
                  f"--record, {_us(rc_['period_p50_with_s'])} us with it: "
                  f"{(rc_['ratio'] - 1) * 100:+.1f} % (target: at most +10 %)."]
        comps = rc_.get("compressions") or {}
        if comps:
            lines += ["", "| --record-compression | period p50 (us) | vs not recorded | "
                      "bytes per interval |", "|---|---|---|---|"]
            for comp, c in comps.items():
                lines.append(f"| {comp} | {_us(c['period_p50_with_s'])} | "
                             f"{(c['ratio'] - 1) * 100:+.1f} % | "
                             f"{c['bytes_per_interval']:.0f} |")
            if "none" in comps and "zstd" in comps:
                shrink = (comps["none"]["bytes_per_interval"]
                          / comps["zstd"]["bytes_per_interval"])
                lines.append(f"\nzstd makes a recording {shrink:.2f}x smaller than "
                             "uncompressed.")
        lv = rc_.get("live_view")
        if lv:
            lines += ["", "## What the live view costs", "",
                      f"The same configuration with --foxglove and a viewer subscribed to "
                      f"everything: period p50 {_us(lv['period_p50_with_s'])} us, "
                      f"{(lv['ratio'] - 1) * 100:+.1f} % against not recorded (target: at "
                      f"most the recording's +10 %); the viewer read "
                      f"{lv['viewer_messages']:.0f} messages for {lv['cycles']:.0f} "
                      "intervals."]
    return lines


def _target(r: dict[str, Any]) -> list[str]:
    lines: list[str] = []
    tg = r.get("target") or {}
    if tg.get("variants"):
        target_us = _us(tg["target_s"])
        lines += ["", f"## The {target_us} us target: freerun period at n = 3, depth 2", "",
                  f"{tg['config']}; mean period (median over repeats, min..max), CPU of "
                  "every process per interval. SCHED_FIFO: every role under --rt-priority "
                  "(at equal priority no role preempts another on wake-up)."
                  + ("" if tg["fifo_permitted"] else " SCHED_FIFO is not permitted to "
                     "this process: those variants were not run."), "",
                  "| placement | scheduling | exchanges / interval | mean period (us) | "
                  "spread (us) | CPU / interval (us) | target |",
                  "|---|---|---|---|---|---|---|"]
        for v in tg["variants"]:
            sp = v["period_mean_spread_s"]
            met = v["period_mean_s"] <= tg["target_s"]
            lines.append(
                f"| {v['placement']} | {v['scheduling']} | "
                f"{(v['exchanges_per_interval'] or 0):.2f} | {_us(v['period_mean_s'])} | "
                + (f"{_us(sp[0])}..{_us(sp[1])}" if sp else "n/a")
                + f" | {_us(v['cpu_per_interval_s'])} | {'met' if met else 'missed'} |")
    return lines


def _balance(r: dict[str, Any]) -> list[str]:
    lines: list[str] = []
    bal = r.get("balance") or {}
    if bal.get("native"):
        lines += ["", "## Load balancing (§ IV.7.2): ctrlunit balance, then a re-run", "",
                  "balance calibrates its schedule model on the first n = 3 native freerun "
                  "run of each depth and recommends a placement; it is re-run alternately "
                  "with the default one (mean periods, medians over repeats). The prediction "
                  "it is judged by comes from the model calibrated again on the median "
                  "default-placement re-run, which saw the same machine as the balanced "
                  "re-runs; the prediction from the sweep's run is given beside it.", "",
                  "| depth | recommendation | model of the sweep run | predicted from it | "
                  "predicted from the re-runs | before | after | after vs predicted | gain |",
                  "|---|---|---|---|---|---|---|---|---|"]
        for e in bal["native"]:
            lines.append(
                f"| {e['depth']} | {e['recommendations'][0]} | {_us(e['model_now_s'])} us | "
                f"{_us(e.get('predicted_from_sweep_s'))} us | "
                f"{_us(e['predicted_period_s'])} us | {_us(e.get('measured_before_s'))} us | "
                f"{_us(e.get('measured_after_s'))} us | {_pct(e.get('error'), sign=True)} | "
                f"{_pct(e.get('gain'), sign=True)} |")
    return lines
