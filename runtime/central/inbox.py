"""What comes in to the central: the keys routed to its inbox, and each event taken from
it (a reply, a sample, a message on the hello key), a malformed one counted against its
sender (:class:`~.flood.FloodWatch`)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from ..transport.node import Event, Node
from .flood import FloodWatch
from .intake import Intake
from .intervals import Intervals
from .meters import Meters
from .records import CycleLog
from .replies import Replies
from .settings import LoopSettings
from .silence import SilenceWatch


class Inbox:
    """The central's inbox.

    Parameters
    ----------
    node, settings : the central's node (the keys are routed here) and settings.
    intervals : the pipeline (the next interval's cycle, the plan, the controller).
    replies : takes each reply (:meth:`Replies.take`).
    intake, flood : decode and check what comes; count what is malformed, by sender.
    silence, log, meters : told of each sample (when the plant spoke, its tracking error,
        its span and misses).
    on_hello : takes a message on the hello key (:meth:`Orders.on_hello`).
    on_message : the recording's hook, or None.
    """

    def __init__(self, node: Node, settings: LoopSettings, *, intervals: Intervals,
                 replies: Replies, intake: Intake, flood: FloodWatch, silence: SilenceWatch,
                 log: CycleLog, meters: Meters, on_hello: Callable[[Event], None],
                 on_message: Callable[..., Any] | None = None) -> None:
        keys = node.keys
        for k in range(settings.peripherals):
            node.route(keys.reply(k + 1), "reply", k)
        if settings.plant:
            node.route(keys.sample, "sample")
        self.node = node
        self.settings = settings
        self.intervals = intervals
        self.replies = replies
        self.intake = intake
        self.flood = flood
        self.silence = silence
        self.log = log
        self.meters = meters
        self.on_hello = on_hello
        self.on_message = on_message

    def handle(self, ev: Event) -> None:
        """Take one event: a reply, a sample, or a message on the hello key; a malformed
        one counts against its sender (raises :class:`~.fault.Fault` past its bound)."""
        kind, index, data, rx = ev
        before = self.node.rejects
        if kind == "reply":
            self.replies.take(index, data, rx)
        elif kind == "sample":
            self.sample(data, rx)
        elif kind == "hello":
            self.on_hello(ev)
        else:
            self.intake.reject("unexpected_key")
        self.flood.check(kind, index, rx, before)

    def sample(self, data: bytes, rx: int) -> None:
        """Take a plant sample received at ``rx``: into the intake, the silence watch and
        the log (with the reference at its time: the run's tracking error)."""
        iv, end = self.intervals, self.settings.end
        s = self.intake.sample(data, first=iv.next_cycle, end=end + self.settings.depth + 1,
                               on_grid=iv.ctl.on_grid)
        if s is None:
            return
        self.silence.heard_sample(rx)
        # the tracking error of the run's samples only: the plant may send one more
        self.log.sampled(s.cycle, s.p, iv.engine.cfg.task.position(  # type: ignore[union-attr]
            iv.ctl.time_of(s.cycle)) if s.cycle < end else None)
        self.meters.plant_sample(s.cycle, s.span, s.misses)
        if self.on_message is not None:
            self.on_message("in", self.node.keys.sample, s.cycle, "sample", data, rx)


__all__ = ["Inbox"]
