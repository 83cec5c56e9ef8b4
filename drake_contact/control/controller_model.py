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
from collections.abc import Sequence

import numpy as np

from drake_contact.arm_axis import arm_axis_ops, per_environment
from drake_contact.blocks import environment_configs
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

    One config: the per-sample methods take and return Python floats. A
    list of N configs (an ensemble's environments): they take arrays (N,)
    per joint or coordinate and return lists of arrays (N,) (rows for the
    matrices), environment i's entries bit for bit its own model's (each
    link's mass, inertia, friction level and motor scale an array over the
    environments; the same operations, elementwise).
    """

    def __init__(self, config: ControllerModelConfig | Sequence[ControllerModelConfig]):
        configs = environment_configs(config, ControllerModelConfig, "controller.hybrid.model")
        self.config = configs[0]
        self.count = len(configs)
        self._ops = arm_axis_ops(self.count)
        arms = [ArmParameters().scaled(c.mass_scale, c.inertia_scale) for c in configs]
        self.arm = arms[0] if self.count == 1 else dc.replace(
            arms[0], masses=tuple(per_environment(m) for m in zip(*(a.masses for a in arms))),
            izz=tuple(per_environment(i) for i in zip(*(a.izz for a in arms))))
        self.friction_levels = np.asarray(self.config.friction_levels, dtype=float)
        self.motor_torque_scale = np.asarray(self.config.motor_torque_scale, dtype=float)
        # F_c and the motor scales per joint: a float or an array (N,) each.
        self.coulomb_levels = [per_environment(f)
                               for f in zip(*(c.friction_levels for c in configs))]
        self._band = per_environment(c.friction_band for c in configs)
        self._motor = [per_environment(s) for s in zip(*(c.motor_torque_scale for c in configs))]

    def evaluate_rows(self, q, qdot):
        """(J, Jdot qdot, M, h) as lists (rows for the matrices) of Python
        floats (one config) or arrays (N,), for the controllers' per-sample
        arithmetic."""
        arm, ops = self.arm, self._ops
        M, h = mass_matrix_and_bias(q, qdot, arm, ops.sin, ops.cos)
        return (tip_jacobian(q, arm, ops.sin, ops.cos), jdot_qdot(q, qdot, arm, ops.sin, ops.cos),
                M, h)

    def evaluate(self, q, qdot):
        """(pose [x, y, phi], J (3x3), Jdot qdot (3), M (3x3), h (3)) as
        arrays, for one config."""
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
        clip, band = self._ops.clip, self._band
        return [f * clip(w / band, -1.0, 1.0) for f, w in zip(self.coulomb_levels, qdot)]
