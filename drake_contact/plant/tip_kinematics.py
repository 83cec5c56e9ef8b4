"""True tip kinematics of the arm, and the wall's force mapped to joints.

This is the simulator's side (ground truth), not a controller's estimate:
controllers read the encoder-based estimator instead. It runs in C++: the
closed forms of :mod:`drake_contact.plant.planar_arm` as Drake symbolic
expressions (``SymbolicVectorSystem``), checked against the plant's own
kinematics when the system is built.
"""

import numpy as np
from pydrake import symbolic
from pydrake.multibody.tree import JacobianWrtVariable
from pydrake.systems.framework import Diagram, DiagramBuilder
from pydrake.systems.primitives import Multiplexer

from drake_contact.arm_axis import StackedSymbolicSystem
from drake_contact.plant.arm import TIP_FRAME
from drake_contact.plant.planar_arm import ArmParameters, tip_jacobian, tip_pose


def CalcTipPoseAndJacobian(plant, plant_context, tip_frame):
    """Planar tip pose [x, y, phi] in world and J = d[x, y, phi]/dv (3 x 3),
    by Drake's multibody functions (the reference the closed forms are
    checked against).

    ``plant_context`` must already hold the arm's positions.
    """
    world = plant.world_frame()
    J = plant.CalcJacobianSpatialVelocity(
        plant_context, JacobianWrtVariable.kV, tip_frame, np.zeros(3), world, world)
    X_WT = tip_frame.CalcPoseInWorld(plant_context)
    R = X_WT.rotation().matrix()
    p = X_WT.translation()
    # Rows vx, vy, wz of the spatial Jacobian [w; v].
    return np.array([p[0], p[1], np.arctan2(R[1, 0], R[0, 0])]), J[[3, 4, 2], :]


#: Configurations (rad) at which the closed forms are checked against a
#: plant when a kinematics system is built.
_CHECK_POSITIONS = ([-0.5377671, 1.3205011, -0.7827340], [0.3, -1.1, 2.0], [2.5, 0.7, -2.9])


def check_closed_forms(plant, arm: ArmParameters = ArmParameters(), tol=1e-12):
    """Raises ValueError unless the closed-form tip pose and Jacobian of
    ``arm`` equal ``plant``'s (its URDF) within ``tol``."""
    context = plant.CreateDefaultContext()
    tip = plant.GetFrameByName(TIP_FRAME)
    for q in _CHECK_POSITIONS:
        plant.SetPositions(context, q)
        pose, J = CalcTipPoseAndJacobian(plant, context, tip)
        closed = np.array(tip_pose(q, arm))
        closed[2] = np.arctan2(np.sin(closed[2]), np.cos(closed[2]))
        error = max(np.max(np.abs(closed - pose)), np.max(np.abs(np.array(tip_jacobian(q, arm)) - J)))
        if not error <= tol:
            raise ValueError(f"the arm's closed-form kinematics differ from the plant's by {error:.3g} "
                             f"at q = {q}: the URDF no longer matches planar_arm.ArmParameters")


def _symbolic(name, size):
    return symbolic.MakeVectorVariable(size, name)


def _trig():
    return {"sin": symbolic.sin, "cos": symbolic.cos}


class TipKinematics(Diagram):
    """Planar pose/velocity of the ``tip`` frame, and J^T F, in C++.

    Input ports:
      plant_state (6): [q; v] of the arm (rad, rad/s).
      force_on_tip (3): [f_x, f_y, tau_z] applied at the tip, world (N, N m).
    Output ports:
      tip_state (6): [x, y, phi, xdot, ydot, phidot], world (m, rad, /s);
        phi = q1 + q2 + q3 (not wrapped).
      generalized_force (3): J(q)^T [f_x, f_y, tau_z] (N m), for the plant's
        applied_generalized_force input.

    ``plant``: the arm's plant, against whose kinematics the closed forms
    are checked once, here. With ``count`` N, the tip kinematics of N arms
    on the arm axis: every port N times its size, arm i's values at
    ``[k i, k (i + 1))``, each evaluated as alone.
    """

    def __init__(self, plant, count=1):
        super().__init__()
        check_closed_forms(plant)
        states, torques = [], []
        for _ in range(count):
            q, v, F = _symbolic("q", 3), _symbolic("v", 3), _symbolic("F", 3)
            pose = tip_pose(q, **_trig())
            J = tip_jacobian(q, **_trig())
            velocity = [J[i][0] * v[0] + J[i][1] * v[1] + J[i][2] * v[2] for i in range(3)]
            force = [J[0][j] * F[0] + J[1][j] * F[1] + J[2][j] * F[2] for j in range(3)]
            states.append({"input": np.concatenate([q, v]), "output": pose + velocity})
            torques.append({"input": np.concatenate([q, v, F]), "output": force})
        builder = DiagramBuilder()
        state = builder.AddNamedSystem("tip_state", StackedSymbolicSystem(states))
        mux = builder.AddNamedSystem("state_and_force", Multiplexer([6 * count, 3 * count]))
        torque = builder.AddNamedSystem("jacobian_transpose", StackedSymbolicSystem(
            torques, input_sizes=[6, 3]))
        builder.ExportInput(state.get_input_port(), "plant_state")
        builder.ConnectInput("plant_state", mux.get_input_port(0))
        builder.ExportInput(mux.get_input_port(1), "force_on_tip")
        builder.Connect(mux.get_output_port(), torque.get_input_port())
        builder.ExportOutput(state.get_output_port(), "tip_state")
        builder.ExportOutput(torque.get_output_port(), "generalized_force")
        builder.BuildInto(self)
