"""The controller's model (Drake multibody functions) against the thesis's
closed forms (Appendix C-D), with and without model errors."""

import numpy as np
import pytest

import thesis_closed_forms as thesis
from drake_contact.plant.arm import LINK_IZZ, LINK_MASSES
from drake_contact.control.controller_model import ArmModel, ControllerModelConfig


@pytest.mark.parametrize("mass_scale,inertia_scale", [
    ([1.0, 1.0, 1.0], [1.0, 1.0, 1.0]),
    ([1.15, 0.9, 1.3], [0.8, 1.2, 1.5]),
])
def test_model_equals_the_thesis_closed_forms_at_random_states(mass_scale, inertia_scale):
    model = ArmModel(ControllerModelConfig(mass_scale=mass_scale, inertia_scale=inertia_scale))
    masses = np.array(LINK_MASSES) * mass_scale
    izz = np.array(LINK_IZZ) * inertia_scale
    rng = np.random.default_rng(4)
    for _ in range(25):
        q = rng.uniform(-np.pi, np.pi, 3)
        qdot = rng.uniform(-3, 3, 3)
        pose, J, jdot_qdot, M, h = model.evaluate(q, qdot)
        np.testing.assert_allclose(pose[:2], thesis.forward_kinematics(q)[:2], atol=1e-12)
        np.testing.assert_allclose(J, thesis.jacobian(q), atol=1e-12)
        np.testing.assert_allclose(jdot_qdot, thesis.jdot_qdot(q, qdot), atol=1e-10)
        np.testing.assert_allclose(M, thesis.mass_matrix(q, masses=masses, izz=izz),
                                   rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose(h, thesis.coriolis_centrifugal(q, qdot, masses=masses, izz=izz),
                                   atol=1e-10)


def test_model_errors_change_the_mass_matrix():
    q = np.array([-0.5, 1.3, -0.8])
    M_true = ArmModel(ControllerModelConfig()).evaluate(q, np.zeros(3))[3]
    M_wrong = ArmModel(ControllerModelConfig(mass_scale=[1.2, 1.2, 1.2])).evaluate(q, np.zeros(3))[3]
    assert np.all(M_wrong[np.diag_indices(3)] > M_true[np.diag_indices(3)])


def test_friction_compensation_is_linear_inside_the_band():
    model = ArmModel(ControllerModelConfig(friction_levels=[4.41, 0.98, 0.0]))
    np.testing.assert_allclose(model.friction_compensation(np.array([0.001, -0.01, 1.0])),
                               [2.205, -0.98, 0.0])
