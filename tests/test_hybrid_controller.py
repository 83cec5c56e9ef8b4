"""The hybrid controller, one sample against the thesis's formulas, its
switching, and the force reference."""

import dataclasses as dc

import numpy as np
import pytest

import thesis_closed_forms as thesis
from drake_contact.plant.arm import FIRST_SAMPLE_S, THESIS_Q0, ApplySampledUpdates
from drake_contact.control.force_reference import ForceReferenceConfig
from drake_contact.errors import ScenarioError
from drake_contact.control.hybrid_controller import (
    HybridControlLaw, HybridController, HybridControllerConfig)

S = np.diag([1.0, 0.0, 0.0])


def sample(config, *, force, q=None, qdot=None, f_d=20.0, k_e=7000.0, steps=1,
           controller=None, context=None):
    controller = controller or HybridController(config)
    if context is None:
        context = controller.CreateDefaultContext()
        context.SetTime(FIRST_SAMPLE_S)  # the first sample instant
    q = np.array(THESIS_Q0) + np.array([0.01, -0.02, 0.005]) if q is None else q
    qdot = np.array([0.02, -0.05, 0.1]) if qdot is None else qdot
    x = thesis.forward_kinematics(q)
    xd = thesis.jacobian(q) @ qdot
    inputs = {"tip_pose": x, "tip_velocity": xd, "joint_positions": q,
              "joint_velocities": qdot, "force": [force], "force_desired": [f_d],
              "stiffness_estimate": [k_e]}
    for name, value in inputs.items():
        controller.GetInputPort(name).FixValue(context, value)
    # Each sample: the outputs are the law at this sample (from the inputs
    # and the state the previous samples left); then the update stores it.
    for _ in range(steps):
        tau = controller.GetOutputPort("joint_torque_commanded").Eval(context).copy()
        mode = controller.GetOutputPort("mode").Eval(context)[0]
        ApplySampledUpdates(controller, context)
    return tau, mode, q, qdot, x, xd


def expected_terms(q, qdot):
    J = thesis.jacobian(q)
    return J, thesis.jdot_qdot(q, qdot), thesis.mass_matrix(q), thesis.coriolis_centrifugal(q, qdot)


def friction(config, qdot):
    if not config.friction_compensation:
        return np.zeros(3)
    return np.array(config.model.friction_levels) * np.clip(qdot / config.model.friction_band, -1, 1)


def test_approach_sample_is_resolved_acceleration_control():
    config = HybridControllerConfig()
    tau, mode, q, qdot, x, xd = sample(config, force=1.0)
    J, jdq, M, h = expected_terms(q, qdot)
    x_d = np.array([config.approach.start_x, 0.0, 0.0])
    u_x = 400.0 * (x_d - x) - 80.0 * xd
    expected = M @ np.linalg.solve(J, u_x - jdq) + h + friction(config, qdot)
    assert mode == 0
    np.testing.assert_allclose(tau, expected, rtol=1e-9, atol=1e-9)


def test_contact_sample_is_the_hybrid_pi_law():
    config = HybridControllerConfig(force_gain=1.0, force_integral_gain=0.003)
    tau, mode, q, qdot, x, xd = sample(config, force=12.0, steps=3)
    J, jdq, M, h = expected_terms(q, qdot)
    u_x = 400.0 * (np.array([config.approach.start_x, 0, 0]) - x) - 80.0 * xd
    # Switched on the first sample; the error summed over three samples.
    u_f = 1.0 * (20.0 - 12.0) + 0.003 * 3 * (20.0 - 12.0)
    expected = (M @ np.linalg.solve(J, (np.eye(3) - S) @ u_x - jdq) + h + friction(config, qdot)
                + J.T @ S @ np.array([20.0, 0, 0]) + J.T @ S @ np.array([u_f, 0, 0]))
    assert mode == 1
    np.testing.assert_allclose(tau, expected, rtol=1e-9, atol=1e-9)


def test_contact_damping_adds_minus_d_xdot_to_the_force_command():
    config = HybridControllerConfig(force_gain=1.0, force_integral_gain=0.003,
                                    contact_damping_x=150.0)
    tau, mode, q, qdot, x, xd = sample(config, force=12.0)
    J, jdq, M, h = expected_terms(q, qdot)
    u_x = 400.0 * (np.array([config.approach.start_x, 0, 0]) - x) - 80.0 * xd
    u_f = 1.0 * 8.0 + 0.003 * 8.0 - 150.0 * xd[0]
    expected = (M @ np.linalg.solve(J, (np.eye(3) - S) @ u_x - jdq) + h + friction(config, qdot)
                + J.T @ S @ np.array([20.0 + u_f, 0, 0]))
    np.testing.assert_allclose(tau, expected, rtol=1e-9, atol=1e-9)


def test_force_rate_damping_adds_minus_d_f_times_the_sampled_force_rate():
    config = HybridControllerConfig(force_gain=1.0, force_integral_gain=0.0,
                                    contact_force_rate_damping=0.003)
    controller = HybridController(config)
    context = controller.CreateDefaultContext()
    context.SetTime(FIRST_SAMPLE_S)
    # The first sample switches to contact at 12 N; the next reads 15 N.
    sample(config, force=12.0, controller=controller, context=context)
    tau, mode, q, qdot, x, xd = sample(config, force=15.0, controller=controller,
                                       context=context)
    J, jdq, M, h = expected_terms(q, qdot)
    u_x = 400.0 * (np.array([config.approach.start_x, 0, 0]) - x) - 80.0 * xd
    u_f = 1.0 * (20.0 - 15.0) - 0.003 * (15.0 - 12.0) / 0.001
    expected = (M @ np.linalg.solve(J, (np.eye(3) - S) @ u_x - jdq) + h + friction(config, qdot)
                + J.T @ S @ np.array([20.0 + u_f, 0, 0]))
    assert mode == 1
    np.testing.assert_allclose(tau, expected, rtol=1e-9, atol=1e-9)
    # Off (the thesis's law), the same two samples give K_fp (f_d - f) only.
    plain = dc.replace(config, contact_force_rate_damping=0.0)
    controller = HybridController(plain)
    context = controller.CreateDefaultContext()
    context.SetTime(FIRST_SAMPLE_S)
    sample(plain, force=12.0, controller=controller, context=context)
    tau_plain = sample(plain, force=15.0, controller=controller, context=context)[0]
    np.testing.assert_allclose(tau - tau_plain, J.T @ S @ np.array([-9.0, 0, 0]), atol=1e-9)


def test_decoupled_law_uses_the_stiffness_input():
    config = HybridControllerConfig(law="decoupled", decoupled_force_gain=400.0,
                                    decoupled_force_damping=40.0)
    tau, mode, q, qdot, x, xd = sample(config, force=12.0, k_e=25000.0)
    J, jdq, M, h = expected_terms(q, qdot)
    u_x = 400.0 * (np.array([config.approach.start_x, 0, 0]) - x) - 80.0 * xd
    accel = (np.eye(3) - S) @ u_x
    accel[0] = (400.0 * (20.0 - 12.0) - 40.0 * 25000.0 * xd[0]) / 25000.0
    expected = (M @ np.linalg.solve(J, accel - jdq) + h + friction(config, qdot)
                + J.T @ S @ np.array([20.0, 0, 0]))
    np.testing.assert_allclose(tau, expected, rtol=1e-9, atol=1e-9)


def test_model_errors_and_motor_belief_change_the_command():
    base = HybridControllerConfig(friction_compensation=False)
    wrong = dc.replace(base, model=dc.replace(base.model, mass_scale=[1.2, 1.2, 1.2],
                                              motor_torque_scale=[1.0, 1.25, 1.0]))
    tau_base = sample(base, force=1.0)[0]
    tau_wrong = sample(wrong, force=1.0)[0]
    assert not np.allclose(tau_base, tau_wrong)
    # The motor belief divides the command.
    only_motor = dc.replace(base, model=dc.replace(base.model, motor_torque_scale=[1.0, 1.25, 1.0]))
    np.testing.assert_allclose(sample(only_motor, force=1.0)[0], tau_base / [1.0, 1.25, 1.0])


def test_switches_at_the_threshold_and_back_when_contact_is_lost():
    config = HybridControllerConfig()
    controller = HybridController(config)
    context = controller.CreateDefaultContext()
    context.SetTime(FIRST_SAMPLE_S)
    kw = dict(controller=controller, context=context)
    _, mode, *_ = sample(config, force=4.9, **kw)
    assert mode == 0
    tau, mode, *_ = sample(config, force=5.1, **kw)
    assert mode == 1
    info = controller.GetOutputPort("contact_info").Eval(context)
    assert info[0] == FIRST_SAMPLE_S  # first contact time (the context's time)
    # Between samples (a plant step finer than 1 ms) the outputs are the
    # last sample's, whatever the inputs do.
    held = tau
    context.SetTime(FIRST_SAMPLE_S + 0.0005)
    controller.GetInputPort("force").FixValue(context, [30.0])
    np.testing.assert_array_equal(
        controller.GetOutputPort("joint_torque_commanded").Eval(context), held)
    context.SetTime(FIRST_SAMPLE_S)
    _, mode, *_ = sample(config, force=-0.1, **kw)
    assert mode == 0


def test_approach_schedule_holds_then_steps_one_mm_per_second():
    config = HybridControllerConfig()
    controller = HybridControlLaw(config)
    assert controller._approach_target(4.999, 0.454) == pytest.approx(0.454)
    assert controller._approach_target(5.0, 0.454) == pytest.approx(0.456)
    assert controller._approach_target(6.5, 0.456) == pytest.approx(0.457)
    assert controller._approach_target(8.0, 0.458) == pytest.approx(0.459)


def test_after_a_contact_loss_x_d_is_kept_one_step_period_then_restarts():
    """Appendix E: the loss sets N1 = 4000; x1d is unchanged until N1 = 5000
    (1 s later) sets 0.456, then the ramp goes on from there."""
    config = HybridControllerConfig()
    controller = HybridController(config)
    context = controller.CreateDefaultContext()
    law = controller.GetSubsystemByName("law")
    law_context = law.GetMyMutableContextFromRoot(context)

    def x_d():  # the law's stored target (its internal state's 2nd entry)
        return law_context.get_discrete_state(0).value()[18]

    kw = dict(controller=controller, context=context)
    context.SetTime(7.5)
    sample(config, force=0.0, steps=7001, **kw)      # 7 s of approach: x_d = 0.458
    assert x_d() == pytest.approx(0.458)
    sample(config, force=5.1, **kw)                  # contact
    _, mode, *_ = sample(config, force=-0.1, **kw)   # lost
    assert mode == 0 and x_d() == pytest.approx(0.458)
    sample(config, force=-0.1, steps=998, **kw)
    assert x_d() == pytest.approx(0.458)             # kept for 1 s ...
    sample(config, force=-0.1, steps=2, **kw)
    assert x_d() == pytest.approx(0.456)             # ... then the ramp restarts


def test_force_reference_square_wave_and_sine():
    square = ForceReferenceConfig(levels=[20.0, 10.0], half_period_s=2.5)
    assert [square.at(t) for t in (-1.0, 0.0, 2.4, 2.5, 4.9, 5.0, 7.6)] == \
        [20.0, 20.0, 20.0, 10.0, 10.0, 20.0, 10.0]
    sine = dc.replace(square, sine_amplitude_n=4.0, sine_frequency_hz=0.5)
    assert sine.at(0.5) == pytest.approx(24.0)
    assert sine.at(3.0) == pytest.approx(10.0 + 4.0 * np.sin(np.pi * 3.0))
    # The sine's time restarts every square-wave cycle (the thesis's counter).
    assert sine.at(5.5) == pytest.approx(24.0)


def test_decoupled_law_clips_the_stiffness_estimate_to_its_bounds():
    config = HybridControllerConfig(law="decoupled", stiffness_bounds=[1000.0, 300000.0])
    for k_e, used in ((-5.0e4, 1000.0), (2.0e6, 300000.0), (25000.0, 25000.0)):
        tau = sample(config, force=12.0, k_e=k_e)[0]
        np.testing.assert_allclose(tau, sample(config, force=12.0, k_e=used)[0],
                                   rtol=1e-12, atol=1e-12)
    assert not np.allclose(sample(config, force=12.0, k_e=2000.0)[0],
                           sample(config, force=12.0, k_e=25000.0)[0])


def test_decoupled_force_integral_adds_the_summed_error_to_the_force_command():
    config = HybridControllerConfig(law="decoupled", decoupled_force_integral_gain=0.01)
    tau, mode, q, qdot, x, xd = sample(config, force=12.0, k_e=25000.0, steps=3)
    J, jdq, M, h = expected_terms(q, qdot)
    u_x = 400.0 * (np.array([config.approach.start_x, 0, 0]) - x) - 80.0 * xd
    accel = (np.eye(3) - S) @ u_x
    accel[0] = (400.0 * 8.0 - 40.0 * 25000.0 * xd[0]) / 25000.0
    expected = (M @ np.linalg.solve(J, accel - jdq) + h + friction(config, qdot)
                + J.T @ S @ np.array([20.0 + 0.01 * 3 * 8.0, 0, 0]))
    np.testing.assert_allclose(tau, expected, rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("law", ["hybrid", "decoupled"])
def test_pose_integral_adds_the_summed_y_and_phi_errors_and_clamps_them(law):
    gain, steps = 2000.0, 3
    config = HybridControllerConfig(law=law, pose_integral_gain=gain, pose_integral_limit=20.0,
                                    y_desired=0.0, phi_desired=0.0)
    plain = dc.replace(config, pose_integral_gain=0.0)
    tau, mode, q, qdot, x, xd = sample(config, force=12.0, steps=steps)
    J, jdq, M, h = expected_terms(q, qdot)
    # Switched on the first sample, so every one of the 3 samples summed.
    extra = np.array([0.0, gain * 1e-3 * steps * -x[1], gain * 1e-3 * steps * -x[2]])
    expected = sample(plain, force=12.0, steps=steps)[0] + M @ np.linalg.solve(J, extra)
    np.testing.assert_allclose(tau, expected, rtol=1e-9, atol=1e-9)
    # A large error saturates the integral: |K_pi T sum| <= pose_integral_limit.
    tight = dc.replace(config, pose_integral_limit=5.0)
    q_far = np.array(THESIS_Q0) + np.array([0.05, -0.2, 0.3])
    tau, mode, q, qdot, x, xd = sample(tight, force=12.0, q=q_far, steps=50)
    unclamped = gain * 1e-3 * 50 * -x[1:]
    assert np.abs(unclamped).max() > 5.0  # one of them is clamped
    J, jdq, M, h = expected_terms(q, qdot)
    extra = np.concatenate([[0.0], np.clip(unclamped, -5.0, 5.0)])
    expected = sample(plain, force=12.0, q=q_far, steps=50)[0] + M @ np.linalg.solve(J, extra)
    np.testing.assert_allclose(tau, expected, rtol=1e-9, atol=1e-9)


def test_force_reference_hold_before_the_cycle():
    held = ForceReferenceConfig(levels=[20.0, 10.0], half_period_s=2.5, hold_s=10.0)
    assert [held.at(t) for t in (-1.0, 0.0, 9.99, 10.0, 12.4, 12.5, 15.0)] == \
        [20.0, 20.0, 20.0, 20.0, 20.0, 10.0, 20.0]
    plain = dc.replace(held, hold_s=0.0)
    assert all(held.at(t + 10.0) == plain.at(t) for t in np.arange(0.0, 20.0, 0.1))


def test_force_integral_band_sums_only_small_errors():
    config = HybridControllerConfig(force_gain=1.0, force_integral_gain=0.003)
    summed = sample(config, force=12.0, steps=3)[0]          # error 8 N, summed 3 times
    inside = sample(dc.replace(config, force_integral_band_n=8.0), force=12.0, steps=3)[0]
    outside = sample(dc.replace(config, force_integral_band_n=7.9), force=12.0, steps=3)[0]
    never = sample(dc.replace(config, force_integral_gain=0.0), force=12.0, steps=3)[0]
    np.testing.assert_array_equal(inside, summed)
    np.testing.assert_allclose(outside, never, rtol=1e-12, atol=1e-12)
    assert not np.allclose(summed, never)


def test_force_reference_probe_is_a_bounded_schroeder_multisine_in_contact_only():
    plain = ForceReferenceConfig(levels=[20.0, 10.0], half_period_s=2.5)
    probed = dc.replace(plain, probe_amplitude_n=3.0, probe_frequencies_hz=[1.0, 4.0])
    # Two components of 1.5 N, phases 0 and -pi k (k - 1) / N = -pi.
    for t in (0.0, 0.1, 0.37, 2.6, 7.3):
        expected = plain.at(t) + 1.5 * (np.sin(2 * np.pi * t) + np.sin(8 * np.pi * t - np.pi))
        assert probed.at(t) == pytest.approx(expected, abs=1e-12)
    assert probed.at(-0.5) == 20.0                       # before contact: the first level
    t = np.arange(0.0, 60.0, 1e-3)
    bounded = dc.replace(plain, levels=[20.0], probe_amplitude_n=3.0)
    deviation = np.array([bounded.at(x) for x in t]) - 20.0
    assert np.abs(deviation).max() <= 3.0 and np.abs(deviation).max() > 1.0
    assert abs(deviation.mean()) < 0.05                  # no bias on the force held


@pytest.mark.parametrize("field, value", [("probe_amplitude_n", -1.0),
                                          ("probe_amplitude_n", float("nan")),
                                          ("probe_amplitude_n", 11.0),
                                          ("probe_frequencies_hz", []),
                                          ("probe_frequencies_hz", [0.0]),
                                          ("probe_frequencies_hz", [float("inf")])])
def test_force_reference_probe_fields_are_validated(field, value):
    config = dc.replace(ForceReferenceConfig(), **{field: value})
    with pytest.raises(ScenarioError, match=f"force_reference.{field} = .* is out of range"):
        config.validate()


def test_coupling_cancellation_leaves_y_and_phi_the_pose_loop_alone():
    """By hand: with the controller's model, the joint torque commanded and
    the measured wall force f give the task acceleration J M^-1 (tau - h -
    J^T e_x f) + Jdot qdot. Its y and phi parts are the pose loop's u_x
    exactly with the cancellation, and off by (Lambda^-1)[y/phi, x] (f_d - f)
    without it."""
    base = HybridControllerConfig(law="decoupled", friction_compensation=False)
    full = dc.replace(base, force_coupling_cancellation=1.0)
    half = dc.replace(base, force_coupling_cancellation=0.5)
    force, f_d = 12.0, 20.0
    results = {}
    for name, config in (("off", base), ("full", full), ("half", half)):
        tau, mode, q, qdot, x, xd = sample(config, force=force, f_d=f_d, k_e=25000.0)
        assert mode == 1
        J, jdq, M, h = expected_terms(q, qdot)
        accel = J @ np.linalg.solve(M, tau - h - J.T @ np.array([force, 0, 0])) + jdq
        results[name] = accel
    u_x = 400.0 * (np.array([config.approach.start_x, 0, 0]) - x) - 80.0 * xd
    coupling = (J @ np.linalg.solve(M, J.T))[1:, 0]
    assert np.abs(coupling).min() > 0.05  # the arm couples x into y and phi here
    np.testing.assert_allclose(results["full"][1:], u_x[1:], rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(results["off"][1:], u_x[1:] + coupling * (f_d - force),
                               rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(results["half"][1:], u_x[1:] + 0.5 * coupling * (f_d - force),
                               rtol=1e-9, atol=1e-9)
    # Along x nothing changes: the force loop is the decoupled law's.
    np.testing.assert_allclose(results["full"][0], results["off"][0], rtol=1e-9, atol=1e-9)


def test_stiffness_halving_time_limits_how_fast_k_e_falls_not_how_fast_it_rises():
    """By hand: the switch sets k_used to the bounds' top (3e5 N/m); each
    sample k_e = max(clip(estimate), k_used 0.5^(T / tau)). An estimate of
    1 kN/m for 3 samples gives 3e5 0.5^0.3; then 2.9e5 (above the floor)
    is used at once. Checked against the law fed those k_e directly."""
    bounds = [1000.0, 300000.0]
    limited = HybridControllerConfig(law="decoupled", stiffness_bounds=bounds,
                                     stiffness_halving_time_s=0.01)
    direct = dc.replace(limited, stiffness_halving_time_s=0.0)
    controller = HybridController(limited)
    context = controller.CreateDefaultContext()
    context.SetTime(FIRST_SAMPLE_S)
    for _ in range(3):
        tau = sample(limited, force=12.0, k_e=1000.0, controller=controller, context=context)[0]
    floor = 300000.0 * 0.5 ** 0.3
    np.testing.assert_allclose(tau, sample(direct, force=12.0, k_e=floor, steps=3)[0],
                               rtol=1e-12, atol=1e-12)
    assert not np.allclose(tau, sample(direct, force=12.0, k_e=1000.0, steps=3)[0])
    tau = sample(limited, force=12.0, k_e=290000.0, controller=controller, context=context)[0]
    np.testing.assert_allclose(tau, sample(direct, force=12.0, k_e=290000.0, steps=4)[0],
                               rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("law", ["hybrid", "decoupled"])
def test_pose_joint_stiffness_adds_k_times_the_pose_error_mapped_to_the_joints(law):
    """By hand: in contact the law adds K (J^-1 (I - S) (x_d - x)) - D (J^-1
    (I - S) xdot) per joint (elementwise); in the approach it adds nothing."""
    stiffness, damping = [30.0, 5.0, 8.0], [0.5, 0.2, 0.05]
    config = HybridControllerConfig(law=law, pose_joint_stiffness=stiffness,
                                    pose_joint_damping=damping, y_desired=0.001,
                                    phi_desired=-0.002)
    plain = dc.replace(config, pose_joint_stiffness=[0.0] * 3, pose_joint_damping=[0.0] * 3)
    tau, mode, q, qdot, x, xd = sample(config, force=12.0, k_e=25000.0)
    assert mode == 1
    J = thesis.jacobian(q)
    e_q = np.linalg.solve(J, [0.0, 0.001 - x[1], -0.002 - x[2]])
    v_q = np.linalg.solve(J, [0.0, xd[1], xd[2]])
    added = np.array(stiffness) * e_q - np.array(damping) * v_q
    # A (y, phi) error here moves joints 1 and 3 (joint 2 barely: J^-1's row).
    assert np.abs(added[[0, 2]]).min() > 1e-3
    expected = sample(plain, force=12.0, k_e=25000.0)[0] + added
    np.testing.assert_allclose(tau, expected, rtol=1e-9, atol=1e-9)
    approach = sample(config, force=1.0)
    assert approach[1] == 0
    np.testing.assert_array_equal(approach[0], sample(plain, force=1.0)[0])


def test_pose_joint_stiffness_fields_are_validated():
    for field in ("pose_joint_stiffness", "pose_joint_damping"):
        for value in ([1.0, 2.0], [0.0, -1.0, 0.0], [0.0, 0.0, float("nan")]):
            config = HybridControllerConfig(**{field: value})
            with pytest.raises(ScenarioError,
                               match=f"controller.hybrid.{field} = .* is out of range"):
                config.validate()
    with pytest.raises(ScenarioError, match="force_integral_hold_s = -0.1 is out of range"):
        HybridControllerConfig(force_integral_hold_s=-0.1).validate()


def test_force_integral_hold_skips_the_samples_after_the_switch_and_each_step_of_f_d():
    """By hand, the hybrid PI law with K_fi 0.003 and a 2 ms hold, the force
    read 12 N: the switch (f_d from none to 20 N) holds the sum for samples 1
    and 2, samples 3-5 sum 8 N each; f_d stepping to 10 N at sample 6 holds
    it for samples 6 and 7, sample 8 sums -2 N. f_d - f is summed as the
    law's own (I - S) part and feed-forward are unchanged: checked against
    the same law with the sum it should hold, u_f = K_fp e + K_fi sum."""
    config = HybridControllerConfig(force_gain=1.0, force_integral_gain=0.003,
                                    force_integral_hold_s=0.002)
    controller = HybridController(config)
    context = controller.CreateDefaultContext()
    expected_sums = [0, 0, 8, 16, 24, 24, 24, 22]
    for k, expected_sum in enumerate(expected_sums):
        f_d = 20.0 if k < 5 else 10.0
        context.SetTime(FIRST_SAMPLE_S + k * 1e-3)
        tau, mode, q, qdot, x, xd = sample(config, force=12.0, f_d=f_d, controller=controller,
                                           context=context)
        assert mode == 1
        J, jdq, M, h = expected_terms(q, qdot)
        u_x = 400.0 * (np.array([config.approach.start_x, 0, 0]) - x) - 80.0 * xd
        u_f = (f_d - 12.0) + 0.003 * expected_sum
        expected = (M @ np.linalg.solve(J, (np.eye(3) - S) @ u_x - jdq) + h
                    + friction(config, qdot) + J.T @ S @ np.array([f_d + u_f, 0, 0]))
        np.testing.assert_allclose(tau, expected, rtol=1e-9, atol=1e-9, err_msg=f"sample {k + 1}")
    # Without the hold every sample sums (the thesis's law).
    plain = dc.replace(config, force_integral_hold_s=0.0)
    tau = sample(plain, force=12.0, steps=3)[0]
    J, jdq, M, h = expected_terms(q, qdot)
    u_f = 8.0 + 0.003 * 24.0
    expected = (M @ np.linalg.solve(J, (np.eye(3) - S) @ u_x - jdq) + h
                + friction(config, qdot) + J.T @ S @ np.array([20.0 + u_f, 0, 0]))
    np.testing.assert_allclose(tau, expected, rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("force, steps", [(19.9, 1), (19.9, 3), (20.3, 2), (12.0, 2)])
def test_force_error_friction_compensation_follows_the_filtered_force_error(force, steps):
    """By hand: the force error e = 20 - f through a first-order low-pass at
    10 Hz (gain g = 1 - exp(-2 pi 10 T) per sample, from 0 at the switch)
    gives e_f = e (1 - (1 - g)^n) after n samples; the law adds c sat(e_f /
    e_0) F_c sgn(J^-1 e_x) per joint, F_c the model's Coulomb levels: small
    errors in proportion, large ones (12 N: 8 N off) the full c F_c."""
    config = HybridControllerConfig(friction_compensation=False,
                                    force_error_friction_compensation=0.6,
                                    force_error_friction_band_n=0.25, force_error_filter_hz=10.0)
    plain = dc.replace(config, force_error_friction_compensation=0.0)
    tau, mode, q, qdot, x, xd = sample(config, force=force, steps=steps)
    assert mode == 1
    g = 1.0 - np.exp(-2.0 * np.pi * 10.0 * 1e-3)
    e_f = (20.0 - force) * (1.0 - (1.0 - g) ** steps)
    push = np.linalg.solve(thesis.jacobian(q), [1.0, 0.0, 0.0])
    added = 0.6 * np.clip(e_f / 0.25, -1.0, 1.0) * np.array([1.0, 0.2, 0.004]) * np.sign(push)
    np.testing.assert_allclose(tau, sample(plain, force=force, steps=steps)[0] + added,
                               rtol=1e-9, atol=1e-12)
    assert np.abs(added[0]) > 1e-3
    # In the approach it adds nothing.
    np.testing.assert_array_equal(sample(config, force=1.0)[0], sample(plain, force=1.0)[0])


@pytest.mark.parametrize("field, value", [("force_error_friction_compensation", 1.5),
                                          ("force_error_friction_compensation", -0.1),
                                          ("force_error_friction_band_n", 0.0),
                                          ("force_error_filter_hz", 0.0),
                                          ("force_error_filter_hz", 500.0)])
def test_force_error_friction_compensation_fields_are_validated(field, value):
    with pytest.raises(ScenarioError, match=f"controller.hybrid.{field} = .* is out of range"):
        HybridControllerConfig(**{field: value}).validate()
