"""Carrying out a change of the control rate that :class:`~.overload.Overload` decided:
the controller's grid from a sample far enough ahead, the plant's order, the recording."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

from ..compute.controller import Controller
from .intake import Intake
from .orders import Orders
from .overload import OVERLOAD_LEAD


class RateChange:
    """``rate(stride, why)``: change the control rate from the first sample of the current
    grid at least :data:`~.overload.OVERLOAD_LEAD` periods past the newest one, and order
    the plant to; returns the change's record (``stride``, ``from_cycle``, ``at_interval``
    and ``why``).

    Parameters
    ----------
    ctl : the central's controller now (its grid).
    where : ``(next_cycle, done)``: the next interval to start and the intervals done.
    intake, orders : the central's parts (the newest sample; the plant's order).
    plant_key : the plant's control key, for the recording.
    on_message : the recording's hook, or None.
    """

    def __init__(self, *, ctl: Callable[[], Controller], where: Callable[[], tuple[int, int]],
                 intake: Intake, orders: Orders, plant_key: str,
                 on_message: Callable[..., None] | None) -> None:
        self.ctl = ctl
        self.where = where
        self.intake = intake
        self.orders = orders
        self.plant_key = plant_key
        self.on_message = on_message

    def __call__(self, stride: int, why: dict[str, int]) -> dict[str, Any]:
        ctl = self.ctl()
        next_cycle, done = self.where()
        grid = ctl.grid
        k = grid.next_on_grid(max(next_cycle, self.intake.newest_sample + 1) + OVERLOAD_LEAD)
        grid.change(stride, k)
        change: dict[str, Any] = {"stride": stride, "from_cycle": k - ctl.first_cycle,
                                  "at_interval": done, **why}
        # the plant reads stride and start; the rest is for the recording's report
        payload = self.orders.say("stride", plant_only=True, start=k, **change)
        if self.on_message is not None:  # the recording: replay changes where the run did
            self.on_message("out", self.plant_key, k, "stride", payload, time.monotonic_ns())
        return change


__all__ = ["RateChange"]
