"""The 1994 unit's block times on the T-800 (the ``t800`` cost model): each block of the
stage graph (:mod:`.graph`) in microseconds, split from the thesis's table
(docs/thesis-notes.md); blocks the table does not list are estimated from their FLOP
counts."""

from __future__ import annotations

# T-800 costs (us). docs/thesis-notes.md: IK 240 us for 3 axes; IK + J^-1 380 us; LU 24 us;
# d/dt(J^-1).pdot 268 us; all kinematics 1320 us; complete law 284 us; whole cycle 1604 us.
T800 = {
    "reference": 60.0,  # profile generator (not in the table; a few dozen FLOP)
    "predict": 10.0,
    "predict_span": 10.0,  # predict over the time since the estimate: as predict
    "ik": 80.0,  # 240 / 3
    "jinv": 140.0 / 3.0,  # (380 - 240) / 3
    "residual": 4.0,
    "observer": 24.0 + 36.0,  # LU of J^-1 + solve and update
    "velocity": 20.0,  # pdot = J qdot (solve with the LU)
    "velocity_diff": 12.0,  # 14 FLOP, as accel
    "jdot": 268.0 / 3.0,
    "accel": 12.0,  # 18 FLOP (§ V.3.4)
    "ahead": 12.0,  # 18 FLOP, as accel
    "foresee": 36.0,  # 18 FLOP per period carried (three at depth 2), as inflight
    "inflight": 24.0,  # 18 FLOP per period of delay, two periods (depth 2)
    "reference_acting": 90.0,  # the profile generator once more, at the acting period
    "law": 30.0,
    "dyn_axis": 30.0,
    "dyn_central": 284.0 - 30.0 - 3 * 30.0,  # rest of the 127 FLOP law after the axis part
    "output": 20.0,
    "ref_rates": 268.0 / 3.0 + 12.0,
    "joint_law": 10.0,
    "joint_pd": 10.0,
    "joint_pd_static": 8.0,
    "collect": 10.0,
    "gravity_central": 40.0,
    "task_accel": 30.0,
}
T800_NOTES = (
    "Per-block T-800 times split from the 1994 table (docs/thesis-notes.md): inverse kinematics "
    "240 us / 3 axes, inverse Jacobian (380-240) us / 3, LU 24 us, d/dt(J^-1).pdot "
    "268 us / 3, complete law 284 us split into 30 us per axis and the rest central; "
    "blocks the table does not list are estimated from their FLOP counts."
)


__all__ = ["T800", "T800_NOTES"]
