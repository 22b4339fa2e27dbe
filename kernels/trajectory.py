"""Reference generation: cycloidal profiles (Eq. II.33) on lines, arcs and half ellipses.

A :class:`Path` is a sequence of segments; each segment is travelled with its own cycloidal
profile ``s(t) = s_f (t/T - sin(2 pi t/T) / (2 pi))`` whose duration follows from the peak
tangential acceleration ``2 pi s_f / T^2`` (docs/thesis-notes.md). The reference at time ``t`` is
``p_c(s(t))``, ``p_c' sdot`` and ``p_c'' sdot^2 + p_c' sddot`` (Eq. II.33).

A :class:`Task` plays its path forward, dwells, plays it backward and dwells, and repeats,
so that a run of any length has a defined reference.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

Vec3 = tuple[float, float, float]

_QUAD_NODES = 256  # Gauss-Legendre nodes for arc length
MIN_OFFSET_M = 1e-6
"""The least distance that makes a curve (a half ellipse's chord and height)."""


@dataclass(frozen=True)
class Line:
    """Straight segment from ``start`` to ``end`` (m)."""

    start: Vec3
    end: Vec3

    def point(self, u: float) -> tuple[Vec3, Vec3, Vec3]:
        a, b = self.start, self.end
        d = (b[0] - a[0], b[1] - a[1], b[2] - a[2])
        return (a[0] + u * d[0], a[1] + u * d[1], a[2] + u * d[2]), d, (0.0, 0.0, 0.0)

    @property
    def uniform(self) -> bool:
        """Arc length is proportional to ``u``."""
        return True


@dataclass(frozen=True)
class Ellipse:
    """Elliptic arc ``centre + cos(th) a + sin(th) b`` for ``th`` from ``th0`` to ``th1``.

    ``a`` and ``b`` are the (conjugate) semi-axis vectors; equal orthogonal lengths give a
    circular arc.
    """

    centre: Vec3
    a: Vec3
    b: Vec3
    th0: float = 0.0
    th1: float = math.pi

    def point(self, u: float) -> tuple[Vec3, Vec3, Vec3]:
        c, a, b = self.centre, self.a, self.b
        k = self.th1 - self.th0
        th = self.th0 + k * u
        ct, st = math.cos(th), math.sin(th)
        k2 = k * k
        return (
            (c[0] + ct * a[0] + st * b[0], c[1] + ct * a[1] + st * b[1],
             c[2] + ct * a[2] + st * b[2]),
            (k * (-st * a[0] + ct * b[0]), k * (-st * a[1] + ct * b[1]),
             k * (-st * a[2] + ct * b[2])),
            (-k2 * (ct * a[0] + st * b[0]), -k2 * (ct * a[1] + st * b[1]),
             -k2 * (ct * a[2] + st * b[2])),
        )

    @property
    def uniform(self) -> bool:
        """A circular arc (orthogonal semi-axes of equal length) is travelled uniformly."""
        la = math.sqrt(sum(x * x for x in self.a))
        lb = math.sqrt(sum(x * x for x in self.b))
        dot = sum(x * y for x, y in zip(self.a, self.b))
        return abs(la - lb) <= 1e-12 * max(la, 1.0) and abs(dot) <= 1e-12 * max(la * lb, 1.0)


def _t3(v: np.ndarray) -> Vec3:
    return (float(v[0]), float(v[1]), float(v[2]))


def _norm(v: Vec3) -> float:
    return math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])


def arc(centre: Vec3, start: Vec3, end: Vec3, *, normal: Vec3 = (0.0, 0.0, 1.0)) -> Ellipse:
    """Circular arc about ``centre`` from ``start`` to ``end``, turning positively about
    ``normal`` (a half circle when ``end`` is opposite ``start``)."""
    c, s, e, n = (np.asarray(v, dtype=float) for v in (centre, start, end, normal))
    a = s - c
    r = float(np.linalg.norm(a))
    if r == 0.0 or abs(np.linalg.norm(e - c) - r) > 1e-9 * max(1.0, r):
        raise ValueError("arc: start and end must be at the same non-zero distance from centre")
    n = n / np.linalg.norm(n)
    b = np.cross(n, a)
    cos_t = float(np.clip((a @ (e - c)) / r**2, -1.0, 1.0))
    sin_t = float((b @ (e - c)) / r**2)
    th1 = math.atan2(sin_t, cos_t)
    if th1 <= 0.0:
        th1 += 2.0 * math.pi
    return Ellipse(_t3(c), _t3(a), _t3(b), 0.0, th1)


def half_ellipse(start: Vec3, top: Vec3, end: Vec3) -> Ellipse:
    """Half ellipse from ``start`` through ``top`` to ``end`` (``top`` above the midpoint)."""
    s, t, e = (np.asarray(v, dtype=float) for v in (start, top, end))
    c = 0.5 * (s + e)
    a = s - c
    chord = float(np.linalg.norm(a))
    if chord < MIN_OFFSET_M or np.linalg.norm(np.cross(a, t - c)) / chord < MIN_OFFSET_M:
        raise ValueError(f"half-ellipse: start and end must differ, and top lie off the line "
                         f"through them, each by at least {MIN_OFFSET_M * 1e6:g} um")
    return Ellipse(_t3(c), _t3(a), _t3(t - c), 0.0, math.pi)


@dataclass
class Segment:
    """A curve travelled with a cycloidal profile of peak tangential acceleration
    ``accel`` (m/s^2)."""

    curve: Line | Ellipse
    accel: float
    length: float = field(init=False)
    duration: float = field(init=False)
    _table_u: np.ndarray = field(init=False, repr=False)
    _table_s: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        if not (math.isfinite(self.accel) and self.accel > 0.0):
            raise ValueError(f"accel must be a positive number of m/s^2, got {self.accel!r}")
        # arc-length table s(u): composite 8-point Gauss-Legendre on 512 panels
        n = 512
        us = np.linspace(0.0, 1.0, n + 1)
        xg, wg = np.polynomial.legendre.leggauss(8)
        s = [0.0]
        for k in range(n):
            a, b = us[k], us[k + 1]
            mid, half = 0.5 * (a + b), 0.5 * (b - a)
            seg = sum(w * _norm(self.curve.point(mid + half * x)[1]) for x, w in zip(xg, wg))
            s.append(s[-1] + half * seg)
        self._table_u = us
        self._table_s = np.array(s)
        self.length = float(s[-1])
        if self.length <= 0.0:
            raise ValueError("segment has zero length")
        self.duration = math.sqrt(2.0 * math.pi * self.length / self.accel)
        self._uniform = self.curve.uniform

    def _u_of_s(self, s: float) -> float:
        """Invert the arc length: exact for lines and circles, else table and Newton."""
        if self._uniform:
            return min(max(s / self.length, 0.0), 1.0)
        ts, tu = self._table_s, self._table_u
        k = int(np.searchsorted(ts, s)) - 1
        k = min(max(k, 0), len(ts) - 2)
        u0, s0 = float(tu[k]), float(ts[k])
        f0 = _norm(self.curve.point(u0)[1])
        u = u0 + (s - s0) / f0 if f0 > 0.0 else u0
        for _ in range(3):  # Newton on s(u) - s, s(u) by Simpson from the table node
            fm = _norm(self.curve.point(0.5 * (u0 + u))[1])
            fu = _norm(self.curve.point(u)[1])
            s_u = s0 + (u - u0) / 6.0 * (f0 + 4.0 * fm + fu)
            u -= (s_u - s) / fu
        return min(max(u, 0.0), 1.0)

    def profile(self, t: float) -> tuple[float, float, float]:
        """Cycloidal ``s, sdot, sddot`` at ``t`` in [0, duration] (Eq. II.33 timing law)."""
        T, sf = self.duration, self.length
        t = min(max(t, 0.0), T)
        w = 2.0 * math.pi / T
        s = sf * (t / T - math.sin(w * t) / (2.0 * math.pi))
        sd = sf / T * (1.0 - math.cos(w * t))
        sdd = sf / T * w * math.sin(w * t)
        return s, sd, sdd

    def sample(self, t: float) -> tuple[Vec3, Vec3, Vec3]:
        """Reference position, velocity and acceleration at ``t`` (Eq. II.33)."""
        s, sd, sdd = self.profile(t)
        u = self._u_of_s(s)
        p, dp, ddp = self.curve.point(u)
        su = _norm(dp)
        tx, ty, tz = dp[0] / su, dp[1] / su, dp[2] / su  # dp/ds
        td = tx * ddp[0] + ty * ddp[1] + tz * ddp[2]
        k = 1.0 / (su * su)
        cx, cy, cz = (ddp[0] - td * tx) * k, (ddp[1] - td * ty) * k, (ddp[2] - td * tz) * k
        sd2 = sd * sd
        return (p, (tx * sd, ty * sd, tz * sd),
                (cx * sd2 + tx * sdd, cy * sd2 + ty * sdd, cz * sd2 + tz * sdd))


@dataclass
class Task:
    """A named path played forward and back, with dwells at both ends."""

    name: str
    segments: list[Segment]
    dwell: float = 0.05
    reference_length_m: float | None = None
    reference_duration_s: float | None = None
    _cache: dict = field(default_factory=dict, repr=False, compare=False)
    _points: dict = field(default_factory=dict, repr=False, compare=False)
    _step: float = field(default=0.0, repr=False, compare=False)
    _grid: int = field(default=0, repr=False, compare=False)

    @property
    def length(self) -> float:
        """Length of the path one way (m)."""
        return sum(s.length for s in self.segments)

    @property
    def duration(self) -> float:
        """Duration of the path one way (s)."""
        return sum(s.duration for s in self.segments)

    @property
    def period(self) -> float:
        """Forward, dwell, backward, dwell (s)."""
        return 2.0 * (self.duration + self.dwell)

    def align(self, step: float) -> Task:
        """Lengthen the dwell so that one loop is a whole number of ``step`` (e.g. half a
        sampling period): the reference then repeats exactly and its cache hits."""
        n = math.ceil(self.period / step - 1e-9)
        self.dwell = 0.5 * n * step - self.duration
        self._cache.clear()
        self._points.clear()
        self._step, self._grid = step, n
        return self

    def start(self) -> np.ndarray:
        """Position at ``t = 0`` (m)."""
        return np.array(self.segments[0].sample(0.0)[0])

    def sample_path(self, t: float) -> tuple[Vec3, Vec3, Vec3]:
        """One way along the path, clamped to its ends."""
        for seg in self.segments:
            if t <= seg.duration:
                return seg.sample(t)
            t -= seg.duration
        return self.segments[-1].sample(self.segments[-1].duration)

    def sample(self, t: float) -> tuple[Vec3, Vec3, Vec3]:
        """Reference ``(p_c, pdot_c, pddot_c)`` at time ``t >= 0`` of the looping task.

        After :meth:`align`, times on the aligned grid are cached by their index within
        one loop (a run meets the same times again every loop; the cache stays bounded by
        the loop's length), with the time within the loop they were computed at; other
        times are computed."""
        step = self._step
        if step:
            x = t / step
            k = round(x)
            if abs(x - k) < 1e-6:
                key = k % self._grid
                hit = self._cache.get(key)
                if hit is None:
                    hit = self._cache[key] = (t % self.period, self._sample(t))
                return hit[1]
        return self._sample(t)

    def position(self, t: float) -> Vec3:
        """Reference position at ``t`` (Eq. II.33), the tracking error's reference. After
        :meth:`align`, a time on the grid is taken at its point in the loop, ``(k mod
        grid) * step`` for grid index ``k``: the same reference (it depends on ``t`` only
        through the time within the loop), rounded once rather than through ``t``'s own
        rounding. So it is a function of the grid index alone, whatever was asked before:
        the central, report and plot agree bit for bit, and it is computed once per grid
        point. Other times are computed at ``t``."""
        step = self._step
        if step:
            x = t / step
            k = round(x)
            if abs(x - k) < 1e-6:
                key = k % self._grid
                p = self._points.get(key)
                if p is None:
                    p = self._points[key] = self._sample(key * step)[0]
                return p
        return self._sample(t)[0]

    def _sample(self, t: float) -> tuple[Vec3, Vec3, Vec3]:
        d, w = self.duration, self.dwell
        t = t % self.period
        if t <= d:
            return self.sample_path(t)
        zero = (0.0, 0.0, 0.0)
        if t <= d + w:
            return self.sample_path(d)[0], zero, zero
        if t <= 2.0 * d + w:
            p, v, a = self.sample_path(2.0 * d + w - t)
            return p, (-v[0], -v[1], -v[2]), a
        return self.sample_path(0.0)[0], zero, zero


def circle_task() -> Task:
    """§ V.6.1: half circle of radius 0.4 m in z = -0.35 m, 120 m/s^2 peak
    (docs/thesis-notes.md)."""
    seg = Segment(arc((0.0, 0.0, -0.35), (0.0, 0.4, -0.35), (0.0, -0.4, -0.35)), 120.0)
    return Task("circle", [seg], reference_length_m=1.257, reference_duration_s=0.253)


def pick_place_task() -> Task:
    """§ V.6.2: half ellipse through (0.125,0,-0.35), (0,0,-0.31), (-0.125,0,-0.35),
    80 m/s^2 peak (docs/thesis-notes.md)."""
    seg = Segment(
        half_ellipse((0.125, 0.0, -0.35), (0.0, 0.0, -0.31), (-0.125, 0.0, -0.35)), 80.0
    )
    return Task("pick-place", [seg], reference_length_m=0.292, reference_duration_s=0.153)


TASKS = {"circle": circle_task, "pick-place": pick_place_task}
