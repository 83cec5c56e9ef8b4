"""Coulomb friction, torque saturation and encoders (Drake primitives)."""

import numpy as np
import pytest
from pydrake.systems.framework import DiagramBuilder

from drake_contact.errors import ScenarioError
from drake_contact.plant.joint_physics import (
    AddEncoders, AddJointFriction, AddTorqueSaturation, EncoderConfig,
    JointFrictionConfig, check_friction_stability)


def friction_diagram(config):
    assert config.model == "regularized"
    builder = DiagramBuilder()
    friction = AddJointFriction(builder, config)
    builder.ExportInput(friction.GetInputPort("plant_state"), "state")
    builder.ExportOutput(friction.GetOutputPort("torque"), "torque")
    diagram = builder.Build()
    return diagram, diagram.CreateDefaultContext()


def test_friction_is_coulomb_outside_the_band_and_linear_inside():
    config = JointFrictionConfig(model="regularized", levels=[4.41, 0.98, 0.05],
                                 regularization_velocity=0.02)
    diagram, context = friction_diagram(config)
    for v in ([1.0, -0.5, 0.3], [0.01, -0.005, 0.0], [-0.02, 0.02, -1e-3]):
        diagram.get_input_port().FixValue(context, np.concatenate([[0.3, 1.0, -0.7], v]))
        expected = -np.clip(np.array(v) / 0.02, -1, 1) * np.array(config.levels)
        np.testing.assert_allclose(diagram.get_output_port().Eval(context), expected)


def test_friction_off_gives_zero_torque():
    diagram, context = friction_diagram(JointFrictionConfig(model="regularized", enabled=False))
    diagram.get_input_port().FixValue(context, [0, 0, 0, 1.0, -1.0, 2.0])
    np.testing.assert_array_equal(diagram.get_output_port().Eval(context), 0.0)


def test_unstable_regularization_is_refused():
    # At the motors' maximum friction, the thesis's compensation band
    # (0.002 rad/s) is too sharp for the plant's explicit friction at a 1 ms
    # step, and fine at 0.1 ms.
    config = JointFrictionConfig(model="regularized", levels=[4.41, 0.98, 0.05],
                                 regularization_velocity=0.002)
    with pytest.raises(ScenarioError, match=r"joint_friction.regularization_velocity = 0.002 "
                       r"is out of range at arm.time_step = 0.001: joint 1 needs > 0.00428"):
        check_friction_stability(config, [1.03, 0.117, 0.00287], 1e-3)
    check_friction_stability(config, [1.03, 0.117, 0.00287], 1e-4)


def test_torque_saturation_clamps_at_the_thesis_limits():
    builder = DiagramBuilder()
    saturation = AddTorqueSaturation(builder, [16.0, 2.5, 0.6])
    context = saturation.CreateDefaultContext()
    saturation.get_input_port().FixValue(context, [20.0, -3.0, 0.1])
    np.testing.assert_allclose(saturation.get_output_port().Eval(context), [16.0, -2.5, 0.1])


def test_encoders_count_from_q0_in_whole_counts():
    q0 = np.array([-0.5377671, 1.3205011, -0.7827340])
    builder = DiagramBuilder()
    encoders = AddEncoders(builder, EncoderConfig(), q0)
    builder.ExportInput(encoders.GetInputPort("plant_state"), "state")
    builder.ExportOutput(encoders.GetOutputPort("joint_positions_measured"), "q")
    diagram = builder.Build()
    context = diagram.CreateDefaultContext()
    steps = 2 * np.pi / np.array([614400, 409600, 2000])
    # At q0 the reading is exact (zeroed at power-up).
    diagram.get_input_port().FixValue(context, np.concatenate([q0, [9, 9, 9]]))
    np.testing.assert_allclose(diagram.get_output_port().Eval(context), q0, atol=1e-12)
    q = q0 + np.array([0.1234567, -0.0654321, 0.0071])
    diagram.get_input_port().FixValue(context, np.concatenate([q, [9, 9, 9]]))
    measured = diagram.get_output_port().Eval(context)
    # Whole counts from q0, never more than one count off.
    assert np.all(np.abs(measured - q) < steps)
    counts = (measured - q0) / steps
    np.testing.assert_allclose(counts, np.round(counts), atol=1e-6)
    assert abs(measured[2] - q[2]) > 1e-4  # joint 3 is visibly coarse


def test_encoders_midpoint_reads_half_a_count_up():
    """encoders.midpoint: the count n reads (n + 1/2) counts from q0, so
    the error is within half a count either way; unquantized joints (0
    counts) pass through unchanged. Checked against a hand count."""
    q0 = np.array([0.3, -0.2, 0.1])
    counts = [2000, 0, 1000]
    config = EncoderConfig(counts_per_revolution=counts, midpoint=True)
    builder = DiagramBuilder()
    encoders = AddEncoders(builder, config, q0)
    builder.ExportInput(encoders.GetInputPort("plant_state"), "state")
    builder.ExportOutput(encoders.GetOutputPort("joint_positions_measured"), "q")
    diagram = builder.Build()
    context = diagram.CreateDefaultContext()
    step1, step3 = 2 * np.pi / 2000, 2 * np.pi / 1000
    # Joint 1 at 2.25 counts above q0, joint 3 at 0.9 counts below it.
    q = q0 + [2.25 * step1, 0.0123, -0.9 * step3]
    diagram.get_input_port().FixValue(context, np.concatenate([q, [0, 0, 0]]))
    measured = diagram.get_output_port().Eval(context)
    expected = q0 + [2.5 * step1, 0.0123, -0.5 * step3]
    # (An unquantized joint is counted at 2**30 per revolution: 6e-9 rad.)
    np.testing.assert_allclose(measured, expected, rtol=0, atol=1e-8)
    # Over many angles: error within half a count, mean near zero (without
    # the option it is up to one count low, half a count on average).
    rng = np.random.default_rng(0)
    errors = []
    for offset in rng.uniform(-0.05, 0.05, 200):
        diagram.get_input_port().FixValue(context, np.concatenate([q0 + offset, [0, 0, 0]]))
        errors.append(diagram.get_output_port().Eval(context)[0] - (q0[0] + offset))
    errors = np.array(errors) / step1
    assert np.all(np.abs(errors) <= 0.5 + 1e-9)
    assert abs(errors.mean()) < 0.1


def lugre_diagram(levels=(4.41, 0.98, 0.05)):
    from drake_contact.plant.joint_physics import LuGreFriction
    config = JointFrictionConfig(levels=list(levels))
    friction = LuGreFriction(config, [1.03, 0.117, 0.00287], 1e-3)
    return friction, friction.CreateDefaultContext()


def step_joint(friction, context, inertia, load, steps, joint=1):
    """One joint with inertia, a constant load torque and the LuGre
    friction, stepped like the plant (symplectic Euler, 1 ms)."""
    q = qd = 0.0
    for n in range(steps):
        state = np.zeros(6)
        state[joint], state[3 + joint] = q, qd
        friction.GetInputPort("plant_state").FixValue(context, state)
        tau = friction.GetOutputPort("torque").Eval(context)[joint]
        context.SetDiscreteState(friction.EvalUniquePeriodicDiscreteUpdate(context)
                                 .get_vector().value().copy())
        qd += 1e-3 * (load + tau) / inertia
        q += 1e-3 * qd
    return q, qd, tau


def test_lugre_holds_a_load_below_the_coulomb_level_without_creeping():
    friction, context = lugre_diagram()
    q1, _, _ = step_joint(friction, context, 0.117, 0.8, 1000)
    friction, context = lugre_diagram()
    q3, qd, tau = step_joint(friction, context, 0.117, 0.8, 3000)
    assert tau == pytest.approx(-0.8, abs=1e-6)
    assert abs(qd) < 1e-9
    # Stuck: a fraction of a milliradian of pre-sliding, then no creep at all
    # (the regularized model would creep at 0.02 * 0.8 / 0.98 = 16 mrad/s).
    assert abs(q3) < 1e-3
    assert abs(q3 - q1) < 1e-9


def test_lugre_slides_at_the_coulomb_level_above_it():
    friction, context = lugre_diagram()
    q, qd, tau = step_joint(friction, context, 0.117, 1.5, 2000)
    assert tau == pytest.approx(-0.98, rel=1e-3)
    # Net 0.52 N m on 0.117 kg m^2 for 2 s.
    assert qd == pytest.approx(0.52 / 0.117 * 2.0, rel=0.02)


def test_lugre_without_friction_gives_zero():
    friction, context = lugre_diagram(levels=(0.0, 0.0, 0.0))
    assert step_joint(friction, context, 0.117, 1.0, 100)[2] == 0.0


def reference_lugre_step(levels, sigma0, sigma1, z, qdot, h):
    """LuGre as the former Python LeafSystem computed it (numpy): returns
    (torque, next z)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        decay = np.where(levels > 0, sigma0 * np.abs(qdot) / levels, 0.0)
    rates = np.where(levels > 0, qdot - decay * z, 0.0)
    torque = -(sigma0 * z + sigma1 * rates)
    new = z.copy()
    for i in range(3):
        if levels[i] <= 0:
            new[i] = 0.0
        elif qdot[i] != 0.0:
            z_slide = levels[i] * np.sign(qdot[i]) / sigma0[i]
            rate = sigma0[i] * abs(qdot[i]) / levels[i]
            new[i] = z_slide + (z[i] - z_slide) * np.exp(-rate * h)
    return torque, new


@pytest.mark.parametrize("levels,inertia", [
    ((1.0, 0.2, 0.004), (1.03, 0.117, 0.00287)),
    ((0.0, 0.98, 0.0), (1.03, 0.117, 0.00287)),
    ((1.0, 1.0, 1.0), (1.0, 1.0, 1.0)),
])
def test_lugre_in_cpp_matches_the_former_numpy_law(levels, inertia):
    """The torque and the bristle update (C++ expressions) do the former
    numpy law's IEEE operations; only the exponential differs (std::exp vs
    numpy's kernel, in the last bit), so the states agree to 1e-14 of their
    scale."""
    from drake_contact.diagram import leaf_systems
    from drake_contact.plant.joint_physics import LuGreFriction
    config = JointFrictionConfig(levels=list(levels))
    friction = LuGreFriction(config, list(inertia), 1e-3)
    python = [s.get_name() for s in leaf_systems(friction)
              if not type(s).__module__.startswith("pydrake")]
    assert python == []
    context = friction.CreateDefaultContext()
    levels = np.asarray(levels, dtype=float)
    sigma0 = np.asarray(inertia) * (2 * np.pi * config.bristle_frequency_hz) ** 2
    sigma1 = 2 * config.bristle_damping_ratio * np.sqrt(sigma0 * np.asarray(inertia))
    rng = np.random.default_rng(3)
    z = np.zeros(3)
    for n in range(1500):
        qdot = rng.normal(0, 10.0 ** rng.uniform(-8, 0), 3) * (rng.random(3) < 0.8)
        friction.GetInputPort("plant_state").FixValue(
            context, np.concatenate([rng.normal(size=3), qdot]))
        # The state is z one step ago; the update advances it with this
        # velocity, and the torque is the law at the advanced z.
        z = context.get_discrete_state_vector().value().copy()
        advanced = friction.EvalUniquePeriodicDiscreteUpdate(context).get_vector().value().copy()
        _, z_next = reference_lugre_step(levels, sigma0, sigma1, z, qdot, 1e-3)
        # One last bit of exp's ~1 result is 1e-16 of the sliding deflection
        # F_c / sigma0, the scale of z.
        np.testing.assert_allclose(advanced, z_next, rtol=0,
                                   atol=1e-14 * np.max(levels / sigma0), err_msg=f"step {n}")
        torque, _ = reference_lugre_step(levels, sigma0, sigma1, advanced, qdot, 1e-3)
        np.testing.assert_array_equal(
            friction.GetOutputPort("torque").Eval(context), torque, err_msg=f"step {n}")
        context.SetDiscreteState(advanced)
