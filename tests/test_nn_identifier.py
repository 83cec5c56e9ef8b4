"""The 3-4-1 identifier network: gradient against finite differences,
learning a linear environment, probing."""

import numpy as np

from drake_contact.plant.arm import CalcSampledUpdate
import pytest

from drake_contact.identification.nn_identifier import ImpedanceNetwork, NnIdentifierConfig


def test_gradient_step_matches_finite_differences():
    net = ImpedanceNetwork(NnIdentifierConfig(learning_rate=1e-4))
    w = net.initial_weights(3)
    x, f = np.array([1.5e-3, -0.02, 0.7]), 12.0

    def loss(weights):
        return 0.5 * (f - net.forward(weights, x)[0]) ** 2

    new, _ = net.train(w, x, f)
    grad = (w - new) / 1e-4
    eps = 1e-6
    fd = np.array([(loss(w + eps * e) - loss(w - eps * e)) / (2 * eps) for e in np.eye(len(w))])
    np.testing.assert_allclose(grad, fd, rtol=1e-5, atol=1e-7)


def test_learns_a_linear_environment_and_probes_its_stiffness():
    """Train on f = K x + B v + M a with rich inputs; the probed K_e comes
    within 10 % (the network is not linear, only near the probe point)."""
    config = NnIdentifierConfig(learning_rate=1e-3)
    net = ImpedanceNetwork(config)
    w = net.initial_weights(0)
    rng = np.random.default_rng(1)
    K, B, M = 7000.0, 80.0, 0.05
    for _ in range(40000):
        x = np.array([rng.uniform(0, 3e-3), rng.uniform(-0.02, 0.02), rng.uniform(-1, 1)])
        w, _ = net.train(w, x, K * x[0] + B * x[1] + M * x[2])
    M_e, B_e, K_e = net.impedance(w)
    assert K_e == pytest.approx(K, rel=0.1)
    assert B_e == pytest.approx(B, rel=0.3)


def _fixed_context(system, force, x, t_contact=1.0, x_switch=0.4):
    context = system.CreateDefaultContext()
    system.GetInputPort("force").FixValue(context, [force])
    system.GetInputPort("tip_pose").FixValue(context, [x_switch + x[0], 0.0, 0.0])
    system.GetInputPort("tip_velocity").FixValue(context, [x[1], 0.0, 0.0])
    system.GetInputPort("tip_acceleration").FixValue(context, [x[2], 0.0, 0.0])
    system.GetInputPort("contact_info").FixValue(context, [t_contact, x_switch, 0.0, 0.0])
    return context


@pytest.mark.parametrize("force_offset", [False, True])
def test_system_step_trains_on_the_force_less_the_switch_force(force_offset):
    """One 1 ms sample of the system equals one ImpedanceNetwork.train step on
    f (the thesis) or on f - f_s (force_offset, f_s = the first force read);
    nothing happens before the switch."""
    from drake_contact.identification.nn_identifier import NnIdentifier
    config = NnIdentifierConfig(force_offset=force_offset)
    system = NnIdentifier(config, seed=4)
    net = ImpedanceNetwork(config)
    x = np.array([1e-3, 0.01, 0.5])
    context = _fixed_context(system, 12.0, x)
    w0 = context.get_discrete_state(0).value().copy()
    state = CalcSampledUpdate(system, context)
    f_s = 12.0 if force_offset else 0.0
    expected, f_hat = net.train(w0, x, 12.0 - f_s)
    np.testing.assert_allclose(state.get_vector(0).value(), expected, rtol=1e-12)
    np.testing.assert_allclose(state.get_vector(1).value(), net.impedance(expected), rtol=1e-12)
    assert state.get_vector(2).value()[0] == pytest.approx(f_hat + f_s)
    assert list(state.get_vector(3).value()) == [1.0, f_s]
    before = _fixed_context(system, 12.0, x, t_contact=-1.0)
    untouched = CalcSampledUpdate(system, before)
    np.testing.assert_array_equal(untouched.get_vector(0).value(), w0)


def _former_train(net, weights, x, f):
    """The network's step and probes as the plain array expressions they
    were first written as (before issue 13's buffers): the reference, bit
    for bit."""
    c = net.c

    def forward(weights, x):
        W, v = weights[:16].reshape(4, 4), weights[16:]
        u = np.concatenate([[1.0], net.scale * x])
        hidden = 2.0 / (1.0 + np.exp(-(W @ u))) - 1.0
        return c.output_scale_n * (v[0] + v[1:] @ hidden), u, hidden

    W, v = weights[:16].reshape(4, 4), weights[16:]
    f_hat, u, hidden = forward(weights, x)
    e = f - f_hat
    S, eta = c.output_scale_n, c.learning_rate
    grad_v = -e * S * np.concatenate([[1.0], hidden])
    grad_W = np.outer(-e * S * v[1:] * 0.5 * (1.0 - hidden**2), u)
    new = np.concatenate([(W - eta * grad_W).ravel(), v - eta * grad_v])
    xs, vs, acc = c.probe
    f_x = forward(new, np.array([xs, 0.0, 0.0]))[0]
    f_xv = forward(new, np.array([xs, vs, 0.0]))[0]
    f_xva = forward(new, np.array([xs, vs, acc]))[0]
    probed = np.array([(f_xva - f_xv) / acc, (f_xv - f_x) / vs, f_x / xs])
    return new, f_hat, probed, (u, hidden)


@pytest.mark.filterwarnings("ignore:overflow encountered in exp")
def test_train_and_probes_are_bit_identical_to_the_array_expressions():
    rng = np.random.default_rng(13)
    net = ImpedanceNetwork(NnIdentifierConfig(learning_rate=1e-3, input_scale=[1e4, 100.0, 1.0],
                                              probe=[2e-4, 1e-2, 0.5]))
    for _ in range(300):
        weights = rng.normal(0, rng.choice([0.3, 3.0]), ImpedanceNetwork.size)
        x = rng.normal(0, [1e-3, 1e-2, 1.0])
        f = rng.normal(10.0, 5.0)
        expected, f_hat_expected, probed, (u, hidden) = _former_train(net, weights, x, f)
        new, f_hat = net.train(weights, x, f)
        np.testing.assert_array_equal(new, expected)
        assert f_hat == f_hat_expected
        np.testing.assert_array_equal(net.impedance(new), probed)
        f_hat, u_new, hidden_new = net.forward(weights, x)
        assert f_hat == f_hat_expected
        np.testing.assert_array_equal(u_new, u)
        np.testing.assert_array_equal(hidden_new, hidden)
