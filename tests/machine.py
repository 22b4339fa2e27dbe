"""What this machine allows, read by the tests themselves.

Tests that check which scheduling policy or idle-state request a unit chose must not ask
the code under test what to expect (``sched.fifo_permitted()``, ``idle.choose()``): a
wrong probe there would agree with itself. These read the kernel's files and try the
system call directly, with the paths and values written out here.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path


def fifo_permitted() -> bool:
    """Whether a new process may take SCHED_FIFO: tried in a child interpreter."""
    code = ("import os, sys\n"
            "try:\n    os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(1))\n"
            "except OSError:\n    sys.exit(3)\n")
    return subprocess.run([sys.executable, "-c", code], timeout=30).returncode == 0


def rt_throttles() -> float | None:
    """The kernel's real-time budget share, or None where it does not throttle."""
    try:
        runtime = int(Path("/proc/sys/kernel/sched_rt_runtime_us").read_text())
        period = int(Path("/proc/sys/kernel/sched_rt_period_us").read_text())
    except (OSError, ValueError):
        return None
    return runtime / period if runtime >= 0 and period > runtime else None


def auto_takes_fifo() -> bool:
    """``--rt-priority auto`` in realtime takes FIFO where permitted and throttled."""
    return rt_throttles() is not None and fifo_permitted()


def idle_can_poll() -> bool:
    """Whether a realtime unit's idle-state request changes anything here: CPU 0 has an
    enabled idle state with an exit latency above 0 us, and this process may write the
    latency request device."""
    deeper = False
    for state in Path("/sys/devices/system/cpu/cpu0/cpuidle").glob("state*"):
        try:
            latency = int((state / "latency").read_text())
            enabled = (state / "disable").read_text().strip() in ("", "0")
        except (OSError, ValueError):
            continue
        deeper |= latency > 0 and enabled
    return deeper and os.access("/dev/cpu_dma_latency", os.W_OK)
