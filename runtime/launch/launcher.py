"""``ctrlunit start``: plant, central and peripherals on this host.

The launcher runs the central in its own process and starts the plant and the peripherals
as children (:mod:`..roles.supervise`; each role's entry point is in its own module). Every
child dies with the launcher (``PR_SET_PDEATHSIG``), exits on the central's ``stop``, and
has a watchdog on the central's silence; on completion, Ctrl-C or any failure the
launcher says stop, waits briefly, then terminates and kills what is left. SIGTERM (``kill``,
``timeout``, a service manager) and SIGHUP (the terminal closed) end a run as Ctrl-C does:
the robot stopped safely, the report written, the recording closed.
"""

from __future__ import annotations

import contextlib
import math
import os
import re
from typing import Any

from ..config import EXIT_CONFIG, EXIT_UNSUSTAINABLE, RunConfig
from ..host import sched
from ..host.idle import IdlePermissionError, idle_request
from ..roles.stopping import stop_of, stop_signals
from .admission import LADDER_S
from .run_parts import listen_ports
from .unit_start import UnitStart


def central_only(rc: RunConfig) -> tuple[int, dict]:
    """Run the central alone (the other roles are started by hand)."""
    return start(rc, spawn=False)


def start(rc: RunConfig, *, echo: Any = print, progress: Any = None, spawn: bool = True,
          inspect: dict | None = None) -> tuple[int, dict]:
    """Run a whole unit on this host; returns ``(exit code, report)``. ``inspect``, if
    given, receives the central (spans, logs) for benchmarks. This process's scheduling
    policy is what it was before when it returns (see :mod:`..host.sched`). SIGTERM and SIGHUP
    end the run as Ctrl-C does (:func:`stop_of`)."""
    with stop_signals():
        return _starts(listen_ports(rc), echo=echo, progress=progress, spawn=spawn,
                       inspect=inspect)


def _quieter(echo: Any, said: set[str]) -> Any:
    """``echo`` for the starts: the placement's choice is said once while it stays the
    same decision (its figures aside), again where a later start decides otherwise."""
    def say(line: Any, *a: Any, **k: Any) -> None:
        text = str(line)
        if text.startswith("ctrlunit: --placement auto:"):
            decision = re.sub(r"[\d.]+ us", "N us", text)
            if decision in said:
                return
            said.add(decision)
        echo(line, *a, **k)
    return say


def _starts(rc: RunConfig, *, echo: Any, progress: Any, spawn: bool,
            inspect: dict | None) -> tuple[int, dict]:
    """:func:`start`'s starts (:class:`~.unit_start.UnitStart`): under ``--period auto``
    a start refused at one period starts again at the period its trial held, up the
    admission's ladder."""
    saved = sched.current()
    tried: list[dict] = []
    view: list[Any] = []  # the live view, kept across starts (its viewers stay connected)
    affinity = os.sched_getaffinity(0)  # a start pins this process (--cpus, --pin)
    idle_hold = contextlib.ExitStack()  # --idle: held over every start, the trials among them
    try:
        try:
            idle_choice = idle_hold.enter_context(idle_request(rc.schedule.idle,
                                                          clock=rc.schedule.clock))
        except (ValueError, IdlePermissionError) as exc:
            return EXIT_CONFIG, {"fault": {"process": "configuration", "message": str(exc),
                                           "code": EXIT_CONFIG}}
        quiet = _quieter(echo, set())
        # --period auto: the first start may go down the ladder, each start climbs it
        for attempt in range(len(LADDER_S)):
            sched.pin_all(affinity)  # each start chooses the roles' CPUs afresh
            code, report = UnitStart(rc, echo=quiet, progress=progress, spawn=spawn,
                                     inspect=inspect, view=view, idle=idle_choice)(
                descend=attempt == 0, tried=tried)
            adm = report.get("admission") or {}
            tried = list(adm.get("rungs") or tried)  # every start's trials so far
            held = adm.get("sustainable_period_s")
            if not (code == EXIT_UNSUSTAINABLE and rc.schedule.period_auto and held
                    and not math.isclose(held, rc.schedule.period)
                    and not rc.schedule.trial_only):
                break
            asked = f"{rc.schedule.period * 1e3:g} ms" + (
                ", held in the last start's trial," if attempt else "")
            echo(f"ctrlunit: --period auto: {asked} was held in this start's trial, and so "
                 f"was {held * 1e3:g} ms; starting again at {held * 1e3:g} ms"
                 if held < rc.schedule.period else
                 f"ctrlunit: --period auto: {asked} was not held in this start's trial, "
                 f"{held * 1e3:g} ms was; starting again at {held * 1e3:g} ms")
            rc = rc.replace(period=held)
        return code, report
    except KeyboardInterrupt as exc:  # between two starts: no role is running
        code, fault = stop_of(exc)
        return code, {"fault": fault}
    finally:
        for v in view:
            v.close()
        idle_hold.close()
        sched.pin_all(affinity)
        sched.restore(saved)


__all__ = ["central_only", "start"]
