"""Idle CPUs that poll instead of halting during a realtime run (``--idle``).

Between two periods every process of the unit sleeps, and an idle CPU enters the deepest
idle state its cpuidle driver offers. In a virtual machine that state halts the virtual
CPU: the hypervisor takes the CPU back, and each wake-up (a timer, a Zenoh message) first
has to have it scheduled again. Every role wakes several times a period, so the unit
pays that exit and return on each message. The kernel's CPU latency request
(``/dev/cpu_dma_latency``, "PM QoS"), held open at 0 us, keeps every CPU in the polling
state instead: an idle CPU spins until there is work. It is what cyclictest does by
default and what LinuxCNC's ``idle=poll`` advice achieves for a whole boot; here it lasts
exactly as long as the file is held open, that is the run.

Measured on the reference VM (docs/measurements/2026-11-25-realtime.md, side by side):
timer wake-up p50 78 -> 30-45 us, p99 0.6-1.0 ms -> 0.08-0.10 ms; the main job at 2 ms
under the default policy 9-13 % less CPU per interval (medians of 5 and 6 pairs) and a
quarter to a third of the late commands. The cost: while a run holds the request, idle
CPUs spin (the host sees them busy). The kernel counts polling as idle time, so the
throttling guard (runtime/host/sched.py, ``cpu_times``) reads the unit's own load as before.

``auto`` (the default) holds the request in the realtime clock where it changes
something (an idle state deeper than polling exists) and this process may write the file
(root); ``poll`` holds it or fails with an error naming the file; ``default`` leaves the
CPUs' idle states alone. Lockstep and freerun runs have no wall-clock deadline and leave
it alone under ``auto``.
"""

from __future__ import annotations

import contextlib
import os
import struct
from collections.abc import Iterator
from pathlib import Path
from typing import Any

CPU_LATENCY_DEV = Path("/dev/cpu_dma_latency")
"""The kernel's CPU latency request: an int32 in microseconds, held while the file is
open (the lowest of all open requests wins)."""

CPUIDLE_DIR = Path("/sys/devices/system/cpu/cpu0/cpuidle")
"""CPU 0's idle states (``state0`` ... with ``name``, ``latency`` in us, ``disable``)."""

IDLE_CHOICES = ("auto", "poll", "default")


class IdlePermissionError(PermissionError):
    """``--idle poll`` was asked and the CPU latency request cannot be made here."""


def check_idle(asked: str) -> None:
    """``auto``, ``poll`` or ``default``, else a ``ValueError`` naming the option."""
    if asked not in IDLE_CHOICES:
        raise ValueError(f"--idle = {asked!r}: allowed auto (poll in realtime where "
                         "permitted), poll or default")


def deeper_states(cpuidle: Path | None = None) -> list[str]:
    """The names of the enabled idle states with an exit latency above 0 us (those a
    latency request of 0 keeps the CPUs out of); ``[]`` where there is no cpuidle driver
    (the CPU then halts in the architecture's default idle, which no request changes)."""
    names = []
    for state in sorted((cpuidle or CPUIDLE_DIR).glob("state[0-9]*")):
        try:
            latency = int((state / "latency").read_text())
            disabled = (state / "disable").read_text().strip() not in ("", "0")
            name = (state / "name").read_text().strip()
        except (OSError, ValueError):
            continue
        if latency > 0 and not disabled:
            names.append(name)
    return names


def choose(asked: str, *, clock: str, dev: Path | None = None,
           cpuidle: Path | None = None) -> tuple[bool, str]:
    """Whether to hold the request for ``--idle asked`` in ``clock``, and why (for
    ``auto``; a plain phrase for the others). ``dev`` and ``cpuidle`` default to
    :data:`CPU_LATENCY_DEV` and :data:`CPUIDLE_DIR`."""
    check_idle(asked)
    dev = dev or CPU_LATENCY_DEV
    if asked == "default":
        return False, "asked: the CPUs' idle states left as they are"
    if asked == "poll":
        return True, "asked"
    if clock != "realtime":
        return False, f"the {clock} clock has no wall-clock deadline"
    deeper = deeper_states(cpuidle)
    if not deeper:
        return False, ("no idle state deeper than polling (no cpuidle driver): a latency "
                       "request would change nothing")
    if not os.access(dev, os.W_OK):
        return False, f"this process may not write {dev} (root)"
    return True, (f"the realtime clock: idle CPUs poll instead of entering "
                  f"{', '.join(deeper)}")


@contextlib.contextmanager
def idle_request(asked: str, *, clock: str, dev: Path | None = None,
                 cpuidle: Path | None = None) -> Iterator[dict[str, Any]]:
    """Hold the CPU latency request at 0 us for the ``with`` block where :func:`choose`
    says so; yields the report's ``idle``: ``{asked, in_force ("poll" or "default"),
    why}``. The request ends when the block does, however it ends (the kernel also drops
    it if the process dies).

    Raises
    ------
    IdlePermissionError
        ``asked`` is ``poll`` and ``dev`` cannot be opened for writing.
    """
    hold, why = choose(asked, clock=clock, dev=dev, cpuidle=cpuidle)
    dev = dev or CPU_LATENCY_DEV
    fd = None
    if hold:
        try:
            fd = os.open(dev, os.O_WRONLY)
            os.write(fd, struct.pack("=i", 0))
        except OSError as exc:
            if fd is not None:
                os.close(fd)
            fd = None
            if asked == "poll":
                raise IdlePermissionError(
                    f"--idle poll: {dev} cannot be written ({exc.strerror}); it needs root, "
                    "or use --idle default") from None
            why = f"{dev} could not be written ({exc.strerror})"
    try:
        yield {"asked": asked, "in_force": "poll" if fd is not None else "default",
               "why": why}
    finally:
        if fd is not None:
            os.close(fd)


__all__ = [
    "CPUIDLE_DIR",
    "CPU_LATENCY_DEV",
    "IDLE_CHOICES",
    "IdlePermissionError",
    "check_idle",
    "choose",
    "deeper_states",
    "idle_request",
]
