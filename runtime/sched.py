"""The scheduling policy of a role's process: SCHED_FIFO for the unit (``--rt-priority``).

With ``--rt-priority N`` every role of a unit (central, plant, peripherals, and their
Zenoh threads) runs under ``SCHED_FIFO`` at priority N. At equal priority FIFO tasks do
not preempt each other: a woken peripheral waits until the central has sent its request
to all three and blocks, instead of taking its CPU at each wake-up as the default
scheduler's wake-up preemption does, and each process runs its message to completion.
Measured on this 2-core VM (n = 3, depth 2, side by side; README): freerun mean period
-22 to -27 %, CPU per interval -15 %. Roles at a lower FIFO priority than the central,
or under ``SCHED_BATCH``, were slower.

Why it is not the default: when the unit needs more CPU than the machine has (realtime at
1 ms here), the kernel's real-time throttling (``/proc/sys/kernel/sched_rt_runtime_us``,
95 % of each second) freezes every FIFO task for up to 50 ms a second: 33-35 ms periods
were measured, where the default policy's longest was 4 ms. Use it at a period the
machine sustains, or in freerun.

``0`` (the default) leaves the policy as it is (the default policy, unless the unit was
started under another, e.g. with ``chrt``); 1-99 needs root, CAP_SYS_NICE or
``ulimit -r`` (an error names them otherwise). Roles started by ``ctrlunit start``
inherit the launcher's policy; the report names each role's.
"""

from __future__ import annotations

import contextlib
import os
import subprocess
import sys

MAX_PRIORITY = 99


class RtPermissionError(PermissionError):
    """SCHED_FIFO was asked for with ``--rt-priority N`` and this process may not use it."""


def _threads() -> list[int]:
    try:
        return [int(t) for t in os.listdir("/proc/self/task")]
    except OSError:
        return [0]


def _set_all(policy: int, priority: int) -> None:
    """``policy`` for every thread of this process (``sched_setscheduler`` acts on one
    thread); the threads started later inherit their creator's."""
    param = os.sched_param(priority)
    os.sched_setscheduler(0, policy, param)  # this thread first: it raises if refused
    for tid in _threads():
        with contextlib.suppress(ProcessLookupError, PermissionError):
            os.sched_setscheduler(tid, policy, param)


def fifo_permitted() -> bool:
    """Whether a process started like this one may use SCHED_FIFO (tried in a child
    interpreter, so that this process's policy is left alone)."""
    code = ("import os\ntry:\n os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(1))"
            "\nexcept PermissionError:\n raise SystemExit(1)")
    return subprocess.run([sys.executable, "-c", code], timeout=30).returncode == 0


def policy_name(tid: int = 0) -> str:
    """``"SCHED_FIFO 10"``, ``"SCHED_OTHER"``, ... for thread ``tid`` (0: this one)."""
    policy = os.sched_getscheduler(tid)
    names = {os.SCHED_OTHER: "SCHED_OTHER", os.SCHED_FIFO: "SCHED_FIFO",
             os.SCHED_RR: "SCHED_RR", os.SCHED_BATCH: "SCHED_BATCH",
             os.SCHED_IDLE: "SCHED_IDLE"}
    name = names.get(policy, f"policy {policy}")
    if policy in (os.SCHED_FIFO, os.SCHED_RR):
        return f"{name} {os.sched_getparam(tid).sched_priority}"
    return name


def check_priority(priority: int) -> None:
    """0 to 99, else a ``ValueError`` naming the option and the range."""
    if isinstance(priority, bool) or not isinstance(priority, int) or not (
            0 <= priority <= MAX_PRIORITY):
        raise ValueError(f"--rt-priority = {priority!r}: allowed 0 (leave the policy as it is) to "
                         f"{MAX_PRIORITY} (SCHED_FIFO priority)")


def apply_rt(priority: int) -> str:
    """Put this process (every thread, and the threads and processes it starts later)
    under SCHED_FIFO at ``priority``; 0 leaves its policy as it is.

    Returns
    -------
    The policy now in force (:func:`policy_name`).

    Raises
    ------
    ValueError
        ``priority`` outside 0-99.
    RtPermissionError
        ``priority`` 1-99 and this process may not use SCHED_FIFO.
    """
    check_priority(priority)
    if priority == 0:
        return policy_name()
    try:
        _set_all(os.SCHED_FIFO, priority)
    except PermissionError:
        raise RtPermissionError(
            f"--rt-priority {priority}: this process may not use SCHED_FIFO (run as root, "
            "grant CAP_SYS_NICE, or raise the real-time limit with ulimit -r); "
            "--rt-priority 0 runs at the default policy") from None
    return policy_name()


def current() -> tuple[int, int]:
    """This thread's ``(policy, priority)``, for :func:`restore`."""
    return os.sched_getscheduler(0), os.sched_getparam(0).sched_priority


def restore(saved: tuple[int, int]) -> None:
    """Every thread of this process back to ``saved`` (after a unit ran inside a
    longer-lived process, such as ``ctrlunit bench``: Zenoh's threads outlive a session)."""
    if current() != saved or any(_policy(t) != saved[0] for t in _threads()):
        with contextlib.suppress(PermissionError):
            _set_all(*saved)


def _policy(tid: int) -> int | None:
    try:
        return os.sched_getscheduler(tid)
    except OSError:
        return None
