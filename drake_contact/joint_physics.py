"""Joint-side physics of the arm, built from Drake's C++ systems.

* Coulomb joint friction: tau_f = -sat(qdot * F_c / v_s, -F_c, F_c), a
  Coulomb law regularized linearly inside |qdot| < v_s (a MatrixGain and a
  Saturation: no Python callback). The thesis (chapter 4) models dry friction
  F_c sgn(qdot) and neglects viscous friction.
* Torque saturation at the controller's limits (Appendix E: 16, 2.5, 0.6 N m).
* Encoders: Drake's ``RotaryEncoders`` quantize the joint angles to the
  counts per revolution of chapter 3 (joint 1 614,400, joint 2 409,600,
  joint 3 2,000; Appendix B swaps the first two; we follow chapter 3).

Stability: the plant applies the friction torque explicitly over one step, so
the regularization acts as a viscous damper of F_c / v_s that must satisfy
F_c / v_s * h / M_ii < 2 (h the plant step, M_ii the joint's inertia).
:func:`check_friction_stability` refuses settings that break it.
"""

import dataclasses as dc

import numpy as np
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import MatrixGain, Saturation
from pydrake.systems.sensors import RotaryEncoders

from drake_contact.errors import ScenarioError

#: Controller torque limits (N m) of Appendix E, joints 1-3.
THESIS_TORQUE_LIMITS = [16.0, 2.5, 0.6]

#: Encoder resolution (counts/rev) of chapter 3, joints 1-3.
THESIS_ENCODER_COUNTS = [614400, 409600, 2000]


@dc.dataclass
class JointFrictionConfig:
    """Coulomb friction at the three joints (the plant's truth)."""

    # Include joint friction in the simulated plant.
    enabled: bool = True
    # Coulomb level per joint (N m). Joints 1-2: the motors' maximum friction
    # torque (Appendix B: 4.41 and 0.98 N m). Joint 3: not given by the thesis;
    # 0.05 N m (2.5 % of its 2 N m peak) is our assumption.
    levels: list[float] = dc.field(default_factory=lambda: [4.41, 0.98, 0.05])
    # Regularization velocity (rad/s): linear inside |qdot| < this.
    regularization_velocity: float = 0.02

    def validate(self, prefix="joint_friction"):
        if len(self.levels) != 3 or any(not np.isfinite(x) or x < 0 for x in self.levels):
            raise ScenarioError(
                f"{prefix}.levels = {self.levels} is out of range: must be 3 values >= 0 N m")
        if not (self.regularization_velocity > 0):
            raise ScenarioError(
                f"{prefix}.regularization_velocity = {self.regularization_velocity} is out of "
                "range: must be > 0 rad/s")


@dc.dataclass
class EncoderConfig:
    """Quantization of the measured joint angles."""

    # Counts per revolution per joint; 0 disables quantization of that joint.
    counts_per_revolution: list[int] = dc.field(
        default_factory=lambda: list(THESIS_ENCODER_COUNTS))

    def validate(self, prefix="encoders"):
        c = self.counts_per_revolution
        if len(c) != 3 or any(x < 0 for x in c):
            raise ScenarioError(
                f"{prefix}.counts_per_revolution = {c} is out of range: must be 3 integers >= 0")


def check_friction_stability(config: JointFrictionConfig, mass_matrix_diagonal, time_step):
    """Raises ScenarioError when the regularized friction would be unstable
    at this plant step (explicit damping F_c/v_s with h F_c/(v_s M_ii) >= 1,
    half the theoretical limit of 2 for margin)."""
    if not config.enabled:
        return
    for i, (level, m_ii) in enumerate(zip(config.levels, mass_matrix_diagonal)):
        ratio = time_step * level / (config.regularization_velocity * m_ii)
        if ratio >= 1.0:
            v_min = time_step * level / m_ii
            raise ScenarioError(
                "joint_friction.regularization_velocity = "
                f"{config.regularization_velocity} is out of range at arm.time_step = "
                f"{time_step}: joint {i + 1} needs > {v_min:.3g} rad/s to stay stable")


def AddJointFriction(builder: DiagramBuilder, config: JointFrictionConfig, *, name="joint_friction"):
    """Adds the friction law; returns (input, output) ports.

    The input is the plant state [q; v] (6); the output the friction torque
    (3, N m) to add to the plant's applied generalized force.
    """
    levels = np.asarray(config.levels if config.enabled else [0.0] * 3, dtype=float)
    gain = np.zeros((3, 6))
    gain[:, 3:] = -np.diag(levels / config.regularization_velocity)
    slope = builder.AddNamedSystem(f"{name}_slope", MatrixGain(gain))
    clamp = builder.AddNamedSystem(name, Saturation(-levels, levels))
    builder.Connect(slope.get_output_port(), clamp.get_input_port())
    return slope.get_input_port(), clamp.get_output_port()


def AddTorqueSaturation(builder: DiagramBuilder, limits, *, name="torque_saturation"):
    """Adds |tau_i| <= limits_i (N m); returns the Saturation system."""
    limits = np.asarray(limits, dtype=float)
    return builder.AddNamedSystem(name, Saturation(-limits, limits))


def AddEncoders(builder: DiagramBuilder, config: EncoderConfig, *, name="encoders"):
    """Adds quantizing encoders reading q from the plant state [q; v] (6).

    A joint with 0 counts per revolution is passed through unquantized
    (RotaryEncoders requires a positive count, so we use a huge one)."""
    counts = [int(c) if c > 0 else 2**30 for c in config.counts_per_revolution]
    return builder.AddNamedSystem(name, RotaryEncoders(6, [0, 1, 2], counts))
