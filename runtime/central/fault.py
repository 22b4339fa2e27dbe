"""What ends a run: a detected :class:`Fault`, naming the failed process and its exit
code (docs/faults-and-errors.md), and the check of a role's final report."""

from __future__ import annotations

from typing import Any


class Fault(RuntimeError):
    """A detected fault: ``process`` names the failed process, ``code`` the exit code."""

    def __init__(self, message: str, *, process: str, code: int) -> None:
        super().__init__(message)
        self.process = process
        self.code = code


ROLE_REPORT_FIELDS: dict[str, tuple[type, ...]] = {
    "exit": (str,), "sched": (str,), "served": (int,), "samples": (int,), "misses": (int,),
    "busy_ns": (int,), "wall_ns": (int,), "cpu_s": (int, float), "rejected": (dict,),
    "rss_kb": (dict,), "safe_stop": (dict,), "commands": (int,), "spares": (int,),
}
"""What a role's ``bye`` report may hold, by field; anything else is left out."""


def role_report(report: dict[str, Any]) -> dict[str, Any]:
    """The fields of a role's final report that have the type the report reader expects
    (:data:`ROLE_REPORT_FIELDS`; ``rejected`` keeps only counts by text reason), so that
    a malformed or forged ``bye`` cannot break the run's report."""
    out: dict[str, Any] = {}
    for name, types in ROLE_REPORT_FIELDS.items():
        v = report.get(name)
        if isinstance(v, bool) or not isinstance(v, types):
            continue
        if name == "rejected" and isinstance(v, dict):
            v = {k: n for k, n in v.items() if isinstance(k, str) and type(n) is int}
        out[name] = v
    return out


__all__ = ["ROLE_REPORT_FIELDS", "Fault", "role_report"]
