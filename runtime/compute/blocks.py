"""Implementations of the stage graph's kernels, bound to value names.

Each kernel reads and writes a context: a dict of values where per-axis values (``*_i``) are
lists of three (``None`` for axes this process does not hold). The same bound functions
run on the central, on the peripherals and in the single-process reference, so the
arithmetic does not depend on where a block runs.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

from ...kernels import kinematics as kin
from ...kernels.dynamics import ModelCoefficients, coefficients, operational_force
from ...kernels.laws import Gains, nominal_joint_inertia, operational_command, saturate
from ...kernels.params import DeltaParams
from ...kernels.trajectory import Task
from ...topology.graph import Block

Ctx = dict


@dataclass
class BlockConfig:
    """What the kernels need besides their inputs."""

    params: DeltaParams
    coef: ModelCoefficients
    gains: Gains
    a0: float
    task: Task | None
    period: float
    observer: str
    lead: float = 0.0
    """Feed-forward lead (s): the reference acceleration is taken at the middle of the
    period in which the command will act, ``(delay + 1/2) T`` after the sample, where
    ``delay`` is the number of periods from the sample to that period's start; the blocks
    ``inflight`` (to the period's start) and ``ahead`` (half a period on) predict the state
    at that instant. An interval whose command acts for ``hold`` periods (the source
    ``hold``, 2 once a realtime run halved its control rate) takes the middle of those,
    ``(delay + hold/2) T`` (:func:`lead_of`)."""
    delay: int = 0
    """Periods from a sample to the start of the period in which its command acts."""

    @classmethod
    def build(
        cls,
        params: DeltaParams,
        *,
        model: str,
        gains: Gains,
        task: Task | None,
        period: float,
        observer: str,
        delay: int = 0,
    ) -> BlockConfig:
        return cls(params, coefficients(params, model), gains, nominal_joint_inertia(params),
                   task, period, observer, (delay + 0.5) * period, delay)


class ObserverDiverged(RuntimeError):
    """The Newton-Raphson observer left the reachable space or did not converge."""


# --- central kernels: f(ctx, cfg, names) -------------------------------------------------


def lead_of(cfg: BlockConfig, hold: int) -> float:
    """The feed-forward lead (s) of an interval whose command acts for ``hold`` periods:
    the middle of that span, ``cfg.lead + (hold - 1) T / 2`` (:attr:`BlockConfig.lead`;
    exactly ``cfg.lead`` at ``hold = 1``)."""
    return cfg.lead if hold == 1 else cfg.lead + 0.5 * (hold - 1) * cfg.period


def k_reference(c: Ctx, cfg: BlockConfig, n: dict[str, str]) -> None:
    """The reference position and velocity at the sample's instant, and its acceleration
    at the middle of the span in which the command acts (Eq. II.33, :func:`lead_of`)."""
    assert cfg.task is not None
    t = c[n["t"]]
    p, v, _ = cfg.task.sample(t)
    a = cfg.task.sample(t + lead_of(cfg, c[n["hold"]]))[2]
    c[n["pc"]] = (float(p[0]), float(p[1]), float(p[2]))
    c[n["vc"]] = (float(v[0]), float(v[1]), float(v[2]))
    c[n["ac"]] = (float(a[0]), float(a[1]), float(a[2]))


def k_reference_acting(c: Ctx, cfg: BlockConfig, n: dict[str, str]) -> None:
    """:func:`k_reference`, and the reference position and velocity at the start of the
    period in which the command acts, ``delay`` periods after the sample (``pcd, vcd``),
    which the law servoes the predicted state to (:func:`k_inflight`)."""
    k_reference(c, cfg, n)
    assert cfg.task is not None
    p, v, _ = cfg.task.sample(c[n["t"]] + cfg.delay * cfg.period)
    c[n["pcd"]] = (float(p[0]), float(p[1]), float(p[2]))
    c[n["vcd"]] = (float(v[0]), float(v[1]), float(v[2]))


def _start_point(est: tuple, dt: float, observer: str) -> Vec:
    """The Newton-Raphson start: the estimate carried ``dt`` on at its own velocity and
    acceleration, ``p + pdot dt + pddot dt^2/2`` (``predict``), or its ``p``
    (``previous``)."""
    p, pd, pdd = est[0], est[1], est[2]
    if observer != "predict":
        return tuple(p)
    h = 0.5 * dt * dt
    return (p[0] + pd[0] * dt + pdd[0] * h, p[1] + pd[1] * dt + pdd[1] * h,
            p[2] + pd[2] * dt + pdd[2] * h)


def k_predict(c: Ctx, cfg: BlockConfig, n: dict[str, str]) -> None:
    c[n["p_lin0"]] = _start_point(c[n["est"]], cfg.period, cfg.observer)


def k_predict_span(c: Ctx, cfg: BlockConfig, n: dict[str, str]) -> None:
    """The observer's starting point from an estimate that may lie several periods back
    (the source ``est2`` of a ``foreseen2`` graph): ``p + pdot dt + pddot dt^2/2`` with
    ``dt`` the time from the estimate's sample to this one's (one period for the starting
    estimate, which is at rest), as :func:`k_predict` does over one period."""
    est = c[n["est"]]
    dt = cfg.period if est[3] is None else c[n["t"]] - est[3]
    c[n["p_lin0"]] = _start_point(est, dt, cfg.observer)


def k_observer(c: Ctx, cfg: BlockConfig, n: dict[str, str]) -> None:
    rows = c[n["row_i"]]
    r = c[n["r_i"]]
    p = c[n["p_lin"]]
    try:
        j = kin.inv3((tuple(rows[0]), tuple(rows[1]), tuple(rows[2])))
    except ZeroDivisionError:
        raise ObserverDiverged(f"inverse Jacobian singular at p = {p}") from None
    step = kin.matvec3(j, (r[0], r[1], r[2]))
    new = (p[0] - step[0], p[1] - step[1], p[2] - step[2])
    if not all(math.isfinite(x) for x in new) or max(abs(x) for x in step) > 0.05:
        raise ObserverDiverged(
            f"Newton-Raphson step of {max(abs(x) for x in step):.3g} m at p = {p}: the "
            "observer lost the robot"
        )
    c[n["p"]] = new
    c[n["J"]] = j


def k_velocity(c: Ctx, cfg: BlockConfig, n: dict[str, str]) -> None:
    """``pdot = J qdot``; the backward-difference rate is the velocity half a period ago,
    so half a period of the last commanded acceleration is added."""
    qd = c[n["qdmeas_i"]]
    v = kin.matvec3(c[n["J"]], (qd[0], qd[1], qd[2]))
    a = c[n["est"]][2]
    h = 0.5 * cfg.period
    c[n["pd"]] = (v[0] + h * a[0], v[1] + h * a[1], v[2] + h * a[2])


def acting_acceleration(est: tuple, start: float, cfg: BlockConfig
                        ) -> tuple[float, float, float]:
    """The commanded acceleration acting in the period that begins at ``start`` (s): that
    of the newest interval in the estimate's history whose command is due by then (sample
    time plus ``delay`` periods), as the plant applies the newest command it has; zero
    before the first one (the plant holds the starting command, which keeps the robot
    still)."""
    due = start - cfg.delay * cfg.period + 0.5 * cfg.period  # half a period of rounding
    a = (0.0, 0.0, 0.0)
    for t_s, pdd in est[4]:
        if t_s <= due:
            a = pdd
    return a


def k_velocity_diff(c: Ctx, cfg: BlockConfig, n: dict[str, str]) -> None:
    """``pdot`` at the sample's instant from the observed positions. On the span ``dt``
    since the previous estimate, ``p - p_prev = pdot dt - integral (s - t_prev) pddot(s)
    ds``; with the accelerations of the commands that acted period by period
    (:func:`acting_acceleration`) this gives ``pdot = (p - p_prev)/dt + sum_m pddot_m T
    (s_m - t_prev)/dt``, ``s_m`` the middle of period ``m`` (``(p - p_prev)/dt +
    pddot dt/2`` at constant acceleration). ``J qdot`` of the backward-difference rates
    (:func:`k_velocity`) maps the rate of half a period ago with this sample's Jacobian,
    off by ``dt/2 Jdot qdot`` (docs/architecture.md, where the model is evaluated). With
    no earlier estimate (the first interval) the handed-off velocity is kept."""
    est = c[n["est"]]
    p_prev, pd_prev, t_prev = est[0], est[1], est[3]
    t = c[n["t"]]
    dt = t - t_prev if t_prev is not None else 0.0
    if dt <= 0.0:
        c[n["pd"]] = tuple(pd_prev)
        return
    T = cfg.period
    m = max(1, round(dt / T))
    w = T / dt
    cx = cy = cz = 0.0
    for k in range(m):
        a = acting_acceleration(est, t_prev + k * T, cfg)
        s = (k + 0.5) * T * w
        cx += a[0] * s
        cy += a[1] * s
        cz += a[2] * s
    p = c[n["p"]]
    c[n["pd"]] = ((p[0] - p_prev[0]) / dt + cx, (p[1] - p_prev[1]) / dt + cy,
                  (p[2] - p_prev[2]) / dt + cz)


def k_inflight(c: Ctx, cfg: BlockConfig, n: dict[str, str]) -> None:
    """The state at the start of the period in which this interval's command acts,
    ``delay`` periods after the sample: the observed ``p, pdot`` carried forward period by
    period at the accelerations of the commands already sent (:func:`acting_acceleration`),
    ``p += pdot T + pddot T^2/2``, ``pdot += pddot T`` (a Smith predictor: the law then
    servoes the state its command will meet, docs/architecture.md)."""
    c[n["p0"]], c[n["v0"]] = carried(c[n["est"]], c[n["t"]], cfg.delay, cfg, c[n["p"]],
                                     c[n["pd"]])


Vec = tuple[float, float, float]


def carried(est: tuple, start: float, periods: int, cfg: BlockConfig, p: Vec, v: Vec
            ) -> tuple[Vec, Vec]:
    """``p, pdot`` at ``start`` (s) carried ``periods`` periods forward, each at the
    acceleration of the command acting in it (:func:`acting_acceleration`): ``p += pdot T
    + pddot T^2/2``, ``pdot += pddot T``."""
    T = cfg.period
    (px, py, pz), (vx, vy, vz) = p, v
    h = 0.5 * T * T
    for k in range(periods):
        a = acting_acceleration(est, start + k * T, cfg)
        px += vx * T + a[0] * h
        py += vy * T + a[1] * h
        pz += vz * T + a[2] * h
        vx += a[0] * T
        vy += a[1] * T
        vz += a[2] * T
    return (px, py, pz), (vx, vy, vz)


def half_span(p: Vec, v: Vec, a: Vec, L: float) -> tuple[Vec, Vec]:
    """``p, pdot`` carried ``L`` (s) on at the acceleration ``a``: ``p + pdot L + a
    L^2/2``, ``pdot + a L``."""
    h = 0.5 * L * L
    return ((p[0] + v[0] * L + a[0] * h, p[1] + v[1] * L + a[1] * h,
             p[2] + v[2] * L + a[2] * h), (v[0] + a[0] * L, v[1] + a[1] * L, v[2] + a[2] * L))


def k_law(c: Ctx, cfg: BlockConfig, n: dict[str, str]) -> None:
    c[n["pdd"]] = operational_command(cfg.gains, c[n["pc"]], c[n["vc"]], c[n["ac"]], c[n["p"]],
                                      c[n["pd"]])


def k_ahead(c: Ctx, cfg: BlockConfig, n: dict[str, str]) -> None:
    """The state in the middle of the span in which the command acts: the state at its
    start (:func:`k_inflight`) carried forward half the span at the commanded ``pddot``,
    ``pa = p0 + pdot0 L + pddot L^2/2``, ``pda = pdot0 + pddot L``, ``L = hold T/2``
    (``hold``: the periods the command acts for; docs/architecture.md, where the model is
    evaluated)."""
    c[n["pa"]], c[n["pda"]] = half_span(c[n["p"]], c[n["pd"]], c[n["pdd"]],
                                        0.5 * cfg.period * c[n["hold"]])


def k_foresee(c: Ctx, cfg: BlockConfig, n: dict[str, str]) -> None:
    """The state in the middle of the span in which this interval's command acts, foreseen
    before its sample from the estimate the previous interval handed off: that estimate's
    ``p, pdot`` carried forward period by period from its own sample to the start of the
    span at the accelerations of the commands already sent (:func:`acting_acceleration`,
    as :func:`k_inflight`), then half the span, ``L = hold T/2``, at the reference
    acceleration ``ac`` (the command of this interval is not known yet). With no earlier
    estimate (the first interval) the estimate's state is taken at the sample's instant.
    The model's kinematics evaluated there need no sample, so at depth 2 they run while
    the previous interval is finishing (docs/architecture.md, where the model is
    evaluated)."""
    est = c[n["est"]]
    t, T = c[n["t"]], cfg.period
    start = t if est[3] is None else est[3]
    p0, v0 = carried(est, start, max(0, round((t - start) / T)) + cfg.delay, cfg, est[0],
                     est[1])
    c[n["pa"]], c[n["pda"]] = half_span(p0, v0, c[n["ac"]], 0.5 * T * c[n["hold"]])


def k_task_accel(c: Ctx, cfg: BlockConfig, n: dict[str, str]) -> None:
    rows = c[n["row_i"]]
    j = kin.inv3((tuple(rows[0]), tuple(rows[1]), tuple(rows[2])))
    qdd, jdp = c[n["qddcmd_i"]], c[n["jdp_i"]]
    c[n["pdd"]] = kin.matvec3(j, (qdd[0] - jdp[0], qdd[1] - jdp[1], qdd[2] - jdp[2]))


def k_dyn_central(c: Ctx, cfg: BlockConfig, n: dict[str, str]) -> None:
    rows = c[n["row_i"]]
    j = kin.inv3((tuple(rows[0]), tuple(rows[1]), tuple(rows[2])))
    f = operational_force(cfg.coef, c[n["pdd"]], [tuple(x) for x in c[n["f_i"]]])
    jt = kin.matTvec3(j, f)
    tq = c[n["tauq_i"]]
    tau = [tq[0] + jt[0], tq[1] + jt[1], tq[2] + jt[2]]
    fb = c.get(n.get("taufb_i", "taufb_i"))
    if fb is not None:
        tau = [tau[k] + fb[k] for k in range(3)]
    c[n["tau"]] = tau


def k_gravity_central(c: Ctx, cfg: BlockConfig, n: dict[str, str]) -> None:
    q = c[n["qmeas_i"]]
    fb = c[n["taufb_i"]]
    jt = kin.matTvec3(c[n["J"]], (0.0, 0.0, cfg.coef.p_g))
    c[n["tau"]] = [fb[k] + cfg.coef.q_g * math.cos(q[k]) + jt[k] for k in range(3)]


def k_collect(c: Ctx, cfg: BlockConfig, n: dict[str, str]) -> None:
    c[n["tau"]] = list(c[n["taufb_i"]])


def k_output(c: Ctx, cfg: BlockConfig, n: dict[str, str]) -> None:
    tau = c[n["tau"]]
    c[n["cmd"]] = list(saturate((tau[0], tau[1], tau[2]), cfg.params.tau_max))


CENTRAL_KERNELS: dict[str, Callable[[Ctx, BlockConfig, dict[str, str]], None]] = {
    "reference": k_reference, "reference_acting": k_reference_acting, "predict": k_predict,
    "observer": k_observer, "velocity": k_velocity, "velocity_diff": k_velocity_diff,
    "inflight": k_inflight, "law": k_law, "ahead": k_ahead, "foresee": k_foresee,
    "predict_span": k_predict_span,
    "task_accel": k_task_accel,
    "dyn_central": k_dyn_central, "gravity_central": k_gravity_central,
    "collect": k_collect, "output": k_output,
}


def names_for(block: Block) -> dict[str, str]:
    """The kernel's default value names mapped through the block's bindings."""

    class _Default(dict):
        def __missing__(self, key: str) -> str:
            self[key] = key  # the next lookup is a plain hit
            return key

    d = _Default()
    d.update(dict(block.bind))
    return d
