"""Live balance against ``ctrlunit balance``, under the T-800 cost model.

The unit (freerun, n = 3, depth 2, T-800 costs x ``scale``) starts from a poor placement:
every block of the model's round (the per-axis blocks of the round that needs the
sample) on the central, the peripherals left the observer's kinematics alone. (At n = 3
every peripheral owns one axis, so the per-axis blocks cannot all go to one peripheral;
the central is the one process they can crowd.)

1. A run of that placement, ``--balance off``: ``ctrlunit balance`` analyses its report
   and writes the placement it recommends.
2. Then, alternately, ``pairs`` times: a run started with balance's placement, and a run
   started with the poor one and ``--balance live``. Both are recorded; the mean period
   of each over intervals ``[window)`` (from the commands' times) is compared.

``python -m ctrlunit.bench.live_balance [--pairs 3] [--cycles 220] [--scale 30]
[--json FILE]`` prints the table and the acceptance figure: the live runs' mean period in
the window within 5 % of the balanced runs'.
"""

from __future__ import annotations

import argparse
import json
import os
import random
import statistics
import tempfile
from pathlib import Path
from typing import Any

from ..runtime.config import RunConfig
from ..runtime.launch.launcher import start
from ..runtime.recording.reader import read
from ..runtime.roles.stopping import raise_if_stopped
from ..topology.balance import analyse, write_placement
from ..topology.graph import stage_graph
from ..topology.placement import default_placement
from ..topology.plan import exchange_plan

WINDOW = (150, 200)
"""The intervals whose mean period is compared: by interval 200 the live run is to run
at the period of balance's placement."""
BOUND = 0.05


def poor_placement(rc: RunConfig, path: Path) -> list[str]:
    """Write the poor placement (the model's round on the central) to ``path``; returns
    its central blocks."""
    graph = stage_graph(rc.control.law, rc.control.model, observer=rc.control.observer,
                        model_state=rc.resolved_model_state)
    plan = exchange_plan(graph, default_placement(3))
    blocks = sorted(b.name for b in plan.rounds[-1].blocks)
    path.write_text(json.dumps({"peripherals": 3, "central_blocks": blocks}))
    return blocks


def run(rc: RunConfig) -> dict[str, Any]:
    """One run of ``rc``; its report, with the exit code."""
    code, rep = start(rc, echo=lambda m: None)
    raise_if_stopped(code, rep)
    rep["exit_code"] = code
    return rep


def window_period(record: Path, window: tuple[int, int] = WINDOW) -> float:
    """The mean period (s) over intervals ``[window)`` of a recording, from the times
    its commands left."""
    t = {m["cycle"]: ts for ts, m in read(str(record)).decoded("/plant/command")}
    a, b = window
    return (t[b - 1] - t[a - 1]) / (b - a) / 1e9


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m ctrlunit.bench.live_balance")
    ap.add_argument("--pairs", type=int, default=3)
    ap.add_argument("--cycles", type=int, default=220)
    ap.add_argument("--scale", type=float, default=30.0)
    ap.add_argument("--json", type=Path)
    args = ap.parse_args(argv)
    tmp = Path(tempfile.mkdtemp(prefix="ctrlunit-live-balance-"))

    def rc_of(**kw: Any) -> RunConfig:
        return RunConfig.of(peripherals=3, pipeline=2, clock="freerun", cost_model="t800",
                            cost_scale=args.scale, cycles=args.cycles,
                            unit=f"lb-{os.getpid()}-{random.randrange(1 << 30)}", **kw)

    poor = tmp / "poor.json"
    blocks = poor_placement(rc_of(), poor)
    first = run(rc_of(placement=str(poor)))
    a = analyse(first)
    balanced = tmp / "balanced.json"
    write_placement(a, balanced)
    rows = []
    for i in range(args.pairs):
        pair: dict[str, Any] = {}
        for name, kw in (("balanced", {"placement": str(balanced)}),
                         ("live", {"placement": str(poor), "balance": "live"})):
            rec = tmp / f"{name}-{i}.mcap"
            rep = run(rc_of(record=str(rec), **kw))
            pair[name] = {"exit": rep["exit_code"], "period_s": window_period(rec),
                          "moves": rep.get("rebalanced") or []}
            rec.unlink()
        pair["ratio"] = pair["live"]["period_s"] / pair["balanced"]["period_s"]
        rows.append(pair)
        print(f"pair {i + 1}: balanced {pair['balanced']['period_s'] * 1e3:.2f} ms, live "
              f"{pair['live']['period_s'] * 1e3:.2f} ms (ratio {pair['ratio']:.3f}; moves at "
              f"{[m['from_cycle'] for m in pair['live']['moves']]})", flush=True)
    ratios = [r["ratio"] for r in rows]
    out = {"scale": args.scale, "cycles": args.cycles, "window": WINDOW,
           "poor_central_blocks": blocks,
           "poor_period_s": first["period_mean_s"],
           "balance_recommends": a["placement"], "balance_predicts_s":
           a["predicted"]["period_s"], "pairs": rows, "ratio_median": statistics.median(ratios),
           "within_bound": all(r - 1.0 <= BOUND for r in ratios)}
    print(f"poor placement (central blocks {blocks}): {first['period_mean_s'] * 1e3:.2f} ms; "
          f"balance recommends {a['placement']['central_blocks']} "
          f"(predicted {a['predicted']['period_s'] * 1e3:.2f} ms)")
    print(f"live / balanced over intervals {WINDOW[0]}-{WINDOW[1]}: median "
          f"{out['ratio_median']:.3f}, max {max(ratios):.3f}; within {BOUND:.0%} in "
          f"{sum(r - 1.0 <= BOUND for r in ratios)} of {len(ratios)} pairs")
    if args.json:
        args.json.write_text(json.dumps(out, indent=1))
    return 0 if out["within_bound"] else 1


if __name__ == "__main__":
    raise SystemExit(main())
