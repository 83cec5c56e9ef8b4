"""The controller's own model of the arm, which may differ from the plant.

The thesis's controllers compensate the arm's dynamics with a model:
M(q), h(q, qdot), J(q), Jdot qdot and the dry friction F_c. Real models are
wrong; here each link's mass and inertia can be scaled and the friction the
controller believes in set apart from the plant's. Everything is computed
with Drake's multibody functions on a MultibodyPlant of the URDF whose
parameters are changed in its own context; the thesis's closed forms
(Appendix C-D) are the test oracle (tests/thesis_closed_forms.py).
"""

import dataclasses as dc

import numpy as np
from pydrake.multibody.tree import JacobianWrtVariable, RotationalInertia, SpatialInertia

from drake_contact.plant.arm import TIP_FRAME, MakeArmModel
from drake_contact.errors import ScenarioError
from drake_contact.plant.tip_kinematics import CalcTipPoseAndJacobian

LINK_NAMES = ("link1", "link2", "link3")


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
        if len(self.friction_levels) != 3 or not all(x >= 0 for x in self.friction_levels):
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
    """M, h, J, Jdot qdot and the tip pose of the controller's arm model.

    Holds a plant and one context with the scaled parameters; ``evaluate``
    overwrites its state, so it carries nothing between calls.
    """

    def __init__(self, config: ControllerModelConfig):
        self.config = config
        self.plant = MakeArmModel()
        self.context = self.plant.CreateDefaultContext()
        for name, ms, js in zip(LINK_NAMES, config.mass_scale, config.inertia_scale):
            body = self.plant.GetBodyByName(name)
            nominal = body.default_spatial_inertia()
            mass = nominal.get_mass()
            p_com = nominal.get_com()
            I_central = _central_inertia(nominal)
            scaled = SpatialInertia.MakeFromCentralInertia(
                mass * ms, p_com, RotationalInertia(*(js * I_central.get_moments()), 0, 0, 0))
            body.SetSpatialInertiaInBodyFrame(self.context, scaled)
        self._tip = self.plant.GetFrameByName(TIP_FRAME)
        self._world = self.plant.world_frame()
        self.friction_levels = np.asarray(config.friction_levels, dtype=float)
        self.motor_torque_scale = np.asarray(config.motor_torque_scale, dtype=float)

    def evaluate(self, q, qdot):
        """(pose [x, y, phi], J (3x3), Jdot qdot (3), M (3x3), h (3))."""
        plant, context = self.plant, self.context
        plant.SetPositions(context, q)
        plant.SetVelocities(context, qdot)
        pose, J = CalcTipPoseAndJacobian(plant, context, self._tip)
        bias = plant.CalcBiasSpatialAcceleration(
            context, JacobianWrtVariable.kV, self._tip, np.zeros(3), self._world, self._world)
        jdot_qdot = np.array([bias.translational()[0], bias.translational()[1],
                              bias.rotational()[2]])
        return pose, J, jdot_qdot, plant.CalcMassMatrix(context), plant.CalcBiasTerm(context)

    def command(self, desired_torque):
        """The motor command that, by the model, gives ``desired_torque``."""
        return desired_torque / self.motor_torque_scale

    def friction_compensation(self, qdot):
        """F_c sgn(qdot), linear inside |qdot| < band (the thesis's code)."""
        return self.friction_levels * np.clip(qdot / self.config.friction_band, -1.0, 1.0)


def _central_inertia(spatial_inertia):
    """Rotational inertia about the COM (body axes) of a SpatialInertia."""
    mass = spatial_inertia.get_mass()
    about_origin = spatial_inertia.CalcRotationalInertia()
    return about_origin.ShiftToCenterOfMass(mass, spatial_inertia.get_com())
