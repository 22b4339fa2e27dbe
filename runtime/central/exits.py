"""The central's exit watch: a role process that this central started and that has
exited is a fault at once, named by its role (docs/faults-and-errors.md), except a
peripheral whose rounds are taken over (:mod:`.takeover`), which is let go."""

from __future__ import annotations

import time

from ..config import EXIT_PERIPHERAL, EXIT_PLANT
from .excuse import UNSUPERVISED, Supervision
from .fault import Fault

CHILD_CHECK_S = 0.05
"""How often the watch asks whether a role process has exited."""


class ExitWatch:
    """Whether a role process has exited, looked at every :data:`CHILD_CHECK_S` at most.

    Parameters
    ----------
    supervision : what the central can learn of the roles' processes (its
        ``child_check``; none: nothing to look at).
    """

    def __init__(self, supervision: Supervision = UNSUPERVISED) -> None:
        self.supervision = supervision
        self.let_go: set[str] = set()
        """Roles whose process's exit is no fault any more (a lost peripheral's)."""
        self._next_check = 0.0

    def wake_at(self, now: int) -> int | None:
        """When the loop must look again, however quiet its inbox, so that an exit is seen
        within :data:`CHILD_CHECK_S` (None: there is nothing to look at)."""
        if self.supervision.child_check is None:
            return None
        return now + int(CHILD_CHECK_S * 1e9)

    def check(self) -> None:
        """Raise the fault of a role process that has exited (at most every
        :data:`CHILD_CHECK_S`)."""
        child_check = self.supervision.child_check
        if child_check is None:
            return
        now = time.monotonic()
        if now < self._next_check:
            return
        self._next_check = now + CHILD_CHECK_S
        dead = child_check(skip=self.let_go)
        if dead is not None:
            name, rc = dead
            code = EXIT_PLANT if name == "plant" else EXIT_PERIPHERAL
            raise Fault(f"{name} exited (status {rc})", process=name, code=code,
                        lost="" if name == "plant" else "exited")


__all__ = ["CHILD_CHECK_S", "ExitWatch"]
