"""A recording's result record (metadata ``ctrlunit.result``, written at the run's end by
:mod:`.recorder`) read as input: each field the report and the plots use, checked for its
type and range, so that an edited or damaged file is one line naming the field
(:class:`ValueError`), never a traceback nor a figure no run could give; the text it
holds made printable (control characters as spaces)."""

from __future__ import annotations

import json
import math
from typing import Any

MAX_S = 1e6
"""The largest duration in seconds a result field may hold (11 days of run)."""


def printable(text: str) -> str:
    """``text`` with its control characters (newlines, escape codes) as spaces."""
    return "".join(c if c.isprintable() else " " for c in text)


def _bad(field: str, value: Any, allowed: str) -> ValueError:
    return ValueError(f"its result record's {field} = {printable(str(value))[:60]!r}: "
                      f"allowed {allowed}")


def _json(result: dict[str, str], field: str, default: Any) -> Any:
    text = result.get(field)
    if text in (None, "", "null", "None"):
        return default
    try:
        return json.loads(text)
    except (TypeError, ValueError):
        raise _bad(field, text, "JSON") from None


def _count(field: str, x: Any) -> int:
    if type(x) is not int or x < 0:
        raise _bad(field, x, "an integer 0 or more")
    return x


def _seconds(field: str, x: Any) -> float:
    if isinstance(x, bool) or not isinstance(x, int | float) or not 0 <= x <= MAX_S:
        raise _bad(field, x, f"a number of seconds from 0 to {MAX_S:g}")
    return float(x)


def _mapping(field: str, x: Any) -> dict[str, Any]:
    if not isinstance(x, dict):
        raise _bad(field, x, "an object")
    for k in x:
        if k != printable(k) or len(k) > 80:
            raise _bad(f"{field} key", k, "a name of printable characters, 80 at most")
    return x


def ns(result: dict[str, str], key: str) -> int:
    """A time (ns) of the result record; 0 where it holds none."""
    text = result.get(key) or "0"
    if not text.isdigit() or len(text) > 20:
        raise _bad(key, text, "an integer of nanoseconds")
    return int(text)


def busy(result: dict[str, str], peripherals: int) -> dict[str, Any]:
    """``busy``: the central's wait and each process's compute (ns), or {}."""
    b = _mapping("busy", _json(result, "busy", {}))
    if b:
        for k in ("central_wait_ns", "plant_busy_ns"):
            _count(f"busy.{k}", b.get(k))
        per = b.get("periph_busy_ns")
        if not isinstance(per, list) or len(per) != peripherals:
            raise _bad("busy.periph_busy_ns", per, f"a list of {peripherals} integers")
        for x in per:
            _count("busy.periph_busy_ns", x)
    return b


def rejected(result: dict[str, str]) -> dict[str, int]:
    """``rejected``: counts by reason, or {}."""
    r = _mapping("rejected", _json(result, "rejected", {}))
    for k, v in r.items():
        _count(f"rejected[{k!r}]", v)
    return r


def t1(result: dict[str, str]) -> float:
    """``t1_s``: the one-process time (NaN where the run did not measure it)."""
    text = result.get("t1_s")
    if text in (None, "None", "", "nan"):
        return math.nan
    try:
        return _seconds("t1_s", float(text))
    except ValueError:
        raise _bad("t1_s", text, "a number of seconds") from None


def block_costs(result: dict[str, str], names: set[str]) -> dict[str, float]:
    """``block_cost_s``: each block of the run's graph and its time (s), or {}."""
    costs = _mapping("block_cost_s", _json(result, "block_cost_s", {}))
    for k, v in costs.items():
        if k not in names:
            raise _bad("block_cost_s key", k, f"the graph's blocks: {', '.join(sorted(names))}")
        _seconds(f"block_cost_s.{k}", v)
    return costs


def cpu(result: dict[str, str]) -> dict[str, Any]:
    """``cpu``: the run's CPU budget (the report's keys of it), or {}."""
    c = _mapping("cpu", _json(result, "cpu", {}))
    for k, v in _mapping("cpu.cpu_per_interval_s", c.get("cpu_per_interval_s") or {}).items():
        _seconds(f"cpu.cpu_per_interval_s.{k}", v)
    if c.get("cpu_cores") is not None and (type(c["cpu_cores"]) is not int
                                           or not 1 <= c["cpu_cores"] <= 4096):
        raise _bad("cpu.cpu_cores", c["cpu_cores"], "an integer from 1 to 4096, or null")
    if c.get("cpu_bound_period_s") is not None:
        _seconds("cpu.cpu_bound_period_s", c["cpu_bound_period_s"])
    return c


def live(result: dict[str, str], keys: Any) -> dict[str, Any] | None:
    """``live``: what only the live run knew, by report key (those of ``keys``), or None
    where the record does not hold it."""
    if result.get("live") is None:
        return None
    facts = _mapping("live", _json(result, "live", None))
    unknown = sorted(set(facts) - set(keys))
    if unknown:
        raise _bad("live key", unknown[0], f"the report's keys: {', '.join(sorted(keys))}")
    return facts


def fault(text: Any) -> dict[str, Any] | None:
    """The run's fault as its result record holds it, checked and made printable: an
    object whose ``process`` and ``message`` are text and whose ``code`` is an exit code
    or null; None for no fault."""
    f = _json({"fault": text}, "fault", None)
    if f is None:
        return None
    code = f.get("code") if isinstance(f, dict) else None
    if not (isinstance(f, dict) and isinstance(f.get("process"), str)
            and isinstance(f.get("message"), str)
            and (code is None or (type(code) is int and 0 <= code <= 255))):
        raise _bad("fault", f, "an object with process and message (text) and code (an "
                   "exit code 0 to 255, or null)")
    return f | {k: printable(f[k]) for k in ("process", "message")}


__all__ = ["block_costs", "busy", "cpu", "fault", "live", "ns", "printable", "rejected", "t1"]
