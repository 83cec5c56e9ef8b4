"""A simple pushing law for the foundation scenario ``push_constant``.

Not one of the thesis's controllers (those come with the hybrid controller):
it pushes the tip along +x with a constant force and holds y and phi with a
task-space PD, mapped to joints by the transpose Jacobian,

    tau = J(q)^T [ f_d - D_x xdot,
                   K_y (y_d - y) - D_y ydot,
                   K_phi (phi_d - phi) - D_phi phidot ],

sampled every 1 ms (torque computed from the sample at t_n, acting from t_n,
held between samples). It reads the true tip state
and J from the plant model: it is a test harness for the plant and the wall,
not a controller under study.
"""

import dataclasses as dc

import numpy as np
import pydrake.symbolic as sym
from pydrake.systems.framework import Diagram, DiagramBuilder
from pydrake.systems.primitives import SymbolicVectorSystem

from drake_contact.errors import ScenarioError
from drake_contact.plant.arm import TIME_TOLERANCE_S
from drake_contact.plant.planar_arm import tip_jacobian, tip_pose
from drake_contact.plant.tip_kinematics import check_closed_forms


@dc.dataclass
class PushConfig:
    """Gains of the constant-force pushing law."""

    # Desired normal force along +x (N), applied from start_time (s) on;
    # before it the arm holds still (only the damping and the y, phi PD act).
    force: float = 20.0
    start_time: float = 0.0
    # Damping along x (N s/m), limits the impact speed.
    damping_x: float = 60.0
    # Stiffness and damping holding y = y_d (N/m, N s/m). The tip's effective
    # mass along y is only about 0.13 kg near q0: with the 1 ms sample and its
    # one-sample delay, damping much above 20 chatters.
    stiffness_y: float = 2000.0
    damping_y: float = 20.0
    # Stiffness and damping holding phi = phi_d (N m/rad, N m s/rad); the
    # effective inertia about phi is about 2.8e-3 kg m^2.
    stiffness_phi: float = 20.0
    damping_phi: float = 0.3
    # Held position y_d (m) and angle phi_d (rad).
    y_desired: float = 0.0
    phi_desired: float = 0.0

    def validate(self, prefix="controller.push"):
        for field in dc.fields(self):
            value = getattr(self, field.name)
            if not np.isfinite(value):
                raise ScenarioError(f"{prefix}.{field.name} = {value} is out of range: must be finite")
            if field.name.startswith(("damping", "stiffness", "start")) and value < 0:
                raise ScenarioError(f"{prefix}.{field.name} = {value} is out of range: must be >= 0")


class ConstantForcePushController(Diagram):
    """Input: plant_state (6, [q; v]). Output: joint_torque_commanded (3, N m),
    the law of the state read at each 1 ms sample (a direct function of
    the input; the station holds it between samples when the plant steps
    finer).

    A Drake ``SymbolicVectorSystem`` (``law``): the closed-form kinematics of
    the arm (plant/planar_arm.py) evaluated in C++, no Python per step;
    ``plant`` is the arm's plant, against which they are checked here."""

    def __init__(self, plant, config: PushConfig):
        super().__init__()
        config.validate()
        check_closed_forms(plant)
        c = config
        t = sym.Variable("t")
        state = sym.MakeVectorVariable(6, "x")
        q, v = state[:3], state[3:]
        _, y, phi = tip_pose(q, sin=sym.sin, cos=sym.cos)
        J = tip_jacobian(q, sin=sym.sin, cos=sym.cos)
        xdot, ydot, phidot = (row[0] * v[0] + row[1] * v[1] + row[2] * v[2] for row in J)
        force = sym.if_then_else(t >= c.start_time - TIME_TOLERANCE_S, c.force, 0.0)
        wrench = [force - c.damping_x * xdot,
                  c.stiffness_y * (c.y_desired - y) - c.damping_y * ydot,
                  c.stiffness_phi * (c.phi_desired - phi) - c.damping_phi * phidot]
        torque = [J[0][j] * wrench[0] + J[1][j] * wrench[1] + J[2][j] * wrench[2]
                  for j in range(3)]
        builder = DiagramBuilder()
        law = builder.AddNamedSystem("law", SymbolicVectorSystem(
            time=t, input=state, output=torque))
        builder.ExportInput(law.get_input_port(), "plant_state")
        builder.ExportOutput(law.get_output_port(), "joint_torque_commanded")
        builder.BuildInto(self)
