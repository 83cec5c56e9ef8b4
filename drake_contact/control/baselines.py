"""Three modern baseline force controllers beside the thesis's hybrid law,
each one Python leaf system sampled every 1 ms.

All three share the approach (a guarded move) and the contact switch of
:mod:`drake_contact.control.hybrid_controller`, and differ in contact:

1. ``impedance``: impedance control with force feed-forward (Hogan 1985,
   "Impedance control: an approach to manipulation", ASME J. Dyn. Sys.
   Meas. Control 107:1-24; Villani & De Schutter, "Force control",
   Springer Handbook of Robotics, 2nd ed. 2016, ch. 9): a spring-damper
   plus f_d along the normal, the pose held on y and phi (see the class
   for why those two are scaled by the arm's inertia):

       tau = J^T [K_x (x_0 - x) - D_x xdot + f_d] e_x
             + M J^-1 ([0, a_y, a_phi] - Jdot qdot) + h + F_c sgn(qdot)

2. ``admittance``: an outer force loop shapes a reference x_r along the
   normal, an inner resolved-acceleration loop tracks it (Villani & De
   Schutter 2016, section 9.3; Seraji & Colbaugh 1997, "Force tracking in
   impedance control", IJRR 16(1):97-117):

       M_a xr_ddot + D_a xr_dot = f_d - f
       a_x = xr_ddot + K_v (xr_dot - xdot) + K_p (x_r - x)
       tau = M J^-1 (a - Jdot qdot) + h + F_c sgn(qdot) + J^T e_x f

3. ``parallel_force``: parallel force/position control (Chiaverini &
   Sciavicco 1993, "The parallel approach to force/position control of
   robotic manipulators", IEEE Trans. Robotics and Automation 9(4):361-373):

       a = K_P (x_d - x) - K_D xdot + [K_F (f_d - f) + K_I T sum_k (f_d - f)] e_x
       tau = M J^-1 (a - Jdot qdot) + h + F_c sgn(qdot) + J^T e_x f

Approach (all three), before the first contact and after a loss: a guarded
move by resolved acceleration with computed torque,

    tau = M J^-1 (a - Jdot qdot) + h + F_c sgn(qdot)
    a = K_p (x_d - x) - K_v xdot,   x_d = [x_o + v max(0, t_a - t_hold), y_d, phi_d]

where t_a is the time since the approach started, v ``approach_speed_m_s``
and x_o the measured x at the hold's last sample: during the hold x_d
follows the measured x (damping only along x), because the estimator's
filters start from zero and its pose is wrong for the first few tens of
ms, so a pose latched at the first sample would be too. After a contact
loss x_o is the x there and the ramp resumes at once (no second hold).
The contact switch is the hybrid controller's: to contact when the
filtered force exceeds ``contact_threshold_n`` (5 N), back to the approach
when it drops below ``contact_loss_threshold_n`` (0 N).

Default gains: one set per controller, tuned closed loop on the
``nn_styrofoam`` scenario (20/10 N square wave) over walls K_e in {3000,
30000, 150000} N/m x B_e in {10, 300} N s/m, none losing contact on any
(see each config's comments for the reasons).

e_x is the wall's normal, world +x; x = [x, y, phi] is the tip pose. M, h,
J and Jdot qdot are the controller's model of the arm (controller_model.py,
the nominal URDF), F_c its dry friction, compensated unless
``friction_compensation`` is off. Sampled as the hybrid controller is (see
arm.py, ``is_sample_time``): the outputs are the law evaluated on the
inputs at each whole millisecond, held between samples; the sampled update
stores them with the law's state (mode, approach timer, integrators,
admittance reference), all in the discrete state.

Each controller is built from a plain options dict by :func:`impedance`,
:func:`admittance` or :func:`parallel_force`; errors name
``controller.options.<field>``.
"""

import dataclasses as dc
import math
import numbers

import numpy as np
from pydrake.systems.framework import Diagram, DiagramBuilder, LeafSystem
from pydrake.systems.primitives import Demultiplexer

from drake_contact.blocks import Layout
from drake_contact.control.controller_model import ArmModel, ControllerModelConfig
from drake_contact.constants import CONTACT_THRESHOLD_N
from drake_contact.control.hybrid_controller import read_measured_state
from drake_contact.errors import ScenarioError
from drake_contact.plant.arm import (
    CONTROL_PERIOD, TIME_TOLERANCE_S, DeclareSampledUpdate, held_while_flagged, is_sample_time)
from drake_contact.plant.planar_arm import solve3
from drake_contact.measured import by_role
from drake_contact.plugins import declare

APPROACH, CONTACT = 0, 1
OPTIONS_PREFIX = "controller.options"

#: Layout of the held law vector (the discrete state): the three outputs,
#: then the approach's state [time since the approach started (s), x_o (m)],
#: then the contact law's own state.
_LAW = Layout(("tau", 3), ("mode", 1), ("info", 4), ("approach", 2))
_TAU, _MODE, _INFO, _APPROACH = _LAW.tau, _LAW.mode, _LAW.info, _LAW.approach
_LAW_STATE = _LAW.size


def _out_of_range(prefix, field, value, allowed):
    return ScenarioError(f"{prefix}.{field} = {value} is out of range: {allowed}")


@dc.dataclass
class ApproachOptions:
    """The guarded move before contact and the contact switch, shared by the
    three baselines (their configs extend it)."""

    # Speed (m/s) of x_d's ramp along +x toward the wall.
    approach_speed_m_s: float = 0.002
    # Time (s) before the ramp: x_d follows the measured x (see the module doc).
    approach_hold_s: float = 1.0
    # Resolved-acceleration gains of the approach: K_p (1/s^2), K_v (1/s),
    # the hybrid controller's (overdamped: K_v^2 >= 4 K_p).
    approach_position_gain: float = 400.0
    approach_velocity_gain: float = 80.0
    # Held position y_d (m) and angle phi_d (rad), approach and contact.
    y_desired: float = 0.0
    phi_desired: float = 0.0
    # Switch to contact above this filtered force (N), back below the other.
    contact_threshold_n: float = CONTACT_THRESHOLD_N
    contact_loss_threshold_n: float = 0.0
    # Compensate the joints' dry friction with the model's F_c.
    friction_compensation: bool = True

    def validate(self, prefix=OPTIONS_PREFIX):
        if not (0 < self.approach_speed_m_s <= 0.1):
            raise _out_of_range(prefix, "approach_speed_m_s", self.approach_speed_m_s,
                                "must be in (0, 0.1] m/s")
        if not (0 <= self.approach_hold_s < math.inf):
            raise _out_of_range(prefix, "approach_hold_s", self.approach_hold_s,
                                "must be >= 0 s")
        _require_positive(self, prefix, ("approach_position_gain", "approach_velocity_gain"))
        if not (abs(self.y_desired) <= 0.1):
            raise _out_of_range(prefix, "y_desired", self.y_desired, "must be in [-0.1, 0.1] m")
        if not (abs(self.phi_desired) <= math.pi):
            raise _out_of_range(prefix, "phi_desired", self.phi_desired,
                                "must be in [-pi, pi] rad")
        if not (-math.inf < self.contact_loss_threshold_n < self.contact_threshold_n < math.inf):
            raise _out_of_range(prefix, "contact_threshold_n", self.contact_threshold_n,
                                "must be finite and exceed contact_loss_threshold_n = "
                                f"{self.contact_loss_threshold_n} N")


def _require_positive(config, prefix, fields, allow_zero=False):
    for field in fields:
        value = getattr(config, field)
        values = value if isinstance(value, list) else [value]
        ok = all(math.isfinite(v) and (v >= 0 if allow_zero else v > 0) for v in values)
        if not ok or (isinstance(value, list) and len(value) != 3):
            count = "3 values" if isinstance(value, list) else "finite and"
            raise _out_of_range(prefix, field, value,
                                f"must be {count} {'>=' if allow_zero else '>'} 0")


@dc.dataclass
class ImpedanceConfig(ApproachOptions):
    """Impedance with force feed-forward along x (Hogan 1985), the pose held
    on y and phi."""

    # Normal stiffness K_x about x_0 (N/m). Small: the feed-forward f_d sets
    # the force, K_x only anchors the tip (force error K_x times the
    # penetration gained since the switch).
    stiffness_x: float = 200.0
    # Normal damping D_x (N s/m), on the arm's own inertia along x (about
    # 7 kg at the start pose).
    damping_x: float = 300.0
    # y and phi: K (1/s^2) and D (1/s) per unit of the arm's inertia.
    pose_position_gain: float = 400.0
    pose_velocity_gain: float = 80.0

    def validate(self, prefix=OPTIONS_PREFIX):
        super().validate(prefix)
        _require_positive(self, prefix, ("stiffness_x",), allow_zero=True)
        _require_positive(self, prefix, ("damping_x", "pose_position_gain",
                                         "pose_velocity_gain"))


@dc.dataclass
class AdmittanceConfig(ApproachOptions):
    """Admittance (position-based force) control (Seraji & Colbaugh 1997)."""

    # Admittance mass M_a (kg) and damping D_a (N s/m) of the reference x_r:
    # at low frequency xr_dot = (f_d - f) / D_a, an integral force loop.
    admittance_mass: float = 5.0
    admittance_damping: float = 1000.0
    # Inner loop in contact, K_p (1/s^2) and K_v (1/s), all three axes.
    position_gain: float = 400.0
    velocity_gain: float = 80.0

    def validate(self, prefix=OPTIONS_PREFIX):
        super().validate(prefix)
        _require_positive(self, prefix, ("admittance_mass", "admittance_damping",
                                         "position_gain", "velocity_gain"))


@dc.dataclass
class ParallelForceConfig(ApproachOptions):
    """Parallel force/position control (Chiaverini & Sciavicco 1993)."""

    # Position loop in contact, K_P (1/s^2) and K_D (1/s), all three axes;
    # its x_d along x is the tip's x at the switch. K_D above the
    # approach's 80 damps the stick-slip of the joints on stiff walls.
    position_gain: float = 400.0
    velocity_gain: float = 120.0
    # Force loop along x: K_F ((m/s^2)/N) and K_I ((m/s^2)/(N s)). The
    # integral outweighs the position loop at steady state. K_F K_e is the
    # force loop's stiffness per unit mass (10500 1/s^2 on a 150000 N/m
    # wall): large enough there to catch the slip after stiction lets go
    # (K_F 0.03-0.05 lost contact on 20 -> 10 N steps), small on soft walls,
    # where the integral does the work (slow pole about K_I K_e / (K_P +
    # K_F K_e): 2 1/s at 3000 N/m).
    force_gain: float = 0.07
    force_integral_gain: float = 0.4

    def validate(self, prefix=OPTIONS_PREFIX):
        super().validate(prefix)
        _require_positive(self, prefix, ("position_gain", "velocity_gain"))
        _require_positive(self, prefix, ("force_gain",), allow_zero=True)
        _require_positive(self, prefix, ("force_integral_gain",))


class _BaselineLaw(LeafSystem):
    """Ports, sampling, the approach and the contact switch of a baseline;
    a subclass supplies the contact law (``_contact``) and its state.

    Input ports (measured signals): tip_pose (3): [x, y, phi] (m, rad,
    world); tip_velocity (3) (m/s, rad/s); joint_positions (3) (rad);
    joint_velocities (3) (rad/s); force (1): the DSP's filtered normal force
    (N, pushing > 0); force_desired (1) (N).
    Output port ``law`` (this sample's values, held between samples; split
    by :class:`BaselineController`): joint_torque_commanded (3): the motor
    command (N m); mode (1): 0 approach, 1 contact; contact_info (4): [time
    of the first switch to contact (s) or -1, x, y, phi at the latest
    switch]; then the law's state (approach timer and origin, its own).
    """

    #: Initial values of the contact law's own state.
    _law_state0 = ()

    def __init__(self, config: ApproachOptions):
        super().__init__()
        config.validate()
        self._config = config
        self._model = ArmModel(ControllerModelConfig())
        self._pose = self.DeclareVectorInputPort("tip_pose", 3)
        self._velocity = self.DeclareVectorInputPort("tip_velocity", 3)
        self._q = self.DeclareVectorInputPort("joint_positions", 3)
        self._qdot = self.DeclareVectorInputPort("joint_velocities", 3)
        self._force = self.DeclareVectorInputPort("force", 1)
        self._force_desired = self.DeclareVectorInputPort("force_desired", 1)
        # The safety supervisor's flag: while it is up, the law holds its
        # output and state (unconnected: never).
        self._fault = self.DeclareVectorInputPort("force_fault", 1)
        held = np.zeros(_LAW_STATE + len(self._law_state0))
        held[_INFO] = [-1.0, 0.0, 0.0, 0.0]
        held[_LAW_STATE:] = self._law_state0
        self._held = self.DeclareDiscreteState(held)
        self._law = self.DeclareVectorOutputPort(
            "law", len(held), self._calc_law,
            prerequisites_of_calc={self.all_input_ports_ticket(), self.xd_ticket(),
                                   self.time_ticket()})
        DeclareSampledUpdate(self, self._update)

    def _update(self, context, state):
        state.set_value(self._law.Eval(context))

    def _calc_law(self, context, value):
        c = self._config
        held = context.get_discrete_state(self._held).value()
        t = context.get_time()
        if not is_sample_time(t) or held_while_flagged(self._fault, context) is not None:
            value.SetFromVector(held)  # zero-order hold between samples, or held
            return
        x, xd, q, qdot = read_measured_state(
            context, self._pose, self._velocity, self._q, self._qdot)
        f = self._force.Eval(context)[0]
        mode = held[_MODE]
        info = held[_INFO].tolist()
        timer, x_origin = held[_APPROACH].tolist()
        law_state = held[_LAW_STATE:].tolist()

        switched = False
        if mode == APPROACH and f > c.contact_threshold_n:
            mode, switched = CONTACT, True
            if info[0] < 0:
                info[0] = t
            info[1:] = x
        elif mode == CONTACT and f < c.contact_loss_threshold_n:
            # Back to the approach from here, the ramp resuming at once.
            mode, timer, x_origin = APPROACH, c.approach_hold_s, x[0]

        J, jdot_qdot, M, h = self._model.evaluate_rows(q, qdot)
        tau = list(h)
        if c.friction_compensation:
            tau = [a + b for a, b in zip(tau, self._model.friction_compensation(qdot))]
        if mode == APPROACH:
            if timer <= c.approach_hold_s + TIME_TOLERANCE_S:  # the ramp starts from here
                x_origin = x[0]
            accel, wrench = self._approach_acceleration(timer, x_origin, x, xd), None
            timer += CONTROL_PERIOD
        else:
            f_d = self._force_desired.Eval(context)[0]
            accel, wrench, law_state = self._contact(
                switched, law_state, info[1:], x, xd, f, f_d)
        if accel is not None:  # computed torque: M J^-1 (a - Jdot qdot)
            qddot = solve3(J, [a - b for a, b in zip(accel, jdot_qdot)])
            tau = [tau[i] + M[i][0] * qddot[0] + M[i][1] * qddot[1] + M[i][2] * qddot[2]
                   for i in range(3)]
        if wrench is not None:  # J^T wrench
            tau = [tau[i] + J[0][i] * wrench[0] + J[1][i] * wrench[1] + J[2][i] * wrench[2]
                   for i in range(3)]
        value.SetFromVector(self._model.command(tau) + [mode] + info + [timer, x_origin]
                            + law_state)

    def _approach_acceleration(self, timer, x_origin, x, xd):
        """a = K_p (x_d - x) - K_v xdot on the guarded move's x_d."""
        c = self._config
        target = (x_origin + c.approach_speed_m_s * max(0.0, timer - c.approach_hold_s),
                  c.y_desired, c.phi_desired)
        return [c.approach_position_gain * (target[i] - x[i]) - c.approach_velocity_gain * xd[i]
                for i in range(3)]

    def _contact(self, switched, law_state, x_switch, x, xd, f, f_d):
        """(acceleration a or None, Cartesian wrench or None, new law state)
        of the contact law: tau adds M J^-1 (a - Jdot qdot) and J^T wrench."""
        raise NotImplementedError


class ImpedanceControlLaw(_BaselineLaw):
    """Impedance control with force feed-forward (Hogan 1985; Villani & De
    Schutter 2016, ch. 9) in contact. Along the normal a spring-damper about
    x_0 (the tip's x at the latest switch) plus f_d, on the arm's own inertia
    (no inertia shaping, no force feedback: the force measurement only
    switches modes); on y and phi the impedance is scaled by the arm's
    inertia, a = K (target - x) - D xdot, by computed torque:

        tau = J^T [K_x (x_0 - x) - D_x xdot + f_d] e_x
              + M J^-1 ([0, a_y, a_phi] - Jdot qdot) + h + F_c sgn(qdot)

    With an exact model the tip then obeys, at rest, f = f_d + K_x (x_0 - x)
    along x and y = y_d, phi = phi_d, whatever the normal force. Why not a
    constant Cartesian K, D on y and phi (tau = J^T [K (x_0 - x) - D xdot
    + ...]): at the start pose the arm's lightest Cartesian mode is joint 3
    (Lambda's smallest eigenvalue 0.0027, mostly phi but with y in it), and
    the y stiffness and damping that hold y against the joints' stiction
    (K_y 3000 N/m, D_y 200 N s/m) put that mode at 25 Hz with D/m 1600 1/s,
    unstable behind the 1 ms sample and the estimator's 35 Hz velocity
    filter (measured: a limit cycle with 20-30 N m torques and no contact).

    Known limitation: at rest the force is off by K_x times the penetration
    gained since the switch (about K_x (f_d - 5 N) / K_e: 1 N for K_x 200 N/m
    on a 3000 N/m wall) and by whatever the joints' stiction holds, which no
    integral removes.
    """

    def __init__(self, config: ImpedanceConfig):
        super().__init__(config)

    def _contact(self, switched, law_state, x_switch, x, xd, f, f_d):
        c = self._config
        kp, kv = c.pose_position_gain, c.pose_velocity_gain
        accel = [0.0, kp * (c.y_desired - x[1]) - kv * xd[1],
                 kp * (c.phi_desired - x[2]) - kv * xd[2]]
        force_x = c.stiffness_x * (x_switch[0] - x[0]) - c.damping_x * xd[0] + f_d
        return accel, [force_x, 0.0, 0.0], law_state


class AdmittanceControlLaw(_BaselineLaw):
    """Admittance control (Villani & De Schutter 2016, section 9.3; Seraji &
    Colbaugh 1997) in contact. Each sample steps the reference along x by
    semi-implicit Euler (T = 1 ms),

        xr_ddot = (f_d - f - D_a xr_dot) / M_a
        xr_dot += T xr_ddot,   x_r += T xr_dot

    from x_r = x and xr_dot = xdot at the switch, and the inner loop tracks
    it with computed torque:

        a = [xr_ddot + K_v (xr_dot - xdot) + K_p (x_r - x),
             K_p (y_d - y) - K_v ydot, K_p (phi_d - phi) - K_v phidot]
        tau = M J^-1 (a - Jdot qdot) + h + F_c sgn(qdot) + J^T e_x f

    (x_r, xr_dot after this sample's step). The measured force's
    feed-forward J^T e_x f makes the inner loop an inverse-dynamics position
    controller that cancels the wall's force on the model (the form of the
    Handbook's inverse-dynamics laws): without it the wall's push reaches
    the light wrist through Lambda^-1 and the pose PD (400, 80) cannot hold
    phi (measured: phi drifted to 1 rad and y by 9 cm on a 3000 N/m wall).
    With the inner loop tracking x_r, the force obeys M_a xr_ddot + D_a
    xr_dot + K_e x_r = f_d (+ const): the wall's stiffness sets the outer
    loop's frequency sqrt(K_e / M_a), so M_a and D_a are chosen for the
    stiffest wall (damped there) at the cost of a slow loop, K_e / D_a, on
    soft ones, the admittance scheme's classic trade-off. The reference
    moves while f != f_d, so at steady state the force error is zero
    whatever the wall or the joints' stiction.
    """

    _law_state0 = (0.0, 0.0)  # x_r (m), xr_dot (m/s)

    def __init__(self, config: AdmittanceConfig):
        super().__init__(config)

    def _contact(self, switched, law_state, x_switch, x, xd, f, f_d):
        c = self._config
        x_r, xr_dot = (x[0], xd[0]) if switched else law_state
        xr_ddot = (f_d - f - c.admittance_damping * xr_dot) / c.admittance_mass
        xr_dot += CONTROL_PERIOD * xr_ddot
        x_r += CONTROL_PERIOD * xr_dot
        kp, kv = c.position_gain, c.velocity_gain
        accel = [xr_ddot + kv * (xr_dot - xd[0]) + kp * (x_r - x[0]),
                 kp * (c.y_desired - x[1]) - kv * xd[1],
                 kp * (c.phi_desired - x[2]) - kv * xd[2]]
        return accel, [f, 0.0, 0.0], [x_r, xr_dot]


class ParallelForceControlLaw(_BaselineLaw):
    """Parallel force/position control (Chiaverini & Sciavicco 1993) in
    contact, in the paper's inverse-dynamics form:

        a = K_P (x_d - x) - K_D xdot + [K_F (f_d - f) + K_I T sum_k (f_d - f)] e_x
        tau = M J^-1 (a - Jdot qdot) + h + F_c sgn(qdot) + J^T e_x f

    with x_d = [x at the latest switch, y_d, phi_d], T = 1 ms and the sum
    restarting at each switch. The measured force's feed-forward J^T e_x f
    cancels the wall's force on the model, so the tip moves as a unit mass
    driven by a. The force PI acts in parallel with the position loop along
    x: at rest K_P (x_d - x) + K_I T sum = 0 with the sum still changing
    unless f = f_d, so the integral dominates and the force error goes to
    zero. Stability (unit mass, wall K_e, no delay) needs
    K_D (K_P + K_F K_e) > K_I K_e.
    """

    _law_state0 = (0.0,)  # sum of the force errors (N)

    def __init__(self, config: ParallelForceConfig):
        super().__init__(config)

    def _contact(self, switched, law_state, x_switch, x, xd, f, f_d):
        c = self._config
        error = f_d - f
        error_sum = (0.0 if switched else law_state[0]) + error
        target = (x_switch[0], c.y_desired, c.phi_desired)
        accel = [c.position_gain * (target[i] - x[i]) - c.velocity_gain * xd[i]
                 for i in range(3)]
        accel[0] += c.force_gain * error + c.force_integral_gain * CONTROL_PERIOD * error_sum
        return accel, [f, 0.0, 0.0], [error_sum]


def _config_from_options(config_type, name, options):
    """``config_type`` built from a plain dict, validated; errors name
    ``controller.options.<key>``."""
    fields = {field.name: field for field in dc.fields(config_type)}
    values = {}
    for key, value in dict(options or {}).items():
        if key not in fields:
            raise ScenarioError(f"{OPTIONS_PREFIX}.{key} is not an option of '{name}': "
                                f"known options are {', '.join(fields)}")
        default = getattr(config_type(), key)
        where = f"{OPTIONS_PREFIX}.{key} = {value!r}"
        if isinstance(default, bool):
            if not isinstance(value, bool):
                raise ScenarioError(f"{where} is not a boolean: must be true or false")
        elif isinstance(default, list):
            if not (isinstance(value, (list, tuple)) and len(value) == len(default)
                    and all(_is_number(v) for v in value)):
                raise ScenarioError(f"{where} is not {len(default)} numbers: must be a list "
                                    f"like {default}")
            value = [float(v) for v in value]
        else:
            if not _is_number(value):
                raise ScenarioError(f"{where} is not a number")
            value = float(value)
        values[key] = value
    config = config_type(**values)
    config.validate(OPTIONS_PREFIX)
    return config


def _is_number(value):
    return isinstance(value, numbers.Real) and not isinstance(value, bool)


class BaselineController(Diagram):
    """A baseline as the station wires it: its law (one Python evaluation
    per sample, ``law``) and a Demultiplexer naming the law's outputs,
    ``joint_torque_commanded`` (3), ``mode`` (1) and ``contact_info`` (4),
    as :class:`~drake_contact.control.hybrid_controller.HybridController`
    does; inputs as the law's, the measured ones under the station's names
    (``force_filtered``, ``tip_pose_measured``, ...)."""

    def __init__(self, law: "_BaselineLaw"):
        super().__init__()
        builder = DiagramBuilder()
        self.law = builder.AddNamedSystem("law", law)
        size = law.get_output_port().size()
        split = builder.AddNamedSystem("outputs", Demultiplexer([3, 1, 4, size - _LAW.info.stop]))
        builder.Connect(law.get_output_port(), split.get_input_port())
        station = by_role()
        for i in range(law.num_input_ports()):
            role = law.get_input_port(i).get_name()
            builder.ExportInput(law.get_input_port(i), station.get(role, role))
        for index, name in enumerate(("joint_torque_commanded", "mode", "contact_info")):
            builder.ExportOutput(split.get_output_port(index), name)
        builder.BuildInto(self)


@declare(check_options=lambda options: _config_from_options(ImpedanceConfig, "impedance", options))
def impedance(options: dict) -> BaselineController:
    """The impedance baseline from ``controller.options`` (a plain dict)."""
    return BaselineController(
        ImpedanceControlLaw(_config_from_options(ImpedanceConfig, "impedance", options)))


@declare(check_options=lambda options: _config_from_options(AdmittanceConfig, "admittance", options))
def admittance(options: dict) -> BaselineController:
    """The admittance baseline from ``controller.options`` (a plain dict)."""
    return BaselineController(
        AdmittanceControlLaw(_config_from_options(AdmittanceConfig, "admittance", options)))


@declare(check_options=lambda options: _config_from_options(ParallelForceConfig, "parallel_force", options))
def parallel_force(options: dict) -> BaselineController:
    """The parallel force/position baseline from ``controller.options``."""
    return BaselineController(ParallelForceControlLaw(
        _config_from_options(ParallelForceConfig, "parallel_force", options)))
