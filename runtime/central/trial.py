"""The admission's trial as the central runs it (runtime/launch/admission.py judges it).

A trial central runs the real pipeline for a few hundred intervals on the plant's trial
samples: on the run's node, with the run's plan and reply mode, a copy of the
controller numbered from the trial's base (far from the run's cycles), and the same watch
over the role processes; its samples and commands are flagged ``probe`` (the plant checks
and drops them). After it, what still arrives of it is drained, its late replies are not
counted as the run's, and the publishers it declared on the shared node are undeclared.
"""

from __future__ import annotations

import copy
from collections.abc import Callable
from typing import Any

from .excuse import Supervision
from .scheduler import Central
from .snapshot import Progress


def trial_central(central: Central, period: float, *, ticks: int, base: int,
                  on_cycle: Callable[[Progress, dict], None] | None = None,
                  on_message: Callable[[str, str, int, Any, bytes, int], None] | None = None
                  ) -> Central:
    """A central for one trial of ``ticks`` intervals at ``period``, numbered from
    ``base``, beside the run's ``central`` (module notes); end it with :func:`end_trial`."""
    trc = central.rc.replace(period=period, t1_cycles=0, record=None, report=None)
    ctl = copy.copy(central.ctl)
    ctl.first_cycle, ctl.q_prev, ctl.k_prev = base, None, base
    return Central(central.node, trc, central.engine, ctl, ticks, trial=True,
                   supervision=Supervision(child_check=central.silence.supervision.child_check),
                   reply_each=central.outgoing.reply_each, on_cycle=on_cycle,
                   on_message=on_message)


def role_exited(central: Central) -> bool:
    """Whether a role process ``central`` watches has exited (a trial's fault is then the
    run's)."""
    child_check = central.silence.supervision.child_check
    return child_check is not None and child_check() is not None


def end_trial(central: Central, probe: Central, *, late_before: int, drain_s: float) -> int:
    """After the trial ``probe``: undeclare its publishers, drop what arrives for
    ``drain_s`` and forget the late replies counted since there were ``late_before`` (the
    trial's, not the run's: they once made the run's summary say 23 late replies for 1
    late round); returns how many those were."""
    central.orders.drain(seconds=drain_s)
    for pub in (*probe.outgoing.publishers, *probe.orders.pubs):
        if pub is not None:
            try:
                pub.undeclare()
            except Exception:  # the session is closing: nothing is left to undeclare
                pass
    rejected = central.node.rejected
    late = rejected["late_reply"] - late_before
    if late_before:
        rejected["late_reply"] = late_before
    else:
        rejected.pop("late_reply", None)
    return late


__all__ = ["end_trial", "role_exited", "trial_central"]
