"""The central's flood rule: a peripheral or the plant that keeps sending malformed
messages on its own key is a fault by name.

A role of the unit sends no malformed message: its codec writes what the central's
checks read. A sender that floods its key (1 MB puts on a reply key, issue 56) costs the
central the receiving and the rejecting of each; counted and dropped one by one they once
starved it until the run faulted on its tracking error, naming no one. Past
``transport.reject_limit`` malformed messages within a second the sender is the fault
(exit 3 for a peripheral, 4 for the plant), its message saying what it sent.

Which role sent a message is known by its key only with the unit's keys: then only
peripheral K may publish on its reply key, only the plant on the sample key, and each
role on its own hello key (runtime/transport/security.py). Without keys any process
that reaches the unit's links may publish there (docs/faults-and-errors.md, Security):
a fault would name a role that sent nothing, and let any such process stop the unit
with a few bytes, so there the malformed messages are counted and dropped, as every
other.
"""

from __future__ import annotations

from collections import deque
from typing import Any

from ..config import EXIT_PERIPHERAL, EXIT_PLANT
from ..transport.node import Node
from .fault import Fault, role_of
from .orders import HELLO_ROLES

MALFORMED = frozenset({"too_large", "undecodable", "not_a_map", "schema_version",
                       "foreign_unit", "bad_cycle", "bad_stage", "bad_parts", "bad_value",
                       "bad_vals"})
"""The rejection reasons (runtime/transport/codec.py, runtime/central/intake.py) that
only a malformed message earns. A late, stale or unexpected reply or sample is no flood:
a role of the unit sends those when it or the central was slow."""

WINDOW_NS = 1_000_000_000
"""The span over which malformed messages are counted: one second."""


class FloodWatch:
    """Counts each sender's malformed messages and raises past the bound.

    Parameters
    ----------
    node : the central's node (its :attr:`~.node.Node.rejects` and
        :attr:`~.node.Node.last_reject` say whether and why an event was rejected).
    limit : how many malformed messages a sender may send within :data:`WINDOW_NS`.
    authenticated : whether a key's sender is known (the unit's keys); if not, nothing is
        a fault (module notes).
    """

    def __init__(self, node: Node, *, limit: int, authenticated: bool = True) -> None:
        self.node = node
        self.limit = limit
        self.authenticated = authenticated
        self._times: dict[tuple[str, int], deque[int]] = {}

    @classmethod
    def of(cls, node: Node, transport: Any) -> FloodWatch:
        """The watch of a run's transport settings: its ``reject_limit``, authenticated
        where it has the unit's ``keys``."""
        return cls(node, limit=transport.reject_limit, authenticated=bool(transport.keys))

    def check(self, kind: str, index: int, rx: int, before: int) -> None:
        """After an event of ``kind`` (``reply`` of peripheral ``index``, ``sample``,
        ``hello`` of :data:`~.orders.HELLO_ROLES` ``[index]``)
        received at ``rx`` (monotonic ns) was handled: if it was rejected as malformed
        (the node counted a rejection since ``before``), count it against its sender.

        Raises
        ------
        Fault
            Naming the sender (exit 3 for a peripheral, 4 for the plant) once more than
            ``limit`` of its messages within a second were malformed."""
        node = self.node
        if not self.authenticated or node.rejects == before \
                or node.last_reject.split(":", 1)[0] not in MALFORMED:
            return
        if kind == "reply":
            who, code, where = role_of(index), EXIT_PERIPHERAL, "its reply key"
        elif kind == "sample":
            who, code, where = "plant", EXIT_PLANT, "the sample key"
        elif kind == "hello":
            who, where = HELLO_ROLES[index], "its hello key"
            code = EXIT_PLANT if who == "plant" else EXIT_PERIPHERAL
        else:
            return
        times = self._times.get((kind, index))
        if times is None:
            times = self._times[(kind, index)] = deque(maxlen=self.limit + 1)
        times.append(rx)
        if len(times) > self.limit and rx - times[0] <= WINDOW_NS:
            raise Fault(f"{who} sent {len(times)} malformed messages on {where} within "
                        f"{(rx - times[0]) / 1e9:.2f} s, more than the {self.limit} a second "
                        f"allowed (transport.reject_limit); the last: {node.last_reject}",
                        process=who, code=code)


__all__ = ["MALFORMED", "WINDOW_NS", "FloodWatch"]
