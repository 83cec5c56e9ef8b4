"""True tip kinematics of the arm, and the wall's force mapped to joints.

This is the simulator's side (ground truth), not a controller's estimate:
controllers read the encoder-based estimator instead.
"""

import numpy as np
from pydrake.multibody.tree import JacobianWrtVariable
from pydrake.common.value import Value
from pydrake.systems.framework import BasicVector, LeafSystem, ValueProducer

from drake_contact.plant.arm import TIP_FRAME
from drake_contact.errors import require_finite


def CalcTipPoseAndJacobian(plant, plant_context, tip_frame):
    """Planar tip pose [x, y, phi] in world and J = d[x, y, phi]/dv (3 x 3).

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


class TipKinematics(LeafSystem):
    """Planar pose/velocity of the ``tip`` frame, and J^T F.

    Input ports:
      plant_state (6): [q; v] of the arm (rad, rad/s).
      force_on_tip (3): [f_x, f_y, tau_z] applied at the tip, world (N, N m).
    Output ports:
      tip_state (6): [x, y, phi, xdot, ydot, phidot], world (m, rad, /s).
      generalized_force (3): J(q)^T [f_x, f_y, tau_z] (N m), for the plant's
        applied_generalized_force input.
    """

    def __init__(self, plant):
        super().__init__()
        self._plant = plant
        # Scratch context: overwritten from the input on every evaluation, so
        # it carries no state between calls.
        self._scratch = plant.CreateDefaultContext()
        self._tip = plant.GetFrameByName(TIP_FRAME)
        self._memo_state = None
        self._memo_value = None
        self._state = self.DeclareVectorInputPort("plant_state", 6)
        self._force = self.DeclareVectorInputPort("force_on_tip", 3)
        # [x, y, phi, J (row-major 3 x 3)], computed once per plant state.
        self._kinematics = self.DeclareCacheEntry(
            description="tip pose and Jacobian",
            value_producer=ValueProducer(
                allocate=Value[BasicVector](BasicVector(12)).Clone,
                calc=self._calc_kinematics),
            prerequisites_of_calc={self._state.ticket()})
        self.DeclareVectorOutputPort(
            "tip_state", 6, self._calc_tip_state,
            prerequisites_of_calc={self._state.ticket()})
        self.DeclareVectorOutputPort(
            "generalized_force", 3, self._calc_generalized_force,
            prerequisites_of_calc={self._state.ticket(), self._force.ticket()})

    def _calc_kinematics(self, context, abstract):
        state = self._state.Eval(context)
        # Drake invalidates this entry more often than the plant's state
        # changes (three times per 1 ms step here); a value memo skips the
        # repeats. It holds a pure function of the state, so contexts and
        # their copies are unaffected.
        if self._memo_state is None or not np.array_equal(state, self._memo_state):
            require_finite(state, context, "tip_kinematics")
            self._plant.SetPositionsAndVelocities(self._scratch, state)
            pose, J = CalcTipPoseAndJacobian(self._plant, self._scratch, self._tip)
            self._memo_state = state.copy()
            self._memo_value = np.concatenate([pose, J.ravel()])
        abstract.get_mutable_value().set_value(self._memo_value)

    def _pose_and_jacobian(self, context):
        kinematics = self._kinematics.Eval(context).value()
        return self._state.Eval(context), kinematics[:3], kinematics[3:].reshape(3, 3)

    def _calc_tip_state(self, context, output):
        state, pose, J = self._pose_and_jacobian(context)
        output.SetFromVector(np.concatenate([pose, J @ state[3:]]))

    def _calc_generalized_force(self, context, output):
        _, _, J = self._pose_and_jacobian(context)
        output.SetFromVector(J.T @ self._force.Eval(context))
