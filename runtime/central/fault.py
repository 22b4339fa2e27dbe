"""What ends a run: a detected :class:`Fault`, naming the failed process and its exit
code (docs/faults-and-errors.md), and the check of a role's final report."""

from __future__ import annotations

from typing import Any

from ..config import EXIT_PLANT


class Fault(RuntimeError):
    """A detected fault: ``process`` names the failed process, ``code`` the exit code;
    ``lost``: how the process was lost, ``exited`` or ``silent`` (a peripheral's rounds
    can then be taken over: runtime/central/takeover.py), else empty."""

    def __init__(self, message: str, *, process: str, code: int, lost: str = "") -> None:
        super().__init__(message)
        self.process = process
        self.code = code
        self.lost = lost


ROLE_REPORT_FIELDS: dict[str, tuple[type, ...]] = {
    "exit": (str,), "sched": (str,), "served": (int,), "samples": (int,), "misses": (int,),
    "busy_ns": (int,), "wall_ns": (int,), "cpu_s": (int, float), "rejected": (dict,),
    "rss_kb": (dict,), "safe_stop": (dict,), "commands": (int,), "spares": (int,),
    "trial_commands": (int,),
    "fault": (dict,),
}
"""What a role's ``bye`` report may hold, by field; anything else is left out."""


def role_of(k: int) -> str:
    """The role name of peripheral index ``k`` (0-based): the process a fault names."""
    return f"peripheral-{k + 1}"


def plant_fault_of(fault: dict[str, Any]) -> dict[str, Any] | None:
    """The plant's fault of its report (``name`` and ``message``, short texts; ``time``,
    a number), or None if it is not one (plant/limits.py, runtime/roles/plant_orders.py)."""
    name, message, at = fault.get("name"), fault.get("message"), fault.get("time")
    if not (isinstance(name, str) and isinstance(message, str) and 0 < len(name) <= 64
            and 0 < len(message) <= 400 and (type(at) is int or type(at) is float)):
        return None
    return {"name": name, "message": message, "time": float(at)}


def plant_fault(report: dict[str, Any]) -> Fault:
    """The run's fault when the plant's report names one (exit code 4): its message, the
    fault's name and the plant time it came at."""
    f = report["fault"]
    return Fault(f"{f['message']} ({f['name']}, at {f['time']:.3f} s of plant time)",
                 process="plant", code=EXIT_PLANT)


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
        if name == "fault" and isinstance(v, dict):
            v = plant_fault_of(v)
            if v is None:
                continue
        out[name] = v
    return out


__all__ = ["ROLE_REPORT_FIELDS", "Fault", "plant_fault", "plant_fault_of", "role_of",
           "role_report"]
