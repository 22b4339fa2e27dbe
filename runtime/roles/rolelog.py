"""What a role writes to its log (its standard error: ``ctrlunit start`` sends it to the
run directory's ``ROLE.log``, kept with the run's spec when the run fails): a timestamped
line when it connects, when the central's go comes, and at its end its final report, so
that a kept folder says what each role saw even when nothing went wrong in it."""

from __future__ import annotations

import json
import os
import sys
import time
from typing import Any


def role_log(role: str, text: str) -> None:
    """One line ``<UTC time> ctrlunit <role>[<pid>]: <text>`` on standard error, flushed
    (a role killed next keeps what it wrote)."""
    now = time.time()
    stamp = time.strftime("%Y-%m-%dT%H:%M:%S", time.gmtime(now)) + f".{int(now % 1 * 1e3):03d}Z"
    print(f"{stamp} ctrlunit {role}[{os.getpid()}]: {text}", file=sys.stderr, flush=True)


def role_log_end(role: str, report: dict[str, Any]) -> None:
    """The role's final report (what it sends the central as its last word), as JSON."""
    role_log(role, f"ended ({report.get('exit')}): "
             + json.dumps(report, default=str, separators=(",", ":")))


__all__ = ["role_log", "role_log_end"]
