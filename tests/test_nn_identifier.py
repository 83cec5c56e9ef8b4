"""The 3-4-1 identifier network: gradient against finite differences,
learning a linear environment, probing."""

import numpy as np
import pytest

from drake_contact.nn_identifier import ImpedanceNetwork, NnIdentifierConfig


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
    config = NnIdentifierConfig(learning_rate=1e-3, probe_from_zero=True)
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
