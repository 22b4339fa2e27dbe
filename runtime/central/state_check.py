"""The robot's state, watched by the central: the observed position must track the
reference within ``--max-error`` and stay in the usable workspace (Eq. V.33); the torques
the plant holds while it stops; and the hint a fault's message carries when the machine
missed most deadlines (docs/faults-and-errors.md)."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

from ...kernels.params import DeltaParams
from ...kernels.workspace import check_point
from ..config import EXIT_OBSERVER
from .fault import Fault

WORKSPACE_EVERY = 10
"""The workspace (Eq. V.33) is checked at every this many cycles."""


def lengths(err: float, limit: float) -> tuple[str, str]:
    """``err`` and ``limit`` (m, ``err > limit``) as a fault's message gives them: in the
    limit's unit (mm, or um under a millimetre), with the decimals that tell them apart
    (at most 3, else every digit)."""
    scale, unit = (1e3, "mm") if limit >= 1e-3 else (1e6, "um")
    for decimals in range(1, 4):
        a, b = f"{err * scale:.{decimals}f}", f"{limit * scale:.{decimals}f}"
        if a != b:
            return f"{a} {unit}", f"{b} {unit}"
    return f"{err * scale!r} {unit}", f"{limit * scale!r} {unit}"


def check_state(cycle: int, p: Sequence[float] | None, pc: Sequence[float] | None, *,
                params: DeltaParams, max_error: float, hint: Callable[[], str] = str
                ) -> None:
    """Raise a :class:`~.fault.Fault` (exit code of the observer) when the estimated
    position ``p`` of ``cycle`` is further than ``max_error`` (m) from the reference
    ``pc``, or, every :data:`WORKSPACE_EVERY` cycles, outside the usable workspace
    (Eq. V.33). ``hint()`` ends the message. Nothing to check where either is None."""
    if p is None or pc is None:
        return
    err = math.dist(p, pc)
    why = None
    if err > max_error:
        why = "tracking error {} exceeds --max-error {}".format(*lengths(err, max_error))
    elif cycle % WORKSPACE_EVERY == 0:
        chk = check_point(params, p)
        if not chk.ok:
            why = f"the robot left the usable workspace: {chk.reason}"
    if why is None:
        return
    raise Fault(f"cycle {cycle}: {why}{hint()}", process="central", code=EXIT_OBSERVER)


def hold_torques(params: DeltaParams, p: Sequence[float]) -> list[float]:
    """Gravity-holding torques at position ``p`` (the first stage of the safe stop);
    zeros if ``p`` is not usable."""
    from ...kernels.dynamics import gravity_torques

    try:
        if check_point(params, p).ok:
            return [float(x) for x in gravity_torques(params, p)]
    except (ValueError, ZeroDivisionError):
        pass
    return [0.0, 0.0, 0.0]


__all__ = ["WORKSPACE_EVERY", "check_state", "hold_torques"]
