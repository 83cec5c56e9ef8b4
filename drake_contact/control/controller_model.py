"""The controller's own model of the arm, which may differ from the plant.

The thesis's controllers compensate the arm's dynamics with a model:
M(q), h(q, qdot), J(q), Jdot qdot and the dry friction F_c. Real models are
wrong; here each link's mass and inertia can be scaled and the friction the
controller believes in set apart from the plant's. Everything is computed
by the closed forms of Appendix C-D (plant/planar_arm.py), which the tests
check against Drake's MultibodyPlant of the URDF, with the scaled
parameters, and against the thesis's own forms (tests/thesis_closed_forms.py).
"""

import dataclasses as dc

import numpy as np

from drake_contact.errors import ScenarioError
from drake_contact.plant.planar_arm import (
    ArmParameters, jdot_qdot, mass_matrix_and_bias, tip_jacobian, tip_pose)



@dc.dataclass
class ControllerModelConfig:
    """What the controller believes about the arm."""

    # Link mass multipliers (1 = the URDF's), links 1-3.
    mass_scale: list[float] = dc.field(default_factory=lambda: [1.0, 1.0, 1.0])
    # Multipliers of each link's rotational inertia about its COM.
    inertia_scale: list[float] = dc.field(default_factory=lambda: [1.0, 1.0, 1.0])
    # Dry friction the controller compensates (N m), joints 1-3. Default: the
    # plant's (a calibrated compensation; see JointFrictionConfig.levels).
    friction_levels: list[float] = dc.field(default_factory=lambda: [1.0, 0.2, 0.004])
    # Velocity band (rad/s) inside which the compensation is linear (thesis: 0.002).
    friction_band: float = 0.002
    # Torque each motor is believed to deliver per N m commanded; the
    # controller commands its desired torque divided by this. 1 = the DAC
    # scaling of the thesis's code (command / motor maximum).
    motor_torque_scale: list[float] = dc.field(default_factory=lambda: [1.0, 1.0, 1.0])

    def validate(self, prefix):
        for field in ("mass_scale", "inertia_scale"):
            value = getattr(self, field)
            if len(value) != 3 or not all(np.isfinite(x) and x > 0 for x in value):
                raise ScenarioError(f"{prefix}.{field} = {value} is out of range: "
                                    "must be 3 values > 0")
        if len(self.friction_levels) != 3 or not all(
                np.isfinite(x) and x >= 0 for x in self.friction_levels):
            raise ScenarioError(f"{prefix}.friction_levels = {self.friction_levels} is out of "
                                "range: must be 3 values >= 0 N m")
        scale = self.motor_torque_scale
        if len(scale) != 3 or not all(np.isfinite(x) and 0.5 <= x <= 2.0 for x in scale):
            raise ScenarioError(f"{prefix}.motor_torque_scale = {scale} is out of range: "
                                "must be 3 values in [0.5, 2]")
        if not (self.friction_band > 0):
            raise ScenarioError(f"{prefix}.friction_band = {self.friction_band} is out of range: "
                                "must be > 0 rad/s")


class ArmModel:
    """M, h, J, Jdot qdot and the tip pose of the controller's arm model,
    by the closed forms of :mod:`drake_contact.plant.planar_arm` with the
    model's scaled masses and inertias (one evaluation: a few dozen scalar
    operations, no Drake call).
    """

    def __init__(self, config: ControllerModelConfig):
        self.config = config
        self.arm = ArmParameters().scaled(config.mass_scale, config.inertia_scale)
        self.friction_levels = np.asarray(config.friction_levels, dtype=float)
        self.motor_torque_scale = np.asarray(config.motor_torque_scale, dtype=float)
        self._friction = [float(x) for x in config.friction_levels]
        self._band = float(config.friction_band)
        self._motor = [float(x) for x in config.motor_torque_scale]

    def evaluate_rows(self, q, qdot):
        """(J, Jdot qdot, M, h) as lists of Python floats (rows for the
        matrices), for the controllers' per-sample arithmetic."""
        arm = self.arm
        M, h = mass_matrix_and_bias(q, qdot, arm)
        return tip_jacobian(q, arm), jdot_qdot(q, qdot, arm), M, h

    def evaluate(self, q, qdot):
        """(pose [x, y, phi], J (3x3), Jdot qdot (3), M (3x3), h (3)) as arrays."""
        q = [float(x) for x in q]
        qdot = [float(x) for x in qdot]
        J, jd, M, h = self.evaluate_rows(q, qdot)
        return (np.array(tip_pose(q, self.arm)), np.array(J), np.array(jd), np.array(M),
                np.array(h))

    def command(self, desired_torque):
        """The motor command that, by the model, gives ``desired_torque``."""
        return [t / s for t, s in zip(desired_torque, self._motor)]

    def friction_compensation(self, qdot):
        """F_c sgn(qdot), linear inside |qdot| < band (the thesis's code)."""
        return [f * min(max(w / self._band, -1.0), 1.0) for f, w in zip(self._friction, qdot)]
