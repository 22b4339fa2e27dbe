"""A helper process of the unit that only works beside it (the live balance's judge,
runtime/central/rebalance.py): it takes a CPU only where the unit leaves one idle, and a
Ctrl-C is the run's to handle, which ends it."""

from __future__ import annotations

import os
import signal

NICE = 19
"""The helper's nice value: the lowest priority a process can take, so that on a busy
machine it waits for the unit's processes rather than the other way round."""


def in_background() -> None:
    """Run in the helper process before anything else (a process pool's initializer)."""
    os.nice(NICE)
    signal.signal(signal.SIGINT, signal.SIG_IGN)


__all__ = ["NICE", "in_background"]
