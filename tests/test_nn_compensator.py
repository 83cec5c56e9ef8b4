"""The 9-12-3 compensator: Appendix E's weights, the forward pass and one
back-propagation step by hand, the gradient by finite differences, and the
system's one sample (learning only in contact, J^T n, context copies)."""

import dataclasses as dc
import re

import numpy as np

from drake_contact.plant.arm import FIRST_SAMPLE_S, ApplySampledUpdates, CalcSampledUpdate
import pytest
from pydrake.systems.framework import DiagramBuilder

from drake_contact.plant.arm import THESIS_Q0
from drake_contact.control.controller_model import ArmModel, ControllerModelConfig
from drake_contact.errors import ScenarioError
from drake_contact.control.nn_compensator import (
    CompensatorNetwork, NnCompensator, NnCompensatorConfig, load_initial_weights)

INPUTS = np.array([0.4561, 2e-4, -1e-3, 0.4560, 1.9e-4, -0.9e-3, 3.1, -0.4, 0.02])


def test_initial_weights_are_appendix_e():
    W, V = load_initial_weights(NnCompensatorConfig().initial_weights)
    assert W.shape == (10, 12) and V.shape == (13, 3)
    # Spot checks against the thesis's listing: w01, w3x1 (input 3 ->
    # hidden 11), v01, vx23 (hidden 12 -> output 3).
    assert W[0, 0] == -1.000e-03
    assert W[3, 10] == 1.404e-03
    assert V[0, 0] == -1.050e-03
    assert V[12, 2] == 8.905e-03


def _hand_forward(W, V, u, text=True):
    """The forward pass written out neuron by neuron."""
    offsets = [0.0, 0.01, 0.01, 0.0, 0.01, 0.01, 0.0, 0.0, 0.0]
    u = [u[i] + offsets[i] for i in range(9)]
    h = [W[0, j] + sum(W[i + 1, j] * u[i] for i in range(9)) for j in range(12)]
    s = [2.0 / (1.0 + np.exp(-hj)) - 1.0 for hj in h]
    act = s if text else h
    o = [V[0, k] + sum(V[j + 1, k] * act[j] for j in range(12)) for k in range(3)]
    R = [20.0, 10.0, 1.0]
    return [R[k] * (2.0 / (1.0 + np.exp(-o[k])) - 1.0) for k in range(3)], u, h, s, o


@pytest.mark.parametrize("layer", ["text", "appendix_e"])
def test_forward_pass_equals_a_hand_computation(layer):
    config = NnCompensatorConfig(output_layer=layer)
    net = CompensatorNetwork(config)
    W, V = load_initial_weights(config.initial_weights)
    n, _ = net.forward(CompensatorNetwork.pack(W, V), INPUTS)
    expected = _hand_forward(W, V, INPUTS, text=layer == "text")[0]
    np.testing.assert_allclose(n, expected, rtol=1e-12)


def test_one_backprop_step_equals_a_hand_computation():
    """The code's update (Appendix E lines 2113-2346), written out."""
    eta = 5e-5
    net = CompensatorNetwork(NnCompensatorConfig(learning_rate=eta))
    W, V = load_initial_weights(NnCompensatorConfig().initial_weights)
    error = np.array([4.0, -1e-3, 2e-3])
    new, n = net.train(CompensatorNetwork.pack(W, V), INPUTS, error)
    W_new, V_new = CompensatorNetwork.unpack(new)

    n_hand, u, h, s, o = _hand_forward(W, V, INPUTS)
    np.testing.assert_allclose(n, n_hand, rtol=1e-12)
    R = [20.0, 10.0, 1.0]
    # Slopes as the code writes them (st1d, sh1d): d n_k/d o_k and d sigma/d h.
    slope_o = [R[k] * 2 * np.exp(-o[k]) / (1 + np.exp(-o[k])) ** 2 for k in range(3)]
    slope_h = [2 * np.exp(-hj) / (1 + np.exp(-hj)) ** 2 for hj in h]
    delta = [error[k] * slope_o[k] for k in range(3)]
    for j in range(13):
        act = 1.0 if j == 0 else s[j - 1]
        for k in range(3):
            assert V_new[j, k] == pytest.approx(V[j, k] + eta * delta[k] * act, rel=1e-12)
    for j in range(12):
        back = sum(delta[k] * V[j + 1, k] for k in range(3)) * slope_h[j]
        for i in range(10):
            ui = 1.0 if i == 0 else u[i - 1]
            assert W_new[i, j] == pytest.approx(W[i, j] + eta * back * ui, rel=1e-10, abs=1e-18)


def test_gradient_matches_finite_differences():
    """The step is -eta dE/dw for E = 1/2 |target - n|^2 (plant Jacobian +1),
    checked on random weights large enough to leave the linear region."""
    eta = 1e-4
    net = CompensatorNetwork(NnCompensatorConfig(learning_rate=eta))
    w = np.random.default_rng(0).normal(0, 0.3, CompensatorNetwork.size)
    u = INPUTS * np.array([1, 100, 100, 1, 100, 100, 0.3, 1, 10])
    target = np.array([5.0, -2.0, 0.3])
    n0 = net.forward(w, u)[0]

    def loss(weights):
        return 0.5 * np.sum((target - net.forward(weights, u)[0]) ** 2)

    new, _ = net.train(w, u, target - n0)
    grad = (w - new) / eta
    eps = 1e-6
    fd = np.array([(loss(w + eps * e) - loss(w - eps * e)) / (2 * eps)
                   for e in np.eye(len(w))])
    np.testing.assert_allclose(grad, fd, rtol=1e-5, atol=1e-8)


def _sample(system, context):
    """The compensator's discrete state after the sample at the context's time."""
    law = system.GetSubsystemByName("law")
    return CalcSampledUpdate(law, law.GetMyContextFromRoot(context))


def _system_context(config, mode, force, force_desired=20.0):
    system = NnCompensator(config)
    context = system.CreateDefaultContext()
    context.SetTime(FIRST_SAMPLE_S)  # the first sample instant
    q = np.array(THESIS_Q0)
    pose = np.array([0.456, 1e-3, -2e-3])
    system.GetInputPort("tip_pose").FixValue(context, pose)
    J = ArmModel(ControllerModelConfig()).evaluate(q, np.zeros(3))[1]
    system.GetInputPort("tip_jacobian").FixValue(context, J.ravel())
    system.GetInputPort("hybrid_torque").FixValue(context, INPUTS[6:])
    system.GetInputPort("force").FixValue(context, [force])
    system.GetInputPort("force_desired").FixValue(context, [force_desired])
    system.GetInputPort("mode").FixValue(context, [mode])
    return system, context, q, pose


def test_system_sample_in_contact_learns_and_outputs_jt_n():
    config = NnCompensatorConfig(learning_rate=5e-5)
    system, context, q, pose = _system_context(config, mode=1, force=15.0)
    weights = context.get_discrete_state(0).value().copy()
    # The previous pose is the state (zero at start); the inputs use it.
    update = _sample(system, context)
    net = CompensatorNetwork(config)
    inputs = np.concatenate([pose, np.zeros(3), INPUTS[6:]])
    expected_weights, n = net.train(weights, inputs, np.array([5.0, -1e-3, 2e-3]))
    np.testing.assert_allclose(update.get_vector(0).value(), expected_weights, rtol=1e-12)
    np.testing.assert_allclose(update.get_vector(1).value(), pose)   # next previous pose
    J = ArmModel(ControllerModelConfig()).evaluate(q, np.zeros(3))[1]
    # Held outputs [J^T n, n], also this sample's output ports.
    np.testing.assert_allclose(update.get_vector(2).value()[:3], J.T @ n, rtol=1e-9)
    np.testing.assert_allclose(update.get_vector(2).value()[3:], n)
    np.testing.assert_allclose(system.GetOutputPort("joint_torque").Eval(context), J.T @ n,
                               rtol=1e-9)
    np.testing.assert_allclose(system.GetOutputPort("nn_output").Eval(context), n)


def test_reference_model_sets_the_force_error_the_network_learns_from():
    tau = 0.05
    a = np.exp(-0.001 / tau)
    config = NnCompensatorConfig(learning_rate=5e-5, reference_time_constant_s=tau)
    system, context, q, pose = _system_context(config, mode=1, force=15.0)
    net = CompensatorNetwork(config)
    inputs = np.concatenate([pose, np.zeros(3), INPUTS[6:]])
    # First sample in contact: f_m starts at the measured force, one lag step
    # towards f_d = 20 N.
    weights = context.get_discrete_state(0).value().copy()
    update = _sample(system, context)
    f_m = a * 15.0 + (1 - a) * 20.0
    expected, _ = net.train(weights, inputs, np.array([f_m - 15.0, -1e-3, 2e-3]))
    np.testing.assert_allclose(update.get_vector(0).value(), expected, rtol=1e-12)
    np.testing.assert_allclose(update.get_vector(3).value(), [f_m], rtol=1e-15)
    # The next sample, at 16 N: f_m lags on from the stored value.
    ApplySampledUpdates(system, context)
    system.GetInputPort("force").FixValue(context, [16.0])
    weights = context.get_discrete_state(0).value().copy()
    update = _sample(system, context)
    f_m2 = a * f_m + (1 - a) * 20.0
    inputs[3:6] = pose  # the previous pose is now this one
    expected, _ = net.train(weights, inputs, np.array([f_m2 - 16.0, -1e-3, 2e-3]))
    np.testing.assert_allclose(update.get_vector(0).value(), expected, rtol=1e-12)
    # Out of contact it is forgotten (the next contact starts from its force).
    ApplySampledUpdates(system, context)
    system.GetInputPort("mode").FixValue(context, [0.0])
    assert np.isnan(_sample(system, context).get_vector(3).value()[0])


def test_system_is_silent_and_does_not_learn_in_approach():
    system, context, _, pose = _system_context(NnCompensatorConfig(), mode=0, force=2.0)
    weights = context.get_discrete_state(0).value().copy()
    update = _sample(system, context)
    np.testing.assert_array_equal(update.get_vector(0).value(), weights)
    np.testing.assert_array_equal(update.get_vector(2).value(), np.zeros(6))
    np.testing.assert_array_equal(update.get_vector(1).value(), pose)


def test_learning_off_keeps_the_weights_and_still_compensates():
    config = NnCompensatorConfig(learning=False)
    system, context, _, _ = _system_context(config, mode=1, force=15.0)
    weights = context.get_discrete_state(0).value().copy()
    update = _sample(system, context)
    np.testing.assert_array_equal(update.get_vector(0).value(), weights)
    assert np.any(update.get_vector(2).value()[3:] != 0)


def test_a_copied_context_carries_what_was_learned():
    system, context, _, _ = _system_context(NnCompensatorConfig(), mode=1, force=10.0)
    ApplySampledUpdates(system, context)
    copy = context.Clone()
    np.testing.assert_array_equal(copy.get_discrete_state(0).value(),
                                  context.get_discrete_state(0).value())
    assert _sample(system, copy).get_vector(0).value()[0] == \
        _sample(system, context).get_vector(0).value()[0]


@pytest.mark.parametrize("change,field", [
    ({"learning_rate": -1e-5}, "controller.nn.learning_rate"),
    ({"output_layer": "hidden"}, "controller.nn.output_layer"),
    ({"output_half_ranges": [20.0, 10.0]}, "controller.nn.output_half_ranges"),
    ({"initial_weights": "nn/missing.yaml"}, "controller.nn.initial_weights"),
])
def test_bad_settings_name_the_field(change, field):
    with pytest.raises(ScenarioError, match=field.replace(".", r"\.")):
        dc.replace(NnCompensatorConfig(), **change).validate()


def test_malformed_weights_file_is_refused(tmp_path):
    bad = tmp_path / "weights.yaml"
    bad.write_text("input_to_hidden: [[1, 2], [3, 4]]\nhidden_to_output: [[1, 2, 3]]\n")
    with pytest.raises(ScenarioError, match=r"must be \(10, 12\) and \(13, 3\)"):
        load_initial_weights(str(bad))


def test_nn_diagram_builds_and_logs_the_compensator():
    """The nn controller wires tau_h + J^T n; before contact n is zero."""
    from drake_contact.diagram import MakeContactDiagram
    from drake_contact.scenario import load_scenario
    builder = DiagramBuilder()
    diagram = builder.AddSystem(MakeContactDiagram(load_scenario("nn_styrofoam")))
    assert diagram.HasOutputPort("nn_output") and diagram.HasOutputPort("hybrid_torque")


def _former_train(net, weights, inputs, error):
    """The network's step as plain array expressions, without the
    preallocated buffers: the reference, bit for bit."""
    def sigma(s):
        return 2.0 / (1.0 + np.exp(-s)) - 1.0
    W, V = CompensatorNetwork.unpack(weights)
    u1 = np.concatenate([[1.0], inputs + net.offsets])
    h = u1 @ W
    s_h = sigma(h)
    o = np.concatenate([[1.0], s_h if net.text_output else h]) @ V
    n = net.R * sigma(o)
    delta = error * net.R * 0.5 * (1.0 - (n / net.R) ** 2)
    back = (V[1:] @ delta) * 0.5 * (1.0 - s_h ** 2)
    V_new = V + net.eta * np.outer(np.concatenate([[1.0], s_h]), delta)
    W_new = W + net.eta * np.outer(u1, back)
    return CompensatorNetwork.pack(W_new, V_new), n, (u1, h, s_h, o)


@pytest.mark.parametrize("layer", ["text", "appendix_e"])
@pytest.mark.filterwarnings("ignore:overflow encountered in exp")
def test_train_and_forward_are_bit_identical_to_the_array_expressions(layer):
    rng = np.random.default_rng(13)
    net = CompensatorNetwork(NnCompensatorConfig(output_layer=layer, learning_rate=1e-3))
    for _ in range(300):
        weights = rng.normal(0, rng.choice([0.01, 0.3, 3.0]), CompensatorNetwork.size)
        inputs = INPUTS * rng.normal(1, rng.choice([0.1, 10.0]), 9)
        error = rng.normal(0, 5, 3)
        expected, n_expected, intermediates = _former_train(net, weights, inputs, error)
        new, n = net.train(weights, inputs, error)
        np.testing.assert_array_equal(new, expected)
        np.testing.assert_array_equal(n, n_expected)
        n, parts = net.forward(weights, inputs)
        np.testing.assert_array_equal(n, n_expected)
        for part, part_expected in zip(parts, intermediates):
            np.testing.assert_array_equal(part, part_expected)


ERROR = np.array([5.0, -1e-3, 2e-3])


def _thesis_step(config):
    """(weights, thesis step g = w_new - w at this sample, eta, u1, s1)."""
    net = CompensatorNetwork(dc.replace(config, leakage=0.0, e_modification=0.0,
                                        dead_zone_n=0.0, normalized=False, weight_bound=0.0))
    W, V = load_initial_weights(config.initial_weights)
    w = CompensatorNetwork.pack(W, V) + 0.01 * np.sin(np.arange(CompensatorNetwork.size))
    new, _ = net.train(w, INPUTS, ERROR)
    u1, _, s, _ = net.forward(w, INPUTS)[1]
    return w, new - w, config.learning_rate, u1, np.concatenate([[1.0], s])


@pytest.mark.parametrize("field,value", [("leakage", 0.5), ("e_modification", 0.2)])
def test_leakage_and_e_modification_pull_towards_the_initial_weights(field, value):
    """sigma-mod: w + g - eta sigma (w - w0); e-mod: sigma = nu |e|."""
    config = dc.replace(NnCompensatorConfig(learning_rate=5e-5), **{field: value})
    w, g, eta, _, _ = _thesis_step(config)
    w0 = CompensatorNetwork.pack(*load_initial_weights(config.initial_weights))
    sigma = value if field == "leakage" else value * np.linalg.norm(ERROR)
    new, _ = CompensatorNetwork(config).train(w, INPUTS, ERROR)
    np.testing.assert_allclose(new, w + g - eta * sigma * (w - w0), rtol=1e-12, atol=1e-15)


def test_dead_zone_holds_the_weights_inside_and_steps_outside():
    w, g, _, _, _ = _thesis_step(NnCompensatorConfig())
    inside = CompensatorNetwork(NnCompensatorConfig(dead_zone_n=5.0))
    np.testing.assert_array_equal(inside.train(w, INPUTS, ERROR)[0], w)   # |e_f| = 5 N
    outside = CompensatorNetwork(NnCompensatorConfig(dead_zone_n=4.9))
    np.testing.assert_allclose(outside.train(w, INPUTS, ERROR)[0], w + g, rtol=1e-12)


def test_normalized_gradient_divides_eta_by_one_plus_the_regressor_norms():
    w, g, _, u1, s1 = _thesis_step(NnCompensatorConfig())
    new, _ = CompensatorNetwork(NnCompensatorConfig(normalized=True)).train(w, INPUTS, ERROR)
    np.testing.assert_allclose(new, w + g / (1.0 + u1 @ u1 + s1 @ s1), rtol=1e-10)


def test_projection_keeps_the_weights_within_the_bound_of_the_initial_ones():
    config = NnCompensatorConfig(learning_rate=0.5, weight_bound=0.05)
    w0 = CompensatorNetwork.pack(*load_initial_weights(config.initial_weights))
    w, g, _, _, _ = _thesis_step(config)   # |w + g - w0| far above 0.05 at this rate
    new, _ = CompensatorNetwork(config).train(w, INPUTS, ERROR)
    offset = w + g - w0
    assert np.linalg.norm(offset) > 0.05
    np.testing.assert_allclose(new, w0 + offset * 0.05 / np.linalg.norm(offset), rtol=1e-10)
    assert np.linalg.norm(new - w0) == pytest.approx(0.05, rel=1e-12)


@pytest.mark.parametrize("field,value,message", [
    ("leakage", -1.0, "must be >= 0"), ("dead_zone_n", float("nan"), "must be >= 0"),
    ("weight_bound", -0.1, "must be >= 0"), ("leakage", 3e4, "learning_rate * leakage"),
    ("reference_time_constant_s", -0.05, "must be >= 0")])
def test_robust_options_are_validated(field, value, message):
    with pytest.raises(ScenarioError, match=rf"controller\.nn\.{field} = .* {re.escape(message)}"):
        dc.replace(NnCompensatorConfig(), **{field: value}).validate()
