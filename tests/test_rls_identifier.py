"""RLS on synthetic data: exact recovery, forgetting, the switch-point bias;
the RlsIdentifier system stepped alone with fixed inputs."""

import numpy as np

from drake_contact.plant.arm import ApplySampledUpdates
import pytest

from drake_contact.errors import ScenarioError
from drake_contact.identification.rls_identifier import RlsConfig, RlsEstimator, RlsIdentifier

TRUE = np.array([0.05, 80.0, 7000.0])
# A diffuse prior: P0 is a ridge toward theta0 of weight 1/P0, which would
# bias the exact-recovery checks at the 1e-5 level.
DIFFUSE = [1e8, 1e12, 1e18, 1e8]


def excitation(n, dt=1e-3, seed=0):
    """A rich displacement (three sines) and its exact derivatives."""
    t = np.arange(n) * dt
    w = np.array([7.0, 23.0, 61.0])
    a = np.array([1.5e-3, 0.4e-3, 0.1e-3])
    xe = 2e-3 + (a[:, None] * np.sin(w[:, None] * t)).sum(0)
    xd = (a[:, None] * w[:, None] * np.cos(w[:, None] * t)).sum(0)
    xdd = -(a[:, None] * w[:, None] ** 2 * np.sin(w[:, None] * t)).sum(0)
    return t, xe, xd, xdd


def test_noise_free_data_recovers_the_parameters_to_1e_6():
    rls = RlsEstimator(RlsConfig(p0=DIFFUSE))
    _, xe, xd, xdd = excitation(3000)
    f = TRUE[0] * xdd + TRUE[1] * xd + TRUE[2] * xe
    for k in range(len(xe)):
        theta = rls.update(xe[k], xd[k], xdd[k], f[k])
    np.testing.assert_allclose(theta, TRUE, rtol=1e-6)


def test_force_offset_option_removes_the_switch_point_bias():
    _, xe, xd, xdd = excitation(3000)
    f = TRUE[0] * xdd + TRUE[1] * xd + TRUE[2] * xe + 5.0  # 5 N at the switch point
    plain = RlsEstimator(RlsConfig(p0=DIFFUSE))
    offset = RlsEstimator(RlsConfig(p0=DIFFUSE, force_offset=True))
    for k in range(len(xe)):
        theta_plain = plain.update(xe[k], xd[k], xdd[k], f[k])
        theta_offset = offset.update(xe[k], xd[k], xdd[k], f[k])
    np.testing.assert_allclose(theta_offset[:3], TRUE, rtol=1e-6)
    assert theta_offset[3] == pytest.approx(5.0, rel=1e-6)
    assert abs(theta_plain[2] / TRUE[2] - 1) > 0.1  # the thesis's form is biased


def test_forgetting_factor_tracks_a_step_in_stiffness():
    """K_e steps from 7000 to 9000 N/m at 2 s; with lambda = 0.99 (a memory
    of about 0.1 s) the estimate is back within 5 % after 0.19 s (0.54 s at
    lambda = 0.995, 0.83 s at 0.998), as stated in docs/studies/identification.md."""
    t, xe, xd, xdd = excitation(4000)
    K = np.where(t < 2.0, 7000.0, 9000.0)
    f = TRUE[0] * xdd + TRUE[1] * xd + K * xe
    rls = RlsEstimator(RlsConfig(p0=DIFFUSE, forgetting_factor=0.99))
    k_est = np.array([rls.update(xe[k], xd[k], xdd[k], f[k])[2] for k in range(len(t))])
    within = np.abs(k_est / K - 1) < 0.05
    after = t >= 2.0
    # First time after the step from which the estimate stays within 5 %.
    outside = np.flatnonzero(after & ~within)
    settle = t[outside[-1] + 1] - 2.0 if len(outside) else 0.0
    assert settle == pytest.approx(0.19, abs=0.01)
    # Without forgetting it does not follow within a second.
    stiff = RlsEstimator(RlsConfig(p0=DIFFUSE))
    k_plain = np.array([stiff.update(xe[k], xd[k], xdd[k], f[k])[2] for k in range(len(t))])
    assert abs(k_plain[(t > 2.9) & (t < 3.0)].mean() / 9000 - 1) > 0.05


# The Drake system alone: inputs fixed, one periodic update at a time.

X_SWITCH = 0.456  # m, the tip's x at the contact switch
# The system's discrete state groups, in declaration order.
IMPEDANCE_GROUP, THETA_P_GROUP = 0, 1


def make_identifier(**fields):
    system = RlsIdentifier(RlsConfig(**fields))
    return system, system.CreateDefaultContext()


def fix_inputs(system, context, *, t_contact, xe, xd, xdd, f):
    system.GetInputPort("force").FixValue(context, [f])
    system.GetInputPort("tip_pose").FixValue(context, [X_SWITCH + xe, 0.1, 0.0])
    # y and phi channels carry junk the identifier must ignore.
    system.GetInputPort("tip_velocity").FixValue(context, [xd, -0.3, 2.0])
    system.GetInputPort("tip_acceleration").FixValue(context, [xdd, 5.0, -7.0])
    system.GetInputPort("contact_info").FixValue(context, [t_contact, X_SWITCH, 0.1, 0.0])


def step(system, context):
    ApplySampledUpdates(system, context)


def impedance(system, context):
    return system.GetOutputPort("impedance").Eval(context).copy()


def run_identifier(system, context, f_offset=0.0, steps=1000):
    _, xe, xd, xdd = excitation(steps)
    f = TRUE[0] * xdd + TRUE[1] * xd + TRUE[2] * xe + f_offset
    for k in range(steps):
        fix_inputs(system, context, t_contact=0.0, xe=xe[k], xd=xd[k], xdd=xdd[k], f=f[k])
        step(system, context)
    return impedance(system, context)


def test_stiffness_drift_adds_the_relative_random_walk_to_p_kk_only():
    """One step by hand: the plain update, then q theta_K^2 on P[K, K]."""
    theta = np.array([0.01, 50.0, 8000.0, 2.0])
    P = np.diag([1.0, 10.0, 1e4, 1.0])
    phi = np.array([0.5, 0.01, 2e-3, 1.0])
    f = 19.0
    plain_theta, plain_P = RlsEstimator.step(theta, P, phi, f, 1.0)
    theta_q, P_q = RlsEstimator.step(theta, P, phi, f, 1.0, 1e-9)
    np.testing.assert_array_equal(theta_q, plain_theta)
    expected = plain_P.copy()
    expected[2, 2] += 1e-9 * plain_theta[2] ** 2
    np.testing.assert_array_equal(P_q, expected)
    # By hand: P phi = (0.5, 0.1, 20, 1); phi' P phi = 0.25 + 0.001 + 0.04 + 1
    # = 1.291; error = 19 - (0.005 + 0.5 + 16 + 2) = 0.495.
    gain = np.array([0.5, 0.1, 20.0, 1.0]) / 2.291
    np.testing.assert_allclose(plain_theta, theta + gain * 0.495, rtol=1e-12)


def test_stiffness_drift_follows_a_drifting_stiffness_where_the_plain_fit_lags():
    """K_e ramps +20 % over 30 s on noisy data: with q = 1e-9 the estimate
    stays within 3 % of the current K_e from 1 s on; the plain RLS (which
    averages the whole run) lags by over 5 %."""
    rng = np.random.default_rng(3)
    n = 32000
    t = np.arange(n) * 1e-3
    xe = 1e-3 * (2.0 + 0.4 * np.sin(2 * np.pi * 1.7 * t))
    xd = np.gradient(xe, 1e-3)
    xdd = np.gradient(xd, 1e-3)
    K = 7000.0 * (1.0 + 0.2 * np.clip((t - 1.0) / 30.0, 0.0, 1.0))
    f = TRUE[0] * xdd + TRUE[1] * xd + K * xe + 5.0 + rng.normal(0.0, 0.5, n)
    worst = {}
    for q in (0.0, 1e-9):
        rls = RlsEstimator(RlsConfig(force_offset=True, stiffness_drift=q))
        k_est = np.array([rls.update(xe[k], xd[k], xdd[k], f[k])[2] for k in range(n)])
        worst[q] = np.abs(k_est[t >= 1.0] / K[t >= 1.0] - 1).max()
    assert worst[1e-9] < 0.03
    assert worst[0.0] > 0.05


def step_data(n=4000, step_at=2.0, seed=5):
    """Noisy samples of a wall whose K_e doubles at ``step_at`` (s)."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * 1e-3
    xe = 1e-3 * (2.0 + 0.4 * np.sin(2 * np.pi * 1.7 * t))
    xd = np.gradient(xe, 1e-3)
    xdd = np.gradient(xd, 1e-3)
    K = np.where(t < step_at, 7000.0, 14000.0)
    f = TRUE[0] * xdd + TRUE[1] * xd + K * xe + 5.0 + rng.normal(0.0, 0.5, n)
    return t, xe, xd, xdd, K, f


def test_change_detection_filters_the_prediction_error_and_resets_p_by_hand():
    """Two samples by hand: e_bar += alpha (e - e_bar), alpha = 1 ms / 50 ms;
    past the threshold (and the hold-off) P returns to diag(p0), theta stays."""
    config = RlsConfig(force_offset=True, change_threshold_n=0.5, change_holdoff_s=0.0)
    rls = RlsEstimator(config)
    rls.theta = np.array([0.0, 0.0, 7000.0, 5.0])
    rls.P = np.diag([1.0, 2.0, 3.0, 4.0])
    phi = np.array([0.0, 0.0, 1e-3, 1.0])
    # Prediction 7000 * 1e-3 + 5 = 12 N; f = 32 N, e = 20 N:
    # e_bar = 0.02 * 20 = 0.4 N, under 0.5 N.
    rls.samples = 1
    assert not rls.detect(phi, 32.0)
    assert rls.error == pytest.approx(0.4)
    np.testing.assert_array_equal(rls.P, np.diag([1.0, 2.0, 3.0, 4.0]))
    # e_bar = 0.4 + 0.02 (20 - 0.4) = 0.792 N: reset.
    rls.samples = 2
    assert rls.detect(phi, 32.0)
    np.testing.assert_array_equal(rls.P, np.diag(RlsConfig().p0))
    np.testing.assert_array_equal(rls.theta, [0.0, 0.0, 7000.0, 5.0])
    assert rls.error == 0.0 and rls.resets == [2]


def test_change_detection_follows_a_jump_the_random_walk_does_not():
    """K_e doubles at 2 s: with the reset (2 N) the estimate is within 5 %
    of the new K_e 0.5 s after the jump and resets once, just after it;
    with the random walk alone it is still far off 2 s after it."""
    t, xe, xd, xdd, K, f = step_data()
    outcomes = {}
    for threshold in (0.0, 2.0):
        rls = RlsEstimator(RlsConfig(force_offset=True, stiffness_drift=1e-9,
                                     change_threshold_n=threshold))
        k_est = np.array([rls.update(xe[k], xd[k], xdd[k], f[k])[2] for k in range(len(t))])
        outcomes[threshold] = (np.abs(k_est / K - 1), rls.resets)
    error, resets = outcomes[2.0]
    assert len(resets) == 1 and 2000 < resets[0] < 2050
    assert error[(t >= 2.5)].max() < 0.05
    assert outcomes[0.0][0][-1] > 0.2


@pytest.mark.parametrize("field, value", [("change_threshold_n", -1.0),
                                          ("change_threshold_n", float("nan")),
                                          ("change_time_constant_s", 0.0),
                                          ("change_holdoff_s", float("inf"))])
def test_change_detection_fields_are_validated(field, value):
    with pytest.raises(ScenarioError, match=rf"rls.{field} = .* is out of range"):
        RlsConfig(**{field: value}).validate("rls")


@pytest.mark.parametrize("value", [-1e-9, 2e-3, float("nan")])
def test_stiffness_drift_is_validated(value):
    with pytest.raises(ScenarioError, match=r"rls.stiffness_drift = .* is out of range"):
        RlsConfig(stiffness_drift=value).validate("rls")


def test_system_ports_and_state_sizes():
    system, context = make_identifier()
    sizes = {system.get_input_port(i).get_name(): system.get_input_port(i).size()
             for i in range(system.num_input_ports())}
    assert sizes == {"force": 1, "tip_pose": 3, "tip_velocity": 3, "tip_acceleration": 3,
                     "contact_info": 4, "force_fault": 1}
    assert system.num_output_ports() == 1
    assert system.GetOutputPort("impedance").size() == 3
    # theta (3) and P (3 x 3); with the offset theta (4) and P (4 x 4).
    assert context.get_discrete_state(THETA_P_GROUP).size() == 3 + 9
    _, offset_context = make_identifier(force_offset=True)
    assert offset_context.get_discrete_state(THETA_P_GROUP).size() == 4 + 16


def test_output_port_reads_the_state():
    system, context = make_identifier(theta0=[0.1, 20.0, 3.0e4])
    np.testing.assert_array_equal(impedance(system, context), [0.1, 20.0, 3.0e4])
    context.get_mutable_discrete_state(IMPEDANCE_GROUP).SetFromVector([1.0, 2.0, 3.0])
    np.testing.assert_array_equal(impedance(system, context), [1.0, 2.0, 3.0])


def test_estimate_holds_theta0_before_contact():
    system, context = make_identifier()
    initial = context.get_discrete_state(THETA_P_GROUP).value().copy()
    _, xe, xd, xdd = excitation(200)
    for k in range(200):
        fix_inputs(system, context, t_contact=-1.0, xe=xe[k], xd=xd[k], xdd=xdd[k],
                   f=TRUE @ [xdd[k], xd[k], xe[k]])
        step(system, context)
    np.testing.assert_array_equal(impedance(system, context), RlsConfig().theta0)
    np.testing.assert_array_equal(context.get_discrete_state(THETA_P_GROUP).value(), initial)


def test_one_step_matches_the_recursion():
    system, context = make_identifier()
    fix_inputs(system, context, t_contact=0.0, xe=1e-3, xd=0.02, xdd=-0.5, f=6.0)
    step(system, context)
    theta, _ = RlsEstimator.step(np.array(RlsConfig().theta0), np.diag(RlsConfig().p0[:3]),
                                 np.array([-0.5, 0.02, 1e-3]), 6.0, 1.0)
    np.testing.assert_allclose(impedance(system, context), theta, rtol=1e-12)


def test_in_contact_the_system_converges_to_the_true_impedance():
    system, context = make_identifier(p0=DIFFUSE)
    np.testing.assert_allclose(run_identifier(system, context), TRUE, rtol=1e-6)


def test_force_offset_form_recovers_the_impedance_under_a_constant_offset():
    system, context = make_identifier(p0=DIFFUSE, force_offset=True)
    np.testing.assert_allclose(run_identifier(system, context, f_offset=5.0), TRUE, rtol=1e-6)
    assert context.get_discrete_state(THETA_P_GROUP).value()[3] == pytest.approx(5.0, rel=1e-6)
    # The thesis's form, fed the same data, over-estimates K_e.
    plain, plain_context = make_identifier(p0=DIFFUSE)
    assert run_identifier(plain, plain_context, f_offset=5.0)[2] / TRUE[2] - 1 > 0.1


def test_system_change_detection_is_bit_identical_to_the_estimator():
    """With change detection on, the system's theta, P and detector state
    equal RlsEstimator's sample for sample through a jump of K_e (which
    resets P once)."""
    t, xe, xd, xdd, K, f = step_data(n=2600)
    config = dict(force_offset=True, stiffness_drift=1e-9, change_threshold_n=2.0)
    system, context = make_identifier(**config)
    rls = RlsEstimator(RlsConfig(**config))
    for k in range(len(t)):
        xe_read = (X_SWITCH + xe[k]) - X_SWITCH
        rls.update(xe_read, xd[k], xdd[k], f[k])
        fix_inputs(system, context, t_contact=0.0, xe=xe[k], xd=xd[k], xdd=xdd[k], f=f[k])
        step(system, context)
        np.testing.assert_array_equal(context.get_discrete_state(THETA_P_GROUP).value(),
                                      np.concatenate([rls.theta, rls.P.ravel()]))
    assert len(rls.resets) == 1
    np.testing.assert_array_equal(context.get_discrete_state(2).value(),
                                  [rls.error, rls.samples, rls.last_reset])


@pytest.mark.parametrize("force_offset,lam,drift", [(False, 1.0, 0.0), (True, 1.0, 0.0),
                                                    (False, 0.98, 0.0), (True, 0.995, 0.0),
                                                    (True, 1.0, 1e-9), (False, 0.99, 1e-6)])
def test_system_step_is_bit_identical_to_the_recursion(force_offset, lam, drift):
    """The system's buffered step does RlsEstimator.step's arithmetic
    operation for operation: theta and P equal it bit for bit, sample after
    sample, on random signals and states."""
    rng = np.random.default_rng(13)
    system, context = make_identifier(force_offset=force_offset, forgetting_factor=lam,
                                      stiffness_drift=drift)
    n = 4 if force_offset else 3
    group = context.get_mutable_discrete_state(THETA_P_GROUP)
    A = rng.normal(0, 1, (n, n))
    group.SetFromVector(np.concatenate([rng.normal(0, 100, n), (A @ A.T).ravel() * 1e3]))
    for _ in range(50):
        xe, xd, xdd, f = rng.normal(0, [1e-3, 1e-2, 1.0, 10.0])
        values = context.get_discrete_state(THETA_P_GROUP).value().copy()
        xe_read = (X_SWITCH + xe) - X_SWITCH  # what the system reads
        theta, P = RlsEstimator.step(values[:n], values[n:].reshape(n, n),
                                     np.array([xdd, xd, xe_read, 1.0][:n]), f, lam, drift)
        fix_inputs(system, context, t_contact=0.0, xe=xe, xd=xd, xdd=xdd, f=f)
        step(system, context)
        np.testing.assert_array_equal(context.get_discrete_state(THETA_P_GROUP).value(),
                                      np.concatenate([theta, P.ravel()]))
        np.testing.assert_array_equal(impedance(system, context), theta[:3])


def test_raw_matched_signals_feed_the_unfiltered_force_and_the_chain_filtered_kinematics():
    """``signals: raw_matched`` wires the DSP's unfiltered force straight in,
    and the tip pose and the unfiltered differences each through the sensor
    chain's nominal model (one filter system each, shared by all such
    identifiers with the same chain model: rls_robust's is zoh, so its
    filters are named ..._zoh)."""
    from drake_contact import load_scenario
    from drake_contact.identification.identifiers import AddIdentifiers
    from pydrake.systems.framework import DiagramBuilder
    scenario = load_scenario("identify_any")
    builder = DiagramBuilder()
    identifiers = AddIdentifiers(builder, scenario)
    names = {identifiers.GetSystems()[i].get_name() for i in range(len(identifiers.GetSystems()))}
    assert {"matched_raw_pose_zoh", "matched_raw_velocity_zoh",
            "matched_raw_acceleration_zoh"} <= names
    inner = {s.get_name(): s for s in identifiers.GetSystems()}
    robust = inner["identifier_rls_robust"]
    for port, source in (("force", "force_raw"), ("tip_pose", "matched_raw_pose_zoh"),
                         ("tip_velocity", "matched_raw_velocity_zoh"),
                         ("tip_acceleration", "matched_raw_acceleration_zoh")):
        connected = _source_of(identifiers, robust.GetInputPort(port))
        assert connected == source, (port, connected)


def _source_of(diagram, input_port):
    """The name of what feeds ``input_port`` inside ``diagram``: a system's
    name, or the name of the diagram's exported input."""
    for (in_system, in_index), (out_system, _) in diagram.connection_map().items():
        if in_system is input_port.get_system() and in_index == input_port.get_index():
            return out_system.get_name()
    for i in range(diagram.num_input_ports()):
        for system, index in diagram.GetInputPortLocators(diagram.get_input_port(i).get_index()):
            if system is input_port.get_system() and index == input_port.get_index():
                return diagram.get_input_port(i).get_name()
    return None


@pytest.mark.parametrize("stiffness, damping, seed", [(7000.0, 100.0, 0), (120000.0, 20.0, 3)])
def test_rls_robust_is_within_5_percent_one_second_after_contact(stiffness, damping, seed):
    """The bar for the best RLS at 1 s, on two walls (the grid is a
    sweep): identify_any's rls_robust, probing on, its K_e within 5 %."""
    from drake_contact import load_scenario, simulate_scenario
    from drake_contact.scoring.metrics import compute_metrics
    scenario = load_scenario("identify_any", [
        f"environment.stiffness={stiffness}", f"environment.damping={damping}",
        f"simulation.seed={seed}", "simulation.duration=10.4"])
    result = simulate_scenario(scenario)
    assert result.status == "completed"
    metrics = compute_metrics(scenario, result.log, 0.0)
    assert abs(metrics["identification_error_1s_rls_robust"]["stiffness"]) < 0.05


def test_thesis_signals_are_line_675s():
    """``signals: thesis`` (identify_styrofoam's rls and networks): the 120 Hz
    force, the estimated pose, the unfiltered velocity and the 35 Hz
    acceleration (line 675: "a 35Hz Butterworth low-pass filter is used only
    for the noisy acceleration signal"); ``filtered`` (ours) takes the
    35 Hz velocity."""
    from drake_contact import load_scenario
    from drake_contact.identification.identifiers import AddIdentifiers
    from pydrake.systems.framework import DiagramBuilder
    scenario = load_scenario("identify_styrofoam")
    assert {c.name for c in scenario.identifiers if c.signals == "thesis"} == {
        "rls", "nn", "nn_slow"}
    builder = DiagramBuilder()
    identifiers = AddIdentifiers(builder, scenario)
    inner = {s.get_name(): s for s in identifiers.GetSystems()}
    expected = {"identifier_rls": ("force", "tip_pose", "tip_velocity_raw", "tip_acceleration"),
                "identifier_rls_offset": ("force", "tip_pose", "tip_velocity",
                                          "tip_acceleration")}
    for name, sources in expected.items():
        for port, source in zip(("force", "tip_pose", "tip_velocity", "tip_acceleration"),
                                sources):
            connected = _source_of(identifiers, inner[name].GetInputPort(port))
            assert connected == source, (name, port, connected)
