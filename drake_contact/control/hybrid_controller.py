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

One :class:`HybridControlLaw` serves N environments (an ensemble; one config
each, a single config for one): the same code runs on Python floats for one
and elementwise on arrays over the arm axis for N, each environment's
branches (approach or contact, the switch, the holds, the clips) as masks,
each environment bit for bit what it computes alone. The configs may differ
in every number, not in the law nor in which options are on.
"""

import dataclasses as dc
import math
from collections.abc import Sequence
from types import SimpleNamespace

import numpy as np
from pydrake.systems.framework import Diagram, DiagramBuilder, LeafSystem
from pydrake.systems.primitives import Demultiplexer

from drake_contact.arm_axis import arm_axis_ops, per_environment
from drake_contact.blocks import Layout, environment_configs
from drake_contact.constants import CONTACT_THRESHOLD_N, RATIO_TOLERANCE
from drake_contact.plant.arm import (
    CONTROL_PERIOD, LINK_LENGTHS, TIME_TOLERANCE_S, DeclareSampledUpdate, held_while_flagged,
    is_sample_time)
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


#: Layout of one environment's part of the law's output vector: the
#: exported signals, then the internal state [approach timer (s), x_d (m),
#: sum of force errors (N), sums of the y and phi errors (m, rad), the force
#: at this sample (N), the k_e the decoupled law used (N/m), f_d at this
#: sample (N), the time until which the force integral is held (s), the
#: low-passed force error (N)]. N environments' vector is field-major, each
#: field env-major: field F (k values) at [N o_F + k i, N o_F + k (i + 1))
#: for environment i, o_F its offset here.
_LAW = Layout(("tau", 3), ("mode", 1), ("info", 4), ("jacobian", 9), ("internal", 10))
_TAU, _MODE, _INFO, _JACOBIAN, _INTERNAL = (
    _LAW.tau, _LAW.mode, _LAW.info, _LAW.jacobian, _LAW.internal)
_LAW_SIZE = _LAW.size


def _gather(count):
    """(_LAW_SIZE, count) indices of the N-environment law vector: row e,
    column i is environment i's element e of :data:`_LAW`."""
    index = np.empty((_LAW_SIZE, count), dtype=int)
    for name, size in zip(_LAW.names(), _LAW.sizes):
        field = getattr(_LAW, name)
        start = field.start if isinstance(field, slice) else field
        for k in range(size):
            index[start + k] = count * start + size * np.arange(count) + k
    return index


#: The options a config switches on (its structure, which an ensemble's
#: environments share), by the field that switches each.
_SWITCHES = {
    "law": lambda c: c.law,
    "contact_damping_x": lambda c: c.contact_damping_x != 0,
    "contact_force_rate_damping": lambda c: c.contact_force_rate_damping != 0,
    "decoupled_force_integral_gain": lambda c: c.decoupled_force_integral_gain != 0,
    "stiffness_source": lambda c: c.stiffness_source != "",
    "stiffness_halving_time_s": lambda c: c.stiffness_halving_time_s != 0,
    "pose_integral_gain": lambda c: c.pose_integral_gain != 0,
    "force_coupling_cancellation": lambda c: c.force_coupling_cancellation != 0,
    "force_integral_hold_s": lambda c: c.force_integral_hold_s != 0,
    "force_error_friction_compensation": lambda c: c.force_error_friction_compensation != 0,
    "pose_joint_stiffness": lambda c: any(c.pose_joint_stiffness) or any(c.pose_joint_damping),
    "friction_compensation": lambda c: bool(c.friction_compensation),
}


def structure(config) -> dict:
    """The options ``config`` switches on (:data:`_SWITCHES`), by field: what
    an ensemble's environments share (their numbers may differ)."""
    return {field: switch(config) for field, switch in _SWITCHES.items()}


def _check_structure(configs, prefix="controller.hybrid"):
    """Raises ScenarioError naming the field if an environment's config
    switches an option on that environment 0's leaves off, or the reverse
    (their numbers may differ)."""
    first = structure(configs[0])
    for i, config in enumerate(configs[1:], start=1):
        for field, value in structure(config).items():
            if value == first[field]:
                continue
            if field == "law":
                raise ScenarioError(
                    f"{prefix}[{i}].law = '{config.law}' differs from environment 0's "
                    f"('{configs[0].law}'): an ensemble's environments share a structure")
            if field == "pose_joint_stiffness" and (
                    any(config.pose_joint_stiffness) == any(configs[0].pose_joint_stiffness)):
                field = "pose_joint_damping"  # joint impedance: stiffness or damping on
            raise ScenarioError(
                f"{prefix}[{i}].{field} = {getattr(config, field)} differs in whether it is on "
                f"from environment 0's ({getattr(configs[0], field)}): an ensemble's "
                "environments share a structure")


def _parameters(configs):
    """Each environment's numbers (Python floats for one, arrays (N,) for
    more), with the constants the law derives from them computed per
    environment in Python floats (exp and pow stay out of the per-sample
    kernel: numpy's differ from math's in the last bit)."""
    def each(get):
        return per_environment(get(c) for c in configs)

    names = ("position_gain", "velocity_gain", "force_gain", "force_integral_gain",
             "contact_damping_x", "contact_force_rate_damping", "decoupled_force_gain",
             "decoupled_force_damping", "decoupled_force_integral_gain", "force_integral_band_n",
             "force_coupling_cancellation", "force_integral_hold_s", "force_step_threshold_n",
             "force_error_friction_compensation", "force_error_friction_band_n",
             "contact_threshold_n", "contact_loss_threshold_n", "y_desired", "phi_desired")
    p = SimpleNamespace(**{name: each(lambda c, name=name: getattr(c, name)) for name in names})
    for name in ("start_x", "hold_time_s", "first_target_x", "step_m", "step_period_s"):
        setattr(p, name, each(lambda c, name=name: getattr(c.approach, name)))
    # The approach holds x_d until hold_end; after a loss the timer restarts
    # one step period before the first target.
    p.hold_end = each(lambda c: c.approach.hold_time_s - TIME_TOLERANCE_S)
    p.restart_timer = each(lambda c: c.approach.hold_time_s - c.approach.step_period_s)
    p.stiffness_low = each(lambda c: c.stiffness_bounds[0])
    p.stiffness_high = each(lambda c: c.stiffness_bounds[1])
    p.stiffness_fall = each(lambda c: 0.5 ** (CONTROL_PERIOD / c.stiffness_halving_time_s)
                            if c.stiffness_halving_time_s else 0.0)
    p.pose_integral_step = each(lambda c: c.pose_integral_gain * CONTROL_PERIOD)
    p.pose_integral_bound = each(
        lambda c: c.pose_integral_limit / (c.pose_integral_gain * CONTROL_PERIOD)
        if c.pose_integral_gain else 0.0)
    # First-order low-pass of the force error, exact for a held input.
    p.error_filter_gain = each(lambda c: 1.0 - math.exp(
        -2.0 * math.pi * c.force_error_filter_hz * CONTROL_PERIOD))
    p.pose_joint_stiffness = [per_environment(k) for k in zip(
        *(c.pose_joint_stiffness for c in configs))]
    p.pose_joint_damping = [per_environment(d) for d in zip(
        *(c.pose_joint_damping for c in configs))]
    return p


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
    """The law of :class:`HybridController` for N environments (one config
    each; a single config: N = 1) as one leaf system: its single output
    ``control`` (27 N: :data:`_LAW` per environment, field-major, each field
    env-major) is the law evaluated on the inputs at a sample instant (k ms)
    and held between them; the discrete update at each sample stores it. So
    the law runs once per sample, in the same event as the plant step it
    drives.

    Inputs are env-major (environment i's k values at [k i, k (i + 1))):
    tip_pose, tip_velocity, joint_positions, joint_velocities (3 N each),
    force, force_desired, stiffness_estimate (N each).

    One code runs the law (:meth:`_law`): on Python floats for one
    environment, elementwise on arrays (N,) for more, its branches per
    environment (approach or contact, the switch and the loss, the held and
    the conditional integral, the clips) as masks through the operations of
    :func:`drake_contact.arm_axis.arm_axis_ops`; environment i's outputs are
    bit for bit those of the law with its config alone. The configs may
    differ in every number, not in the options they switch on (the law, and
    which optional terms are on: :func:`_check_structure`). With
    ``action_input``, a policy's action (4 per environment, env-major)
    acts on each environment's law."""

    def __init__(self, config: HybridControllerConfig | Sequence[HybridControllerConfig],
                 action_input: bool = False):
        super().__init__()
        configs = environment_configs(config, HybridControllerConfig, "controller.hybrid")
        self._count = count = len(configs)
        for i, c in enumerate(configs):
            c.validate("controller.hybrid" if count == 1 else f"controller.hybrid[{i}]")
        _check_structure(configs)
        first = configs[0]
        if action_input and first.law != "hybrid":
            raise ScenarioError(f"controller.hybrid.law = '{first.law}': a policy's action "
                                "acts on the hybrid law only: choose law: hybrid")
        self._ops = arm_axis_ops(count)
        self._p = _parameters(configs)
        self._model = ArmModel(first.model if count == 1 else [c.model for c in configs])
        # The structure: which optional terms the law computes.
        self._hybrid = first.law == "hybrid"
        self._friction_compensation = bool(first.friction_compensation)
        self._damping_x = first.contact_damping_x != 0
        self._force_rate_damping = first.contact_force_rate_damping != 0
        self._decoupled_integral = first.decoupled_force_integral_gain != 0
        self._stiffness_fall = first.stiffness_halving_time_s != 0
        self._pose_integral = first.pose_integral_gain != 0
        self._coupling = first.force_coupling_cancellation != 0
        self._integral_hold = first.force_integral_hold_s != 0
        self._friction_from_error = first.force_error_friction_compensation != 0
        self._joint_impedance = _SWITCHES["pose_joint_stiffness"](first)
        self._pose = self.DeclareVectorInputPort("tip_pose", 3 * count)
        self._velocity = self.DeclareVectorInputPort("tip_velocity", 3 * count)
        self._q = self.DeclareVectorInputPort("joint_positions", 3 * count)
        self._qdot = self.DeclareVectorInputPort("joint_velocities", 3 * count)
        self._force = self.DeclareVectorInputPort("force", count)
        self._force_desired = self.DeclareVectorInputPort("force_desired", count)
        self._stiffness = self.DeclareVectorInputPort("stiffness_estimate", count)
        # The safety supervisor's flag: while it is up, the law holds its
        # output and state (unconnected: never).
        self._fault = self.DeclareVectorInputPort("force_fault", count)
        self._index = _gather(count)
        rows = np.zeros((_LAW_SIZE, count))
        rows[_INFO] = np.array([[-1.0], [0.0], [0.0], [0.0]])
        start = _INTERNAL.start
        rows[start + 1], rows[start + 6] = self._p.start_x, self._p.stiffness_high  # x_d, k_e
        held = np.empty(_LAW_SIZE * count)
        held[self._index] = rows
        self._rows = rows  # the N-environment output's work buffer
        self._held = self.DeclareDiscreteState(held)
        # A policy's action (drake_contact.control.policy), and the law's
        # held output (the previous sample's) for the policy's observation:
        # it does not depend on the action.
        self._action = None
        self._applied = None  # (the action's bytes, apply_action of it): a memo
        if action_input:
            self._action = self.DeclareVectorInputPort("policy_action", ACTION.size * count)
            self.DeclareStateOutputPort("held", self._held)
        self._control = self.DeclareVectorOutputPort(
            "control", _LAW_SIZE * count, self._calc_control,
            prerequisites_of_calc={self.all_input_ports_ticket(), self.xd_ticket(),
                                   self.time_ticket()})
        DeclareSampledUpdate(self, self._update)

    def _update(self, context, state):
        # At t = 0 (before the first sample) the output is the held state.
        state.set_value(self._control.Eval(context))

    def _calc_control(self, context, output):
        held = context.get_discrete_state(self._held).value()
        t = context.get_time()
        if not is_sample_time(t):
            output.SetFromVector(held)  # zero-order hold between samples
            return
        paused = held_while_flagged(self._fault, context)
        if self._count == 1:
            if paused is not None:
                output.SetFromVector(held)
                return
            x, xd, q, qdot = read_measured_state(
                context, self._pose, self._velocity, self._q, self._qdot)
            output.SetFromVector(self._law(context, t, held.tolist(), x, xd, q, qdot))
            return
        # Rows over the arm axis; a diverging environment's non-finite
        # values stay its own (the station reports it).
        x, xd, q, qdot = (list(port.Eval(context).reshape(self._count, 3).T) for port in (
            self._pose, self._velocity, self._q, self._qdot))
        rows = self._rows
        before = held[self._index]
        for e, value in enumerate(self._law(context, t, before, x, xd, q, qdot)):
            rows[e] = value
        if paused is not None:
            rows[:, paused] = before[:, paused]
        output.get_mutable_value()[self._index] = rows

    def _value(self, port, context):
        """An input of one value per environment: a Python float for one
        (numpy's scalars cost more per operation), else an array (N,)."""
        value = port.Eval(context)
        return float(value[0]) if self._count == 1 else value

    def _law(self, context, t, held, x, xd, q, qdot):
        """The law at the sample at ``t``: the output (a list of
        :data:`_LAW`'s 27 values, each a float or an array (N,)) from the
        held one and the measured [x, y, phi], their rates, q and qdot."""
        p, ops = self._p, self._ops
        where = ops.where
        f = self._value(self._force, context)
        mode = held[_MODE]
        info = list(held[_INFO])
        (timer, x_d, error_sum, y_sum, phi_sum, f_previous, k_used, fd_previous,
         hold_until, error_lp) = held[_INTERNAL]

        enter = (mode == APPROACH) & (f > p.contact_threshold_n)
        leave = (mode == CONTACT) & (f < p.contact_loss_threshold_n)
        if ops.any(enter):
            mode = where(enter, CONTACT, mode)
            error_sum, y_sum, phi_sum, error_lp = (
                where(enter, 0.0, v) for v in (error_sum, y_sum, phi_sum, error_lp))
            k_used = where(enter, p.stiffness_high, k_used)
            info[0] = where(enter & (info[0] < 0), t, info[0])
            info[1:] = [where(enter, x[i], info[i + 1]) for i in range(3)]
        if ops.any(leave):
            mode = where(leave, APPROACH, mode)
            timer = where(leave, p.restart_timer, timer)
        approach = mode == APPROACH
        if ops.any(approach):
            x_d = where(approach, self._approach_target(timer, x_d), x_d)
            timer = where(approach, timer + CONTROL_PERIOD, timer)

        J, jdot_qdot, M, h = self._model.evaluate_rows(q, qdot)
        target = (x_d, p.y_desired, p.phi_desired)
        u_x = [p.position_gain * (target[i] - x[i]) - p.velocity_gain * xd[i] for i in range(3)]
        tau = list(h)
        if self._friction_compensation:
            tau = [a + b for a, b in zip(tau, self._model.friction_compensation(qdot))]
        force_x = 0.0
        accel = u_x
        contact = mode == CONTACT
        in_contact = ops.any(contact)
        if in_contact:
            # Every state this branch changes is masked with `contact`
            # (arrays are never updated in place: x = x + y, not x += y).
            f_d = self._value(self._force_desired, context)
            error = f_d - f
            if self._integral_hold:
                hold_until = where(contact & (abs(f_d - fd_previous) > p.force_step_threshold_n),
                                   t + p.force_integral_hold_s, hold_until)
            fd_previous = where(contact, f_d, fd_previous)
            integrate = contact & (t > hold_until - 0.5 * CONTROL_PERIOD) & (
                (p.force_integral_band_n == 0.0) | (abs(error) <= p.force_integral_band_n))
            error_sum = where(integrate, error_sum + error, error_sum)
            accel = [0.0, u_x[1], u_x[2]]  # (I - S) u_x
            if self._pose_integral:
                gain, bound = p.pose_integral_step, p.pose_integral_bound
                y_sum = where(contact, ops.clip(y_sum + (target[1] - x[1]), -bound, bound), y_sum)
                phi_sum = where(contact, ops.clip(phi_sum + (target[2] - x[2]), -bound, bound),
                                phi_sum)
                accel[1] = accel[1] + gain * y_sum
                accel[2] = accel[2] + gain * phi_sum
            if self._hybrid:
                force_x = self._hybrid_x(context, f, f_d, error, error_sum, f_previous, xd)
            else:
                force_x, k_e = self._decoupled_x(
                    context, f_d, error, error_sum, k_used, xd, accel, J, M)
                k_used = where(contact, k_e, k_used)
            accel = [where(contact, a, u) for a, u in zip(accel, u_x)]
            force_x = where(contact, force_x, 0.0)
        qddot = solve3(J, [a - b for a, b in zip(accel, jdot_qdot)])
        tau = [tau[i] + M[i][0] * qddot[0] + M[i][1] * qddot[1] + M[i][2] * qddot[2]
               + J[0][i] * force_x for i in range(3)]
        if in_contact and (self._friction_from_error or self._joint_impedance):
            terms, error_lp_new = self._contact_joint_terms(
                tau, error, error_lp, J, target, x, xd)
            tau = [where(contact, a, b) for a, b in zip(terms, tau)]
            error_lp = where(contact, error_lp_new, error_lp)

        return (self._model.command(tau) + [mode] + info + J[0] + J[1] + J[2]
                + [timer, x_d, error_sum, y_sum, phi_sum, f, k_used, fd_previous, hold_until,
                   error_lp])

    def _approach_target(self, timer, x_d):
        """x_d of the approach schedule at ``timer``: held until the hold
        ends (start_x at the start, the last target after a loss), then the
        steps from first_target_x."""
        p, ops = self._p, self._ops
        holding = timer < p.hold_end
        if ops.all(holding):
            return x_d
        steps = ops.floor((timer - p.hold_time_s) / p.step_period_s + RATIO_TOLERANCE)
        return ops.where(holding, x_d, p.first_target_x + p.step_m * steps)

    def _hybrid_x(self, context, f, f_d, error, error_sum, f_previous, xd):
        """The hybrid law's force along x (4.13-4.15) and its options; with
        a policy's action (one environment) its residual and gains."""
        p = self._p
        force_gain, integral_gain, damping_x = (
            p.force_gain, p.force_integral_gain, p.contact_damping_x)
        if self._action is not None:
            # The action changes once per policy period: what it makes of
            # the gains is computed once per action (C's pow per
            # environment costs 15 % of a step at N = 64).
            action = self._action.Eval(context)
            key = action.tobytes()
            if self._applied is None or self._applied[0] != key:
                self._applied = (key, apply_action(
                    action if self._count == 1 else action.reshape(self._count, ACTION.size),
                    force_gain, integral_gain, damping_x, self._ops))
            residual, force_gain, integral_gain, damping_x = self._applied[1]
        force_x = f_d + force_gain * error + integral_gain * error_sum
        if self._action is not None:
            force_x = force_x + residual
            # Each environment's damping where its action leaves one.
            force_x = self._ops.where(damping_x != 0.0, force_x - damping_x * xd[0], force_x)
        elif self._damping_x:
            force_x = force_x - damping_x * xd[0]
        if self._force_rate_damping:
            force_x = force_x - p.contact_force_rate_damping * (f - f_previous) / CONTROL_PERIOD
        return force_x

    def _decoupled_x(self, context, f_d, error, error_sum, k_used, xd, accel, J, M):
        """The decoupled law's x (4.19-4.21) with this sample's K_e estimate:
        sets ``accel[0]`` (and cancels the force imbalance's y, phi part in
        ``accel``); returns the force along x and the K_e it used."""
        p, ops = self._p, self._ops
        k_e = ops.clip(self._value(self._stiffness, context), p.stiffness_low, p.stiffness_high)
        if self._stiffness_fall:
            k_e = ops.maximum(k_e, k_used * p.stiffness_fall)
        accel[0] = (p.decoupled_force_gain * error
                    - p.decoupled_force_damping * k_e * xd[0]) / k_e
        force_x = f_d
        if self._decoupled_integral:
            force_x = force_x + p.decoupled_force_integral_gain * error_sum
        if self._coupling:
            # Lambda^-1 e_x = J M^-1 J^T e_x: the task acceleration a unit
            # force along x gives; cancel its y, phi part for f_d - f.
            v = solve3(M, [J[0][0], J[0][1], J[0][2]])
            imbalance = p.force_coupling_cancellation * error
            for i in (1, 2):
                accel[i] = accel[i] - (J[i][0] * v[0] + J[i][1] * v[1]
                                       + J[i][2] * v[2]) * imbalance
        return force_x, k_e

    def _contact_joint_terms(self, tau, error, error_lp, J, target, x, xd):
        """In contact, the joint torques' options: static friction
        compensated in the direction the low-passed force error asks, and
        joint-space stiffness and damping of y and phi. Returns the torques
        and the low-passed force error."""
        p, ops = self._p, self._ops
        if self._friction_from_error:
            error_lp = error_lp + p.error_filter_gain * (error - error_lp)
            push = solve3(J, [1.0, 0.0, 0.0])  # the joints' turn for +x, y and phi held
            level = p.force_error_friction_compensation * ops.clip(
                error_lp / p.force_error_friction_band_n, -1.0, 1.0)
            friction = self._model.coulomb_levels
            tau = [tau[i] + level * friction[i] * ops.copysign(1.0, push[i]) for i in range(3)]
        if self._joint_impedance:
            stiffness, damping = p.pose_joint_stiffness, p.pose_joint_damping
            e_q = solve3(J, [0.0, target[1] - x[1], target[2] - x[2]])
            v_q = solve3(J, [0.0, xd[1], xd[2]])
            tau = [tau[i] + stiffness[i] * e_q[i] - damping[i] * v_q[i] for i in range(3)]
        return tau, error_lp


class HybridController(Diagram):
    """The thesis's approach and contact controllers, sampled every 1 ms,
    for N environments (one config each; a single config: N = 1).

    Input ports (measured signals; env-major: environment i's k values at
    [k i, k (i + 1))):
      tip_pose (3 N): [x, y, phi] (m, rad); tip_velocity (3 N) (m/s, rad/s);
      joint_positions (3 N) (rad); joint_velocities (3 N) (rad/s);
      force (N): the DSP's filtered force (N); force_desired (N) (N);
      stiffness_estimate (N): k_e for the decoupled law (N/m).
    Output ports (this sample's values, held between samples; env-major):
      joint_torque_commanded (3 N) (N m); mode (N): 0 approach, 1 contact;
      tip_jacobian (9 N): this sample's J of [x, y, phi] w.r.t. q, row-major,
        from the controller's model (for the compensator's J^T n);
      contact_info (4 N): [time of the first switch (s) or -1, x, y, phi at
        the latest switch] for the reference generator and identifiers.
    With ``action_input``: the input policy_action (4 N, see
    :mod:`drake_contact.control.policy_spaces`) and the output held (the
    law's output at the previous sample: its layout's mode, contact_info,
    ...; for N environments field-major, as :func:`_gather` lays it out).

    A sub-diagram: the law (:class:`HybridControlLaw`, one Python
    evaluation per sample for all N) and a Demultiplexer that names its
    outputs.
    """

    def __init__(self, config: HybridControllerConfig | Sequence[HybridControllerConfig],
                 action_input: bool = False):
        super().__init__()
        builder = DiagramBuilder()
        law = builder.AddNamedSystem("law", HybridControlLaw(config, action_input))
        count = law._count
        if action_input:
            builder.ExportOutput(law.GetOutputPort("held"), "held")
        split = builder.AddNamedSystem("outputs",
                                       Demultiplexer([size * count for size in _LAW.sizes]))
        builder.Connect(law.GetOutputPort("control"), split.get_input_port())
        for port in range(law.num_input_ports()):
            builder.ExportInput(law.get_input_port(port), law.get_input_port(port).get_name())
        for index, name in enumerate(("joint_torque_commanded", "mode", "contact_info",
                                      "tip_jacobian")):
            builder.ExportOutput(split.get_output_port(index), name)
        builder.BuildInto(self)
