"""The identifier network with Appendix E's output layer (issue 16)."""

import numpy as np
import pytest

from drake_contact.errors import ScenarioError
from drake_contact.identification.nn_identifier import (
    AppendixEImpedanceNetwork, ImpedanceNetwork, NnIdentifierConfig, make_network)


def test_output_layer_is_validated_and_linear_by_default():
    assert type(make_network(NnIdentifierConfig())) is ImpedanceNetwork
    assert type(make_network(NnIdentifierConfig(output_layer="appendix_e"))) is \
        AppendixEImpedanceNetwork
    with pytest.raises(ScenarioError, match=r"identifiers\[0\]\.nn\.output_layer"):
        NnIdentifierConfig(output_layer="sigmoid").validate("identifiers[0].nn")


def _sigma(s):
    return 2.0 / (1.0 + np.exp(-s)) - 1.0


def test_appendix_e_output_layer_one_step_by_hand():
    """Forward on the pre-activations, output a sigmoid of +-S, and the
    update written out as the code's loops (Appendix E: st1d, sh_d, cr_j,
    w_ij -= alf cr_j sh_jd iv_i, v_j -= alf dif st1d sh_j, alf = -eta)."""
    config = NnIdentifierConfig(learning_rate=1e-3, output_layer="appendix_e")
    net = AppendixEImpedanceNetwork(config)
    w = net.initial_weights(2)
    x, f = np.array([1.2e-3, 0.01, -0.4]), 9.0
    W, v = w[:16].reshape(4, 4), w[16:]
    u = np.concatenate([[1.0], np.array(config.input_scale) * x])
    h = W @ u
    t = v[0] + v[1:] @ h
    S = config.output_scale_n
    f_hat = S * _sigma(t)
    dif = f - f_hat
    st_d = 2 * S * np.exp(-t) / (1 + np.exp(-t)) ** 2
    sh_d = 2 * np.exp(-h) / (1 + np.exp(-h)) ** 2
    cr = dif * st_d * v[1:]
    alf = -config.learning_rate
    W_new = W - alf * np.outer(cr * sh_d, u)
    v_new = v - alf * dif * st_d * np.concatenate([[1.0], _sigma(h)])
    new, estimate = net.train(w, x, f)
    assert estimate == pytest.approx(f_hat, rel=1e-12)
    np.testing.assert_allclose(new, np.concatenate([W_new.ravel(), v_new]), rtol=1e-12)
    # The probe: K_e = f_hat(x*, 0, 0) / x* on the same forward pass.
    xs = config.probe[0]
    u_probe = np.concatenate([[1.0], np.array(config.input_scale) * [xs, 0.0, 0.0]])
    assert net.impedance(w)[2] == pytest.approx(
        S * _sigma(v[0] + v[1:] @ (W @ u_probe)) / xs, rel=1e-12)
