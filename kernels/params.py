"""Delta robot parameters (thesis Eq. V.1-V.6) and their validation.

The defaults are the Delta-IA of the thesis (``docs/thesis-notes.md``). A TOML file can
override any field; unknown fields and out-of-range values raise :class:`ParameterError`
naming the field and the allowed range.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import asdict, dataclass, fields, replace
from pathlib import Path
from typing import Any

from .small_file import read_small_text

GRAVITY = 9.81
"""Gravity acceleration used throughout the thesis (m/s^2), acting along -z."""


class ParameterError(ValueError):
    """A parameter is missing, unknown or outside its allowed range."""


# field -> (low, high, unit, description); bounds are inclusive.
_BOUNDS: dict[str, tuple[float, float, str, str]] = {
    "l_a": (0.01, 5.0, "m", "arm length (Eq. V.1)"),
    "l_b": (0.01, 10.0, "m", "forearm length (Eq. V.1)"),
    "r_a": (0.0, 5.0, "m", "base joint radius (Eq. V.1)"),
    "r_b": (0.0, 5.0, "m", "platform joint radius (Eq. V.1)"),
    "m_a": (0.0, 100.0, "kg", "arm mass (Eq. V.3)"),
    "m_b": (0.0, 100.0, "kg", "mass of one forearm, a pair of rods (Eq. V.3)"),
    "m_c": (0.0, 100.0, "kg", "platform mass (Eq. V.3)"),
    "g_a": (0.0, 5.0, "m", "arm centre of mass from the joint (Eq. V.4)"),
    "g_b": (0.0, 10.0, "m", "forearm centre of mass from the arm tip (Eq. V.4)"),
    "j_a": (1e-6, 10.0, "kg m^2", "arm + rotor + transmission inertia at the joint (Eq. V.6)"),
    "j_b": (0.0, 10.0, "kg m^2", "forearm inertia about its centre (Eq. V.5)"),
    "tau_max": (0.0, 1e4, "N m", "joint torque limit"),
    "encoder_counts": (1.0, 1e9, "counts/turn", "encoder increments per arm turn"),
    "q_min": (-math.pi, math.pi, "rad", "lower joint bound of the Eq. V.32 box"),
    "q_max": (-math.pi, math.pi, "rad", "upper joint bound of the Eq. V.32 box"),
    "beta_min": (0.0, 1e6, "-", "lowest eigenvalue of l_a^2 J^-T J^-1 allowed (Eq. V.33)"),
    "beta_max": (0.0, 1e9, "-", "highest eigenvalue of l_a^2 J^-T J^-1 allowed (Eq. V.33)"),
}


@dataclass(frozen=True)
class DeltaParams:
    """Geometry, masses and limits of a Delta robot.

    All values are SI. Angles ``gamma`` of the three kinematic chains are fixed at
    0, 120 and 240 degrees (thesis Table 7).
    """

    l_a: float = 0.260
    l_b: float = 0.480
    r_a: float = 0.194
    r_b: float = 0.030
    m_a: float = 0.200
    m_b: float = 0.088
    m_c: float = 0.092
    g_a: float = 0.130
    g_b: float = 0.240
    j_a: float = 0.0131
    j_b: float = 0.0017
    tau_max: float = 20.0
    encoder_counts: float = 200_000.0
    q_min: float = math.radians(-125.0)
    q_max: float = math.radians(15.0)
    beta_min: float = 0.1
    beta_max: float = 10.0

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            lo, hi, unit, what = _BOUNDS[f.name]
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise ParameterError(
                    f"{f.name} ({what}) must be a number in [{lo}, {hi}] {unit}, "
                    f"got {value!r}"
                )
            if not math.isfinite(value) or not lo <= value <= hi:
                raise ParameterError(
                    f"{f.name} ({what}) = {value!r} is outside the allowed range "
                    f"[{lo}, {hi}] {unit}"
                )
        if self.q_min >= self.q_max:
            raise ParameterError(
                f"q_min = {self.q_min!r} rad must be below q_max = {self.q_max!r} rad"
            )
        if self.beta_min >= self.beta_max:
            raise ParameterError(
                f"beta_min = {self.beta_min!r} must be below beta_max = {self.beta_max!r}"
            )
        if self.g_b > self.l_b:
            raise ParameterError(f"g_b = {self.g_b!r} m must lie in [0, l_b = {self.l_b}] m")
        if self.g_a > self.l_a:
            raise ParameterError(f"g_a = {self.g_a!r} m must lie in [0, l_a = {self.l_a}] m")

    @property
    def r_r(self) -> float:
        """Radius difference ``r_a - r_b`` used by the inverse kinematics (Eq. V.14)."""
        return self.r_a - self.r_b

    @property
    def increment(self) -> float:
        """One encoder increment in radians (``2 pi / encoder_counts``)."""
        return 2.0 * math.pi / self.encoder_counts

    def with_(self, **changes: Any) -> DeltaParams:
        """Return a copy with ``changes`` applied (validated)."""
        return replace(self, **changes)

    def to_dict(self) -> dict[str, float]:
        """Plain dictionary of every field."""
        return asdict(self)


DELTA_IA = DeltaParams()
"""The Delta-IA of the thesis (Eq. V.1-V.6, docs/thesis-notes.md)."""


def params_from_mapping(data: dict[str, Any], *, source: str = "parameters") -> DeltaParams:
    """Build :class:`DeltaParams` from a mapping, starting from the Delta-IA defaults.

    Angles may be given in degrees with the keys ``q_min_deg`` / ``q_max_deg``.

    Raises
    ------
    ParameterError
        On an unknown key or a value outside its range; the message names the field.
    """
    data = dict(data)
    if "delta" in data and isinstance(data["delta"], dict):
        data = dict(data["delta"])
    for key in ("q_min", "q_max"):
        deg_key = f"{key}_deg"
        if deg_key in data:
            value = data.pop(deg_key)
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise ParameterError(f"{source}: {deg_key} must be a number of degrees")
            data[key] = math.radians(value)
    known = {f.name for f in fields(DeltaParams)}
    unknown = sorted(set(data) - known)
    if unknown:
        raise ParameterError(
            f"{source}: unknown field(s) {', '.join(unknown)}; allowed: {', '.join(sorted(known))}"
        )
    try:
        return DeltaParams(**data)
    except ParameterError as exc:
        raise ParameterError(f"{source}: {exc}") from None


def load_params(path: str | Path) -> DeltaParams:
    """Load Delta parameters from a TOML file (top level or a ``[delta]`` table), read
    as kernels/small_file.py reads an input file.

    Raises
    ------
    ParameterError
        If the file cannot be read or parsed, or a field is unknown or out of range.
    """
    text = read_small_text(path, whose=f"parameters file {path}", error=ParameterError)
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ParameterError(f"{path}: cannot read parameters: {exc}") from None
    return params_from_mapping(data, source=str(path))
