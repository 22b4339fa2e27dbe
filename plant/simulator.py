"""The simulated Delta: integration, actuators, sensors (brief: "The plant").

Fixed-step RK4 with sub-steps and projection onto the constraints, first-order actuator lag
(Eq. IV.6), torque saturation, encoder quantisation, viscous friction and an optional
elastic belt (two-mass model per axis, § V.6.3). Usable in-process; the Zenoh role lives in
:mod:`ctrlunit.runtime.roles.plant_node`.

The plant never raises on a command: its arms stop inelastically at their mechanical stops
(:mod:`.limits`), and where the integration meets a singular or unreachable configuration,
a state no longer finite, or a command that is not three finite torques, it stops (the
last valid state held, every rate zero) and names the fault in :attr:`Plant.fault`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from ..kernels.params import DELTA_IA, DeltaParams
from . import mechanics as mech
from .limits import (
    ARM_STOPS,
    BAD_COMMAND,
    MAX_EVENTS,
    MECHANICAL_STOP,
    NON_FINITE_STATE,
    NUMERIC_ERRORS,
    SINGULAR,
    PlantEvent,
    check_command,
    clamp_to_stops,
    degrees,
    reproject,
    singular_message,
    stop_message,
)
from .substeps import MAX_SUBSTEP_BELT_S, MAX_SUBSTEP_S, substeps_for

_FREE: list[float | None] = [None, None, None]
""":attr:`Plant.at_stop` while no arm rests at a stop."""

class PlantConfigError(ValueError):
    """A plant option is out of range; the message names it."""


@dataclass(frozen=True)
class PlantConfig:
    """Options of the simulated plant.

    Attributes
    ----------
    period : control period (s): one :meth:`Plant.step` advances this much.
    substeps : RK4 sub-steps per period (>= 1); ``None`` (default): the fewest whose
        length is at most :data:`MAX_SUBSTEP_S` (:data:`MAX_SUBSTEP_BELT_S` with the
        belt), :attr:`n_substeps`, and more in a period where an arm turns fast
        (:func:`~.substeps.substeps_for`).
    lag : actuator time constant (s) of Eq. IV.6; 0 applies the command at once.
    friction : viscous friction on each joint (N m s/rad).
    quantise : round encoder readings to whole increments.
    belt : simulate the elastic belt between motor and arm (§ V.6.3).
    belt_stiffness : k_e at the joint (N m/rad).
    belt_ratio : reduction n_r (reported; the model is written at the joint).
    motor_inertia : motor and pulley inertia reflected at the joint (kg m^2).
    belt_damping : damping of the belt (N m s/rad).
    arm_stops : ``(lower, upper)`` mechanical stops of each arm (rad), :data:`~.limits.
        ARM_STOPS` by default (-135 and +45 deg, outside the joint box of Eq. V.32);
        ``None``: none, the arms swing freely (to measure the integrator alone, e.g. its
        energy drift in a free fall that swings the arms past -180 deg).
    """

    period: float = 1e-3
    substeps: int | None = None
    lag: float = 0.0
    friction: float = 0.0
    quantise: bool = True
    belt: bool = False
    belt_stiffness: float = 8080.0
    belt_ratio: float = 10.0
    motor_inertia: float = 0.0065
    belt_damping: float = 0.0
    arm_stops: tuple[float, float] | None = ARM_STOPS

    def __post_init__(self) -> None:
        checks = {
            "period": (1e-6, 1.0, self.period),
            "lag": (0.0, 1.0, self.lag),
            "friction": (0.0, 100.0, self.friction),
            "belt_stiffness": (1.0, 1e7, self.belt_stiffness),
            "belt_ratio": (1.0, 1000.0, self.belt_ratio),
            "motor_inertia": (1e-6, 1.0, self.motor_inertia),
            "belt_damping": (0.0, 1e3, self.belt_damping),
        }
        for name, (lo, hi, val) in checks.items():
            if isinstance(val, bool) or not isinstance(val, int | float) or not (
                math.isfinite(val) and lo <= val <= hi
            ):
                raise PlantConfigError(f"plant {name} = {val!r} is outside [{lo}, {hi}]")
        if self.substeps is not None and (
            isinstance(self.substeps, bool) or not isinstance(self.substeps, int)
            or not 1 <= self.substeps <= 10_000
        ):
            raise PlantConfigError(
                f"plant substeps = {self.substeps!r} must be an integer in [1, 10000] (or "
                "None: automatic)")
        lo_hi = self.arm_stops
        if lo_hi is not None and not (isinstance(lo_hi, tuple) and len(lo_hi) == 2
                and all(isinstance(v, float) and math.isfinite(v) for v in lo_hi)
                and -math.pi <= lo_hi[0] < lo_hi[1] <= math.pi):
            raise PlantConfigError(
                f"plant arm_stops = {lo_hi!r} must be two floats lower < upper within "
                "[-pi, pi] rad, or None")

    @property
    def n_substeps(self) -> int:
        """RK4 sub-steps per period: ``substeps``, or the automatic base count (the turn
        rule may add to it: :meth:`Plant.step`)."""
        if self.substeps is not None:
            return self.substeps
        h = MAX_SUBSTEP_BELT_S if self.belt else MAX_SUBSTEP_S
        return max(1, math.ceil(self.period / h - 1e-9))


@dataclass
class PlantState:
    """Full state of the plant (SI units, lists of three floats)."""

    q: list[float]
    p: list[float]
    qd: list[float]
    pd: list[float]
    motor: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    motor_d: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    tau_applied: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    time: float = 0.0


class Plant:
    """The simulated Delta robot.

    Parameters
    ----------
    params : robot parameters.
    config : plant options.
    q0 : initial arm angles (rad); the platform is assembled from them.
    """

    def __init__(
        self,
        params: DeltaParams = DELTA_IA,
        config: PlantConfig | None = None,
        *,
        q0: tuple[float, float, float] | list[float] = (-0.4, -0.4, -0.4),
        p_guess: tuple[float, float, float] = (0.0, 0.0, -0.4),
    ) -> None:
        self.params = params
        self.config = config or PlantConfig()
        arm_inertia = params.j_a
        if self.config.belt:
            arm_inertia = params.j_a - self.config.motor_inertia
            if arm_inertia <= 0.0:
                raise PlantConfigError(
                    f"plant motor_inertia = {self.config.motor_inertia} must be below "
                    f"j_a = {params.j_a} kg m^2 (j_a includes the motor)"
                )
        self.bc = mech.body_constants(params, arm_inertia=arm_inertia)
        q = [float(v) for v in q0]
        p = mech.assemble_platform(params, q, list(p_guess))
        self.state = PlantState(q=q, p=p, qd=[0.0] * 3, pd=[0.0] * 3, motor=list(q))
        self.command = [0.0, 0.0, 0.0]
        self.step_count = 0
        self.fault: PlantEvent | None = None
        """The fault that stopped the plant (:mod:`.limits`), or None while it runs."""
        self.events: list[PlantEvent] = []
        """The first :data:`~.limits.MAX_EVENTS` events (arms reaching a stop, the fault)."""
        self.event_count = 0
        self.at_stop: list[float | None] = [None, None, None]
        """The stop each arm rests at (rad), None while it is within its stops."""

    # -- actuators ------------------------------------------------------------------------

    def set_command(self, tau: list[float] | tuple[float, ...]) -> None:
        """Set the commanded torques (N m), saturated at ``tau_max``. The caller validates
        the message; this clamps, and a command that is not three finite torques is not
        applied: the plant stops with a :data:`~.limits.BAD_COMMAND` fault."""
        why = check_command(tau)
        if why is not None:
            self._stop(BAD_COMMAND, why)
            return
        lim = self.params.tau_max
        self.command = [min(max(float(t), -lim), lim) for t in tau]

    # -- integration ----------------------------------------------------------------------

    def _deriv(self, y: list[float], tau_a: list[float]) -> list[float]:
        """Time derivative of the state vector ``y`` (see :meth:`_pack`)."""
        q, p, qd, pd = y[0:3], y[3:6], y[6:9], y[9:12]
        cfg = self.config
        if cfg.belt:
            m, md = y[12:15], y[15:18]
            tb = [
                cfg.belt_stiffness * (m[i] - q[i]) + cfg.belt_damping * (md[i] - qd[i])
                for i in range(3)
            ]
            net = tb
            mdd = [
                (tau_a[i] - tb[i] - cfg.friction * md[i]) / cfg.motor_inertia for i in range(3)
            ]
        else:
            net = [tau_a[i] - cfg.friction * qd[i] for i in range(3)]
        qdd, pdd = mech.accelerations(self.params, self.bc, q, p, qd, pd, net)
        out = qd + pd + qdd + pdd
        if cfg.belt:
            out += md + mdd
        return out

    def _pack(self) -> list[float]:
        s = self.state
        y = s.q + s.p + s.qd + s.pd
        if self.config.belt:
            y += s.motor + s.motor_d
        return y

    def _unpack(self, y: list[float]) -> None:
        s = self.state
        s.q, s.p, s.qd, s.pd = y[0:3], y[3:6], y[6:9], y[9:12]
        if self.config.belt:
            s.motor, s.motor_d = y[12:15], y[15:18]

    def substep(self, h: float) -> None:
        """Advance one sub-step of ``h`` seconds (RK4; an arm beyond a stop is stopped
        there and the state projected onto the constraints). A stopped plant only lets
        the time pass."""
        cfg = self.config
        s = self.state
        if self.fault is not None:
            s.time += h
            return
        # exact first-order lag over the sub-step (Eq. IV.6), torque held within it
        if cfg.lag > 0.0:
            k = 1.0 - math.exp(-h / cfg.lag)
            s.tau_applied = [a + k * (c - a) for a, c in zip(s.tau_applied, self.command)]
        else:
            s.tau_applied = list(self.command)
        tau = s.tau_applied
        y0 = y = self._pack()
        try:
            k1 = self._deriv(y, tau)
            hh = 0.5 * h
            k2 = self._deriv([a + hh * b for a, b in zip(y, k1)], tau)
            k3 = self._deriv([a + hh * b for a, b in zip(y, k2)], tau)
            k4 = self._deriv([a + h * b for a, b in zip(y, k3)], tau)
            h6 = h / 6.0
            y = [a + h6 * (b + 2.0 * (c + d) + e) for a, b, c, d, e in zip(y, k1, k2, k3, k4)]
        except NUMERIC_ERRORS as exc:
            self._stop(SINGULAR, singular_message(s.q, exc))
        else:
            if all(map(math.isfinite, y)):
                self._unpack(y)
            else:
                self._stop(NON_FINITE_STATE, "plant: the state is no longer finite after a "
                                             f"sub-step from q = {degrees(s.q)}")
        s.time += h
        if self.fault is None and cfg.arm_stops is not None:
            hit = clamp_to_stops(s.q, s.qd, cfg.arm_stops)
            if hit or self.at_stop != _FREE:
                self._at_stops(hit, y0)

    def _at_stops(self, hit: list[tuple[int, float]], y0: list[float]) -> None:
        """After a sub-step: record each arm that came to a stop (``hit``: the arms
        :func:`~.limits.clamp_to_stops` stopped) and let go of each that left its stop;
        where an arm was stopped, project the state onto the constraints again (the
        platform follows the arm), or stop the plant at ``y0`` (the state the sub-step
        began from) if the loops no longer close."""
        clamped = dict(hit)
        for i in range(3):
            stop = clamped.get(i)
            if stop is not None and self.at_stop[i] != stop:
                self._record(PlantEvent(MECHANICAL_STOP, stop_message(i, stop),
                                        self.state.time))
            self.at_stop[i] = stop
        if not hit:
            return
        s = self.state
        settled = reproject(self.params, s.q, s.p, s.qd, s.pd, time=s.time)
        if isinstance(settled, PlantEvent):
            self._unpack(y0)
            self._stop(settled.name, settled.message)
        else:
            s.p, s.pd = settled

    def _record(self, event: PlantEvent) -> None:
        """Keep ``event`` (the first :data:`~.limits.MAX_EVENTS`) and count it."""
        self.event_count += 1
        if len(self.events) < MAX_EVENTS:
            self.events.append(event)

    def _stop(self, name: str, message: str) -> None:
        """Stop the plant on a fault: the state held as it is, every rate zero, the fault
        named (the first one stays)."""
        if self.fault is not None:
            return
        s = self.state
        s.qd, s.pd, s.motor_d = [0.0] * 3, [0.0] * 3, [0.0] * 3
        self.fault = PlantEvent(name, message, s.time)
        self._record(self.fault)

    def project(self) -> None:
        """Project the state back onto the constraints (positions and velocities); where
        that cannot be solved, stop the plant (a singular configuration)."""
        if self.fault is not None:
            return
        s = self.state
        try:
            p, pd = mech.project(self.params, s.q, s.p, s.qd, s.pd)
        except NUMERIC_ERRORS as exc:
            self._stop(SINGULAR, singular_message(s.q, exc))
            return
        if not all(map(math.isfinite, p + pd)):
            self._stop(NON_FINITE_STATE, "plant: the projection onto the constraints left "
                                         f"no finite platform state at q = {degrees(s.q)}")
            return
        s.p, s.pd = p, pd

    def step(self) -> None:
        """Advance one control period with the current command (RK4 sub-steps, then one
        projection onto the constraints): :attr:`PlantConfig.n_substeps` of them, more
        where an arm turns fast (:func:`~.substeps.substeps_for`) unless the count was
        given."""
        cfg = self.config
        n = cfg.n_substeps
        if cfg.substeps is None:  # the turn rule (plant/substeps.py)
            s = self.state
            n = substeps_for(cfg.period, n, s.motor_d + s.qd if cfg.belt else s.qd)
        h = cfg.period / n
        for _ in range(n):
            self.substep(h)
        self.project()
        self.step_count += 1

    # -- sensors --------------------------------------------------------------------------

    def sensed_angles(self) -> list[float]:
        """Angles the encoders see: the arm, or the motor side when a belt is simulated."""
        return list(self.state.motor if self.config.belt else self.state.q)

    def encoder_counts(self) -> list[int]:
        """Encoder readings in increments (``encoder_counts`` per turn), rounded to the
        nearest increment."""
        inc = self.params.increment
        return [round(a / inc) for a in self.sensed_angles()]

    # -- diagnostics ----------------------------------------------------------------------

    def energy(self) -> float:
        """Total mechanical energy (J), motor side included when a belt is simulated."""
        s = self.state
        e = mech.energy(self.params, self.bc, s.q, s.p, s.qd, s.pd)
        if self.config.belt:
            cfg = self.config
            for i in range(3):
                e += 0.5 * cfg.motor_inertia * s.motor_d[i] ** 2
                e += 0.5 * cfg.belt_stiffness * (s.motor[i] - s.q[i]) ** 2
        return e

    def constraint_error(self) -> float:
        """Largest ``| |d_i| - l_b |`` (m)."""
        s = self.state
        return max(abs(r) for r in mech.constraint_residual(self.params, s.q, s.p))

    def set_state(
        self, q: list[float], qd: list[float] | None = None, *, p_guess: list[float] | None = None
    ) -> None:
        """Place the robot at arm angles ``q`` with rates ``qd`` (platform assembled)."""
        qd = [0.0] * 3 if qd is None else [float(v) for v in qd]
        q = [float(v) for v in q]
        p = mech.assemble_platform(self.params, q, p_guess or list(self.state.p))
        pd = mech.platform_velocity(self.params, q, p, qd)
        self.state = PlantState(q=q, p=p, qd=qd, pd=pd, motor=list(q), motor_d=list(qd),
                                tau_applied=list(self.state.tau_applied), time=self.state.time)
