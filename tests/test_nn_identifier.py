"""The 3-4-1 identifier network: gradient against finite differences,
learning a linear environment, probing."""

import dataclasses as dc

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
    """The network's step and probes as plain array expressions, without
    the preallocated buffers: the reference, bit for bit."""
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


# The self-scaling network (nn_auto): normalization running, readouts at
# the current operating point.

def _running_config(**kwargs):
    return NnIdentifierConfig(normalization="running", readout="jacobian", learning_rate=0.1,
                              **kwargs)


def test_running_scales_step_and_jacobian_against_a_hand_computation():
    """W = 0 and v = (0.25, 0.4, 0.4, 0.4, 0.4): the hidden layer is 0, so
    f_hat = s_f v_0 and one step moves v_0 by eta e and each W row by
    eta e v_k / 2 [1, u]."""
    net = ImpedanceNetwork(_running_config())
    weights = np.concatenate([np.zeros(16), [0.25, 0.4, 0.4, 0.4, 0.4]])
    x, f = np.array([2e-3, -0.01, 0.5]), 8.0
    scales = net.update_scales(np.array([1e-6, 1e-4, 1e-2, 0.1]), x, f)
    np.testing.assert_array_equal(scales, [2e-3, 0.01, 0.5, 8.0])
    # A smaller sample leaves the scales alone; a floor stays a floor.
    np.testing.assert_array_equal(net.update_scales(scales, x / 2, -4.0), scales)
    np.testing.assert_array_equal(net.update_scales([1e-6, 1e-4, 1e-2, 0.1], [0, 0, 0], 0.0),
                                  [1e-6, 1e-4, 1e-2, 0.1])
    new, f_hat = net.train_scaled(weights, x, f, scales)
    assert f_hat == pytest.approx(8.0 * 0.25)
    e = (8.0 - 2.0) / 8.0                             # 0.75, normalized by s_f
    u = np.array([1.0, 1.0, -1.0, 1.0])               # [1, x / s]
    expected_W = np.tile(0.1 * e * 0.4 * 0.5 * u, (4, 1))  # 0.015 [1, 1, -1, 1]
    np.testing.assert_allclose(new[:16].reshape(4, 4), expected_W, rtol=1e-14)
    np.testing.assert_allclose(new[16:], [0.25 + 0.1 * e, 0.4, 0.4, 0.4, 0.4], rtol=1e-14)
    # Jacobian at x: every pre-activation is 0.015 * 4 = 0.06, f(0.06) = tanh(0.03).
    h = np.tanh(0.03)
    d_u = 4 * 0.4 * 0.5 * (1 - h * h) * 0.015 * np.array([1.0, -1.0, 1.0])
    M_e, B_e, K_e = net.jacobian(new, x, scales)
    np.testing.assert_allclose([K_e, B_e, M_e], 8.0 * d_u / scales[:3], rtol=1e-12)
    assert K_e == pytest.approx(8.0 * 0.012 * (1 - h * h) / 2e-3)   # about 48 N/m


@pytest.mark.parametrize("seed", range(4))
def test_jacobian_readout_matches_finite_differences(seed):
    rng = np.random.default_rng(seed)
    net = ImpedanceNetwork(_running_config())
    weights = rng.normal(0.0, 1.0, ImpedanceNetwork.size)
    scales = np.array([rng.uniform(1e-4, 5e-3), rng.uniform(1e-3, 0.05),
                       rng.uniform(0.1, 3.0), rng.uniform(5.0, 30.0)])
    x = rng.uniform(-1, 1, 3) * scales[:3]
    jacobian = net.jacobian(weights, x, scales)
    fd = []
    for i in range(3):
        step = 1e-6 * scales[i]
        dx = np.zeros(3)
        dx[i] = step
        fd.append((net.forward_scaled(weights, x + dx, scales)[0]
                   - net.forward_scaled(weights, x - dx, scales)[0]) / (2 * step))
    np.testing.assert_allclose(jacobian, fd[::-1], rtol=1e-6)


def test_operating_point_readout_probes_at_the_current_displacement_and_the_scales():
    """Secants at x* = xe (its floor at 0), v* = s_v, a* = s_a; a network
    that is linear near the origin reads its slopes."""
    net = ImpedanceNetwork(NnIdentifierConfig(normalization="running",
                                              readout="operating_point"))
    # One hidden unit in its linear range: f_hat ~ s_f v_1 (a . u) / 2.
    weights = np.zeros(ImpedanceNetwork.size)
    weights[4:8] = [0.0, 1e-3, 2e-3, 3e-3]             # W row 1: [bias, u_x, u_v, u_a]
    weights[18] = 1.0                                  # v_1
    scales = np.array([1e-3, 0.02, 1.0, 10.0])
    M_e, B_e, K_e = net.operating_point(weights, [5e-4, 0.0, 0.0], scales)
    # f(h) = tanh(h / 2) departs from h / 2 by h^2 / 12 relative: < 1e-5 here.
    assert K_e == pytest.approx(10.0 * 1e-3 / 2 / 1e-3, rel=1e-5)    # 5 N/m
    assert B_e == pytest.approx(10.0 * 2e-3 / 2 / 0.02, rel=1e-5)
    assert M_e == pytest.approx(10.0 * 3e-3 / 2 / 1.0, rel=1e-5)

    def f_hat(p):
        return net.forward_scaled(weights, np.array(p), scales)[0]
    floor = net.c.scale_floor[0]
    at_zero = net.operating_point(weights, [0.0, 0.01, 0.3], scales)
    assert at_zero[2] == f_hat([floor, 0, 0]) / floor
    assert at_zero[1] == (f_hat([floor, 0.02, 0]) - f_hat([floor, 0, 0])) / 0.02


@pytest.mark.parametrize("readout", ["jacobian", "operating_point"])
def test_running_system_step_updates_scales_weights_and_readout(readout):
    from drake_contact.identification.nn_identifier import NnIdentifier
    config = NnIdentifierConfig(normalization="running", readout=readout, force_offset=True,
                                learning_rate=0.05)
    system = NnIdentifier(config, seed=4)
    net = ImpedanceNetwork(config)
    x = np.array([1e-3, 0.01, 0.5])
    context = _fixed_context(system, 12.0, x)
    x[0] = (0.4 + 1e-3) - 0.4                          # xe as the system computes it
    w0 = context.get_discrete_state(0).value().copy()
    state = CalcSampledUpdate(system, context)
    # The first sample: f_s = 12 N, so the network trains on 0 N.
    scales = net.update_scales(np.array(config.scale_floor), x, 0.0)
    expected, f_hat = net.train_scaled(w0, x, 0.0, scales)
    np.testing.assert_array_equal(state.get_vector(4).value(), scales)
    np.testing.assert_array_equal(state.get_vector(0).value(), expected)
    readout_of = net.jacobian if readout == "jacobian" else net.operating_point
    np.testing.assert_array_equal(state.get_vector(1).value(), readout_of(expected, x, scales))
    assert state.get_vector(2).value()[0] == pytest.approx(f_hat + 12.0)


@pytest.mark.parametrize("field,value,message", [
    ("normalization", "rms", "identifiers[0].nn.normalization = 'rms' is unknown: choose one "
                             "of fixed, running"),
    ("readout", "secant", "identifiers[0].nn.readout = 'secant' is unknown: choose one of "
                          "probe, operating_point, jacobian"),
    ("readout", "jacobian", "identifiers[0].nn.readout = 'jacobian' needs "
                            "identifiers[0].nn.normalization = 'running'"),
    ("scale_floor", [1e-6, 0.0, 1e-2, 0.1], "identifiers[0].nn.scale_floor = [1e-06, 0.0, "
                                            "0.01, 0.1] is out of range: must be 4 finite "
                                            "values > 0"),
    ("scale_floor", [1e-6, 1e-4, 1e-2], "identifiers[0].nn.scale_floor = [1e-06, 0.0001, "
                                        "0.01] is out of range"),
])
def test_bad_self_scaling_fields_name_the_field_and_the_range(field, value, message):
    from drake_contact.errors import ScenarioError
    from drake_contact.scenario import load_scenario
    with pytest.raises(ScenarioError) as error:
        load_scenario({"identifiers": [{"name": "auto", "kind": "nn",
                                        "nn": {field: value}}]})
    assert message in str(error.value)


@pytest.mark.parametrize("stiffness,damping", [(7000.0, 100.0), (100000.0, 30.0)])
def test_self_scaling_identifier_meets_the_10_percent_bar_at_1_s_in_closed_loop(
        tmp_path, stiffness, damping):
    """The self-scaling network's bar on two grid points (seed 0): nn_auto,
    with the same settings on both walls, has K_e within 10 % 1 s after
    contact (8-9.1 s); the run stops shortly after."""
    from drake_contact.app.runner import run
    from drake_contact.scenario import load_scenario
    scenario = load_scenario("identify_any", [f"environment.stiffness={stiffness}",
                                              f"environment.damping={damping}"],
                             duration=10.4, seed=0)
    m = run(scenario, tmp_path, figures=False).metrics
    assert m["contact_time_s"] < 9.4                   # so the 1 s sample is in the run
    assert abs(m["identification_error_1s_nn_auto"]["stiffness"]) < 0.10


def test_averaged_readout_is_the_weighted_least_squares_of_the_secants():
    """Two samples by hand: sums decay by d and add step * rise and
    step^2; the readout is their ratio, so a secant with a tiny step (the
    first samples after the switch) hardly moves it."""
    sums = np.zeros(6)
    d = np.exp(-1e-3 / 0.5)
    sums, first = ImpedanceNetwork.average_secants(
        sums, np.array([0.2, 1.5, 1e-3]), np.array([1.0, 0.01, 1e-6]), d)
    np.testing.assert_allclose(first, [0.2, 150.0, 1000.0], rtol=1e-15)   # one sample: its secants
    sums, second = ImpedanceNetwork.average_secants(
        sums, np.array([0.4, 1.0, 10.0]), np.array([1.0, 0.01, 1e-3]), d)
    np.testing.assert_array_equal(
        sums, [d * 0.2 + 0.4, d * 0.015 + 0.01, d * 1e-9 + 1e-2,
               d + 1.0, d * 1e-4 + 1e-4, d * 1e-12 + 1e-6])
    assert second[0] == pytest.approx((0.2 * d + 0.4) / (d + 1.0), rel=1e-15)
    assert second[1] == pytest.approx((0.015 * d + 0.01) / (1e-4 * (d + 1.0)), rel=1e-15)
    # K_e: the wild 1000 N/m secant at 1 um weighs 1e-6 of the 10 kN/m one at 1 mm.
    assert second[2] == pytest.approx(1e4 * (1 + d * 1e-7) / (1 + d * 1e-6), rel=1e-12)
    assert second[2] == pytest.approx(1e4, rel=1e-5)


def test_running_system_averages_its_readout_over_samples():
    """The system's update with readout_time_constant_s: the sums in the
    state, the output their ratio; equal to the per-sample readout on the
    first sample and to the hand-weighted mean of the two on the second."""
    from drake_contact.identification.nn_identifier import NnIdentifier
    config = NnIdentifierConfig(normalization="running", readout="operating_point",
                                force_offset=True, learning_rate=0.05,
                                readout_time_constant_s=0.5)
    system = NnIdentifier(config, seed=4)
    net = ImpedanceNetwork(config)
    x = np.array([1e-3, 0.01, 0.5])
    context = _fixed_context(system, 12.0, x)
    x[0] = (0.4 + 1e-3) - 0.4
    first = CalcSampledUpdate(system, context)
    sums_index = first.num_groups() - 1
    scales = first.get_vector(4).value()
    weights = first.get_vector(0).value()
    rises, steps = net.secants(weights, x, scales)
    np.testing.assert_array_equal(first.get_vector(sums_index).value(),
                                  np.concatenate([steps * rises, steps * steps]))
    np.testing.assert_allclose(first.get_vector(1).value(),
                               net.operating_point(weights, x, scales), rtol=1e-14)
    context.SetDiscreteState(first)
    second = CalcSampledUpdate(system, context)
    rises2, steps2 = net.secants(second.get_vector(0).value(), x,
                                 second.get_vector(4).value())
    d = np.exp(-1e-3 / 0.5)
    expected = ((d * steps * rises + steps2 * rises2) / (d * steps**2 + steps2**2))
    np.testing.assert_allclose(second.get_vector(1).value(), expected, rtol=1e-14)


@pytest.mark.parametrize("nn,message", [
    ({"readout_time_constant_s": -1.0},
     "identifiers[0].nn.readout_time_constant_s = -1.0 is out of range: must be in [0, 100] s"),
    ({"normalization": "running", "readout": "jacobian", "readout_time_constant_s": 0.5},
     "identifiers[0].nn.readout_time_constant_s = 0.5 needs identifiers[0].nn.readout = "
     "'operating_point'"),
])
def test_bad_readout_time_constant_names_the_field_and_the_range(nn, message):
    from drake_contact.errors import ScenarioError
    from drake_contact.scenario import load_scenario
    with pytest.raises(ScenarioError) as error:
        load_scenario({"identifiers": [{"name": "auto", "kind": "nn", "nn": nn}]})
    assert message in str(error.value)


def test_sigmoid_output_layer_is_the_texts_network_and_its_gradient():
    """The text's network (output_layer sigmoid): f_hat = S f(v . [1, f(h)]),
    one step of eqs. 4.26-4.29 by hand, and the step against finite
    differences of 1/2 (f - f_hat)^2."""
    from drake_contact.identification.nn_identifier import (
        SigmoidImpedanceNetwork, make_network)
    config = NnIdentifierConfig(learning_rate=1e-4, output_layer="sigmoid", output_scale_n=40.0)
    net = make_network(config)
    assert type(net) is SigmoidImpedanceNetwork
    w = net.initial_weights(5)
    x, f = np.array([1.2e-3, 0.01, -0.4]), 21.0
    W, v = w[:16].reshape(4, 4), w[16:]
    sigma = lambda s: 2.0 / (1.0 + np.exp(-s)) - 1.0  # noqa: E731
    u = np.concatenate([[1.0], np.array(config.input_scale) * x])
    y = sigma(W @ u)
    t = v[0] + v[1:] @ y
    f_hat = 40.0 * sigma(t)
    d = (f - f_hat) * 40.0 * (1 - sigma(t) ** 2) / 2                # e Gamma'(u_k) S
    W_new = W + 1e-4 * np.outer(d * v[1:] * (1 - y ** 2) / 2, u)     # eq. 4.28
    v_new = v + 1e-4 * d * np.concatenate([[1.0], y])                # eq. 4.29
    new, estimate = net.train(w, x, f)
    assert estimate == pytest.approx(f_hat, rel=1e-12)
    np.testing.assert_allclose(new, np.concatenate([W_new.ravel(), v_new]), rtol=1e-12)
    eps = 1e-6

    def loss(weights):
        return 0.5 * (f - net.forward(weights, x)[0]) ** 2
    fd = np.array([(loss(w + eps * e) - loss(w - eps * e)) / (2 * eps) for e in np.eye(len(w))])
    np.testing.assert_allclose((w - new) / 1e-4, fd, rtol=1e-5, atol=1e-7)
    # The probes read the same output: K_e = f_hat(x*, 0, 0) / x*.
    xs = config.probe[0]
    u_probe = np.concatenate([[1.0], np.array(config.input_scale) * [xs, 0.0, 0.0]])
    assert net.impedance(w)[2] == pytest.approx(
        40.0 * sigma(v[0] + v[1:] @ sigma(W @ u_probe)) / xs, rel=1e-12)
    # N environments: each bit for bit its own alone.
    stack = make_network([config, dc.replace(config, learning_rate=2e-5)])
    weights = np.stack([w, net.initial_weights(6)])
    new_stack, _ = stack.train(weights, np.stack([x, 2 * x]), np.array([f, 15.0]))
    alone = make_network(dc.replace(config, learning_rate=2e-5))
    assert np.array_equal(new_stack[0], new)
    assert np.array_equal(new_stack[1], alone.train(weights[1], 2 * x, 15.0)[0])


def test_an_identifiers_seed_depends_on_the_run_and_its_key_not_its_place():
    """Reordering the identifiers keeps each one's seed; the same seed_key
    starts two identifiers alike; another run seed or name differs."""
    from drake_contact.identification.identifiers import IdentifierConfig
    nn, slow = IdentifierConfig(name="nn", kind="nn"), IdentifierConfig(name="nn_slow", kind="nn")
    assert nn.seed(3) == IdentifierConfig(name="nn", kind="nn").seed(3)
    assert len({nn.seed(3), nn.seed(4), slow.seed(3)}) == 3
    shared = dc.replace(slow, seed_key="nn")
    assert shared.seed(3) == nn.seed(3)
    assert nn.factory_options(3)["seed"] == nn.seed(3)


def test_reordering_the_identifiers_changes_no_identifiers_log():
    """identify_styrofoam's networks (and RLSs) with the list reversed, alone
    and in an ensemble: each identifier's estimate is its own, bit for bit."""
    from drake_contact.scenario import load_scenario
    from drake_contact.simulation import simulate_ensemble, simulate_scenario
    scenario = load_scenario("identify_styrofoam", ["simulation.duration=9.4"])
    reordered = dc.replace(scenario, identifiers=scenario.identifiers[::-1])
    base = simulate_scenario(scenario).log
    assert np.any(base["contact_info"][:, 0] >= 0)  # the identifiers ran
    other_seed = dc.replace(reordered, simulation=dc.replace(reordered.simulation, seed=7))
    for log in (simulate_scenario(reordered).log,
                simulate_ensemble([reordered, other_seed])[0].log):
        for config in scenario.identifiers:
            assert np.array_equal(log[f"impedance_{config.name}"],
                                  base[f"impedance_{config.name}"], equal_nan=True), config.name
