"""The per-axis kernels of the stage graph, bound to value names: ``f(ctx, i, cfg,
names)`` computes axis ``i`` (:mod:`.blocks` holds the central ones and the conventions).

Each wraps a kernel of :mod:`ctrlunit.kernels`: the axis's inverse kinematics (Eq.
V.16-V.21), its row of J^-1 (Eq. V.24-V.26), the row's d/dt(J^-1) pdot (Eq. V.28-V.30),
the joint acceleration (Eq. V.31), the axis's share of the dynamics (Eq. V.38-V.50) and the
joint laws (Eq. IV.13-IV.14). A point out of reach is :class:`~.blocks.ObserverDiverged`.
"""

from __future__ import annotations

from collections.abc import Callable

from ...kernels import kinematics as kin
from ...kernels.dynamics import axis_dynamics
from ...kernels.laws import joint_command, joint_pd
from .blocks import BlockConfig, Ctx, ObserverDiverged


def k_ik(c: Ctx, i: int, cfg: BlockConfig, n: dict[str, str]) -> None:
    p = c[n["p"]]
    try:
        ax = kin.ik_axis(cfg.params, i, p[0], p[1], p[2])
    except kin.UnreachableError as exc:
        raise ObserverDiverged(str(exc)) from None
    c[n["ax_i"]][i] = ax
    c[n["q_i"]][i] = ax.q


def k_jinv(c: Ctx, i: int, cfg: BlockConfig, n: dict[str, str]) -> None:
    c[n["row_i"]][i] = kin.jinv_row(cfg.params, i, _ax(c[n["ax_i"]][i]))


def k_residual(c: Ctx, i: int, cfg: BlockConfig, n: dict[str, str]) -> None:
    c[n["r_i"]][i] = c[n["q_i"]][i] - c[n["qmeas_i"]][i]


def k_jdot(c: Ctx, i: int, cfg: BlockConfig, n: dict[str, str]) -> None:
    row = c[n["row_i"]][i]
    pd = c[n["pd"]]
    qd = kin.dot_row(row, pd)
    c[n["qd_i"]][i] = qd
    c[n["jdp_i"]][i] = kin.jinvdot_pdot_row(cfg.params, i, _ax(c[n["ax_i"]][i]), pd, qd)


def k_accel(c: Ctx, i: int, cfg: BlockConfig, n: dict[str, str]) -> None:
    c[n["qdd_i"]][i] = kin.accel_row(c[n["row_i"]][i], c[n["pdd"]], c[n["jdp_i"]][i])


def k_dyn_axis(c: Ctx, i: int, cfg: BlockConfig, n: dict[str, str]) -> None:
    d = axis_dynamics(cfg.coef, i, _ax(c[n["ax_i"]][i]), c[n["qd_i"]][i], c[n["qdd_i"]][i],
                      c[n["pdd"]])
    c[n["tauq_i"]][i] = d.tau_q
    c[n["f_i"]][i] = d.force


def k_ref_rates(c: Ctx, i: int, cfg: BlockConfig, n: dict[str, str]) -> None:
    ax = _ax(c[n["axr_i"]][i])
    row = c[n["rowr_i"]][i]
    vc, ac = c[n["vc"]], c[n["ac"]]
    qd = kin.dot_row(row, vc)
    c[n["qdc_i"]][i] = qd
    c[n["qddc_i"]][i] = kin.accel_row(row, ac, kin.jinvdot_pdot_row(cfg.params, i, ax, vc, qd))


def k_joint_law(c: Ctx, i: int, cfg: BlockConfig, n: dict[str, str]) -> None:
    c[n["qddcmd_i"]][i] = joint_command(cfg.gains, c[n["qc_i"]][i], c[n["qdc_i"]][i],
                                        c[n["qddc_i"]][i], c[n["qmeas_i"]][i],
                                        c[n["qdmeas_i"]][i])


def k_joint_pd(c: Ctx, i: int, cfg: BlockConfig, n: dict[str, str]) -> None:
    c[n["taufb_i"]][i] = joint_pd(cfg.gains, cfg.a0, c[n["qc_i"]][i], c[n["qdc_i"]][i],
                                  c[n["qmeas_i"]][i], c[n["qdmeas_i"]][i])


def k_joint_pd_static(c: Ctx, i: int, cfg: BlockConfig, n: dict[str, str]) -> None:
    c[n["taufb_i"]][i] = joint_pd(cfg.gains, cfg.a0, c[n["qc_i"]][i], 0.0,
                                  c[n["qmeas_i"]][i], c[n["qdmeas_i"]][i])


def _ax(v: object) -> kin.AxisIK:
    return v if isinstance(v, kin.AxisIK) else kin.AxisIK(*v)  # type: ignore[misc]


AXIS_KERNELS: dict[str, Callable[[Ctx, int, BlockConfig, dict[str, str]], None]] = {
    "ik": k_ik, "jinv": k_jinv, "residual": k_residual, "jdot": k_jdot, "accel": k_accel,
    "dyn_axis": k_dyn_axis, "ref_rates": k_ref_rates, "joint_law": k_joint_law,
    "joint_pd": k_joint_pd, "joint_pd_static": k_joint_pd_static,
}


__all__ = ["AXIS_KERNELS"]
