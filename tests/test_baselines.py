"""The baseline controllers: one sample of each law against a hand
computation with the arm model's J, Jdot qdot, M and h, the approach, the
5 N contact switch, the hold between samples and the options factories."""

import numpy as np
import pytest

from drake_contact.control import baselines
from drake_contact.control.controller_model import ArmModel, ControllerModelConfig
from drake_contact.errors import ScenarioError
from drake_contact.plant.arm import THESIS_Q0, CalcSampledUpdate

FACTORIES = {"impedance": baselines.impedance, "admittance": baselines.admittance,
             "parallel_force": baselines.parallel_force}
T = 1e-3
Q = np.array(THESIS_Q0) + [0.01, -0.02, 0.005]
QDOT = np.array([0.02, -0.05, 0.1])
# The pose and velocity inputs are the estimator's, not exactly FK(q): the
# law must read them from their ports and J, M, h from q.
MODEL = ArmModel(ControllerModelConfig())
POSE = MODEL.evaluate(Q, QDOT)[0] + [0.0003, 0.0012, -0.004]
VELOCITY = np.array([0.004, -0.003, 0.02])
SAMPLE_T = 2.345  # a sample instant (whole ms)


def terms():
    _, J, jdot_qdot, M, h = MODEL.evaluate(Q, QDOT)
    friction = np.array([1.0, 0.2, 0.004]) * np.clip(QDOT / 0.002, -1, 1)
    return J, jdot_qdot, M, h + friction


def computed_torque(accel):
    J, jdot_qdot, M, bias = terms()
    return M @ np.linalg.solve(J, accel - jdot_qdot) + bias


def sample(system, *, force, f_d=20.0, state=None, t=SAMPLE_T):
    """(tau, mode, contact_info, the state after the update) at time t."""
    context = system.CreateDefaultContext()
    context.SetTime(t)
    if state is not None:
        context.SetDiscreteState(np.asarray(state, dtype=float))
    inputs = {"tip_pose_measured": POSE, "tip_velocity_measured": VELOCITY,
              "joint_positions_estimated": Q, "joint_velocities_estimated": QDOT,
              "force_filtered": [force], "force_desired": [f_d]}
    for name, value in inputs.items():
        system.GetInputPort(name).FixValue(context, value)
    tau = system.GetOutputPort("joint_torque_commanded").Eval(context).copy()
    mode = system.GetOutputPort("mode").Eval(context)[0]
    info = system.GetOutputPort("contact_info").Eval(context).copy()
    law_context = system.law.GetMyContextFromRoot(context)
    return tau, mode, info, CalcSampledUpdate(system.law, law_context).get_vector().value().copy()


def held_state(system, *, mode, info=(-1.0, 0.0, 0.0, 0.0), timer=0.0, x_origin=0.0,
               law=()):
    """A discrete state: [tau (3), mode, contact_info (4), timer, x_o, law...]."""
    state = [0.0, 0.0, 0.0, mode, *info, timer, x_origin, *law]
    assert len(state) == system.CreateDefaultContext().get_discrete_state_vector().size()
    return state


def contact_state(system, law=()):
    return held_state(system, mode=1, info=(1.2, POSE[0] - 0.002, 0.0, 0.0), timer=1.5,
                      x_origin=0.455, law=law)


@pytest.mark.parametrize("name", FACTORIES)
def test_ports_are_named_and_sized(name):
    system = FACTORIES[name]({})
    inputs = {system.get_input_port(i).get_name(): system.get_input_port(i).size()
              for i in range(system.num_input_ports())}
    outputs = {system.get_output_port(i).get_name(): system.get_output_port(i).size()
               for i in range(system.num_output_ports())}
    # The measured signals as the station names (and logs) them.
    assert inputs == {"tip_pose_measured": 3, "tip_velocity_measured": 3,
                      "joint_positions_estimated": 3, "joint_velocities_estimated": 3,
                      "force_filtered": 1, "force_desired": 1, "force_fault": 1}
    assert outputs == {"joint_torque_commanded": 3, "mode": 1, "contact_info": 4}


@pytest.mark.parametrize("name", FACTORIES)
def test_approach_ramp_is_resolved_acceleration_control(name):
    system = FACTORIES[name]({})
    # 0.5 s into the ramp from x_o = 0.450 m: x_d = 0.450 + 0.002 * 0.5.
    state = held_state(system, mode=0, timer=1.5, x_origin=0.450,
                       law=[0.0] * (len(system.CreateDefaultContext()
                                        .get_discrete_state_vector().value()) - 10))
    tau, mode, info, after = sample(system, force=1.0, state=state)
    x_d = np.array([0.451, 0.0, 0.0])
    expected = computed_torque(400.0 * (x_d - POSE) - 80.0 * VELOCITY)
    assert mode == 0
    np.testing.assert_allclose(tau, expected, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(info, [-1, 0, 0, 0])
    np.testing.assert_allclose(after[8:10], [1.5 + T, 0.450])  # timer on, x_o kept


@pytest.mark.parametrize("name", FACTORIES)
def test_approach_hold_follows_the_measured_x(name):
    system = FACTORIES[name]({"approach_hold_s": 0.5})
    tau, mode, info, after = sample(system, force=0.0, t=0.3)
    # During the hold x_d = the measured x: damping only along x.
    expected = computed_torque(400.0 * (np.array([POSE[0], 0, 0]) - POSE) - 80.0 * VELOCITY)
    np.testing.assert_allclose(tau, expected, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(after[8:10], [T, POSE[0]])


def test_impedance_contact_sample():
    system = baselines.impedance({"stiffness_x": 250.0, "damping_x": 280.0})
    tau, mode, info, after = sample(system, force=12.0, f_d=18.0, state=contact_state(system))
    J = terms()[0]
    x_0 = POSE[0] - 0.002  # x at the switch, from contact_info
    force_x = 250.0 * (x_0 - POSE[0]) - 280.0 * VELOCITY[0] + 18.0
    accel = np.array([0.0, 400.0 * -POSE[1] - 80.0 * VELOCITY[1],
                      400.0 * -POSE[2] - 80.0 * VELOCITY[2]])
    expected = computed_torque(accel) + J.T @ [force_x, 0.0, 0.0]
    assert mode == 1
    np.testing.assert_allclose(tau, expected, rtol=1e-9, atol=1e-9)
    # The measured force does not enter: only the switch reads it.
    tau_other, *_ = sample(system, force=30.0, f_d=18.0, state=contact_state(system))
    np.testing.assert_allclose(tau_other, tau, rtol=1e-12)


def test_admittance_contact_sample_steps_the_reference():
    system = baselines.admittance({"admittance_mass": 4.0, "admittance_damping": 900.0})
    x_r, xr_dot = POSE[0] + 0.001, 0.003
    tau, mode, info, after = sample(system, force=12.0, f_d=18.0,
                                    state=contact_state(system, law=[x_r, xr_dot]))
    xr_ddot = (18.0 - 12.0 - 900.0 * xr_dot) / 4.0
    xr_dot_new = xr_dot + T * xr_ddot
    x_r_new = x_r + T * xr_dot_new
    accel = np.array([xr_ddot + 80.0 * (xr_dot_new - VELOCITY[0]) + 400.0 * (x_r_new - POSE[0]),
                      400.0 * -POSE[1] - 80.0 * VELOCITY[1],
                      400.0 * -POSE[2] - 80.0 * VELOCITY[2]])
    J = terms()[0]
    expected = computed_torque(accel) + J.T @ [12.0, 0.0, 0.0]
    assert mode == 1
    np.testing.assert_allclose(tau, expected, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(after[10:], [x_r_new, xr_dot_new], rtol=1e-12)


def test_admittance_reference_starts_at_the_switch_pose():
    system = baselines.admittance({})
    state = held_state(system, mode=0, timer=3.0, x_origin=0.45, law=[0.1, 5.0])
    _, mode, _, after = sample(system, force=6.0, f_d=20.0, state=state)
    xr_ddot = (20.0 - 6.0 - 1000.0 * VELOCITY[0]) / 5.0
    xr_dot = VELOCITY[0] + T * xr_ddot
    assert mode == 1
    np.testing.assert_allclose(after[10:], [POSE[0] + T * xr_dot, xr_dot], rtol=1e-12)


def test_parallel_force_contact_sample_sums_the_force_error():
    system = baselines.parallel_force({"force_gain": 0.02, "force_integral_gain": 0.5})
    error_sum = 150.0  # N, over the previous samples
    tau, mode, info, after = sample(system, force=12.0, f_d=18.0,
                                    state=contact_state(system, law=[error_sum]))
    x_d = np.array([POSE[0] - 0.002, 0.0, 0.0])
    accel = 400.0 * (x_d - POSE) - 120.0 * VELOCITY
    accel[0] += 0.02 * 6.0 + 0.5 * T * (error_sum + 6.0)
    J = terms()[0]
    expected = computed_torque(accel) + J.T @ [12.0, 0.0, 0.0]
    assert mode == 1
    np.testing.assert_allclose(tau, expected, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(after[10:], [error_sum + 6.0])


@pytest.mark.parametrize("name", FACTORIES)
def test_switch_to_contact_above_5_n_and_back_below_0_n(name):
    system = FACTORIES[name]({})
    size = system.CreateDefaultContext().get_discrete_state_vector().size()
    approach = held_state(system, mode=0, timer=2.0, x_origin=0.45, law=[0.0] * (size - 10))
    _, mode, info, _ = sample(system, force=4.99, state=approach)
    assert mode == 0 and info[0] == -1
    _, mode, info, after = sample(system, force=5.01, state=approach)
    assert mode == 1 and after[3] == 1
    np.testing.assert_allclose(info, [SAMPLE_T, *POSE])
    # In contact, hysteresis: a force between 0 and 5 N keeps the mode.
    contact = held_state(system, mode=1, info=(0.7, 0.456, 0.0, 0.0), timer=2.0,
                         x_origin=0.45, law=[0.0] * (size - 10))
    _, mode, info, _ = sample(system, force=0.5, state=contact)
    assert mode == 1
    # Below 0 N: back to the approach, the ramp resuming from here at once;
    # the first switch's time is kept.
    tau, mode, info, after = sample(system, force=-0.1, state=contact)
    assert mode == 0
    np.testing.assert_allclose(info, [0.7, 0.456, 0.0, 0.0])
    np.testing.assert_allclose(after[8:10], [1.0 + T, POSE[0]])
    expected = computed_torque(400.0 * (np.array([POSE[0], 0, 0]) - POSE) - 80.0 * VELOCITY)
    np.testing.assert_allclose(tau, expected, rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("name", FACTORIES)
def test_outputs_hold_between_samples(name):
    system = FACTORIES[name]({})
    size = system.CreateDefaultContext().get_discrete_state_vector().size()
    state = held_state(system, mode=1, info=(0.7, 0.456, 0.0, 0.0), law=[0.0] * (size - 10))
    state[:3] = [1.0, -2.0, 0.5]
    tau, mode, info, _ = sample(system, force=50.0, state=state, t=SAMPLE_T + 0.0004)
    np.testing.assert_allclose(tau, [1.0, -2.0, 0.5])
    assert mode == 1
    np.testing.assert_allclose(info, [0.7, 0.456, 0.0, 0.0])


@pytest.mark.parametrize("name", FACTORIES)
def test_factory_rejects_an_unknown_option(name):
    with pytest.raises(ScenarioError, match=rf"controller\.options\.gain_x is not an option "
                                            rf"of '{name}': known options are "):
        FACTORIES[name]({"gain_x": 1.0})


@pytest.mark.parametrize("name, field, value", [
    ("impedance", "damping_x", -1.0),
    ("impedance", "approach_speed_m_s", 0.0),
    ("admittance", "admittance_mass", 0.0),
    ("parallel_force", "force_integral_gain", -0.1),
    ("parallel_force", "contact_threshold_n", -1.0),
])
def test_factory_names_the_out_of_range_field(name, field, value):
    with pytest.raises(ScenarioError, match=rf"^controller\.options\.{field} = .* is out of "
                                            r"range: must .*$"):
        FACTORIES[name]({field: value})


def test_factory_rejects_a_non_number():
    with pytest.raises(ScenarioError, match=r"controller\.options\.admittance_damping = 'x'"):
        baselines.admittance({"admittance_damping": "x"})
    with pytest.raises(ScenarioError, match=r"controller\.options\.friction_compensation"):
        baselines.impedance({"friction_compensation": 1.0})


def test_friction_compensation_can_be_turned_off():
    on = sample(baselines.parallel_force({}), force=1.0, t=0.5)[0]
    off = sample(baselines.parallel_force({"friction_compensation": False}), force=1.0,
                 t=0.5)[0]
    friction = np.array([1.0, 0.2, 0.004]) * np.clip(QDOT / 0.002, -1, 1)
    np.testing.assert_allclose(on - off, friction, rtol=1e-9, atol=1e-12)
