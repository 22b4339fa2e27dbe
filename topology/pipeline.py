"""The rules of the two-stage interleaved pipeline (§ IV.7.2, Fig. 24), as pure functions.

The central's scheduler (:class:`ctrlunit.runtime.central.Central`) and the schedule model
that ``ctrlunit balance`` calibrates (:mod:`ctrlunit.topology.schedule`) both decide by
these functions, so that the model cannot drift from what the unit does. Each rule takes
the few facts it needs as plain values (no clock, no message):

- **hand-off** (:func:`handoff_step`): the plan step after which an interval's estimate
  ``p, pdot, pddot`` is final, so that the next interval may start from it;
- **start** (:func:`may_start`): up to ``depth`` intervals in flight, and the newest has
  handed off;
- **run ahead** (:func:`may_prime`): at depth 2 the next interval's sample-free steps run
  as soon as the newest interval has handed off;
- **hold** (:func:`holds_lone_round`, :func:`hold_rule`): at depth 2 a lone round of an
  interval past its hand-off waits to travel with the next interval's first round (one
  exchange for two rounds), except in realtime by default;
- **finish late** (:func:`finishes_after_next_request`): at depth 2 an interval whose last
  round came back finishes after the next request is out;
- **replies** (:func:`reply_mode`): ``each`` (a reply per round, first rounds first) when
  the central's work between two rounds exceeds a round trip, else ``fused``.
"""

from __future__ import annotations

from collections.abc import Iterable

from .plan import ExchangePlan

EST_NAMES = ("p", "pd", "pdd")
"""The observer's estimate: the values the next interval starts from."""


def handoff_step(plan: ExchangePlan) -> int:
    """Index of the plan step after which the next interval may start: the step that
    produces the last of :data:`EST_NAMES` (-1 if none does)."""
    last = -1
    for k, step in enumerate(plan.steps):
        blocks = step.round.blocks if step.round is not None else [step.block]
        for b in blocks:
            if b is not None and any(o in EST_NAMES for o in b.outputs):
                last = k
    return last


def may_start(*, depth: int, live: int, next_cycle: int, cycles: int,
              newest_handed_off: bool | None) -> bool:
    """Whether interval ``next_cycle`` may start (its sample aside).

    Parameters
    ----------
    depth : pipeline depth (1 or 2).
    live : intervals in flight that are not finishing.
    next_cycle, cycles : the interval to start and how many the run has.
    newest_handed_off : whether the newest interval in flight has handed off its
        estimate; None when nothing is in flight.
    """
    if live >= depth or next_cycle >= cycles:
        return False
    return newest_handed_off is None or newest_handed_off


def may_prime(*, depth: int, primed: bool, next_cycle: int, cycles: int,
              newest_handed_off: bool | None) -> bool:
    """Whether the next interval's sample-free steps may run now (depth 2 only, once per
    interval, after the newest interval in flight has handed off)."""
    if depth < 2 or primed or next_cycle >= cycles:
        return False
    return newest_handed_off is None or newest_handed_off


def prime_cycles(*, next_cycle: int, cycles: int, foresight: int, next_is_one: bool,
                 after_on_grid: bool) -> list[int]:
    """The intervals whose sample-free steps run ahead (:func:`may_prime`): the next one,
    and, where the sample-free steps read the estimate of two intervals back (``foresight``
    2) and the next interval after it comes a period later (``next_is_one``: it holds for
    one period; ``after_on_grid``: its successor is on the control rate's grid), that one
    too: its estimate two back is final already, and both intervals' rounds go in one
    request (one exchange per two intervals)."""
    if foresight > 1 and next_is_one and next_cycle + 1 < cycles and after_on_grid:
        return [next_cycle, next_cycle + 1]
    return [next_cycle]


HOLD_RULES = ("auto", "always", "never")
"""``--hold-rounds``: whether a lone round ready early waits to be fused with the next
interval's first round (``always``: one exchange per interval instead of two), or goes at
once (``never``); ``auto`` (:func:`hold_rule`): never in realtime, always otherwise."""


def hold_rule(asked: str, *, clock: str) -> bool:
    """Whether lone rounds are held (:func:`holds_lone_round`) for ``--hold-rounds asked``.

    ``auto`` holds them except in realtime. Holding trades latency for throughput: it saves
    an exchange per interval, but in realtime the next interval's first round exists only
    once its sample has come, a period later, so a held round puts up to a period into
    its interval's traversal, whose budget is the command delay (``depth`` periods). In
    freerun the next interval is ready at once and holding only saves; in lockstep the
    commands are the same either way. Side by side (2-core machine, n = 3, depth 2,
    admission trials from 1 ms up, docs/measurements/2026-11-23-realtime.md), holding
    held no period up to 3.2 ms, not holding held 2-3.2 ms."""
    if asked not in HOLD_RULES:
        raise ValueError(f"hold rule {asked!r}: expected one of {', '.join(HOLD_RULES)}")
    if asked == "auto":
        return clock != "realtime"
    return asked == "always"


def holds_lone_round(*, depth: int, ready: int, handed_off: bool, cycle: int,
                     next_cycle: int, cycles: int, hold: bool = True) -> bool:
    """Whether the one round ready to send (of interval ``cycle``) waits for the next
    interval's first round, so that both travel in one exchange: at depth 2, when lone
    rounds are held at all (``hold``, :func:`hold_rule`), the round's interval has handed
    off and the next interval is the one right after it."""
    return (hold and depth >= 2 and ready == 1 and handed_off and next_cycle == cycle + 1
            and next_cycle < cycles)


def finishes_after_next_request(*, depth: int, round_index: int, last_round: int) -> bool:
    """Whether an interval whose round ``round_index`` just came back finishes only after
    the next request is out (depth 2, its last round): its last central steps, command and
    logs then overlap the peripherals' work."""
    return depth > 1 and round_index == last_round


def reply_order(rounds: Iterable[int], *, each: bool) -> list[int]:
    """The order in which a peripheral computes the parts of a request: first rounds
    first when it answers each part at once, else as sent."""
    rounds = list(rounds)
    return sorted(range(len(rounds)), key=lambda i: rounds[i]) if each else list(
        range(len(rounds)))


def reply_mode(asked: str, *, depth: int, peripherals: int, between_s: float,
               round_trip_s: float) -> tuple[str, str]:
    """How peripherals answer fused requests (``--replies``): ``(mode, why)``.

    ``auto`` takes ``each`` when the central's work between two rounds (``between_s``)
    exceeds a round trip: the overlap then gains more than the extra reply costs."""
    if depth < 2 or peripherals == 0:
        return "fused", "one interval per exchange"
    if asked == "auto":
        mode = "each" if between_s > round_trip_s else "fused"
        return mode, "each if the central's work between two rounds exceeds a round trip"
    return asked, "asked"
