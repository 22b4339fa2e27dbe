"""Run configuration: every option of ``ctrlunit start`` with its validation."""

from __future__ import annotations

import math
import re
import secrets
import types
import typing
from dataclasses import asdict, dataclass, field
from typing import Any

CLOCKS = ("lockstep", "realtime", "freerun")
REPLY_MODES = ("auto", "fused", "each")
LATE_POLICIES = ("wait", "hold", "fault")
COMMAND_DELAYS = ("full", "short")
"""When the plant applies the command of sample k (docs/architecture.md, Clocks): ``full``
(causal): at depth d, to the period that begins at tick k + d, d periods after the sample;
``short``: the convention of the code before 2026-11-22, d - 1 periods (the realtime plant
integrated the period that *ended* at tick k + d with the command due at that tick)."""
"""Realtime, a peripheral's reply past its round's share of the deadline: ``wait`` for it
(the plant counts the miss), ``hold`` the peripheral's last values for its axes, or treat
it as a ``fault``."""

# exit codes, one per fault class
EXIT_OK = 0
EXIT_CONFIG = 1
EXIT_PERIPHERAL = 3
EXIT_PLANT = 4
EXIT_OBSERVER = 5
EXIT_LINK = 6
EXIT_UNSUSTAINABLE = 7
"""Realtime: the admission trial showed that the period asked cannot be held; refused
before any command reached the plant."""
EXIT_INTERRUPTED = 130

_UNITS = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "µs": 1e-6, "ns": 1e-9, "min": 60.0}


class ConfigError(ValueError):
    """An option is out of range; the message names it and the allowed range."""


def _has_type(value: Any, tp: Any) -> bool:
    """``value`` (decoded JSON) is of the annotated type: ``int``, ``float`` (an int is
    one), ``str``, ``bool``, ``X | None``, ``list[str]``, ``dict[str, str]``; bool is no
    number; a float must be finite."""
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin in (typing.Union, types.UnionType):
        return any(_has_type(value, a) for a in args)
    if tp is type(None):
        return value is None
    if tp is bool:
        return isinstance(value, bool)
    if tp is int:
        return isinstance(value, int) and not isinstance(value, bool)
    if tp is float:
        return (isinstance(value, (int, float)) and not isinstance(value, bool)
                and math.isfinite(value))
    if tp is str:
        return isinstance(value, str)
    if origin is list:
        return isinstance(value, list) and all(_has_type(x, args[0]) for x in value)
    if origin is dict:
        return isinstance(value, dict) and all(
            _has_type(k, args[0]) and _has_type(x, args[1]) for k, x in value.items())
    return False


def _type_name(tp: Any) -> str:
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin in (typing.Union, types.UnionType):
        return " or ".join(_type_name(a) for a in args)
    names = {type(None): "null", bool: "true or false", int: "an integer",
             float: "a finite number", str: "a string"}
    if tp in names:
        return names[tp]
    if origin is list:
        return f"a list of {_type_name(args[0]).removeprefix('a ')}s"
    if origin is dict:
        return "an object of strings"
    return str(tp)


def parse_duration(text: str | float, *, field_name: str = "duration") -> float:
    """``500us``, ``1ms``, ``30s``, ``2min`` or a bare number of seconds -> seconds."""
    if isinstance(text, int | float):
        value = float(text)
    else:
        m = re.fullmatch(r"\s*([0-9]*\.?[0-9]+(?:[eE][-+]?[0-9]+)?)\s*([a-zµ]*)\s*", text)
        if not m or (m.group(2) and m.group(2) not in _UNITS):
            raise ConfigError(
                f"{field_name} = {text!r}: expected a number with a unit (s, ms, us, ns, min) "
                "or a bare number of seconds"
            )
        value = float(m.group(1)) * _UNITS.get(m.group(2) or "s", 1.0)
    if not value > 0.0:
        raise ConfigError(f"{field_name} = {text!r} must be positive")
    return value


def parse_host_port(text: str, *, field_name: str, default_host: str = "127.0.0.1"
                    ) -> tuple[str, int]:
    """``[HOST:]PORT`` -> ``(host, port)``; the port 0 to 65535 (0: any free port), the
    host a name or an IPv4 address, or an IPv6 one in brackets (``[::1]:8765``)."""
    text = str(text)
    m = re.fullmatch(r"(?:(\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9_.-]+):)?([0-9]{1,5})", text)
    if not m or int(m.group(2)) > 65535:
        raise ConfigError(f"{field_name} = {text!r}: expected [HOST:]PORT with PORT 0 to "
                          "65535 (e.g. 8765 or 127.0.0.1:8765)")
    host = m.group(1) or default_host
    return host.strip("[]"), int(m.group(2))


@dataclass
class RunConfig:
    """Options of one run (see ``ctrlunit start --help``)."""

    peripherals: int = 3
    pipeline: int = 1
    clock: str = "realtime"
    period: float = 1e-3
    task: str = "pick-place"
    law: str = "resolved-acceleration"
    model: str = "complete"
    cycles: int | None = None
    duration: float | None = None
    record: str | None = None
    record_compression: str = "zstd"
    """Chunk compression of ``--record`` (runtime/mcap_writer.py, ``COMPRESSIONS``)."""
    foxglove: str | None = None
    """``[HOST:]PORT`` of the live view's Foxglove WebSocket server (runtime/viewer.py)."""
    foxglove_rate: float = 200.0
    """``/signals/state`` messages per second of the live view (0: every interval)."""
    report: str | None = None
    unit: str = field(default_factory=lambda: "u" + secrets.token_hex(4))
    cost_model: str = "native"
    placement: str | None = None
    params: str | None = None
    observer: str = "predict"
    bandwidth_hz: float | None = None
    listen: list[str] | None = None
    connect: list[str] | None = None
    zenoh_config: str | None = None
    timeout: float = 2.0
    startup_timeout: float = 30.0
    pin: str | None = None
    plant_substeps: int | None = None
    plant_lag: float = 0.0
    plant_friction: float = 0.0
    belt: bool = False
    t1_cycles: int = 500
    progress: bool = False
    status_file: str | None = None
    trace: bool = False
    cpus: str | None = None
    max_error: float = 0.02
    cost_scale: float = 1.0
    late_policy: str = "wait"
    late: dict[str, str] = field(default_factory=dict)
    replies: str = "auto"
    fault_periods: float = 3.0
    rt_priority: int = 0
    command_delay: str = "full"
    hold_rounds: str = "always"
    """``--hold-rounds`` (topology/pipeline.py, ``HOLD_RULES``)."""
    period_auto: bool = False
    """``--period auto``: realtime runs at the shortest period of the admission ladder that
    holds (runtime/admission.py); ``period`` is where the ladder starts."""
    admission: bool = True
    trial_only: bool = False
    """Run the admission trial and stop before the first command (``ctrlunit latency
    --unit``)."""
    """Realtime: run the admission trial before the first command (runtime/admission.py)."""

    def validate(self) -> RunConfig:
        from ..topology.graph import LAWS

        def bad(name: str, allowed: str) -> ConfigError:
            """Names the option (``--max-error``) and the value as the user would write it."""
            value = getattr(self, name)
            unit = {"period": " s", "timeout": " s", "max_error": " m", "bandwidth_hz": " Hz",
                    "foxglove_rate": " Hz"}.get(name, "")
            shown = f"{value:g}{unit}" if isinstance(value, float) else repr(value)
            option = "--" + name.removesuffix("_hz").replace("_", "-")
            return ConfigError(f"{option} = {shown}: allowed {allowed}")

        if self.peripherals not in (0, 1, 2, 3):
            raise bad("peripherals", "0, 1, 2 or 3")
        if self.pipeline not in (1, 2):
            raise bad("pipeline", "1 or 2")
        if self.clock not in CLOCKS:
            raise bad("clock", ", ".join(CLOCKS))
        if not 20e-6 <= self.period <= 1.0:
            raise bad("period", "20us to 1s")
        if self.law not in (*LAWS, "kinematics"):
            raise bad("law", ", ".join(LAWS))
        if self.model not in ("complete", "simplified"):
            raise bad("model", "complete or simplified")
        if self.cycles is not None and not 1 <= self.cycles <= 10**9:
            raise bad("cycles", "1 to 1e9")
        if self.cost_model not in ("native", "t800"):
            raise bad("cost_model", "native or t800")
        if self.observer not in ("predict", "previous"):
            raise bad("observer", "predict or previous")
        if self.bandwidth_hz is not None and not 0.1 <= self.bandwidth_hz <= 200.0:
            raise bad("bandwidth_hz", "0.1 to 200 Hz")
        if not 0.01 <= self.timeout <= 600.0:
            raise bad("timeout", "0.01 to 600 s")
        if self.cpus not in (None, "same", "split"):
            raise bad("cpus", "same (every role on CPU 0) or split (central on 0, the rest "
                      "on 1)")
        if self.late_policy not in LATE_POLICIES:
            raise bad("late_policy", ", ".join(LATE_POLICIES))
        for block, pol in self.late.items():
            if pol not in LATE_POLICIES:
                raise ConfigError(f"--late {block}={pol}: the policy must be one of "
                                  f"{', '.join(LATE_POLICIES)}")
        if not 0.01 <= self.cost_scale <= 1000.0:
            raise bad("cost_scale", "0.01 to 1000")
        if not 1.0 <= self.fault_periods <= 1000.0:
            raise bad("fault_periods", "1 to 1000 periods")
        from .mcap_writer import COMPRESSIONS

        if self.record_compression not in COMPRESSIONS:
            raise bad("record_compression", ", ".join(COMPRESSIONS))
        if self.foxglove is not None:
            parse_host_port(self.foxglove, field_name="--foxglove")
        if not (self.foxglove_rate == 0 or 1.0 <= self.foxglove_rate <= 100_000.0):
            raise bad("foxglove_rate", "0 (every interval) or 1 to 100000 Hz")
        if self.hold_rounds not in ("always", "never"):
            raise bad("hold_rounds", "always or never")
        if self.command_delay not in COMMAND_DELAYS:
            raise bad("command_delay", ", ".join(COMMAND_DELAYS))
        if self.replies not in REPLY_MODES:
            raise bad("replies", ", ".join(REPLY_MODES))
        if not 1e-5 <= self.max_error <= 1.0:
            raise bad("max_error", "10 um to 1 m")
        if self.plant_substeps is not None and not 1 <= self.plant_substeps <= 1000:
            raise bad("plant_substeps", "1 to 1000")
        from .sched import check_priority

        try:
            check_priority(self.rt_priority)
        except ValueError as exc:
            raise ConfigError(str(exc)) from None
        from .zsession import check_endpoint, check_unit_id, check_zenoh_config

        try:
            check_unit_id(self.unit)
        except ValueError as exc:
            raise ConfigError(f"--unit: {exc}") from None
        try:
            for option, endpoints in (("--listen", self.listen), ("--connect", self.connect)):
                for e in endpoints or []:
                    check_endpoint(e, option=option)
            if self.zenoh_config is not None:
                check_zenoh_config(self.zenoh_config)
        except ValueError as exc:
            raise ConfigError(str(exc)) from None
        return self

    @property
    def bandwidth(self) -> float:
        """Closed-loop bandwidth of the gains (Hz): ``--bandwidth``, else 20 Hz but at most
        ``1 / (50 T)`` so that slower periods keep their phase margin."""
        if self.bandwidth_hz is not None:
            return self.bandwidth_hz
        return min(20.0, 1.0 / (50.0 * self.period))

    @property
    def delay_periods(self) -> int:
        """Periods from sample k to the start of the period in which the command of
        interval k acts: the depth (``full``) or one less (``short``)."""
        return self.pipeline if self.command_delay == "full" else self.pipeline - 1

    @property
    def lead_periods(self) -> int:
        """The ``delay`` of the feed-forward lead (``(delay + 1/2) T``, runtime/blocks.py):
        :attr:`delay_periods`, except that ``short`` in realtime keeps the earlier code's
        lead of d + 1/2 periods, so that its recordings replay bit for bit."""
        legacy = self.command_delay == "short" and self.clock == "realtime"
        return self.delay_periods + (1 if legacy else 0)

    @classmethod
    def from_dict(cls, data: Any, *, source: str = "configuration") -> RunConfig:
        """A configuration as written by :meth:`to_dict` (a spec file, a recording); one
        written before ``command_delay`` existed used the ``short`` convention.

        Every field is checked for its type (a :class:`ConfigError` names the field, the
        value and the type allowed); ranges are :meth:`validate`'s."""
        if not isinstance(data, dict):
            raise ConfigError(f"{source}: expected an object of run options, got "
                              f"{type(data).__name__}")
        data = dict(data)
        data.setdefault("command_delay", "short")
        hints = typing.get_type_hints(cls)
        for k, v in data.items():
            if k not in hints:
                raise ConfigError(f"{source}: unknown run option {k!r}")
            if not _has_type(v, hints[k]):
                shown = repr(v) if len(repr(v)) <= 60 else repr(v)[:57] + "..."
                raise ConfigError(f"{source}: {k} = {shown}: allowed "
                                  f"{_type_name(hints[k])}")
        return cls(**data)

    def total_cycles(self, task_period: float) -> int:
        """Cycles to run: ``cycles``, else ``duration / period``, else one task loop."""
        if self.cycles is not None:
            return self.cycles
        if self.duration is not None:
            return max(1, round(self.duration / self.period))
        return max(1, round(task_period / self.period)) + 1

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)
