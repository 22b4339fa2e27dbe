"""The exchange plan: the stage graph cut into central steps and scatter/gather rounds.

Derived from a :class:`~ctrlunit.topology.graph.StageGraph` and a
:class:`~ctrlunit.topology.placement.Placement`. Consecutive per-axis blocks that run on
the peripherals are fused into one round (one request and one reply per peripheral, all
its axes and blocks in it), and a central block that needs none of a round's outputs is
hoisted before the round, so that the plan has as few round trips as the data flow allows.
The request carries exactly the central values the round's blocks need that the peripheral
does not hold yet; the reply carries exactly the per-axis values that later central work
needs.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from .graph import AXIS, MEASURED, Block, StageGraph
from .placement import Placement


@dataclass
class Round:
    """One scatter/gather round.

    Attributes
    ----------
    index : 0-based round number within the interval (the message ``stage``).
    blocks : per-axis blocks the peripherals run, in order.
    send : values in the request (central values whole, per-axis values for owned axes).
    recv : per-axis values in the reply.
    """

    index: int
    blocks: list[Block] = field(default_factory=list)
    send: list[str] = field(default_factory=list)
    recv: list[str] = field(default_factory=list)


@dataclass
class Step:
    """A plan step: a central block, a per-axis block run on the central, or a round."""

    kind: str  # "central" | "local_axis" | "round"
    block: Block | None = None
    round: Round | None = None


@dataclass
class ExchangePlan:
    """The ordered steps of one interval and its rounds."""

    graph: StageGraph
    placement: Placement
    steps: list[Step]

    @property
    def rounds(self) -> list[Round]:
        return [s.round for s in self.steps if s.round is not None]

    @property
    def presample_steps(self) -> int:
        """How many leading steps run without the sample: they need neither the measured
        sources (:data:`~ctrlunit.topology.graph.MEASURED`) nor anything made from them.
        At depth 2 an interval runs them as soon as the previous interval has handed off,
        before its sample is here: central steps (the reference and the observer's
        prediction, for resolved acceleration) and, where the graph runs ahead
        (:attr:`~ctrlunit.topology.graph.StageGraph.runs_ahead`), the rounds among them
        (:attr:`ahead_rounds`)."""
        tainted = needs_sample(self.graph)
        count = 0
        for s in self.steps:
            blocks = s.round.blocks if s.round is not None else [s.block]
            if any(b is None or b.name in tainted for b in blocks):
                break
            if s.round is not None and not self.graph.runs_ahead:
                break
            count += 1
        return count

    @property
    def ahead_rounds(self) -> int:
        """How many rounds lie among the :attr:`presample_steps`: rounds that need no
        sample, sent at depth 2 before it arrives (off the path from sample to command)."""
        return sum(1 for s in self.steps[:self.presample_steps] if s.round is not None)

    def middle_blocks(self, *, ahead: bool) -> list[str]:
        """The central's blocks from the end of one round to the send of the next interval's
        first round: every central step before the last round, less the sample-free ones
        when they run ahead (depth 2)."""
        last = max((k for k, st in enumerate(self.steps) if st.round is not None), default=-1)
        first = self.presample_steps if ahead else 0
        return [st.block.name for st in self.steps[first:last] if st.block is not None]

    @property
    def round_trips(self) -> int:
        """Round trips per interval (each is one request and one reply per peripheral)."""
        return len(self.rounds)

    def describe(self) -> str:
        lines = []
        ahead = self.ahead_rounds
        for s in self.steps:
            if s.kind == "round":
                r = s.round
                assert r is not None
                lines.append(
                    f"round {r.index}{' (needs no sample)' if r.index < ahead else ''}: "
                    f"send {', '.join(r.send)} -> run "
                    f"{', '.join(b.name for b in r.blocks)} -> recv {', '.join(r.recv)}"
                )
            else:
                assert s.block is not None
                where = "central" if s.kind == "central" else "central (all axes)"
                lines.append(f"{where}: {s.block.name}")
        return "\n".join(lines)


def needs_sample(graph: StageGraph) -> set[str]:
    """Names of the blocks that need the sample: those with a measured source
    (:data:`~ctrlunit.topology.graph.MEASURED`) or a value made from one among their
    inputs. Where the graph's sample-free steps run two intervals ahead
    (:attr:`~ctrlunit.topology.graph.StageGraph.foresight`), the previous interval's
    estimate ``est`` counts as the sample's: it is final only once that interval has
    handed off, which is after those steps ran."""
    tainted_vals = set(MEASURED) | ({"est"} if graph.foresight > 1 else set())
    out: set[str] = set()
    for b in graph.blocks:  # a topological order
        if any(v in tainted_vals for v in b.inputs):
            out.add(b.name)
            tainted_vals.update(b.outputs)
    return out


def _remote(block: Block, placement: Placement) -> bool:
    return block.kind == AXIS and placement.peripherals > 0 and (
        block.name not in placement.central_blocks
    )


def exchange_plan(graph: StageGraph, placement: Placement) -> ExchangePlan:
    """Cut ``graph`` into central steps and rounds for ``placement``."""
    # 1. Reorder: hoist central/local blocks over remote blocks they do not depend on, so
    #    that remote blocks group into as few runs as possible (a stable list scheduling).
    #    Where the graph runs ahead, blocks that need no sample go first, so that they
    #    form rounds of their own before the sample's.
    ahead = graph.runs_ahead
    tainted = needs_sample(graph) if ahead else set()
    pending = list(graph.blocks)
    produced_by = {o: b for b in graph.blocks for o in b.outputs}
    done: set[str] = set()
    order: list[Block] = []
    while pending:
        ready = [b for b in pending if all(
            v in graph.sources or produced_by[v].name in done for v in b.inputs)]
        if ahead:
            ready.sort(key=lambda b: b.name in tainted)  # stable: graph order otherwise
        # prefer continuing the current kind (remote run or central run), else the first
        cur_remote = bool(order) and _remote(order[-1], placement)
        pick = next((b for b in ready if _remote(b, placement) == cur_remote), ready[0])
        # but never start a remote run while a central block is ready (hoist central work)
        if _remote(pick, placement):
            central_ready = [b for b in ready if not _remote(b, placement)]
            if central_ready and not cur_remote:
                pick = central_ready[0]
        order.append(pick)
        done.add(pick.name)
        pending.remove(pick)

    # 2. Group consecutive remote blocks into rounds.
    steps: list[Step] = []
    for b in order:
        if _remote(b, placement):
            last = steps[-1].round if steps else None  # a step is a round or has none
            if last is None or (b.name in tainted
                                and not any(x.name in tainted for x in last.blocks)):
                last = Round(index=0)
                steps.append(Step("round", round=last))
            last.blocks.append(b)
        else:
            steps.append(Step("central" if b.kind != AXIS else "local_axis", block=b))
    for k, r in enumerate(s.round for s in steps if s.round is not None):
        r.index = k

    # 3. Values to send and to return.
    on_periph: set[str] = set()  # values the peripherals already hold this interval
    for idx, s in enumerate(steps):
        if s.round is None:
            continue
        r = s.round
        made_here: set[str] = set()
        for b in r.blocks:
            for v in b.inputs:
                if v not in made_here and v not in on_periph and v not in r.send:
                    r.send.append(v)
            made_here.update(b.outputs)
        on_periph.update(r.send)
        on_periph.update(made_here)
        later_needs: set[str] = set()
        for s2 in steps[idx + 1:]:
            blocks: list[Block | None] = (list(s2.round.blocks) if s2.round is not None
                                          else [s2.block])
            for blk in blocks:
                if blk is not None and not (s2.round is not None):
                    later_needs.update(blk.inputs)
        r.recv = [v for b in r.blocks for v in b.outputs if v in later_needs]
    # per-axis values produced remotely but needed by a later *remote* round are already on
    # the peripheral; per-axis values computed on the central and needed remotely are sent.
    return ExchangePlan(graph, placement, steps)
