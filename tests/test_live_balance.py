"""Live balance (``--balance live``, runtime/central/rebalance.py): the central moves per-axis
blocks at a drained interval boundary, the peripherals follow from the interval it names,
and the commands are bit for bit those of a run that never moved; ``replay --verify``
re-executes such a run with the plan each interval had; ``ctrlunit balance``'s model
chooses the move (topology/balance.py, ``live_choice``)."""

from __future__ import annotations

import functools
import json
from concurrent.futures import Future
from pathlib import Path
from typing import Any

import pytest
from ctrlunit.runtime.central import rebalance
from ctrlunit.runtime.config import ConfigError, RunConfig
from ctrlunit.runtime.observe.summary import summary
from ctrlunit.runtime.recording import replay
from ctrlunit.runtime.recording.plot_data import changes
from ctrlunit.runtime.recording.reader import read
from ctrlunit.topology.graph import stage_graph
from ctrlunit.topology.live_choice import live_choice
from ctrlunit.topology.placement import default_placement
from ctrlunit.topology.plan import exchange_plan
from loopback import LoopbackUnit, lockstep_config, record_lockstep
from runner import start_json, unit_id

CYCLES = 200
FIGURES = Path(__file__).parent / "data" / "live_balance"
"""Two runs' reports as balance reads them (``source`` in each says which)."""


def model_round(**kw: Any) -> list[str]:
    """The per-axis blocks of the last round of a lockstep plan at n = 3 (the model's)."""
    rc = RunConfig.of(peripherals=3, clock="lockstep", **kw)
    graph = stage_graph(rc.control.law, rc.control.model, observer=rc.control.observer,
                        model_state=rc.resolved_model_state)
    return sorted(b.name for b in exchange_plan(graph, default_placement(3)).rounds[-1].blocks)


class Inline:
    """A judge that gives its verdict at once, in this process."""

    def __init__(self, *args: Any, **kw: Any) -> None:
        pass

    def submit(self, fn: Any, *args: Any) -> Future:
        f: Future = Future()
        f.set_result(fn(*args))
        return f

    def shutdown(self, **kw: Any) -> None:
        pass


def forced(monkeypatch: pytest.MonkeyPatch, moves: list[list[str]], *, settle: int) -> None:
    """Judgements that move to each placement of ``moves`` in turn, the first after
    ``settle`` intervals (then none)."""
    left = list(moves)

    def verdict(figures: dict[str, Any]) -> tuple[dict[str, Any] | None, int]:
        assert figures["placement"]["peripherals"] == 3  # the window, as balance reads it
        if not left:
            return None, 0
        return {"central_blocks": left.pop(0), "why": "forced by the test",
                "predicted_period_s": 1e-3, "model_period_s": 2e-3,
                "measured_period_s": figures["period_mean_s"]}, 0

    monkeypatch.setattr(rebalance, "ProcessPoolExecutor", Inline)
    monkeypatch.setattr(rebalance, "live_verdict", verdict)
    monkeypatch.setattr(rebalance, "SETTLE", settle)
    monkeypatch.setattr(rebalance, "EVERY", 5)
    monkeypatch.setattr(rebalance, "COST_SHARE", 1.0)


def lockstep(tag: str, **kw: Any) -> LoopbackUnit:
    u = LoopbackUnit(lockstep_config(unit_id(tag), peripherals=3, cycles=CYCLES,
                                     max_error=1.0, **kw))
    u.run()
    return u


@functools.cache
def undisturbed(pipeline: int, model_state: str) -> str:
    """The command digest of a run that never moves (one per depth and model state)."""
    return lockstep("lbplain", pipeline=pipeline, model_state=model_state
                    ).central.snapshot().digest


@pytest.mark.parametrize("settle", [0, 7, 40])
@pytest.mark.parametrize(("pipeline", "model_state"),
                         [(1, "auto"), (2, "auto"), (2, "foreseen"), (2, "foreseen2")])
def test_moves_keep_the_commands_bit_identical(monkeypatch, settle, pipeline, model_state):
    """Blocks moved to the central and back, at an early, a middle and a late boundary, at
    both depths and with rounds run ahead of the sample in flight: the commands equal an
    undisturbed run's bit for bit, every move is made where it was named, and the
    peripherals refused nothing."""
    kw = {"pipeline": pipeline, "model_state": model_state}
    model = model_round(**kw)
    forced(monkeypatch, [model, [], model[:2]], settle=settle)
    moved = lockstep("lbmoved", balance="live", **kw)
    run = moved.central.snapshot()
    assert run.digest == undisturbed(pipeline, model_state)
    assert [m["central_blocks"] for m in run.rebalanced] == [model, [], model[:2]]
    cycles = [m["from_cycle"] for m in run.rebalanced]
    assert cycles == sorted(cycles) and cycles[0] >= settle and cycles[-1] < CYCLES
    assert sorted(moved.central.engine.plan.placement.central_blocks) == model[:2]
    for pnode, periph in moved.peripherals:
        assert periph.engine.plan.placement == moved.central.engine.plan.placement
        assert periph.from_cycle == cycles[-1]
        assert not pnode.rejected, pnode.rejected
    assert not run.rejected


def test_a_recorded_move_replays_bit_for_bit_and_only_with_its_plan(monkeypatch, tmp_path):
    """``replay --verify`` switches plans where the recording's ``/central/placement``
    says; verified as if the run had never moved, the same recording diverges."""
    model = model_round(pipeline=2)
    forced(monkeypatch, [model], settle=20)
    path = tmp_path / "moved.mcap"
    record_lockstep(str(path), unit_id("lbrec"), peripherals=3, pipeline=2, cycles=CYCLES,
                    balance="live")
    rec = read(str(path))
    assert replay.placements(rec) and replay.placements(rec)[0][1] == model
    assert [k for k, _ in changes(rec)] == [k for k, _ in replay.placements(rec)]  # plotted
    done, div = replay.verify(rec)
    assert div is None and done == CYCLES
    monkeypatch.setattr(replay, "placements", lambda rec: [])
    _, div = replay.verify(rec)
    assert div is not None


def test_a_peripheral_takes_a_move_only_as_a_live_placement():
    """Once started, a peripheral takes a ``place`` order only in a run that balances
    itself and only with the interval it starts at; it then refuses request parts of
    earlier intervals, and an order given again is acknowledged without dropping what it
    holds."""
    u = LoopbackUnit(lockstep_config(unit_id("lbperiph"), peripherals=3, cycles=10,
                                     balance="live", clock="freerun"))
    u.run()
    request = next(d for k, d in u.bus.log if k == u.node.keys.request)  # interval 0's
    pnode, periph = u.peripherals[0]
    pnode.rejected.clear()
    model = model_round()
    off = LoopbackUnit(lockstep_config(unit_id("lboff"), peripherals=3, cycles=10))
    _, fixed = off.peripherals[0]  # a run that does not balance itself takes no move
    assert fixed.on_place({"central_blocks": model, "from_cycle": 40}, "peripheral-1",
                          started=True) is None
    assert periph.on_place({"central_blocks": model}, "peripheral-1", started=True) is None
    assert pnode.rejected["bad_stage"] == 1
    assert periph.on_place({"central_blocks": model, "from_cycle": -1}, "peripheral-1",
                           started=True) is None
    ack = periph.on_place({"central_blocks": model, "from_cycle": 40}, "peripheral-1",
                          started=True)
    assert ack is not None and periph.from_cycle == 40
    assert sorted(periph.engine.plan.placement.central_blocks) == model
    periph._ctxs[41] = {"kept": True}
    assert periph.on_place({"central_blocks": model, "from_cycle": 40}, "peripheral-1",
                           started=True) is not None
    assert 41 in periph._ctxs  # the same order again drops nothing
    assert list(periph.on_request(request)) == []
    assert pnode.rejected == {"bad_stage": 2, "unknown_cycle": 1}


def test_realtime_is_refused_with_the_fix():
    with pytest.raises(ConfigError, match="--balance live: not with --clock realtime.*freerun "
                                          "or lockstep"):
        RunConfig.of(balance="live", clock="realtime").validate()


def test_the_model_gives_a_crowded_central_its_round_back():
    """From the figures of a window with the model's round on the central (T-800 costs
    x30, freerun, n = 3, depth 2, as a run measured them), ``live_choice`` gives the whole
    round back, predicted far faster; from the balanced placement's figures it calls for
    no move."""
    poor = json.loads((FIGURES / "poor.json").read_text())
    choice = live_choice(poor)
    assert choice is not None and choice["central_blocks"] == []
    assert choice["predicted_period_s"] < 0.5 * choice["model_period_s"]
    assert live_choice(json.loads((FIGURES / "balanced.json").read_text())) is None


@pytest.mark.slow
def test_the_unit_balances_itself_to_balance_s_period(tmp_path):
    """The acceptance's setting, as a user runs it (T-800 costs x30, freerun, n = 3, depth
    2), one pair side by side: started with the model's round on the central and
    ``--balance live``, the unit moves it back within 100 intervals, and over intervals
    150-200 runs within 10 % of the period of a run started with that placement (the
    bench's pairs hold 5 %: docs/measurements/2026-11-28-live-balance.md); the commands
    are those of that run, bit for bit."""
    from ctrlunit.bench.live_balance import poor_placement, window_period

    poor = tmp_path / "poor.json"
    blocks = poor_placement(RunConfig.of(peripherals=3, pipeline=2, clock="freerun"), poor)
    common = ("--peripherals", "3", "--pipeline", "2", "--clock", "freerun", "--cost-model",
              "t800", "--cost-scale", "30", "--cycles", "200")
    out: dict[str, Any] = {}
    for name, extra in (("live", ("--placement", str(poor), "--balance", "live")),
                        ("axes", ("--placement", "axes"))):
        rec = tmp_path / f"{name}.mcap"
        code, rep, text = start_json(tmp_path, *common, *extra, "--record", str(rec),
                                     tag=f"lb{name}")
        assert code == 0, text
        out[name] = (rep, window_period(rec))
    (live, live_s), (axes, axes_s) = out["live"], out["axes"]
    assert len(blocks) > 1 and live["placement"]["central_blocks"] == blocks
    moves = live["rebalanced"]
    assert [m["central_blocks"] for m in moves] == [[]] and moves[0]["from_cycle"] <= 100
    assert "placement   live, from interval" in summary(live)
    assert live["command_digest"] == axes["command_digest"]
    assert live_s / axes_s < 1.10, (live_s, axes_s)


def test_balance_refuses_a_report_whose_figures_mix_placements():
    from ctrlunit.topology.balance import analyse
    from ctrlunit.topology.balance_report import ReportError

    doc = json.loads((FIGURES / "poor.json").read_text())
    assert analyse(doc)["placement"]["central_blocks"] == []
    with pytest.raises(ReportError, match="rebalanced.*--balance off"):
        analyse(doc | {"rebalanced": [{"from_cycle": 48, "central_blocks": []}]})


@pytest.mark.parametrize(("field", "value"), [
    ("clock", "lockstep"), ("pipeline", 1), ("cost_model", "native"), ("cost_scale", 60.0),
    ("task", "circle"), ("law", "computed-torque")])
def test_compare_refuses_a_rerun_of_another_run(field, value):
    """``balance --compare``: a re-run made with the written placement but another clock,
    depth, cost model, scale, task or law measures another thing: refused, naming it.
    The re-run as balance's command makes it is compared."""
    from ctrlunit.topology.balance import analyse, compare

    doc = json.loads((FIGURES / "poor.json").read_text())
    a = analyse(doc)
    rerun = doc | {"placement": a["placement"]}
    assert compare(a, rerun)["predicted_period_s"] > 0
    if field == "law":  # its block costs are another graph's
        rerun = rerun | {"block_cost_s": {}}
        with pytest.raises(ValueError, match="block_cost_s"):
            compare(a, rerun | {field: value})
        return
    with pytest.raises(ValueError, match=f"the re-run's {field} is {value!r}"):
        compare(a, rerun | {field: value})


def test_a_judge_that_dies_leaves_the_run_going(monkeypatch):
    """The judge's process killed (out of memory, by hand): live balance stops, saying
    why, and the run goes on to its end with the placement it has."""
    from concurrent.futures.process import BrokenProcessPool

    class Dead(Inline):
        def submit(self, fn: Any, *args: Any) -> Future:
            f: Future = Future()
            f.set_exception(BrokenProcessPool("killed"))
            return f

    monkeypatch.setattr(rebalance, "ProcessPoolExecutor", Dead)
    monkeypatch.setattr(rebalance, "EVERY", 5)
    u = lockstep("lbdead", pipeline=2, balance="live")
    assert u.central.done == CYCLES and not u.central.snapshot().rebalanced
    assert "the judge's process ended (BrokenProcessPool)" in u.central.balance.ended


def test_a_run_that_made_no_move_says_why(tmp_path):
    """A live run too short for a judgement, and one with no peripheral, each say so in
    their summary and report, where they said nothing."""
    for n, said in ((1, "live: no judgement, the run ended before its first (after "
                        "interval 48)"), (0, "live: no peripheral: nothing to move")):
        code, rep, out = start_json(tmp_path, "--peripherals", str(n), "--clock", "lockstep",
                                    "--cycles", "20", "--balance", "live", tag=f"lbnone{n}")
        assert code == 0, out
        assert rep["rebalanced"] == [] and rep["live_balance"]["judged"] == 0
        assert f"placement   {said}" in out or f"              {said}" in out, out


def test_the_judge_starts_before_the_warm_up_and_once(monkeypatch):
    """The judge's process (a new interpreter, at the unit's priority until its
    initializer runs) starts and is ready before the warm-up's first round, so that its
    start-up takes no CPU from the run's intervals; every judgement then uses it."""
    from ctrlunit.runtime.central import warmup as warmup_module

    events: list[str] = []

    class Pool(Inline):
        def __init__(self, *args: Any, **kw: Any) -> None:
            events.append("pool")

        def submit(self, fn: Any, *args: Any) -> Future:
            events.append(fn.__name__)
            return super().submit(fn, *args)

    real_run = warmup_module.WarmUp.run

    def run(self: Any) -> None:
        events.append("warm-up")
        real_run(self)

    monkeypatch.setattr(rebalance, "ProcessPoolExecutor", Pool)
    monkeypatch.setattr(warmup_module.WarmUp, "run", run)
    monkeypatch.setattr(rebalance, "EVERY", 5)
    monkeypatch.setattr(rebalance, "COST_SHARE", 1.0)
    u = LoopbackUnit(lockstep_config(unit_id("lbready"), peripherals=3, cycles=CYCLES,
                                     max_error=1.0, pipeline=2, balance="live"))
    u.plant_muted = True  # the plant's samples begin with the run
    u.central.warm_up()
    u.plant_muted = False
    u.run()
    assert u.central.balance.judged >= 2
    assert events[:3] == ["pool", "judge_ready", "warm-up"], events
    assert events.count("pool") == 1 and events.count("judge_ready") == 1
    assert events.count("live_verdict") == u.central.balance.judged
