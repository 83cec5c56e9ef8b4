"""The hybrid controller's law over the arm axis: one system for N
environments, each environment bit for bit the single-environment law with
its config (gains, thresholds, approach schedules, arm models, options'
numbers), fed the same inputs, with environments entering and leaving
contact at different samples; outputs and state compared each sample."""

import dataclasses as dc

import numpy as np
import pytest

from drake_contact.control.builtin import hybrid, nn
from drake_contact.control.controller_model import ControllerModelConfig
from drake_contact.control.hybrid_controller import (
    _LAW, APPROACH, CONTACT, ApproachConfig, HybridControlLaw, HybridController,
    HybridControllerConfig)
from drake_contact.errors import ScenarioError
from drake_contact.plant.arm import CONTROL_PERIOD, THESIS_Q0

PORTS = ("tip_pose", "tip_velocity", "joint_positions", "joint_velocities", "force",
         "force_desired", "stiffness_estimate")

#: The structures (which options are on); each environment's numbers vary
#: around these (see _config).
STRUCTURES = {
    "hybrid": HybridControllerConfig(),
    "hybrid_options": HybridControllerConfig(
        contact_damping_x=150.0, contact_force_rate_damping=0.003, force_integral_gain=0.01,
        pose_integral_gain=2000.0, pose_integral_limit=0.3, force_integral_hold_s=0.01,
        force_integral_band_n=3.0, force_error_friction_compensation=0.6,
        pose_joint_stiffness=[0.0, 1.0, 8.0], pose_joint_damping=[0.1, 0.0, 0.05],
        friction_compensation=True),
    "decoupled": HybridControllerConfig(law="decoupled"),
    "decoupled_options": HybridControllerConfig(
        law="decoupled", stiffness_source="rls", stiffness_halving_time_s=0.01,
        stiffness_bounds=[1000.0, 60000.0], decoupled_force_integral_gain=0.01,
        force_coupling_cancellation=1.0, pose_integral_gain=2000.0, pose_integral_limit=0.3,
        force_integral_hold_s=0.01, force_error_friction_compensation=0.6,
        pose_joint_stiffness=[0.0, 0.0, 8.0]),
}


def _config(base, i):
    """Environment i's config: base's structure, its own numbers."""
    j = i % 5
    scaled = {"contact_damping_x", "contact_force_rate_damping", "force_integral_gain",
              "pose_integral_gain", "pose_integral_limit", "force_integral_hold_s",
              "stiffness_halving_time_s", "decoupled_force_integral_gain"}
    change = {field: getattr(base, field) * (1.0 + 0.3 * j) for field in scaled}
    change.update(
        position_gain=400.0 * (1.0 + 0.1 * j), velocity_gain=80.0 + 5.0 * j,
        force_gain=1.0 - 0.15 * j, decoupled_force_gain=400.0 - 30.0 * j,
        decoupled_force_damping=0.01 * (1 + j), stiffness_estimate=7000.0 * (1 + j),
        contact_threshold_n=5.0 + 0.5 * j, contact_loss_threshold_n=-1.0 + 0.5 * j,
        force_step_threshold_n=1.0 + 0.2 * j, y_desired=1e-3 * (j - 2),
        phi_desired=2e-3 * (2 - j),
        approach=ApproachConfig(hold_time_s=0.02 + 0.005 * j, step_period_s=0.03 + 0.01 * j,
                                first_target_x=0.456 + 0.001 * j),
        model=ControllerModelConfig(mass_scale=[1.0 + 0.1 * j, 0.9, 1.2 - 0.05 * j],
                                    inertia_scale=[1.2, 0.85 + 0.05 * j, 1.2],
                                    friction_levels=[1.0, 0.2 + 0.05 * j, 0.004],
                                    friction_band=0.002 * (1 + j),
                                    motor_torque_scale=[1.0, 1.0 + 0.05 * j, 1.0]))
    if base.force_integral_band_n:
        change["force_integral_band_n"] = 3.0 + j
    if base.force_error_friction_compensation:
        change.update(force_error_friction_compensation=0.6 - 0.1 * j,
                      force_error_friction_band_n=0.25 * (1 + j),
                      force_error_filter_hz=10.0 + 5.0 * j)
    if any(base.pose_joint_stiffness):
        change.update(pose_joint_stiffness=[0.0, base.pose_joint_stiffness[1] * j, 8.0 + j],
                      pose_joint_damping=[d * (1 + j) for d in base.pose_joint_damping])
    if base.stiffness_source:
        change.update(stiffness_bounds=[1000.0 * (1 + j), 60000.0 + 1e4 * j],
                      force_coupling_cancellation=1.0 - 0.15 * j)
    return dc.replace(base, **change)


def _inputs(count, samples):
    """Per sample, per environment, the inputs in PORTS order: poses and
    joints that wander near THESIS_Q0, forces that cross each threshold
    (every environment its own period, so they switch at different
    samples), f_d steps, stiffness estimates that sometimes leave their
    bounds (environment i's from seed i % 7)."""
    k = np.arange(1, samples + 1)[:, None]
    rows = np.empty((samples, count, 15))
    for i in range(count):
        rng = np.random.default_rng(i % 7)
        seed = i % 7
        t = k * CONTROL_PERIOD
        q = (np.array(THESIS_Q0) + 0.03 * np.sin(5 * t + seed) * np.array([1.0, -1.0, 0.5])
             + rng.normal(0, 1e-3, (samples, 3)))
        qdot = rng.normal(0, 0.01, (samples, 3)) * (rng.random((samples, 3)) < 0.7)
        pose = np.hstack([0.455 + 0.002 * np.sin(7 * t + seed),
                          rng.normal(0, 1e-3, (samples, 1)), rng.normal(0, 2e-3, (samples, 1))])
        velocity = rng.normal(0, 0.005, (samples, 3))
        force = (6.0 + 9.0 * np.sin(2 * np.pi * k / (70 + 9 * seed) + seed)
                 + rng.normal(0, 0.5, (samples, 1)))
        f_d = np.where((k // (40 + 3 * seed)) % 2, 20.0, 10.0) + rng.normal(0, 0.3, (samples, 1))
        k_e = 7000.0 * np.exp(rng.normal(0, 1.5, (samples, 1)))
        odd = rng.random((samples, 1))
        k_e = np.where(odd < 0.05, -500.0, np.where(odd < 0.1, 1e13, k_e))
        rows[:, i] = np.hstack([pose, velocity, q, qdot, force, f_d, k_e])
    return rows


_SIZES = (3, 3, 3, 3, 1, 1, 1)
_STARTS = np.cumsum((0,) + _SIZES)


def _fix(system, context, rows):
    """Fixes the inputs to ``rows`` (environments, 15), env-major."""
    for p, name in enumerate(PORTS):
        system.GetInputPort(name).FixValue(
            context, rows[:, _STARTS[p]:_STARTS[p + 1]].ravel())


def _environment(vector, i, count):
    """Environment i's :data:`_LAW` vector from the N-environment vector
    (field-major, each field env-major)."""
    parts, offset = [], 0
    for size in _LAW.sizes:
        start = count * offset + size * i
        parts.append(vector[start:start + size])
        offset += size
    return np.concatenate(parts)


def _run(configs, samples):
    """Drives the N-environment law and N one-environment laws through
    ``samples`` samples (output Eval between and at each sample, then the
    periodic update), asserting environment i's output and state equal its
    one-environment law's; returns each environment's modes (samples, N)."""
    count = len(configs)
    ensemble = HybridControlLaw(configs)
    singles = [HybridControlLaw(c) for c in configs]
    together = ensemble.CreateDefaultContext()
    contexts = [s.CreateDefaultContext() for s in singles]
    inputs = _inputs(count, samples)
    modes = np.empty((samples, count))
    for k in range(1, samples + 1):
        _fix(ensemble, together, inputs[k - 1])
        for i, (single, context) in enumerate(zip(singles, contexts)):
            _fix(single, context, inputs[k - 1, i:i + 1])
        # Between samples (a plant step finer than 1 ms) the held values;
        # at the sample, this sample's.
        for t in ((k - 0.5) * CONTROL_PERIOD, k * CONTROL_PERIOD):
            together.SetTime(t)
            both = ensemble.get_output_port().Eval(together)
            for i, (single, context) in enumerate(zip(singles, contexts)):
                context.SetTime(t)
                np.testing.assert_array_equal(_environment(both, i, count),
                                              single.get_output_port().Eval(context),
                                              err_msg=f"sample {k}, env {i}, t = {t}")
        together.SetDiscreteState(ensemble.EvalUniquePeriodicDiscreteUpdate(together))
        held = together.get_discrete_state_vector().CopyToVector()
        for i, (single, context) in enumerate(zip(singles, contexts)):
            context.SetDiscreteState(single.EvalUniquePeriodicDiscreteUpdate(context))
            alone = context.get_discrete_state_vector().CopyToVector()
            np.testing.assert_array_equal(_environment(held, i, count), alone,
                                          err_msg=f"state after sample {k}, env {i}")
            modes[k - 1, i] = alone[_LAW.mode]
    return modes


@pytest.mark.parametrize("count,samples", [(1, 400), (2, 400), (3, 400), (16, 300), (64, 200)])
@pytest.mark.parametrize("structure", list(STRUCTURES))
def test_mixed_configs_equal_their_single_laws_bit_for_bit(structure, count, samples):
    configs = [_config(STRUCTURES[structure], i) for i in range(count)]
    modes = _run(configs, samples)
    # Every environment enters contact and loses it; with more than one,
    # some sample has environments in both modes (the masks at work).
    entered = (modes[1:] == CONTACT) & (modes[:-1] == APPROACH)
    left = (modes[1:] == APPROACH) & (modes[:-1] == CONTACT)
    assert entered.any(axis=0).all() and left.any(axis=0).all()
    if count > 1:
        assert ((modes == CONTACT).any(axis=1) & (modes == APPROACH).any(axis=1)).any()


def test_each_environment_uses_its_own_numbers():
    """Two environments fed the same inputs, their configs different: their
    outputs differ (the comparison above would catch a law that used
    environment 0's numbers for all)."""
    configs = [_config(STRUCTURES["decoupled_options"], i) for i in (0, 3)]
    law = HybridControlLaw(configs)
    context = law.CreateDefaultContext()
    same = np.repeat(_inputs(1, 200)[:, :1], 2, axis=1)
    differ = 0
    for k in range(1, 201):
        _fix(law, context, same[k - 1])
        context.SetTime(k * CONTROL_PERIOD)
        output = law.get_output_port().Eval(context)
        differ += not np.array_equal(_environment(output, 0, 2), _environment(output, 1, 2))
        context.SetDiscreteState(law.EvalUniquePeriodicDiscreteUpdate(context))
    assert differ > 150


def test_the_controller_ports_are_env_major():
    configs = [_config(STRUCTURES["hybrid_options"], i) for i in range(3)]
    ensemble = HybridController(configs)
    singles = [HybridController(c) for c in configs]
    together = ensemble.CreateDefaultContext()
    contexts = [s.CreateDefaultContext() for s in singles]
    sizes = {"joint_torque_commanded": 3, "mode": 1, "contact_info": 4, "tip_jacobian": 9}
    inputs = _inputs(3, 120)
    for k in range(1, 121):
        _fix(ensemble, together, inputs[k - 1])
        together.SetTime(k * CONTROL_PERIOD)
        for i, (single, context) in enumerate(zip(singles, contexts)):
            _fix(single, context, inputs[k - 1, i:i + 1])
            context.SetTime(k * CONTROL_PERIOD)
            for name, size in sizes.items():
                np.testing.assert_array_equal(
                    ensemble.GetOutputPort(name).Eval(together)[size * i:size * (i + 1)],
                    single.GetOutputPort(name).Eval(context), err_msg=f"{name}, sample {k}")
            law = single.GetSubsystemByName("law")
            law_context = law.GetMyMutableContextFromRoot(context)
            law_context.SetDiscreteState(law.EvalUniquePeriodicDiscreteUpdate(law_context))
        law = ensemble.GetSubsystemByName("law")
        law_context = law.GetMyMutableContextFromRoot(together)
        law_context.SetDiscreteState(law.EvalUniquePeriodicDiscreteUpdate(law_context))
    assert {name: ensemble.GetOutputPort(name).size() for name in sizes} == {
        name: 3 * size for name, size in sizes.items()}


@pytest.mark.parametrize("change,field,value", [
    ({"law": "decoupled"}, "law", None),
    ({"contact_damping_x": 10.0}, "contact_damping_x", 10.0),
    ({"contact_force_rate_damping": 0.01}, "contact_force_rate_damping", 0.01),
    ({"pose_integral_gain": 100.0}, "pose_integral_gain", 100.0),
    ({"force_integral_hold_s": 0.1}, "force_integral_hold_s", 0.1),
    ({"force_error_friction_compensation": 0.5}, "force_error_friction_compensation", 0.5),
    ({"pose_joint_stiffness": [0.0, 0.0, 1.0]}, "pose_joint_stiffness", None),
    ({"pose_joint_damping": [0.0, 0.0, 1.0]}, "pose_joint_damping", None),
    ({"decoupled_force_integral_gain": 0.01}, "decoupled_force_integral_gain", 0.01),
    ({"force_coupling_cancellation": 0.5}, "force_coupling_cancellation", 0.5),
    ({"stiffness_halving_time_s": 0.01}, "stiffness_halving_time_s", 0.01),
    ({"stiffness_source": "rls"}, "stiffness_source", "rls"),
    ({"friction_compensation": True}, "friction_compensation", True),
])
def test_configs_that_differ_in_structure_are_refused(change, field, value):
    configs = [HybridControllerConfig(), HybridControllerConfig(), HybridControllerConfig(),
               dc.replace(HybridControllerConfig(), **change)]
    message = rf"controller\.hybrid\[3\]\.{field} = "
    message += "'decoupled' differs from environment 0's" if field == "law" else ""
    if value is not None:
        message += rf"{value} differs in whether it is on from environment 0's"
    with pytest.raises(ScenarioError, match=message) as raised:
        HybridControlLaw(configs)
    assert "share a structure" in str(raised.value) and "\n" not in str(raised.value)


def test_numbers_may_differ_and_a_policy_acts_on_each_environment():
    HybridControlLaw([HybridControllerConfig(), HybridControllerConfig(force_gain=0.2,
                                                                       force_integral_band_n=2.0)])
    law = HybridControlLaw([HybridControllerConfig()] * 3, action_input=True)
    assert law.GetInputPort("policy_action").size() == 12
    with pytest.raises(ScenarioError, match="acts on the hybrid law only"):
        HybridControlLaw([HybridControllerConfig(law="decoupled")] * 2, action_input=True)


def test_each_config_is_validated_with_its_environment_named():
    bad = HybridControllerConfig(position_gain=-1.0)
    with pytest.raises(ScenarioError, match=r"controller\.hybrid\[1\]\.position_gain"):
        HybridControlLaw([HybridControllerConfig(), bad])


def test_the_factories_serve_a_list_and_pick_each_k_e_alone():
    decoupled = {"law": "decoupled", "stiffness_source": "rls",
                 "stiffness_bounds": [1000.0, 60000.0]}
    controller = hybrid([decoupled, decoupled | {"decoupled_force_gain": 300.0}])
    context = controller.CreateDefaultContext()
    for i in range(controller.num_input_ports()):
        port = controller.get_input_port(i)
        port.FixValue(context, np.zeros(port.size()))
    # Environment 0's identifier gives a non-finite R_e and B_e: its K_e is
    # still its own, and environment 1's is untouched.
    controller.GetInputPort("impedance_estimate").FixValue(
        context, [np.nan, np.inf, 5000.0, 1.0, 2.0, 3.0e4])
    law = controller.GetSubsystemByName("hybrid").GetSubsystemByName("law")
    np.testing.assert_array_equal(
        law.GetInputPort("stiffness_estimate").Eval(law.GetMyContextFromRoot(context)),
        [5000.0, 3.0e4])
    with pytest.raises(ScenarioError, match=r"controller\.hybrid\[1\]\.pose_integral_gain"):
        hybrid([{}, {"pose_integral_gain": 100.0}])
    both = nn([{"hybrid": {"force_gain": 0.25}, "nn": {}},
               {"hybrid": {"force_gain": 0.5, "y_desired": 0.001}, "nn": {"learning_rate": 1e-5}}])
    assert {both.GetOutputPort(name).size() for name in (
        "joint_torque_commanded", "hybrid_torque", "nn_output")} == {6}
    assert both.GetInputPort("tip_pose_measured").size() == 6
