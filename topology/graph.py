"""The stage graph of one sampling interval, as data (thesis Fig. 19-21).

A graph is an ordered list of :class:`Block`. A block is ``axis`` (runs once per axis, may
run on a peripheral) or ``central`` (sequential, on the central). Values whose name ends in
``_i`` are per-axis (a list of three on the central, one entry per owned axis on a
peripheral); other values are central. The order is a valid topological order; the
exchange plan (:mod:`ctrlunit.topology.plan`) is derived from it and a placement.

Each block names the kernel it runs (``kernel``), the thesis equation, and its cost on a
T-800 in microseconds (per axis for axis blocks), derived from the 1994 timing table of
docs/thesis-notes.md (see :data:`~.t800.T800_NOTES`).
"""

from __future__ import annotations

from dataclasses import dataclass

from .t800 import T800

AXIS = "axis"
CENTRAL = "central"

LAWS = ("resolved-acceleration", "computed-torque", "pd-feedforward", "pd-gravity", "pd")
KINEMATICS = "kinematics"
"""Not a control law: the kinematics part of the resolved-acceleration interval alone
(observer, J^-1, d/dt(J^-1) pdot, acceleration mapper), for the thesis's 'all kinematics'
efficiency (1320 us on one T-800, 582 us on four)."""
OBSERVERS = ("predict", "previous")
MODEL_STATES = ("acting", "sample", "foreseen", "foreseen2")
"""Where resolved acceleration evaluates its model (the second round's kinematics and the
dynamics of Eq. V.50): ``acting``, at the state predicted for the middle of the period in
which the command acts (block ``ahead``), from a velocity at the sample's instant taken
from the observed positions (kernel ``velocity_diff``); ``sample``, at the sample's
estimate with ``pdot = J qdot`` of the backward-difference rates, as the thesis;
``foreseen``, the model's kinematics (IK, J^-1 rows, d/dt(J^-1) pdot) at the same instant
but foreseen from the previous interval's estimate (block ``foresee``), so that they need
no sample and run ahead of it at depth 2 (the feedback still uses the sample: ``inflight``
and the law are as with ``acting``); ``foreseen2``, as ``foreseen`` but from the estimate of
two intervals back (source ``est2``), the observer's prediction too, so that at depth 2
the sample-free rounds of two intervals travel in one exchange. The other laws evaluate at
the sample (or at the reference) either way."""
MEASURED = ("qmeas_i", "qdmeas_i")
"""The sources that come from the plant's sample (the others, ``t``, ``hold`` and ``est``,
are known before the sample arrives)."""
SOURCES = ("t", "hold", "est", "qmeas_i", "qdmeas_i")
"""An interval's sources: the sample's time ``t`` (s), ``hold`` (the periods its command
acts for: 1, or 2 once a realtime run halved its control rate on overload), the estimate
handed off by the previous interval, and the measured angles and rates."""
EST2 = "est2"
"""The extra source of a ``foreseen2`` graph: the newest estimate handed off by an interval
at least two periods before this one's sample (runtime/compute/controller.py), final when the
interval before this one starts."""


@dataclass(frozen=True)
class Block:
    """One block of the interval.

    Attributes
    ----------
    name : unique name in the graph.
    kind : ``"axis"`` or ``"central"``.
    kernel : the implementation to run (several blocks may share one, with other names).
    inputs, outputs : value names; ``*_i`` are per-axis.
    equation : the thesis equation it implements.
    t800_us : T-800 time for this block (per axis for axis blocks), microseconds.
    bind : pairs (kernel argument, value name) renaming the kernel's default names.
    """

    name: str
    kind: str
    kernel: str
    inputs: tuple[str, ...]
    outputs: tuple[str, ...]
    equation: str
    t800_us: float
    bind: tuple[tuple[str, str], ...] = ()

    @property
    def per_axis(self) -> bool:
        return self.kind == AXIS

    def t800_s(self, scale: float = 1.0) -> float:
        """T-800 time of the block for all the axes it runs on, seconds, times ``scale``."""
        return self.t800_us * (3 if self.per_axis else 1) * scale * 1e-6


@dataclass(frozen=True)
class StageGraph:
    """An interval as an ordered list of blocks plus the values it starts from."""

    law: str
    model: str
    observer: str
    iterations: int
    blocks: tuple[Block, ...]
    sources: tuple[str, ...]
    model_state: str = "sample"
    """Where the model is evaluated (:data:`MODEL_STATES`): ``acting`` only when the graph
    has the block ``ahead``."""

    @property
    def runs_ahead(self) -> bool:
        """Whether per-axis blocks that need no sample form rounds of their own, which at
        depth 2 run before the sample (``foreseen``: the model's kinematics); in the other
        graphs a round holds whatever per-axis blocks are ready together."""
        return self.model_state in ("foreseen", "foreseen2")

    @property
    def foresight(self) -> int:
        """How many intervals ahead of its sample an interval's sample-free steps may run:
        2 when they read the estimate of two intervals back (``foreseen2``), else 1."""
        return 2 if self.model_state == "foreseen2" else 1

    def block(self, name: str) -> Block:
        for b in self.blocks:
            if b.name == name:
                return b
        raise KeyError(name)

    @property
    def axis_blocks(self) -> tuple[Block, ...]:
        return tuple(b for b in self.blocks if b.per_axis)

    def t_single_t800_us(self) -> float:
        """T-800 time of the whole interval on one processor."""
        return sum(b.t800_s() for b in self.blocks) * 1e6


def _b(name: str, kind: str, kernel: str, inputs: str, outputs: str, eq: str,
       bind: tuple[tuple[str, str], ...] = ()) -> Block:
    return Block(name, kind, kernel, tuple(inputs.split()), tuple(outputs.split()), eq,
                 T800[kernel], bind)


def _observer_blocks(iterations: int, observer: str, *, velocity: str = "jacobian",
                     est2: bool = False) -> list[Block]:
    """Newton-Raphson observer (Eq. II.20): ``iterations`` rounds of IK + J^-1 row +
    residual on the axes, update on the central; then the velocity at the sample,
    ``jacobian`` (``pdot = J qdot``, the thesis) or ``difference`` (of the observed
    positions, docs/architecture.md, where the model is evaluated). ``est2``: the
    prediction starts from the estimate of two intervals back (:data:`EST2`), carried
    over the time since it (kernel ``predict_span``)."""
    if est2:
        out = [_b("predict", CENTRAL, "predict_span", f"t {EST2}", "p_lin0",
                  "prediction p + pdot dt + pddot dt^2/2 from the estimate two intervals "
                  "back" if observer == "predict" else "previous p", (("est", EST2),))]
    else:
        out = [_b("predict", CENTRAL, "predict", "est", "p_lin0",
                  "prediction p + pdot T + pddot T^2/2" if observer == "predict"
                  else "previous p")]
    for k in range(iterations):
        lin, nxt = f"p_lin{k}", (f"p_lin{k + 1}" if k + 1 < iterations else "p")
        s = f"{k}"
        out += [
            _b(f"ik_obs{s}", AXIS, "ik", f"{lin}", f"axo{s}_i qo{s}_i", "V.16-V.21",
               (("p", lin), ("ax_i", f"axo{s}_i"), ("q_i", f"qo{s}_i"))),
            _b(f"jinv_obs{s}", AXIS, "jinv", f"axo{s}_i", f"rowo{s}_i", "V.24-V.26",
               (("ax_i", f"axo{s}_i"), ("row_i", f"rowo{s}_i"))),
            _b(f"residual{s}", AXIS, "residual", f"qo{s}_i qmeas_i", f"r{s}_i", "II.20",
               (("q_i", f"qo{s}_i"), ("r_i", f"r{s}_i"))),
            _b(f"observer{s}", CENTRAL, "observer", f"{lin} rowo{s}_i r{s}_i",
               f"{nxt} J", "II.20 (errata sign), LU of J^-1",
               (("p_lin", lin), ("row_i", f"rowo{s}_i"), ("r_i", f"r{s}_i"), ("p", nxt))),
        ]
    if velocity == "difference":
        out.append(_b("velocity", CENTRAL, "velocity_diff", "t p est", "pd",
                      "pdot = (p - p_prev) / dt + the acting pddot, weighted by time"))
    else:
        out.append(_b("velocity", CENTRAL, "velocity", "J qdmeas_i est", "pd",
                      "pdot = J qdot"))
    return out


def _state_blocks(p: str = "p", pd: str = "pd") -> list[Block]:
    """Per-axis kinematics at the state ``p``, ``pd`` (by default the observed one): q_i,
    the J^-1 row and its derivative times pdot (Eq. V.16-V.30)."""
    return [
        _b("ik", AXIS, "ik", p, "ax_i q_i", "V.16-V.21", (("p", p),) if p != "p" else ()),
        _b("jinv", AXIS, "jinv", "ax_i", "row_i", "V.24-V.26"),
        _b("jdot", AXIS, "jdot", f"ax_i row_i {pd}", "qd_i jdp_i", "V.28-V.30",
           (("pd", pd),) if pd != "pd" else ()),
    ]


def _reference_joint_blocks() -> list[Block]:
    """Joint-space reference q_c, qdot_c, qddot_c from the operational one (per axis)."""
    return [
        _b("ik_ref", AXIS, "ik", "pc", "axr_i qc_i", "V.16-V.21",
           (("p", "pc"), ("ax_i", "axr_i"), ("q_i", "qc_i"))),
        _b("jinv_ref", AXIS, "jinv", "axr_i", "rowr_i", "V.24-V.26",
           (("ax_i", "axr_i"), ("row_i", "rowr_i"))),
        _b("ref_rates", AXIS, "ref_rates", "axr_i rowr_i vc ac", "qdc_i qddc_i", "V.28-V.31"),
    ]


def stage_graph(
    law: str = "resolved-acceleration",
    model: str = "complete",
    *,
    observer: str = "predict",
    iterations: int | None = None,
    model_state: str = "acting",
) -> StageGraph:
    """The stage graph of one interval for a control law and model.

    Parameters
    ----------
    law : one of :data:`LAWS`.
    model : ``complete`` or ``simplified``.
    observer : ``predict`` (start the Newton-Raphson from a prediction) or ``previous``
        (from the previous estimate, as the thesis).
    iterations : Newton-Raphson iterations; default 1 with ``predict``, 2 with ``previous``.
    model_state : where resolved acceleration evaluates its model (:data:`MODEL_STATES`);
        ``acting`` adds the central block ``ahead`` between the law and the second round,
        whose kinematics and dynamics then run at its predicted state ``pa, pda``, and
        takes the velocity at the sample from the observed positions (``velocity_diff``)
        rather than ``J qdot``; ``foreseen`` does the same but computes ``pa, pda``
        before the sample (block ``foresee``, from the previous interval's estimate), so
        that the second round's kinematics need no sample and come first. The graph's
        ``model_state`` is ``sample`` for the other laws.
    """
    if law not in (*LAWS, KINEMATICS):
        raise ValueError(f"law must be one of {', '.join(LAWS)}, got {law!r}")
    if model not in ("complete", "simplified"):
        raise ValueError(f"model must be complete or simplified, got {model!r}")
    if observer not in OBSERVERS:
        raise ValueError(f"observer must be one of {', '.join(OBSERVERS)}, got {observer!r}")
    if model_state not in MODEL_STATES:
        raise ValueError(f"model state must be one of {', '.join(MODEL_STATES)}, "
                         f"got {model_state!r}")
    if iterations is None:
        iterations = 1 if observer == "predict" else 2
    if not 1 <= iterations <= 5:
        raise ValueError(f"observer iterations must be in [1, 5], got {iterations}")
    acting = law == "resolved-acceleration" and model_state in ("acting", "foreseen",
                                                                "foreseen2")
    foreseen = acting and model_state in ("foreseen", "foreseen2")
    est2 = acting and model_state == "foreseen2"
    ahead_est = EST2 if est2 else "est"
    ref = [_b("reference", CENTRAL, "reference_acting", "t hold", "pc vc ac pcd vcd",
              "II.33, also at the acting period's start")] if acting else [
        _b("reference", CENTRAL, "reference", "t hold", "pc vc ac", "II.33")]
    out = [_b("output", CENTRAL, "output", "tau", "cmd", "saturation, command out")]
    if law == "resolved-acceleration":
        blocks = _resolved_acceleration(ref, out, iterations, observer, acting=acting,
                                        foreseen=foreseen, est2=est2, ahead_est=ahead_est)
    else:
        blocks = _LAW_BLOCKS[law](ref, out, iterations, observer)
    graph = StageGraph(law, model, observer, iterations, tuple(blocks),
                       (*SOURCES, EST2) if est2 else SOURCES,
                       model_state if acting else "sample")
    validate_graph(graph)
    return graph


def _resolved_acceleration(ref: list[Block], out: list[Block], iterations: int,
                           observer: str, *, acting: bool, foreseen: bool, est2: bool,
                           ahead_est: str) -> list[Block]:
    """Resolved acceleration (IV.14 in the operational space, then the model, V.50)."""
    velocity = "difference" if acting else "jacobian"
    law_blocks = [
        _b("inflight", CENTRAL, "inflight", "t p pd est", "p0 v0",
           "the state where the command starts to act: p, pdot carried forward at "
           "the commands in flight"),
        _b("law", CENTRAL, "law", "pcd vcd ac p0 v0", "pdd",
           "IV.14 at the acting period's start",
           (("pc", "pcd"), ("vc", "vcd"), ("p", "p0"), ("pd", "v0"))),
        _b("ahead", CENTRAL, "ahead", "p0 v0 pdd hold", "pa pda",
           "the middle of the acting period: p0 + pdot0 T/2 + pddot T^2/8, "
           "pdot0 + pddot T/2", (("p", "p0"), ("pd", "v0"))),
    ] if acting else [_b("law", CENTRAL, "law", "pc vc ac p pd", "pdd", "IV.14")]
    if foreseen:  # the model's state from the previous estimate: no sample needed
        law_blocks.pop()  # no ``ahead``: ``foresee`` gives pa, pda
        ref.append(_b("foresee", CENTRAL, "foresee", f"t hold {ahead_est} ac", "pa pda",
                      "the middle of the acting period foreseen from the previous "
                      "estimate: p, pdot carried at the commands in flight"
                      + (" (two intervals back)" if est2 else ""),
                      (("est", EST2),) if est2 else ()))
        ref += _state_blocks("pa", "pda")
    return ref + _observer_blocks(iterations, observer, velocity=velocity, est2=est2) + [
        *law_blocks,
        *(() if foreseen else _state_blocks("pa", "pda") if acting else _state_blocks()),
        _b("accel", AXIS, "accel", "row_i pdd jdp_i", "qdd_i", "V.31"),
        _b("dyn_axis", AXIS, "dyn_axis", "ax_i qd_i qdd_i pdd", "tauq_i f_i",
           "V.50 joint part (qA qddot + qg + coupling)"),
        _b("dyn_central", CENTRAL, "dyn_central", "row_i tauq_i f_i pdd", "tau",
           "V.50 operational part and J^T"),
    ] + out


def _kinematics_only(ref: list[Block], out: list[Block], iterations: int,
                     observer: str) -> list[Block]:
    """The kinematics part alone: its commands are joint accelerations."""
    return ref + _observer_blocks(iterations, observer) + [
        _b("law", CENTRAL, "law", "pc vc ac p pd", "pdd", "IV.14"),
        *_state_blocks(),
        _b("accel", AXIS, "accel", "row_i pdd jdp_i", "qdd_i", "V.31"),
        _b("collect", CENTRAL, "collect", "qdd_i", "tau", "joint accelerations out",
           (("taufb_i", "qdd_i"),)),
    ] + out


def _computed_torque(ref: list[Block], out: list[Block], iterations: int,
                     observer: str) -> list[Block]:
    """Computed torque in the joint space (Fig. 18)."""
    return ref + _reference_joint_blocks() + [
        _b("joint_law", AXIS, "joint_law", "qc_i qdc_i qddc_i qmeas_i qdmeas_i",
           "qddcmd_i", "Fig. 18 (qddot* = qddot_c + kp q~ + kd q~dot)"),
    ] + _observer_blocks(iterations, observer) + _state_blocks() + [
        _b("task_accel", CENTRAL, "task_accel", "row_i qddcmd_i jdp_i", "pdd",
           "pddot = J (qddot* - dJ^-1/dt pdot)"),
        _b("dyn_axis", AXIS, "dyn_axis", "ax_i qd_i qddcmd_i pdd", "tauq_i f_i",
           "V.50 joint part", (("qdd_i", "qddcmd_i"),)),
        _b("dyn_central", CENTRAL, "dyn_central", "row_i tauq_i f_i pdd", "tau",
           "V.50 operational part and J^T"),
    ] + out


def _pd_feedforward(ref: list[Block], out: list[Block], iterations: int,
                    observer: str) -> list[Block]:
    """Joint PD with the model's feedforward at the reference (IV.13)."""
    return ref + _reference_joint_blocks() + [
        _b("dyn_ref", AXIS, "dyn_axis", "axr_i qdc_i qddc_i ac", "tauq_i f_i",
           "V.50 joint part at the reference",
           (("ax_i", "axr_i"), ("qd_i", "qdc_i"), ("qdd_i", "qddc_i"), ("pdd", "ac"))),
        _b("joint_pd", AXIS, "joint_pd", "qc_i qdc_i qmeas_i qdmeas_i", "taufb_i",
           "IV.13 feedback"),
        _b("dyn_central", CENTRAL, "dyn_central", "rowr_i tauq_i f_i ac taufb_i", "tau",
           "V.50 operational part at the reference, J^T, plus feedback",
           (("row_i", "rowr_i"), ("pdd", "ac"))),
    ] + out


def _pd_gravity(ref: list[Block], out: list[Block], iterations: int,
                observer: str) -> list[Block]:
    """Joint PD with gravity compensation at the measured state (V.38)."""
    return ref + _reference_joint_blocks()[:1] + [
        _b("joint_pd", AXIS, "joint_pd_static", "qc_i qmeas_i qdmeas_i", "taufb_i",
           "V.38 feedback (reference velocity zero-order)"),
    ] + _observer_blocks(iterations, observer)[:-1] + [
        _b("gravity_central", CENTRAL, "gravity_central", "J qmeas_i taufb_i", "tau",
           "V.38: qg(q) + J^T pg + feedback"),
    ] + out


def _pd(ref: list[Block], out: list[Block], iterations: int,
        observer: str) -> list[Block]:
    """Joint PD, no model terms."""
    return ref + _reference_joint_blocks() + [
        _b("joint_pd", AXIS, "joint_pd", "qc_i qdc_i qmeas_i qdmeas_i", "taufb_i",
           "joint PD, no model terms"),
        _b("collect", CENTRAL, "collect", "taufb_i", "tau", "tau = feedback"),
    ] + out


_LAW_BLOCKS = {KINEMATICS: _kinematics_only, "computed-torque": _computed_torque,
               "pd-feedforward": _pd_feedforward, "pd-gravity": _pd_gravity, "pd": _pd}
"""The blocks of each law but resolved acceleration, after its reference."""


def validate_graph(graph: StageGraph) -> None:
    """Check names are unique and every input is produced before it is used."""
    seen = set(graph.sources)
    names = set()
    for b in graph.blocks:
        if b.name in names:
            raise ValueError(f"stage graph: block {b.name!r} appears twice")
        names.add(b.name)
        for v in b.inputs:
            if v not in seen:
                raise ValueError(f"stage graph: block {b.name!r} needs {v!r} before it exists")
        if b.kind == CENTRAL and any(o.endswith("_i") for o in b.outputs):
            raise ValueError(f"stage graph: central block {b.name!r} outputs a per-axis value")
        seen.update(b.outputs)
