"""Approach, the contact switch and hybrid position/force control
(thesis chapter 4, equations 4.10-4.21), sampled every 1 ms.

Approach (position control, resolved acceleration, 4.10-4.11):

    tau = M J^-1 (u_x - Jdot qdot) + h + F_c sgn(qdot)
    u_x = K_pv (xd_d - xd) + K_pp (x_d - x)

with x_d held at the start for ``hold_time_s``, then stepped to
``first_target_x`` and on by ``step_m`` every ``step_period_s``. When the
filtered force exceeds ``contact_threshold_n`` (5 N) the controller switches
to contact; if it drops below ``contact_loss_threshold_n`` (0 N) it returns
to the approach: x_d keeps its last value for one step period, then the ramp
restarts at ``first_target_x`` (Appendix E: N1 = 4000 at the loss, x1d
unchanged until N1 = 5000 sets 0.456).

Contact, hybrid law (4.13-4.15), S = diag(1, 0, 0):

    tau = M J^-1 [(I - S) u_x - Jdot qdot] + h + F_c sgn(qdot) + J^T S f_d + J^T S u_f
    u_f = K_fp (f_d - f) + K_fi sum_k (f_d - f)        (integral as the per-sample sum)

with the option ``contact_damping_x`` D_x adding -D_x xdot to u_f (active
damping along x, which S otherwise leaves to the environment alone), and
the option ``contact_force_rate_damping`` D_f adding -D_f (f_k - f_{k-1}) / T
(force-rate feedback: on a wall f = K_e x + B_e xdot, so D_f fdot is a
damping of D_f K_e along x that scales with the wall's stiffness, as the
lag of the force feedback's negative damping does; Volpe & Khosla 1993
compare both forms).

Contact, decoupled law (4.19-4.21, Yoshikawa's form), with k_e from the
``stiffness_estimate`` input:

    tau = M J^-1 [(I - S) u_x + S k_e^-1 u_f - Jdot qdot] + h + F_c sgn(qdot) + J^T S f_d
    u_f = K_fd (f_d - f) - K_fv k_e xd

The thesis prints "S k_e u_f"; only k_e^-1 makes u_f, a force per time
squared, an acceleration (Yoshikawa et al. 1988, the thesis's reference
[25]). We add the force-rate damping K_fv k_e xd (k_e xd = df/dt), without
which the decoupled force loop is undamped; K_fv = 0 gives (4.21) as printed.
With an identifier's K_e (``stiffness_source``, the adaptive hybrid
controller), k_e is its estimate clipped to ``stiffness_bounds``: from the
first millisecond of contact, before the estimate has converged, the force
loop's gain is K_e / k_e times its design value, so an estimate above the
truth only slows the loop; the upper bound (with an identifier that starts
there) is the safe prior. An estimate can swing below the truth in the
first milliseconds of contact, though (even below zero: then k_e sits at the
lower bound, and the loop's gain is K_e / k_e times its design); with
``stiffness_halving_time_s`` tau the law follows a rise of the estimate at
once and a fall by at most half per tau, k_e = max(clip(k_hat), k_(e,prev)
0.5^(T / tau)), from the bounds' top at each switch to contact, so such a
swing cannot raise the loop's gain by more than 2^(t / tau) in t (the
asymmetry follows the one above: a high k_e only slows the loop).

The arm's own mass is small (about 0.1-0.5 kg at the tip), so the
acceleration-level force loop commands little torque
against the joints' stiction (1 N m at joint 1, some 2 N at the tip): the
force then sits a few N off f_d. The option ``decoupled_force_integral_gain``
adds the hybrid law's integral of the force error to the force command,
J^T S (f_d + K_fdi sum_k (f_d - f)); at low frequency the tip passes the
commanded force to the wall whatever its stiffness, so this loop's gain
(K_fdi per ms, a time constant T / K_fdi) does not depend on K_e.

Option (ours) for the decoupled law: cancel the force imbalance's coupling
into y and phi (Khatib 1987, "A unified approach for motion and force
control of robot manipulators: the operational space formulation", IEEE J.
Robotics and Automation 3(1)). The feed-forward J^T S f_d accelerates the
tip by Lambda^-1 e_x (f_d - f_wall), Lambda^-1 = J M^-1 J^T: along x, as it
must to move the wall, but also along y and phi through the arm's inertia,
for as long as the wall's force lags a step of f_d (on a 3 kN/m wall the
tip travels 3.3 mm per 10 N step). With ``force_coupling_cancellation`` c
the law subtracts that part, measured with the DSP's force f:

    u_x[y, phi] -= c (Lambda^-1)[y/phi, x] (f_d - f)

With the model right, x's dynamics are unchanged and y and phi see only
(f - f_wall), the force filter's lag. The integral's share of the force
command (what the joints' stiction and the model's errors take up in the
steady state) is not cancelled: cancelling it fed a steady push into y and
phi, and the force hunted +-0.6 N with a 2.4 s period (15 kN/m, measured).

Option (ours, not the thesis's) for the position-controlled directions in
contact: integral action on y and phi,

    u_x[y, phi] += K_pi sum_k (target - pose) T        (T = 1 ms)

restarting at each switch to contact, each sum clipped so that
|K_pi sum| <= ``pose_integral_limit``. The tip sticks after the impact
(joint stiction and, with wall friction, the surface): the PD alone
leaves the offset the stiction holds; the integral builds the torque that
breaks it (classical PID with clamping anti-windup, e.g. Astrom & Hagglund,
"PID Controllers", 1995, section 3.5).

Option (ours) for the force integral: hold it for ``force_integral_hold_s``
after each step of f_d (a change of more than ``force_step_threshold_n``
between two samples) and after each switch to contact. The proportional
loop makes a step's transient; summed during it (conditional integration
lets in the part of the step within ``force_integral_band_n``), the
integral winds up by the transient's area and the joints stick past the
new level. Freezing the integrator through a set-point change is the
conditional integration of Astrom & Hagglund ("PID Controllers", 1995,
section 3.5) keyed to the reference instead of the error.

Option (ours) for the joints' static friction in contact: compensate it in
the direction the force error asks the joints to turn,

    tau += c sat(e_f / e_0) F_c sgn(J^-1 e_x)        (elementwise)

with c ``force_error_friction_compensation`` (0-1), F_c the model's
Coulomb levels, J^-1 e_x the joints' motion that moves the tip along +x with
y and phi held, e_0 ``force_error_friction_band_n`` and e_f the force error
f_d - f through a first-order low-pass at ``force_error_filter_hz``. The
thesis's compensation F_c sgn(qdot) needs the joint to move; a stuck joint
has no velocity, and joint 2's stiction alone (0.2 N m through dx/dq2 =
-0.11 m) holds some 1.85 N at the tip, which the integral otherwise has to
build up after every reversal. Compensating Coulomb friction by the sign of
the servo error rather than of the velocity is the nonlinear compensator of
Southward, Radcliffe & MacCluer (1991, "Robust nonlinear stick-slip
friction compensation", ASME J. Dyn. Sys., Meas., Control 113(4)); c < 1
leaves a margin against over-compensation (a limit cycle), and e_0 sits
at about the low-passed force noise so the term is linear within it.

Option (ours) for the position-controlled directions in contact: a joint
stiffness and damping on their error,

    tau += K_q J^-1 (I - S) (x_d - x) - D_q J^-1 (I - S) xdot   (elementwise)

(``pose_joint_stiffness`` K_q, ``pose_joint_damping`` D_q, per joint). The
resolved-acceleration PD holds each joint with a stiffness weighted by the
arm's inertia, M J^-1 K_pp J: joint 3 (2.9e-3 kg m^2) by only 1.2 N m/rad,
less than the wall's push on link 3, a negative stiffness a3 f (3 N m/rad at
20 N) that the feed-forward J^T f_d cancels only to joint 3's encoder count
(3.1 mrad); within a count phi drifted by up to 6.6 mrad. Raising K_pp for
phi instead stiffens joints 1-2 through M J^-1 and feeds them the coarse
count's noise (measured: a 50 Hz oscillation of joint 1). A joint-space
stiffness on joint 3 alone is the active stiffness control of Salisbury
(1980, "Active stiffness control of a manipulator in Cartesian
coordinates", IEEE CDC) restricted to the joint that needs it.

Sampled at each whole millisecond, in the same event as the plant step its
torque acts over (see arm.py, ``is_sample_time``). Reads measured signals only: the estimator's tip pose, velocity, joint
angles and velocities, and the DSP's filtered force. M, h, J, Jdot qdot and
F_c come from the controller's own model of the arm (controller_model.py),
which may be wrong. Jdot qdot is the true one (the thesis's code used a
product linear in qdot, Appendix E).
"""

import dataclasses as dc
import math

import numpy as np
from pydrake.systems.framework import Diagram, DiagramBuilder, LeafSystem
from pydrake.systems.primitives import Demultiplexer

from drake_contact.blocks import Layout
from drake_contact.constants import CONTACT_THRESHOLD_N, RATIO_TOLERANCE
from drake_contact.plant.arm import (
    CONTROL_PERIOD, LINK_LENGTHS, TIME_TOLERANCE_S, DeclareSampledUpdate, is_sample_time)
from drake_contact.control.controller_model import ArmModel, ControllerModelConfig
from drake_contact.plant.planar_arm import solve3
from drake_contact.control.policy_spaces import ACTION, apply_action
from drake_contact.errors import ScenarioError, require_finite

CONTACT_LAWS = ("hybrid", "decoupled")
APPROACH, CONTACT = 0, 1


@dc.dataclass
class ApproachConfig:
    """The approach schedule of x_d (thesis chapter 4, Appendix E)."""

    # Hold x_d at start_x (m) for this long (s).
    hold_time_s: float = 5.0
    start_x: float = 0.454
    # Then x_d = first_target_x (m), plus step_m (m) every step_period_s (s).
    first_target_x: float = 0.456
    step_m: float = 0.001
    step_period_s: float = 1.0

    def validate(self, prefix):
        for field in ("hold_time_s", "step_period_s"):
            if not (getattr(self, field) > 0):
                raise ScenarioError(f"{prefix}.{field} = {getattr(self, field)} is out of range: "
                                    "must be > 0 s")
        if not (0 < self.step_m <= 0.01):
            raise ScenarioError(f"{prefix}.step_m = {self.step_m} is out of range: "
                                "must be in (0, 0.01] m")
        reach = sum(LINK_LENGTHS)
        for field in ("start_x", "first_target_x"):
            if not (abs(getattr(self, field)) <= reach):
                raise ScenarioError(f"{prefix}.{field} = {getattr(self, field)} is out of range: "
                                    f"must be in [-{reach:.4g}, {reach:.4g}] m (the arm's reach)")


@dc.dataclass
class HybridControllerConfig:
    """Gains and switching of the approach and contact controllers."""

    # Contact law: hybrid (4.13-4.15) or decoupled (4.19-4.21).
    law: str = "hybrid"
    # Position gains K_pp (1/s^2) and K_pv (1/s); overdamped: K_pv^2 >= 4 K_pp.
    position_gain: float = 400.0
    velocity_gain: float = 80.0
    # Force gains of the hybrid law: K_fp (dimensionless) and K_fi (per sample).
    force_gain: float = 1.0
    force_integral_gain: float = 0.003
    # Active damping along x in contact, hybrid law (N s/m): adds -D_x xdot to
    # the commanded force, S zeroing the position loop's damping there. Not in
    # the thesis (0 = its law); velocity feedback in explicit force control
    # (Volpe & Khosla 1993).
    contact_damping_x: float = 0.0
    # Force-rate damping D_f along x in contact, hybrid law (s): adds
    # -D_f (f_k - f_{k-1}) / T to the commanded force (0 = the thesis's law).
    contact_force_rate_damping: float = 0.0
    # Decoupled law: K_fd (1/s^2) and K_fv (1/s).
    decoupled_force_gain: float = 400.0
    decoupled_force_damping: float = 40.0
    # Integral of the force error in the decoupled law's force command, as
    # K_fi in the hybrid law (per sample; 0 = 4.19 as printed): J^T S (f_d +
    # K_fdi sum_k (f_d - f)). Ours: see the module doc.
    decoupled_force_integral_gain: float = 0.0
    # Conditional integration (N; 0 = always, the thesis): the force error
    # is summed only while |f_d - f| <= this, so a step of f_d does not wind
    # the integral up (Astrom & Hagglund 1995, section 3.5).
    force_integral_band_n: float = 0.0
    # Stiffness (N/m) the decoupled law uses when no identifier feeds it.
    stiffness_estimate: float = 7000.0
    # Name of an identifier whose K_e feeds the decoupled law ('' = the constant).
    stiffness_source: str = ""
    # [lowest, highest] k_e (N/m) the decoupled law uses; an identifier's
    # estimate is clipped to them.
    stiffness_bounds: list[float] = dc.field(default_factory=lambda: [1.0, 1.0e12])
    # The k_e the decoupled law uses follows a rise of the estimate at once
    # and a fall by at most half per this time (s; 0 = at once). It starts
    # at the bounds' top at each switch to contact. See the module doc.
    stiffness_halving_time_s: float = 0.0
    # Integral gain K_pi on y and phi in contact (1/s^3; 0 = the thesis's PD)
    # and the bound on the integral's acceleration (m/s^2 and rad/s^2).
    pose_integral_gain: float = 0.0
    pose_integral_limit: float = 20.0
    # Decoupled law: the fraction (0-1; 0 = 4.19-4.21) of the force
    # imbalance's coupling into y and phi cancelled (see the module doc).
    force_coupling_cancellation: float = 0.0
    # Hold the force integral for this long (s; 0 = never) after each step
    # of f_d larger than force_step_threshold_n (N) between two samples, and
    # after each switch to contact: the proportional loop makes the step's
    # transient, the integral only what stiction leaves (see the module doc).
    force_integral_hold_s: float = 0.0
    force_step_threshold_n: float = 1.0
    # Static-friction compensation driven by the force error (ours; 0 = off):
    # in contact each joint gets this fraction (0-1) of the model's Coulomb
    # level F_c, in the direction it turns to push the tip along +x
    # (sign of J^-1 e_x), scaled by sat(e_f / band), e_f the force error
    # f_d - f through a first-order low-pass at force_error_filter_hz (Hz).
    # See the module doc.
    force_error_friction_compensation: float = 0.0
    force_error_friction_band_n: float = 0.25
    force_error_filter_hz: float = 10.0
    # Joint stiffness (N m/rad) and damping (N m s/rad), joints 1-3, on the
    # pose error of the position-controlled directions mapped to the joints,
    # J^-1 (I - S) (x_d - x), in contact (zeros = the thesis's law; see the
    # module doc).
    pose_joint_stiffness: list[float] = dc.field(default_factory=lambda: [0.0, 0.0, 0.0])
    pose_joint_damping: list[float] = dc.field(default_factory=lambda: [0.0, 0.0, 0.0])
    # Compensate dry friction with the model's F_c sgn(qdot) (the text's
    # 4.10, 4.13, 4.19; clipped within friction_band). Off: Appendix E as it
    # ran adds sgn1*co1*0.9*9.8 and sgn2*co2*0.3 in the approach only, with
    # co = |qdot|/0.002 set only while |qdot| <= 0.002 rad/s and 0 at the
    # start, and a count-quantized velocity is never that small but 0: the
    # code's compensation is exactly 0 throughout.
    friction_compensation: bool = False
    # Switch to contact above this filtered force (N), back below the other.
    contact_threshold_n: float = CONTACT_THRESHOLD_N
    contact_loss_threshold_n: float = 0.0
    # Held position y_d (m) and angle phi_d (rad) in contact.
    y_desired: float = 0.0
    phi_desired: float = 0.0
    approach: ApproachConfig = dc.field(default_factory=ApproachConfig)
    model: ControllerModelConfig = dc.field(default_factory=ControllerModelConfig)

    def validate(self, prefix="controller.hybrid"):
        if self.law not in CONTACT_LAWS:
            raise ScenarioError(f"{prefix}.law = '{self.law}' is unknown: choose one of "
                                f"{', '.join(CONTACT_LAWS)}")
        for field in ("position_gain", "velocity_gain", "force_gain", "force_integral_gain",
                      "contact_damping_x", "contact_force_rate_damping", "decoupled_force_gain",
                      "decoupled_force_damping", "decoupled_force_integral_gain",
                      "force_integral_band_n", "pose_integral_gain", "pose_integral_limit",
                      "stiffness_halving_time_s", "force_integral_hold_s",
                      "force_step_threshold_n"):
            value = getattr(self, field)
            if not (np.isfinite(value) and value >= 0):
                raise ScenarioError(f"{prefix}.{field} = {value} is out of range: must be >= 0")
        for field, unit in (("pose_joint_stiffness", "N m/rad"),
                            ("pose_joint_damping", "N m s/rad")):
            value = getattr(self, field)
            if len(value) != 3 or not all(np.isfinite(v) and v >= 0 for v in value):
                raise ScenarioError(f"{prefix}.{field} = {value} is out of range: must be 3 "
                                    f"values >= 0 {unit}")
        if not (0.0 <= self.force_error_friction_compensation <= 1.0):
            raise ScenarioError(f"{prefix}.force_error_friction_compensation = "
                                f"{self.force_error_friction_compensation} is out of range: "
                                "must be in [0, 1]")
        for field, unit in (("force_error_friction_band_n", "N"),
                            ("force_error_filter_hz", "Hz")):
            if not (np.isfinite(getattr(self, field)) and getattr(self, field) > 0):
                raise ScenarioError(f"{prefix}.{field} = {getattr(self, field)} is out of "
                                    f"range: must be > 0 {unit}")
        if not (self.force_error_filter_hz < 500.0):
            raise ScenarioError(f"{prefix}.force_error_filter_hz = {self.force_error_filter_hz} "
                                "is out of range: must be below 500 Hz (the 1 kHz sample's "
                                "Nyquist rate)")
        if not (0.0 <= self.force_coupling_cancellation <= 1.0):
            raise ScenarioError(f"{prefix}.force_coupling_cancellation = "
                                f"{self.force_coupling_cancellation} is out of range: "
                                "must be in [0, 1]")
        if not (abs(self.y_desired) <= 0.1):
            raise ScenarioError(f"{prefix}.y_desired = {self.y_desired} is out of range: "
                                "must be in [-0.1, 0.1] m")
        if not (abs(self.phi_desired) <= math.pi):
            raise ScenarioError(f"{prefix}.phi_desired = {self.phi_desired} is out of range: "
                                "must be in [-pi, pi] rad")
        if not (self.stiffness_estimate > 0):
            raise ScenarioError(f"{prefix}.stiffness_estimate = {self.stiffness_estimate} is out "
                                "of range: must be > 0 N/m")
        bounds = self.stiffness_bounds
        if len(bounds) != 2 or not (0 < bounds[0] < bounds[1] < np.inf):
            raise ScenarioError(f"{prefix}.stiffness_bounds = {bounds} is out of range: must be "
                                "[lowest, highest] with 0 < lowest < highest (N/m)")
        if not (self.contact_threshold_n > self.contact_loss_threshold_n):
            raise ScenarioError(
                f"{prefix}.contact_threshold_n = {self.contact_threshold_n} is out of range: "
                f"must exceed contact_loss_threshold_n = {self.contact_loss_threshold_n} N")
        self.approach.validate(f"{prefix}.approach")
        self.model.validate(f"{prefix}.model")


#: Layout of the law's output vector: the exported signals, then the
#: internal state [approach timer (s), x_d (m), sum of force errors (N),
#: sums of the y and phi errors (m, rad), the force at this sample (N), the k_e
#: the decoupled law used (N/m), f_d at this sample (N), the time until which
#: the force integral is held (s), the low-passed force error (N)].
_LAW = Layout(("tau", 3), ("mode", 1), ("info", 4), ("jacobian", 9), ("internal", 10))
_TAU, _MODE, _INFO, _JACOBIAN, _INTERNAL = (
    _LAW.tau, _LAW.mode, _LAW.info, _LAW.jacobian, _LAW.internal)
_LAW_SIZE = _LAW.size


def read_measured_state(context, pose, velocity, joint_positions, joint_velocities):
    """The tip pose and velocity and the joint angles and velocities a
    controller's input ports hold at ``context``, as lists of Python floats
    (on 3-vectors numpy's per-call cost is most of the work); a non-finite
    value stops the run, saying when (SimulationDiverged)."""
    x = pose.Eval(context).tolist()
    xd = velocity.Eval(context).tolist()
    q = joint_positions.Eval(context).tolist()
    qdot = joint_velocities.Eval(context).tolist()
    if not math.isfinite(sum(x) + sum(xd) + sum(q) + sum(qdot)):
        require_finite(np.array([math.nan]), context, "controller",
                       "the controller's measured state")
    return x, xd, q, qdot


class HybridControlLaw(LeafSystem):
    """The law of :class:`HybridController` as one leaf system: its single
    output ``control`` (20) is the law evaluated on the inputs at a sample
    instant (k ms) and held between them; the discrete update at each sample
    stores it. So the law runs once per sample, in the same event as the
    plant step it drives."""

    def __init__(self, config: HybridControllerConfig, action_input: bool = False):
        super().__init__()
        config.validate()
        if action_input and config.law != "hybrid":
            raise ScenarioError(f"controller.hybrid.law = '{config.law}': a policy's action "
                                "acts on the hybrid law only: choose law: hybrid")
        self._config = config
        self._model = ArmModel(config.model)
        self._joint_impedance = any(config.pose_joint_stiffness) or any(config.pose_joint_damping)
        # First-order low-pass of the force error, exact for a held input.
        self._error_filter_gain = 1.0 - math.exp(-2.0 * math.pi * config.force_error_filter_hz
                                                 * CONTROL_PERIOD)
        self._pose = self.DeclareVectorInputPort("tip_pose", 3)
        self._velocity = self.DeclareVectorInputPort("tip_velocity", 3)
        self._q = self.DeclareVectorInputPort("joint_positions", 3)
        self._qdot = self.DeclareVectorInputPort("joint_velocities", 3)
        self._force = self.DeclareVectorInputPort("force", 1)
        self._force_desired = self.DeclareVectorInputPort("force_desired", 1)
        self._stiffness = self.DeclareVectorInputPort("stiffness_estimate", 1)
        held = np.zeros(_LAW_SIZE)
        held[_INFO] = [-1.0, 0.0, 0.0, 0.0]
        held[_INTERNAL] = [0.0, config.approach.start_x, 0.0, 0.0, 0.0, 0.0,
                           config.stiffness_bounds[1], 0.0, 0.0, 0.0]
        self._held = self.DeclareDiscreteState(held)
        # A policy's action (drake_contact.control.policy), and the law's
        # held output (the previous sample's) for the policy's observation:
        # it does not depend on the action.
        self._action = None
        if action_input:
            self._action = self.DeclareVectorInputPort("policy_action", ACTION.size)
            self.DeclareStateOutputPort("held", self._held)
        self._control = self.DeclareVectorOutputPort(
            "control", _LAW_SIZE, self._calc_control,
            prerequisites_of_calc={self.all_input_ports_ticket(), self.xd_ticket(),
                                   self.time_ticket()})
        DeclareSampledUpdate(self, self._update)

    def _update(self, context, state):
        # At t = 0 (before the first sample) the output is the held state.
        state.set_value(self._control.Eval(context))

    def _approach_target(self, timer, x_d):
        a = self._config.approach
        if timer < a.hold_time_s - TIME_TOLERANCE_S:
            return x_d  # start_x at the start; the last target after a loss
        return a.first_target_x + a.step_m * np.floor((timer - a.hold_time_s) / a.step_period_s
                                                      + RATIO_TOLERANCE)

    def _calc_control(self, context, output):
        c = self._config
        held = context.get_discrete_state(self._held).value()
        t = context.get_time()
        if not is_sample_time(t):
            output.SetFromVector(held)  # zero-order hold between samples
            return
        x, xd, q, qdot = read_measured_state(
            context, self._pose, self._velocity, self._q, self._qdot)
        f = self._force.Eval(context)[0]
        mode = held[_MODE]
        info = held[_INFO].tolist()
        (timer, x_d, error_sum, y_sum, phi_sum, f_previous, k_used, fd_previous,
         hold_until, error_lp) = held[_INTERNAL].tolist()

        if mode == APPROACH and f > c.contact_threshold_n:
            mode, error_sum, y_sum, phi_sum, error_lp = CONTACT, 0.0, 0.0, 0.0, 0.0
            k_used = c.stiffness_bounds[1]
            if info[0] < 0:
                info[0] = t
            info[1:] = x
        elif mode == CONTACT and f < c.contact_loss_threshold_n:
            mode = APPROACH
            timer = c.approach.hold_time_s - c.approach.step_period_s
        if mode == APPROACH:
            x_d = self._approach_target(timer, x_d)
            timer += CONTROL_PERIOD

        J, jdot_qdot, M, h = self._model.evaluate_rows(q, qdot)
        target = (x_d, c.y_desired, c.phi_desired)
        u_x = [c.position_gain * (target[i] - x[i]) - c.velocity_gain * xd[i] for i in range(3)]
        tau = list(h)
        if c.friction_compensation:
            tau = [a + b for a, b in zip(tau, self._model.friction_compensation(qdot))]
        force_x = 0.0
        if mode == APPROACH:
            accel = u_x
        else:
            f_d = self._force_desired.Eval(context)[0]
            error = f_d - f
            if c.force_integral_hold_s and abs(f_d - fd_previous) > c.force_step_threshold_n:
                hold_until = t + c.force_integral_hold_s
            fd_previous = f_d
            if t > hold_until - 0.5 * CONTROL_PERIOD and (not c.force_integral_band_n
                                    or abs(error) <= c.force_integral_band_n):
                error_sum += error
            accel = [0.0, u_x[1], u_x[2]]  # (I - S) u_x
            if c.pose_integral_gain:
                gain = c.pose_integral_gain * CONTROL_PERIOD
                bound = c.pose_integral_limit / gain
                y_sum = min(max(y_sum + (target[1] - x[1]), -bound), bound)
                phi_sum = min(max(phi_sum + (target[2] - x[2]), -bound), bound)
                accel[1] += gain * y_sum
                accel[2] += gain * phi_sum
            if c.law == "hybrid":
                force_gain, integral_gain, damping_x = (
                    c.force_gain, c.force_integral_gain, c.contact_damping_x)
                if self._action is not None:
                    residual, force_gain, integral_gain, damping_x = apply_action(
                        self._action.Eval(context), force_gain, integral_gain, damping_x)
                force_x = f_d + force_gain * error + integral_gain * error_sum
                if self._action is not None:
                    force_x += residual
                if damping_x:
                    force_x -= damping_x * xd[0]
                if c.contact_force_rate_damping:
                    force_x -= c.contact_force_rate_damping * (f - f_previous) / CONTROL_PERIOD
            else:
                force_x, k_used = self._decoupled_x(
                    context, f_d, error, error_sum, k_used, xd, accel, J, M)
        qddot = solve3(J, [a - b for a, b in zip(accel, jdot_qdot)])
        tau = [tau[i] + M[i][0] * qddot[0] + M[i][1] * qddot[1] + M[i][2] * qddot[2]
               + J[0][i] * force_x for i in range(3)]
        if mode == CONTACT:
            tau, error_lp = self._contact_joint_terms(tau, error, error_lp, J, target, x, xd)

        output.SetFromVector(self._model.command(tau) + [mode] + info + J[0] + J[1] + J[2]
                             + [timer, x_d, error_sum, y_sum, phi_sum, f, k_used, fd_previous,
                                hold_until, error_lp])


    def _decoupled_x(self, context, f_d, error, error_sum, k_used, xd, accel, J, M):
        """The decoupled law's x (4.19-4.21) with this sample's K_e estimate:
        sets ``accel[0]`` (and cancels the force imbalance's y, phi part in
        ``accel``); returns the force along x and the K_e it used."""
        c = self._config
        low, high = c.stiffness_bounds
        k_e = min(max(self._stiffness.Eval(context)[0], low), high)
        if c.stiffness_halving_time_s:
            k_e = max(k_e, k_used * 0.5 ** (CONTROL_PERIOD / c.stiffness_halving_time_s))
        accel[0] = (c.decoupled_force_gain * error
                    - c.decoupled_force_damping * k_e * xd[0]) / k_e
        force_x = f_d
        if c.decoupled_force_integral_gain:
            force_x += c.decoupled_force_integral_gain * error_sum
        if c.force_coupling_cancellation:
            # Lambda^-1 e_x = J M^-1 J^T e_x: the task acceleration a unit
            # force along x gives; cancel its y, phi part for f_d - f.
            v = solve3(M, [J[0][0], J[0][1], J[0][2]])
            imbalance = c.force_coupling_cancellation * error
            for i in (1, 2):
                accel[i] -= (J[i][0] * v[0] + J[i][1] * v[1] + J[i][2] * v[2]) * imbalance
        return force_x, k_e

    def _contact_joint_terms(self, tau, error, error_lp, J, target, x, xd):
        """In contact, the joint torques' options: static friction
        compensated in the direction the low-passed force error asks, and
        joint-space stiffness and damping of y and phi. Returns the torques
        and the low-passed force error."""
        c = self._config
        if c.force_error_friction_compensation:
            error_lp += self._error_filter_gain * (error - error_lp)
            push = solve3(J, [1.0, 0.0, 0.0])  # the joints' turn for +x, y and phi held
            level = c.force_error_friction_compensation * min(
                max(error_lp / c.force_error_friction_band_n, -1.0), 1.0)
            friction = self._model.friction_levels
            tau = [tau[i] + level * friction[i] * math.copysign(1.0, push[i])
                   for i in range(3)]
        if self._joint_impedance:
            stiffness, damping = c.pose_joint_stiffness, c.pose_joint_damping
            e_q = solve3(J, [0.0, target[1] - x[1], target[2] - x[2]])
            v_q = solve3(J, [0.0, xd[1], xd[2]])
            tau = [tau[i] + stiffness[i] * e_q[i] - damping[i] * v_q[i] for i in range(3)]
        return tau, error_lp


class HybridController(Diagram):
    """The thesis's approach and contact controllers, sampled every 1 ms.

    Input ports (measured signals):
      tip_pose (3): [x, y, phi] (m, rad); tip_velocity (3) (m/s, rad/s);
      joint_positions (3) (rad); joint_velocities (3) (rad/s);
      force (1): the DSP's filtered force (N); force_desired (1) (N);
      stiffness_estimate (1): k_e for the decoupled law (N/m).
    Output ports (this sample's values, held between samples):
      joint_torque_commanded (3) (N m); mode (1): 0 approach, 1 contact;
      tip_jacobian (9): this sample's J of [x, y, phi] w.r.t. q, row-major,
        from the controller's model (for the compensator's J^T n);
      contact_info (4): [time of the first switch (s) or -1, x, y, phi at
        the latest switch] for the reference generator and identifiers.
    With ``action_input``: the input policy_action (4, see
    :mod:`drake_contact.control.policy_spaces`) and the output held (the
    law's output at the previous sample: its layout's mode, contact_info,
    ...).

    A sub-diagram: the law (:class:`HybridControlLaw`, one Python
    evaluation per sample) and a Demultiplexer that names its outputs.
    """

    def __init__(self, config: HybridControllerConfig, action_input: bool = False):
        super().__init__()
        builder = DiagramBuilder()
        law = builder.AddNamedSystem("law", HybridControlLaw(config, action_input))
        if action_input:
            builder.ExportOutput(law.GetOutputPort("held"), "held")
        split = builder.AddNamedSystem("outputs", Demultiplexer(_LAW.sizes))
        builder.Connect(law.GetOutputPort("control"), split.get_input_port())
        for port in range(law.num_input_ports()):
            builder.ExportInput(law.get_input_port(port), law.get_input_port(port).get_name())
        for index, name in enumerate(("joint_torque_commanded", "mode", "contact_info",
                                      "tip_jacobian")):
            builder.ExportOutput(split.get_output_port(index), name)
        builder.BuildInto(self)
