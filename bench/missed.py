"""What late commands cost the tracking, held or replaced by the extrapolated command.

Offline and deterministic: the one-process controller of a run (runtime/compute/setup.py) and the
simulated Delta, with the realtime unit's timing at depth 2 (sample k's command due at the
start of period k + 2) and the plant's own rule for a command that is not there in time
(runtime/roles/plant_node.py, ``PlantServer.apply``). A burst of ``length`` consecutive commands,
each ``late`` periods late, is placed at 16 phases of the task; the worst tracking error
over the phases is reported for ``--missed-command hold`` (no extrapolated command: the
plant's own rule from the first missed period, runtime/roles/plant_hold.py) and
``extrapolate``. Each
command's extrapolation is
:func:`~ctrlunit.runtime.central.settings.extrapolated_command`, as the central sends it.

``python -m ctrlunit.bench.missed [--period 1.6ms ...]`` prints the table.
"""

from __future__ import annotations

import math
import time
from collections import Counter
from types import SimpleNamespace
from typing import Any

from ..plant.simulator import Plant, PlantConfig
from ..runtime.central.settings import extrapolated_command
from ..runtime.compute.controller import initial_angles, initial_command
from ..runtime.compute.setup import make_setup
from ..runtime.config import RunConfig
from ..runtime.roles.plant_node import PlantServer

PHASES = 16


class _Offline:
    """What :class:`PlantServer` needs of a node, with no messages."""

    def __init__(self) -> None:
        self.rejected: Counter[str] = Counter()
        self.last_heard_ns = time.monotonic_ns()
        self.keys = SimpleNamespace(sample="", command="")

    def publisher(self, _key: str) -> None:
        return None

    def route(self, *_: Any) -> None:
        return None


def tracking_with_late(period_s: float, late: dict[int, int], *, missed: str,
                       bandwidth_hz: float | None = None) -> float:
    """Max tracking error (m) of the default task at ``period_s``, depth 2, when the
    command of each sample in ``late`` arrives that many periods after it is due (the
    gains: ``bandwidth_hz``, else the default, ``RunConfig.bandwidth``)."""
    rc = RunConfig.of(period=period_s, pipeline=2, peripherals=0, clock="lockstep",
                      bandwidth_hz=bandwidth_hz).validate()
    setup = make_setup(rc)
    engine = setup.engine(peripherals_plan=False)
    ctl = setup.controller(engine)
    delay = rc.delay_periods
    plant = Plant(setup.params, PlantConfig(period=period_s),
                  q0=initial_angles(setup.params, setup.task), p_guess=tuple(setup.task.start()))
    server = PlantServer(_Offline(), plant, depth=2,  # type: ignore[arg-type]
                         initial=initial_command(setup.params, setup.task), period_s=period_s)
    arriving: dict[int, list[tuple[int, list[float], list[float] | None]]] = {}
    prev: list[float] | None = None
    worst = 0.0
    for k in range(setup.cycles):
        ctx = engine.run_local(ctl.sources(k, plant.encoder_counts()))
        ctl.handoff(ctx)
        ref = ctx.get("pc")
        if ref is not None:
            worst = max(worst, math.dist(ref, plant.state.p))
        tau = [float(x) for x in ctx["cmd"]]
        nxt = extrapolated_command(tau, prev) if prev is not None and missed == "extrapolate" \
            else None
        prev = tau
        due = k + delay
        arriving.setdefault(due + late.get(k, 0), []).append((due, tau, nxt))
        for cycle, t, n in arriving.pop(k, []):  # what reached the plant before its tick
            server.commands[cycle] = t
            if n is not None:
                server.spares[cycle + 1] = n
        if k >= delay:
            server.apply(k)
        plant.step()
    return worst


def burst_table(period_s: float, *, lengths: tuple[int, ...] = (1, 4),
                lates: tuple[int, ...] = (1, 2)) -> list[dict[str, Any]]:
    """For each burst length and lateness, the worst tracking over :data:`PHASES` phases
    of the task, held and extrapolated; and the tracking with no late command."""
    cycles = make_setup(RunConfig.of(period=period_s, pipeline=2, peripherals=0,
                                     clock="lockstep").validate()).cycles
    starts = [cycles // 10 + j * (8 * cycles // 10) // PHASES for j in range(PHASES)]
    rows = [{"length": 0, "late": 0,
             **{m: tracking_with_late(period_s, {}, missed=m) for m in ("hold", "extrapolate")}}]
    for length in lengths:
        for late in lates:
            row: dict[str, Any] = {"length": length, "late": late}
            for m in ("hold", "extrapolate"):
                row[m] = max(tracking_with_late(
                    period_s, {c: late for c in range(s, s + length)}, missed=m) for s in starts)
            rows.append(row)
    return rows


def main(argv: list[str] | None = None) -> None:
    """``python -m ctrlunit.bench.missed``: the table at each ``--period``."""
    import argparse

    from ..runtime.config import parse_duration

    ap = argparse.ArgumentParser(prog="python -m ctrlunit.bench.missed",
                                 description=__doc__.split("\n\n")[0])
    ap.add_argument("--period", action="append", default=None,
                    help="period(s) to simulate (default 1ms, 1.6ms, 2.5ms)")
    args = ap.parse_args(argv)
    try:
        periods = [parse_duration(p, field_name="--period") for p in
                   (args.period or ["1ms", "1.6ms", "2.5ms"])]
    except ValueError as exc:
        ap.error(str(exc))
    print("period  burst  late by  tracking max held / extrapolated (mm)")
    for period in periods:
        for r in burst_table(period):
            what = "none" if not r["length"] else f"{r['length']:5d}  {r['late']:7d}"
            print(f"{period * 1e3:6g}  {what:14s}  {r['hold'] * 1e3:.3f} / "
                  f"{r['extrapolate'] * 1e3:.3f}")


if __name__ == "__main__":
    main()
