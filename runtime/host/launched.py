"""``python -m ctrlunit.runtime.host.launched ROLE ...``: a role's process as ``ctrlunit start``
starts it (runtime/roles/supervise.py, ``spawn_role``); then the command line, as ``python
-m ctrlunit.runtime.cli ROLE ...``.

What the process does first, before anything else is imported (numpy's and Zenoh's
threads inherit its CPUs): it takes the CPUs the launcher gave it (:data:`CPUS_ENV`),
leaves the terminal's Ctrl-C and hang-up to the launcher (:data:`LEFT_TO_THE_LAUNCHER`),
and dies with its parent (``PR_SET_PDEATHSIG``; at once if that parent is gone already).

This is done here, not between fork and exec (a ``preexec_fn``): with one, Python forks
the whole launcher, its 60 MB and its threads, to start a role; without one it uses
``vfork``. A peripheral started again during a run stalled the unit 4-12 ms when forked
(docs/measurements/2026-11-29-restart-without-fork.md).

This module imports nothing of ctrlunit's: importing the package would start numpy's
threads before the CPUs are taken.
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import runpy
import signal
import sys

CPUS_ENV = "CTRLUNIT_CPUS"
"""The CPUs the launcher gives the role (``0,1``); unset: those it inherits."""
PARENT_ENV = "CTRLUNIT_PARENT"
"""The launcher's process id: the role ends if its parent is another by the time it
asks the kernel to end it with its parent."""

LEFT_TO_THE_LAUNCHER = (signal.SIGINT, signal.SIGHUP)
"""Signals a role the launcher started ignores. A terminal's Ctrl-C and hang-up reach
every process of the foreground group; a role that ended on them at once left the robot
without its safe stop (the plant gone before the central's stop order came). The launcher
gets them too and stops every role in order (runtime/roles/stopping.py)."""

_PR_SET_PDEATHSIG = 1


def take_place() -> None:
    """The launcher's settings for this process (the module's docstring), from its
    environment, which keeps none of them for the processes this one starts."""
    for s in LEFT_TO_THE_LAUNCHER:
        signal.signal(s, signal.SIG_IGN)
    cpus = os.environ.pop(CPUS_ENV, "")
    if cpus:
        with contextlib.suppress(ValueError, OSError):
            os.sched_setaffinity(0, {int(c) for c in cpus.split(",")})
    parent = os.environ.pop(PARENT_ENV, "")
    with contextlib.suppress(Exception):
        ctypes.CDLL(None, use_errno=True).prctl(_PR_SET_PDEATHSIG, signal.SIGTERM)
    if parent.isdigit() and os.getppid() != int(parent):
        sys.exit("ctrlunit: the launcher ended before this role started")


def main() -> None:
    take_place()
    # then numpy and Zenoh: the command line, as ``python -m ctrlunit.runtime.cli`` runs
    # it (by name: this module is below the command line, which starts the roles)
    runpy.run_module("ctrlunit.runtime.cli", run_name="__main__", alter_sys=True)


if __name__ == "__main__":
    main()
