"""The URDF arm against the thesis's link data (Appendix D) computed by hand."""

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder

from drake_contact.plant.arm import (
    LINK_COM_OFFSETS, LINK_IZZ, LINK_LENGTHS, LINK_MASSES, THESIS_Q0, TIP_FRAME,
    AddArmPlant, ArmConfig, MakeArmModel)
from drake_contact.plant.tip_kinematics import CalcTipPoseAndJacobian


def hand_mass_matrix(q):
    """M(q) = sum_i m_i Jv_i^T Jv_i + Izz_i Jw_i^T Jw_i for the planar chain."""
    a, m, izz = LINK_LENGTHS, LINK_MASSES, LINK_IZZ
    com = [a[i] + LINK_COM_OFFSETS[i] for i in range(3)]
    angles = np.cumsum(q)
    M = np.zeros((3, 3))
    for i in range(3):
        # Position of COM i: sum of full links before i, plus com_i along link i.
        Jv = np.zeros((2, 3))
        for j in range(i + 1):
            # d(p_ci)/dq_j = sum over links k >= j up to i of their length terms.
            for k in range(j, i + 1):
                length = com[i] if k == i else a[k]
                Jv[0, j] += -length * np.sin(angles[k])
                Jv[1, j] += length * np.cos(angles[k])
        Jw = np.array([[1.0 if j <= i else 0.0 for j in range(3)]])
        M += m[i] * Jv.T @ Jv + izz[i] * Jw.T @ Jw
    return M


def hand_forward_kinematics(q):
    a = LINK_LENGTHS
    c = np.cumsum(q)
    return np.array([sum(a[i] * np.cos(c[i]) for i in range(3)),
                     sum(a[i] * np.sin(c[i]) for i in range(3)), c[2]])


@pytest.fixture(scope="module")
def arm():
    plant = MakeArmModel()
    return plant, plant.CreateDefaultContext()


def test_mass_matrix_matches_hand_computation(arm):
    plant, context = arm
    rng = np.random.default_rng(0)
    for _ in range(20):
        q = rng.uniform(-np.pi, np.pi, 3)
        plant.SetPositions(context, q)
        M = plant.CalcMassMatrix(context)
        expected = hand_mass_matrix(q)
        assert np.max(np.abs(M - expected)) / np.max(np.abs(expected)) < 1e-9


def test_tip_frame_follows_forward_kinematics(arm):
    plant, context = arm
    tip = plant.GetFrameByName(TIP_FRAME)
    rng = np.random.default_rng(1)
    for _ in range(20):
        q = rng.uniform(-np.pi, np.pi, 3)
        plant.SetPositions(context, q)
        pose, J = CalcTipPoseAndJacobian(plant, context, tip)
        expected = hand_forward_kinematics(q)
        np.testing.assert_allclose(pose[:2], expected[:2], atol=1e-12)
        assert abs(np.angle(np.exp(1j * (pose[2] - expected[2])))) < 1e-12
        # Jacobian by central differences of the hand kinematics.
        eps = 1e-6
        J_fd = np.column_stack([
            (hand_forward_kinematics(q + eps * e) - hand_forward_kinematics(q - eps * e))
            / (2 * eps) for e in np.eye(3)])
        np.testing.assert_allclose(J, J_fd, atol=1e-8)


def test_q0_puts_the_tip_at_the_thesis_start(arm):
    plant, context = arm
    plant.SetPositions(context, THESIS_Q0)
    pose, _ = CalcTipPoseAndJacobian(plant, context, plant.GetFrameByName(TIP_FRAME))
    assert np.linalg.norm(pose[:2] - [0.454, 0.0]) < 0.5e-3
    assert abs(pose[2]) < 1e-3


def test_gravity_has_no_effect_and_effort_limits_are_the_motors(arm):
    plant, context = arm
    plant.SetPositions(context, [0.3, -1.0, 2.0])
    np.testing.assert_array_equal(plant.CalcGravityGeneralizedForces(context), 0.0)
    limits = [plant.get_joint_actuator(i).effort_limit() for i in plant.GetJointActuatorIndices()]
    assert limits == [88.2, 9.8, 2.0]


@pytest.mark.parametrize("time_step", [1e-3, 1e-4])
def test_plant_starts_at_q0_and_coasts_at_both_time_steps(time_step):
    builder = DiagramBuilder()
    plant, _ = AddArmPlant(builder, ArmConfig(time_step=time_step))
    assert plant.time_step() == time_step
    diagram = builder.Build()
    simulator = Simulator(diagram)
    context = simulator.get_mutable_context()
    plant_context = plant.GetMyMutableContextFromRoot(context)
    plant.get_actuation_input_port().FixValue(plant_context, [0.5, 0.0, 0.0])
    np.testing.assert_allclose(plant.GetPositions(plant_context), THESIS_Q0)
    simulator.AdvanceTo(0.05)
    # Joint 1's generalized momentum is the arm's angular momentum about the
    # base axis; with no gravity and no external force it grows by tau_1 t.
    v = plant.GetVelocities(plant_context)
    assert np.all(np.isfinite(v)) and abs(v[0]) > 0
    M = plant.CalcMassMatrix(plant_context)
    np.testing.assert_allclose((M @ v)[0], 0.5 * 0.05, rtol=2e-2)
