"""Run configuration: every option of ``ctrlunit start`` with its validation."""

from __future__ import annotations

import os
import re
import typing
from dataclasses import asdict, dataclass, field, fields
from decimal import Decimal
from typing import Any

from .choices import (  # noqa: F401  (re-exported: the sets belong with the configuration)
    CLOCKS,
    COMMAND_DELAYS,
    COMPRESSIONS,
    CPU_SPREADS,
    LATE_POLICIES,
    MISSED_COMMANDS,
    OVERLOAD_ACTIONS,
    PERIPHERAL_LOSSES,
    REPLY_MODES,
)
from .outputs import central_output_error, view_error
from .sections import (
    RENAMED,
    SECTIONS,
    ControlConfig,
    PlantOptions,
    RunOptions,
    ScheduleConfig,
    TransportConfig,
)
from .setting import about, allowed_text, integers, out_of_range, user_allowed
from .value_types import has_type, type_name

# exit codes, one per fault class
EXIT_OK = 0
EXIT_CONFIG = 1
EXIT_PERIPHERAL = 3
EXIT_PLANT = 4
EXIT_OBSERVER = 5
EXIT_LINK = 6
EXIT_UNSUSTAINABLE = 7
"""Realtime: the admission trial showed that the period asked cannot be held; refused
before the plant acted on any command (a trial's commands are checked and dropped)."""
EXIT_INTERRUPTED = 130
"""Ctrl-C (SIGINT). SIGTERM and SIGHUP stop a run the same way, with exit 128 + the
signal's number (143, 129), as a shell reports a process the signal ended."""

_UNITS: dict[str, Decimal] = {"s": Decimal(1), "ms": Decimal("1e-3"), "us": Decimal("1e-6"),
                               "µs": Decimal("1e-6"), "ns": Decimal("1e-9"), "min": Decimal(60)}
"""Seconds per unit, exact: ``20us`` is the same float as ``0.00002``."""


class ConfigError(ValueError):
    """An option is out of range; the message names it and the allowed range."""


def parse_duration(text: str | float, *, field_name: str = "duration",
                   zero: bool = False) -> float:
    """``500us``, ``1ms``, ``30s``, ``2min`` or a bare number of seconds -> seconds, the
    nearest float to the value written (``2ms`` is ``0.002``); positive, or 0 too with
    ``zero``."""
    if isinstance(text, int | float):
        value = float(text)
    else:
        m = re.fullmatch(r"\s*([0-9]*\.?[0-9]+(?:[eE][-+]?[0-9]+)?)\s*([a-zµ]*)\s*", text)
        if not m or (m.group(2) and m.group(2) not in _UNITS):
            raise ConfigError(f"{field_name} = {text!r}: expected a number with a unit (s, "
                              "ms, us, ns, min) or a bare number of seconds")
        value = float(Decimal(m.group(1)) * _UNITS[m.group(2) or "s"])
    if not (value > 0.0 or (zero and value == 0.0)):
        raise ConfigError(f"{field_name} = {text!r} must be {'0 or more' if zero else 'positive'}")
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


def _flat_names() -> dict[str, tuple[str, str]]:
    back = {v: k for k, v in RENAMED.items()}
    return {back.get(f.name, f.name): (section, f.name)
            for section, cls in SECTIONS.items() for f in fields(cls)}


FLAT = _flat_names()
"""Each option's flat name (the CLI's, a spec's, a recording's) -> (section, field)."""
BY_FIELD = {(sec, name): flat for flat, (sec, name) in FLAT.items()}
"""(section, field) -> the option's flat name."""
_FLAT_TYPES = {flat: typing.get_type_hints(SECTIONS[sec])[name]
               for flat, (sec, name) in FLAT.items()}
_ABOUT = {flat: about(f) for flat, (sec, name) in FLAT.items()
          for f in fields(SECTIONS[sec]) if f.name == name}


@dataclass(frozen=True)
class RunConfig:
    """Options of one run (see ``ctrlunit start --help``), in frozen sections
    (runtime/config/sections.py). Build one with :meth:`of` from flat option names; a changed
    copy with :meth:`replace`."""

    control: ControlConfig = field(default_factory=ControlConfig)
    schedule: ScheduleConfig = field(default_factory=ScheduleConfig)
    plant: PlantOptions = field(default_factory=PlantOptions)
    transport: TransportConfig = field(default_factory=TransportConfig)
    run: RunOptions = field(default_factory=RunOptions)

    @classmethod
    def of(cls, **options: Any) -> RunConfig:
        """A configuration from flat option names (``peripherals=3, plant_lag=1e-4``), the
        rest at their defaults. An unknown name is a :class:`ConfigError`."""
        parts: dict[str, dict[str, Any]] = {name: {} for name in SECTIONS}
        for flat, value in options.items():
            where = FLAT.get(flat)
            if where is None:
                raise ConfigError(f"unknown run option {flat!r}")
            parts[where[0]][where[1]] = value
        return cls(**{name: SECTIONS[name](**kw) for name, kw in parts.items()})

    def replace(self, **options: Any) -> RunConfig:
        """A copy with the options named (flat names) changed; this one is unchanged."""
        return RunConfig.of(**{**self.to_dict(), **options})

    def option(self, flat: str) -> Any:
        """The value of one option by its flat name."""
        section, name = FLAT[flat]
        return getattr(getattr(self, section), name)

    def validate(self, *, roles: tuple[str, ...] | list[str] = ()) -> RunConfig:
        """Check every option's value; returns ``self``. With ``--keys``, the keys
        directory and the credentials of ``roles`` (the roles this process starts or is:
        :attr:`started_roles` for ``ctrlunit start``, ``("plant",)`` for ``ctrlunit
        plant``; none: the directory and its authority alone) are checked too
        (runtime/transport/security.py, ``check_credentials``).

        Raises
        ------
        ConfigError
            Naming the first option out of its range and the range allowed, or the first
            key file that will not do and why.
        """
        self._check_values()
        self._check_outputs()
        self._check_host(roles)
        if not roles or "central" in roles:  # what the central writes and binds
            if (why := central_output_error(self.run, self.transport.listen if roles else None)):
                raise ConfigError(why)
        return self

    @property
    def started_roles(self) -> tuple[str, ...]:
        """The roles ``ctrlunit start`` runs: the central, the plant (not in freerun) and
        peripheral-1 to -n."""
        plant = () if self.schedule.clock == "freerun" else ("plant",)
        return ("central", *plant,
                *(f"peripheral-{k}" for k in range(1, self.schedule.peripherals + 1)))

    def _bad(self, name: str, allowed: str) -> ConfigError:
        """Names the option (``--max-error``) and the value as the user would write it."""
        value, timed = self.option(name), _ABOUT[name].kind in ("duration", "period")
        unit = " s" if timed else {"max_error": " m", "bandwidth_hz": " Hz",
                                   "foxglove_rate": " Hz"}.get(name, "")
        shown = repr(value) if not isinstance(value, float) else f"{value * 1e6:g} us" if (
            timed and 0 < value < 1e-3) else f"{value:g}{unit}"  # 5us, not 5e-06 s
        option = "--" + name.removesuffix("_hz").replace("_", "-")
        return ConfigError(f"{option} = {shown}: allowed {allowed}")

    def _check_values(self) -> None:
        """Each setting against its field's type and the choices and bounds it declares
        (runtime/config/setting.py), in the order of the sections and their fields."""
        for flat, (section, name) in FLAT.items():
            a = _ABOUT[flat]
            value = getattr(getattr(self, section), name)
            if not has_type(value, tp := _FLAT_TYPES[flat]):  # as the range says, if one does
                allowed = allowed_text(a) if a.choices or a.bounds or a.allowed else type_name(tp)
                raise self._bad(flat, integers(allowed) if tp in (int, int | None)
                                else allowed)
            if out_of_range(a, value):
                raise self._bad(flat, user_allowed(a) if a.kind == "duration"
                                else allowed_text(a))

    def _check_outputs(self) -> None:
        """What the declared choices and bounds do not say: the late data's blocks, the
        live view, one run length, and whether the gains hold a halved rate."""
        for block, pol in self.schedule.late.items():
            if pol not in LATE_POLICIES:
                raise ConfigError(f"--late {block}={pol}: the policy must be one of "
                                  f"{', '.join(LATE_POLICIES)}")
        if (why := view_error(self.run.foxglove, insecure=self.transport.insecure,
                              parse=parse_host_port)):
            raise ConfigError(why)
        if not (self.run.foxglove_rate == 0 or 1.0 <= self.run.foxglove_rate <= 100_000.0):
            raise self._bad("foxglove_rate", "0 (every interval) or 1 to 100000 Hz")
        if None not in (self.run.cycles, self.run.duration):
            raise ConfigError("--cycles and --duration: give one (the run's length in "
                              "intervals, or in time)")
        if self.schedule.balance == "live" and self.schedule.clock == "realtime":
            raise ConfigError("--balance live: not with --clock realtime (the default), where "
                              "a move costs deadlines; allowed with --clock freerun or lockstep")
        if self.schedule.overload == "halve" and not self.gains_hold_halved:
            limit = self.bandwidth_limit(2.0 * self.schedule.period)
            raise ConfigError(
                f"--overload halve: the gains' bandwidth {self.bandwidth:g} Hz would lose "
                f"its phase margin at twice the period ({2e3 * self.schedule.period:g} ms); "
                f"allowed with --bandwidth at most {limit:.3g} Hz, or --overload continue")

    def _check_host(self, roles: tuple[str, ...] | list[str]) -> None:
        """The host's scheduling and CPUs, the unit id, the endpoints, the keys of ``roles``."""
        from ..host.idle import check_idle
        from ..host.sched import check_pin, check_priority

        try:
            check_pin(self.schedule.pin)
            check_priority(self.schedule.rt_priority)
            check_idle(self.schedule.idle)
        except ValueError as exc:
            raise ConfigError(str(exc)) from None
        from ..transport.endpoints import check_endpoint, check_unit_id
        from ..transport.zsession import check_zenoh_config

        try:
            check_unit_id(self.transport.unit)
        except ValueError as exc:
            raise ConfigError(f"--unit: {exc}") from None
        try:
            for option, endpoints in (("--listen", self.transport.listen),
                                      ("--connect", self.transport.connect)):
                for e in endpoints or []:
                    check_endpoint(e, option=option)
            if self.transport.zenoh_config is not None:
                check_zenoh_config(self.transport.zenoh_config)
            if self.run.ros2 is not None:  # the ROS 2 router's link, by the same rule
                from ..transport.ros2_zenoh import session_config

                session_config(os.environ, insecure=self.transport.insecure)
            self.link_security(roles=roles)
        except ValueError as exc:
            raise ConfigError(str(exc)) from None

    def link_security(self, *, check_files: bool = True, central: str | None = None,
                      roles: tuple[str, ...] | list[str] = ()) -> str:
        """How this run's links are protected, the weakest of them
        (runtime/transport/security.py, ``PROTECTIONS``): ``tls``, ``local``, ``loopback``
        or ``insecure``. Raises ValueError for a link beyond the host (a ``--zenoh-config``
        file's, its multicast scouting included) without ``--keys`` or ``--insecure``, or
        one that cannot carry a certificate with ``--keys``; with ``check_files``, for a
        ``--keys`` directory whose authority or whose credentials of ``roles`` will not do
        (``check_credentials``: the file and the reason)."""
        from ..transport.security import check_credentials, weakest

        t = self.transport
        links = self.links(central=central)  # the link rule first: it needs no file
        if check_files and t.keys is not None:
            check_credentials(t.keys, roles)
        return weakest(links, keys=t.keys)

    def links(self, *, central: str | None = None) -> list[dict[str, str]]:
        """Every link of this run with what protects it (runtime/transport/security.py,
        ``unit_links``); ``central``: the endpoint a launcher's central listens on when
        ``--listen`` is not given. Raises ValueError as :meth:`link_security`."""
        from ..transport.security import unit_links
        from ..transport.zsession import file_links

        path = self.transport.zenoh_config
        return unit_links(self.transport, central=central,
                          file=file_links(path) if path is not None else None)

    @property
    def bandwidth(self) -> float:
        """Closed-loop bandwidth of the gains (Hz): ``--bandwidth``, else 20 Hz but at most
        ``1 / (50 T)`` (the phase margin against the delay from a sample to its command's
        action), or, where the law servoes the state predicted for the period its command
        acts in (:attr:`predicts_acting`), ``1 / (12.5 T')`` at ``T' = 2 T``: its margin
        then holds a period more than designed, every command a period late or the rate
        halved. 20 Hz up to 2 ms (docs/architecture.md, commands in flight, overload)."""
        if self.control.bandwidth_hz is not None:
            return self.control.bandwidth_hz
        period = self.schedule.period
        return min(20.0, self.bandwidth_limit(period * (2.0 if self.predicts_acting else 1.0)))

    @property
    def predicts_acting(self) -> bool:
        """Whether the law servoes the state predicted for the period in which its command
        acts (resolved acceleration at the ``acting`` model state or a foreseen one)."""
        return (self.control.law == "resolved-acceleration"
                and self.resolved_model_state in ("acting", "foreseen", "foreseen2"))

    def bandwidth_limit(self, period: float) -> float:
        """The highest bandwidth (Hz) whose loop keeps its phase margin at a control period
        ``period`` (s): ``1 / (12.5 T)`` for resolved acceleration at the ``acting`` model
        state, ``1 / (50 T)`` for the other laws (:attr:`bandwidth`)."""
        return 1.0 / ((12.5 if self.predicts_acting else 50.0) * period)

    @property
    def resolved_model_state(self) -> str:
        """``--model-state`` resolved: ``auto`` is ``foreseen2`` where the model's round
        can run ahead of the sample and the time from sample to command counts
        (resolved acceleration in realtime at depth 2: the path then holds the central's
        work alone, and two intervals' rounds share an exchange, which saves a quarter of
        the unit's CPU), else ``acting``, which computes the same commands to within 1 %
        of the tracking error: in freerun its rounds of two intervals fuse into one
        exchange, and lockstep has no deadline (docs/architecture.md, where the model is
        evaluated)."""
        asked = self.control.model_state
        if asked != "auto":
            return asked
        if (self.control.law == "resolved-acceleration" and self.schedule.clock == "realtime"
                and self.schedule.pipeline >= 2):
            return "foreseen2"
        return "acting"

    @property
    def gains_hold_halved(self) -> bool:
        """Whether the gains keep their phase margin at twice the period, where a realtime
        run that halves its control rate on overload continues (``--overload``): the
        default bandwidth of resolved acceleration does at every period (:attr:`bandwidth`);
        a ``--bandwidth`` over ``1 / (25 T)`` does not (at 5 ms 16 Hz: the one-process
        loop diverges once halved; docs/architecture.md, overload)."""
        return self.bandwidth <= self.bandwidth_limit(2.0 * self.schedule.period)

    @property
    def halves_on_overload(self) -> bool:
        """``--overload`` resolved: ``halve`` in realtime; ``auto`` in realtime with the
        admission on (the main job) where :attr:`gains_hold_halved`; never otherwise."""
        s = self.schedule
        return s.clock == "realtime" and s.overload != "continue" and (
            s.overload == "halve" or (s.admission and self.gains_hold_halved))

    @property
    def delay_periods(self) -> int:
        """Periods from sample k to the start of the period in which the command of
        interval k acts: the depth (``full``) or one less (``short``)."""
        return self.schedule.pipeline - (0 if self.schedule.command_delay == "full" else 1)

    @property
    def lead_periods(self) -> int:
        """The ``delay`` of the feed-forward lead (``(delay + 1/2) T``, runtime/compute/blocks.py):
        :attr:`delay_periods`, except that ``short`` in realtime keeps the earlier code's
        lead of d + 1/2 periods, so that its recordings replay bit for bit."""
        legacy = self.schedule.command_delay == "short" and self.schedule.clock == "realtime"
        return self.delay_periods + legacy

    @classmethod
    def from_dict(cls, data: Any, *, source: str = "configuration") -> RunConfig:
        """A configuration as written by :meth:`to_dict` (a spec file, a recording); one
        written before ``command_delay`` existed used the ``short`` convention, one written
        before ``model_state`` existed evaluated the model at the sample.

        Every field is checked for its type (a :class:`ConfigError` names the field, the
        value and the type allowed); ranges are :meth:`validate`'s."""
        if not isinstance(data, dict):
            raise ConfigError(f"{source}: expected an object of run options, got "
                              f"{type(data).__name__}")
        data = dict(data)
        data.setdefault("command_delay", "short")
        data.setdefault("model_state", "sample")
        for k, v in data.items():
            if k not in _FLAT_TYPES:
                raise ConfigError(f"{source}: unknown run option {k!r}")
            if not has_type(v, _FLAT_TYPES[k]):
                shown = repr(v) if len(repr(v)) <= 60 else repr(v)[:57] + "..."
                raise ConfigError(f"{source}: {k} = {shown}: allowed "
                                  f"{type_name(_FLAT_TYPES[k])}")
        return cls.of(**data)

    @classmethod
    def from_recording(cls, data: Any) -> RunConfig:
        """The configuration a recording was made with (:meth:`from_dict`), its model state
        as it ran. The recorder writes ``--model-state auto`` resolved; a recording that
        says ``auto`` was made when ``auto`` meant ``foreseen`` where it now means
        ``foreseen2`` (:attr:`resolved_model_state`), and replays as it ran."""
        rc = cls.from_dict(data, source="recording")
        if rc.control.model_state != "auto":
            return rc
        state = rc.resolved_model_state
        return rc.replace(model_state="foreseen" if state == "foreseen2" else state)

    def total_cycles(self, task_period: float) -> int:
        """Cycles to run: ``cycles``, else ``duration / period``, else one task loop."""
        if self.run.cycles is not None:
            return self.run.cycles
        if self.run.duration is not None:
            return max(1, round(self.run.duration / self.schedule.period))
        return max(1, round(task_period / self.schedule.period)) + 1

    def to_dict(self) -> dict[str, Any]:
        """Every option by its flat name (what :meth:`from_dict` and :meth:`of` read)."""
        sections = {name: asdict(getattr(self, name)) for name in SECTIONS}
        return {flat: sections[sec][name] for flat, (sec, name) in FLAT.items()}
