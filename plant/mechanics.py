"""Constrained multibody mechanics of the Delta, derived from its bodies.

Independent of the controller's model: no inverse kinematics, no Jacobian, no two-spaces
model from :mod:`ctrlunit.kernels` (only the parameter record). The coordinates are the
natural ones, ``x = (q_1, q_2, q_3, p_x, p_y, p_z)``: three arm angles and the platform
position, tied by the geometric constraints of Eq. II.8,

    phi_i = |d_i|^2 - l_b^2 = 0,    d_i = p + R_i [r_b, 0, 0] - R_i [r_a + l_a cos q_i, 0,
                                                                    l_a sin q_i].

Bodies
------
* arm ``i``: rotational inertia ``j_arm`` about its joint, centre of mass at ``g_a`` (for
  gravity);
* forearm ``i``: a rigid thin rod between the arm tip ``A`` and the platform joint ``B``,
  mass ``m_b`` with its centre of mass at ``rho = g_b / l_b`` from ``A`` and transverse
  inertia ``j_b``. Its kinetic energy is the quadratic form
  ``1/2 [vA vB] K [vA vB]^T`` with ``K = [[m_b (1-rho)^2 + j, m_b rho (1-rho) - j],
  [.., m_b rho^2 + j]]``, ``j = j_b / l_b^2`` (rigid-body kinetic energy written with the
  end-point velocities);
* platform: point mass ``m_c``.

Lagrange's equations with multipliers ``lambda``::

    M(x) xddot + G(x)^T lambda = Q(x, xdot, tau)
    G(x) xddot = -gamma(x, xdot)                  (phi_ddot = 0)

with ``G = d phi / dx``. The nine unknowns are solved by eliminating ``qddot`` per axis and
then ``lambda``, leaving one 3x3 system in ``pddot`` (all on plain floats: the plant runs
many sub-steps per control period). Drift is removed by projecting positions and
velocities back onto the constraint manifold after every sub-step.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from ..kernels.params import GRAVITY, DeltaParams

_G = (0.0, 2.0 * math.pi / 3.0, 4.0 * math.pi / 3.0)
COS = tuple(math.cos(g) for g in _G)
SIN = tuple(math.sin(g) for g in _G)

Vec = list[float]


@dataclass(frozen=True)
class BodyConstants:
    """Constants of the bodies derived from :class:`DeltaParams`.

    Attributes
    ----------
    j_arm : arm rotational inertia used on the arm side (kg m^2).
    k_aa, k_ab, k_bb : forearm end-point kinetic matrix entries (kg).
    m_plat : platform mass plus the forearms' share at the platform end (kg).
    grav_arm : gravity torque gain on each arm, ``g (m_a g_a + m_b (1-rho) l_a)`` (N m).
    grav_plat : gravity force on the platform coordinates ``g (m_c + 3 m_b rho)`` (N).
    """

    j_arm: float
    k_aa: float
    k_ab: float
    k_bb: float
    m_plat: float
    grav_arm: float
    grav_plat: float


def body_constants(params: DeltaParams, *, arm_inertia: float | None = None) -> BodyConstants:
    """Constants of the bodies; ``arm_inertia`` overrides ``j_a`` (e.g. minus the motor's
    share when an elastic belt separates the motor)."""
    rho = params.g_b / params.l_b
    j = params.j_b / params.l_b**2
    k_aa = params.m_b * (1.0 - rho) ** 2 + j
    k_ab = params.m_b * rho * (1.0 - rho) - j
    k_bb = params.m_b * rho**2 + j
    return BodyConstants(
        j_arm=params.j_a if arm_inertia is None else arm_inertia,
        k_aa=k_aa,
        k_ab=k_ab,
        k_bb=k_bb,
        m_plat=params.m_c + 3.0 * k_bb,
        # gravity: arm centre of mass, and the rod's mass (1-rho) at A-end, rho at B-end
        # (the rod's centre of mass height is linear in the end heights)
        grav_arm=GRAVITY * (params.m_a * params.g_a + params.m_b * (1.0 - rho) * params.l_a),
        grav_plat=GRAVITY * (params.m_c + 3.0 * params.m_b * rho),
    )


def _solve3(a: list[list[float]], b: Vec) -> Vec:
    """Solve a 3x3 system by Gaussian elimination with partial pivoting (the first row of
    largest magnitude is the pivot), written out: the same operations in the same order as
    the loop over columns it replaces, so the same bits (a NaN's sign aside) and the same
    ZeroDivisionError, at about a fifth of its cost (the plant projects once a period)."""
    r0, r1, r2 = a[0] + [b[0]], a[1] + [b[1]], a[2] + [b[2]]
    # column 0: the pivot as max(key=abs) picks it (NaN included)
    piv, top = 0, abs(r0[0])
    if abs(r1[0]) > top:
        piv, top = 1, abs(r1[0])
    if abs(r2[0]) > top:
        piv = 2
    if piv == 1:
        r0, r1 = r1, r0
    elif piv == 2:
        r0, r2 = r2, r0
    inv = 1.0 / r0[0]
    f = r1[0] * inv
    if f != 0.0:
        r1 = [r1[0] - f * r0[0], r1[1] - f * r0[1], r1[2] - f * r0[2], r1[3] - f * r0[3]]
    f = r2[0] * inv
    if f != 0.0:
        r2 = [r2[0] - f * r0[0], r2[1] - f * r0[1], r2[2] - f * r0[2], r2[3] - f * r0[3]]
    # column 1
    if abs(r2[1]) > abs(r1[1]):
        r1, r2 = r2, r1
    inv = 1.0 / r1[1]
    f = r2[1] * inv
    if f != 0.0:
        r2 = [r2[0], r2[1] - f * r1[1], r2[2] - f * r1[2], r2[3] - f * r1[3]]
    x2 = r2[3] / r2[2]
    x1 = (r1[3] - (0 + r1[2] * x2)) / r1[1]
    x0 = (r0[3] - (0 + r0[1] * x1 + r0[2] * x2)) / r0[0]
    return [x0, x1, x2]


class Geometry:
    """Per-axis geometric quantities at a configuration ``(q, p)``."""

    __slots__ = ("d", "u", "v")

    def __init__(self, params: DeltaParams, q: Vec, p: Vec) -> None:
        l_a = params.l_a
        self.u: list[tuple[float, float, float]] = []
        self.v: list[tuple[float, float, float]] = []
        self.d: list[tuple[float, float, float]] = []
        for i in range(3):
            c, s = COS[i], SIN[i]
            cq, sq = math.cos(q[i]), math.sin(q[i])
            # arm direction v and its derivative u (world)
            v = (c * cq, s * cq, sq)
            u = (-c * sq, -s * sq, cq)
            rad = params.r_a + l_a * cq - params.r_b
            d = (p[0] - c * rad, p[1] - s * rad, p[2] - l_a * sq)
            self.u.append(u)
            self.v.append(v)
            self.d.append(d)


def constraint_residual(params: DeltaParams, q: Vec, p: Vec) -> Vec:
    """``|d_i| - l_b`` for each forearm (m): the constraint error as a length."""
    g = Geometry(params, q, p)
    return [math.sqrt(d[0] ** 2 + d[1] ** 2 + d[2] ** 2) - params.l_b for d in g.d]


def _inv_sym3(a00, a01, a02, a11, a12, a22):
    """Inverse of a symmetric 3x3 matrix as its six distinct entries."""
    c00 = a11 * a22 - a12 * a12
    c01 = a02 * a12 - a01 * a22
    c02 = a01 * a12 - a02 * a11
    c11 = a00 * a22 - a02 * a02
    c12 = a01 * a02 - a00 * a12
    c22 = a00 * a11 - a01 * a01
    inv = 1.0 / (a00 * c00 + a01 * c01 + a02 * c02)
    return c00 * inv, c01 * inv, c02 * inv, c11 * inv, c12 * inv, c22 * inv


def _multipliers(a: float, a0: tuple[float, float, float, float, float, float],
                 r1: tuple[float, float, float],
                 es: list[tuple[float, float, float]], gqs: list[float], r2s: list[float]
                 ) -> tuple[float, float, float, float, float, float]:
    """The platform's acceleration and the multipliers of :func:`accelerations`' reduced
    system: ``lam = (E^T A0^-1 E + D)^-1 (E^T A0^-1 r1 - r2)``, ``pdd = A0^-1 (r1 - E
    lam)``, with ``A0`` given by its upper triangle and ``D = diag(Gq_i^2 / a)``. Returns
    ``(pdd_x, pdd_y, pdd_z, lam_0, lam_1, lam_2)``."""
    a00, a01, a02, a11, a12, a22 = a0
    b0, b1, b2 = r1
    i00, i01, i02, i11, i12, i22 = _inv_sym3(a00, a01, a02, a11, a12, a22)
    (e00, e01, e02), (e10, e11, e12), (e20, e21, e22) = es
    # y = A0^-1 r1 and A0^-1 e_i
    yr0 = i00 * b0 + i01 * b1 + i02 * b2
    yr1 = i01 * b0 + i11 * b1 + i12 * b2
    yr2 = i02 * b0 + i12 * b1 + i22 * b2
    y00 = i00 * e00 + i01 * e01 + i02 * e02
    y01 = i01 * e00 + i11 * e01 + i12 * e02
    y02 = i02 * e00 + i12 * e01 + i22 * e02
    y10 = i00 * e10 + i01 * e11 + i02 * e12
    y11 = i01 * e10 + i11 * e11 + i12 * e12
    y12 = i02 * e10 + i12 * e11 + i22 * e12
    y20 = i00 * e20 + i01 * e21 + i02 * e22
    y21 = i01 * e20 + i11 * e21 + i12 * e22
    y22 = i02 * e20 + i12 * e21 + i22 * e22
    # S = E^T A0^-1 E + D (symmetric), rhs = E^T A0^-1 r1 - r2
    g0, g1, g2 = gqs
    s00 = e00 * y00 + e01 * y01 + e02 * y02 + g0 * g0 / a
    s11 = e10 * y10 + e11 * y11 + e12 * y12 + g1 * g1 / a
    s22 = e20 * y20 + e21 * y21 + e22 * y22 + g2 * g2 / a
    s01 = e00 * y10 + e01 * y11 + e02 * y12
    s02 = e00 * y20 + e01 * y21 + e02 * y22
    s12 = e10 * y20 + e11 * y21 + e12 * y22
    h0 = e00 * yr0 + e01 * yr1 + e02 * yr2 - r2s[0]
    h1 = e10 * yr0 + e11 * yr1 + e12 * yr2 - r2s[1]
    h2 = e20 * yr0 + e21 * yr1 + e22 * yr2 - r2s[2]
    j00, j01, j02, j11, j12, j22 = _inv_sym3(s00, s01, s02, s11, s12, s22)
    l0 = j00 * h0 + j01 * h1 + j02 * h2
    l1 = j01 * h0 + j11 * h1 + j12 * h2
    l2 = j02 * h0 + j12 * h1 + j22 * h2
    x0 = yr0 - l0 * y00 - l1 * y10 - l2 * y20
    x1 = yr1 - l0 * y01 - l1 * y11 - l2 * y21
    x2 = yr2 - l0 * y02 - l1 * y12 - l2 * y22
    return x0, x1, x2, l0, l1, l2


def accelerations(
    params: DeltaParams,
    bc: BodyConstants,
    q: Vec,
    p: Vec,
    qd: Vec,
    pd: Vec,
    tau: Vec,
) -> tuple[Vec, Vec]:
    """Solve the equations of motion with multipliers for ``(qddot, pddot)``.

    ``tau`` is the net generalised torque on each arm coordinate (actuator, belt and
    friction already combined), N m. Written out by hand: the plant evaluates it four
    times per sub-step.

    Elimination: the arm rows give ``qdd_i = (Qq_i - s u_i.pdd - Gq_i lam_i) / a``; the
    platform rows then read ``A0 pdd + E lam = r1`` with the positive definite
    ``A0 = m I - (s^2/a) sum u_i u_i^T`` and ``e_i = 2 d_i - (s Gq_i / a) u_i``; the
    constraint rows ``E^T pdd - D lam = r2`` with ``D = diag(Gq_i^2 / a)``. So
    ``(E^T A0^-1 E + D) lam = E^T A0^-1 r1 - r2``: positive definite while the constraint
    gradients are independent, also where ``Gq_i = 0`` (arm and forearm aligned).
    """
    l_a = params.l_a
    a = bc.j_arm + bc.k_aa * l_a * l_a
    s = bc.k_ab * l_a
    s_a = s / a
    ss_a = s * s_a
    px, py, pz = p
    rr = params.r_a - params.r_b
    a00 = a11 = a22 = bc.m_plat
    a01 = a02 = a12 = 0.0
    b0, b1, b2 = 0.0, 0.0, -bc.grav_plat
    us, es, Qqs, Gqs, r2s = [], [], [], [], []
    for i in range(3):
        c, sn = COS[i], SIN[i]
        cq, sq = math.cos(q[i]), math.sin(q[i])
        vx, vy, vz = c * cq, sn * cq, sq
        ux, uy, uz = -c * sq, -sn * sq, cq
        rad = rr + l_a * cq
        dx, dy, dz = px - c * rad, py - sn * rad, pz - l_a * sq
        w = qd[i]
        w2 = w * w
        Qq = tau[i] - bc.grav_arm * cq
        kv = bc.k_ab * l_a * w2
        Gq = -2.0 * l_a * (dx * ux + dy * uy + dz * uz)
        ex, ey, ez = pd[0] - l_a * ux * w, pd[1] - l_a * uy * w, pd[2] - l_a * uz * w
        gam = 2.0 * (ex * ex + ey * ey + ez * ez) + 2.0 * l_a * w2 * (dx * vx + dy * vy + dz * vz)
        k = Gq * s_a
        sq_a = s_a * Qq
        b0 += kv * vx - sq_a * ux
        b1 += kv * vy - sq_a * uy
        b2 += kv * vz - sq_a * uz
        a00 -= ss_a * ux * ux
        a11 -= ss_a * uy * uy
        a22 -= ss_a * uz * uz
        a01 -= ss_a * ux * uy
        a02 -= ss_a * ux * uz
        a12 -= ss_a * uy * uz
        us.append((ux, uy, uz))
        es.append((2.0 * dx - k * ux, 2.0 * dy - k * uy, 2.0 * dz - k * uz))
        Qqs.append(Qq)
        Gqs.append(Gq)
        r2s.append(-gam - Gq * Qq / a)
    x0, x1, x2, l0, l1, l2 = _multipliers(a, (a00, a01, a02, a11, a12, a22), (b0, b1, b2),
                                          es, Gqs, r2s)
    g0, g1, g2 = Gqs
    (u00, u01, u02), (u10, u11, u12), (u20, u21, u22) = us
    q0, q1, q2 = Qqs
    return [
        (q0 - s * (u00 * x0 + u01 * x1 + u02 * x2) - g0 * l0) / a,
        (q1 - s * (u10 * x0 + u11 * x1 + u12 * x2) - g1 * l1) / a,
        (q2 - s * (u20 * x0 + u21 * x1 + u22 * x2) - g2 * l2) / a,
    ], [x0, x1, x2]


def project(params: DeltaParams, q: Vec, p: Vec, qd: Vec, pd: Vec) -> tuple[Vec, Vec]:
    """Project onto the constraint manifold: positions by Gauss-Newton on ``p`` (arm angles
    kept), velocities so that ``G xdot = 0`` by correcting ``pdot``.

    Returns the corrected ``(p, pdot)``.
    """
    p = list(p)
    for _ in range(3):
        geo = Geometry(params, q, p)
        phi = [d[0] ** 2 + d[1] ** 2 + d[2] ** 2 - params.l_b**2 for d in geo.d]
        if max(abs(x) for x in phi) < 1e-15:
            break  # ``geo`` is the geometry at ``p``
        jac = [[2.0 * d[0], 2.0 * d[1], 2.0 * d[2]] for d in geo.d]
        step = _solve3(jac, phi)
        p = [p[0] - step[0], p[1] - step[1], p[2] - step[2]]
    else:
        geo = Geometry(params, q, p)
    # velocity: 2 d_i.(pd - l_a u_i qd_i) = 0
    jac = [[2.0 * d[0], 2.0 * d[1], 2.0 * d[2]] for d in geo.d]
    rhs = []
    for i in range(3):
        d, u = geo.d[i], geo.u[i]
        rhs.append(
            2.0 * (d[0] * (pd[0] - params.l_a * u[0] * qd[i])
                   + d[1] * (pd[1] - params.l_a * u[1] * qd[i])
                   + d[2] * (pd[2] - params.l_a * u[2] * qd[i]))
        )
    corr = _solve3(jac, rhs)
    return p, [pd[0] - corr[0], pd[1] - corr[1], pd[2] - corr[2]]


def assemble_platform(params: DeltaParams, q: Vec, p_guess: Vec) -> Vec:
    """Platform position that closes the three loops for arm angles ``q``, by Newton on the
    constraints from ``p_guess`` (the plant's own forward kinematics). Plain floats out
    whatever comes in: one numpy scalar in the state makes every later sub-step numpy
    arithmetic, 3.4 times slower (a task's start point is a numpy array)."""
    q = [float(v) for v in q]
    p, _ = project(params, q, [float(v) for v in p_guess], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0])
    for _ in range(20):
        res = constraint_residual(params, q, p)
        if max(abs(r) for r in res) < 1e-13:
            break
        p, _ = project(params, q, p, [0.0, 0.0, 0.0], [0.0, 0.0, 0.0])
    return p


def platform_velocity(params: DeltaParams, q: Vec, p: Vec, qd: Vec) -> Vec:
    """``pdot`` consistent with arm rates ``qd`` (solves ``G xdot = 0`` for ``pdot``)."""
    _, pd = project(params, q, p, qd, [0.0, 0.0, 0.0])
    return pd


def energy(params: DeltaParams, bc: BodyConstants, q: Vec, p: Vec, qd: Vec, pd: Vec) -> float:
    """Kinetic plus potential energy of the bodies (J), potential zero at z = 0."""
    l_a = params.l_a
    ke = 0.5 * bc.m_plat * (pd[0] ** 2 + pd[1] ** 2 + pd[2] ** 2)
    pe = bc.grav_plat * p[2]
    geo = Geometry(params, q, p)
    for i in range(3):
        u = geo.u[i]
        va = (l_a * u[0] * qd[i], l_a * u[1] * qd[i], l_a * u[2] * qd[i])
        ke += 0.5 * bc.j_arm * qd[i] ** 2
        ke += 0.5 * bc.k_aa * (va[0] ** 2 + va[1] ** 2 + va[2] ** 2)
        ke += bc.k_ab * (va[0] * pd[0] + va[1] * pd[1] + va[2] * pd[2])
        pe += bc.grav_arm * math.sin(q[i])
    return ke + pe
