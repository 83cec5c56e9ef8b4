"""The Cramér-Rao bound on (M_e, B_e, K_e) from a run's log, against the
time-domain Fisher information of a synthetic wall (white noise) and with a
spectral line in the noise (which must not widen a low-frequency bound)."""

import numpy as np

from drake_contact.scoring.identifiability import fisher_information, identifiability_bound, noise_psd

RATE = 1000.0
SIGMA = 0.7
M, B, K = 0.01, 30.0, 15000.0


def synthetic_log(seed=0, line_amplitude=0.0):
    """20 s at 1 kHz: rest to 8 s, then the tip pressing with a 1.7 Hz and a
    7.3 Hz motion; the measured force is the true one plus white noise (and
    a 480 Hz line)."""
    rng = np.random.default_rng(seed)
    t = np.arange(20000) / RATE
    contact = t >= 8.0
    s = np.where(contact, t - 8.0, 0.0)
    w1, w2 = 2 * np.pi * 1.7, 2 * np.pi * 7.3
    x = np.where(contact, 1.3e-3 + 2e-4 * np.sin(w1 * s) + 5e-5 * np.sin(w2 * s), 0.0)
    v = np.where(contact, 2e-4 * w1 * np.cos(w1 * s) + 5e-5 * w2 * np.cos(w2 * s), 0.0)
    a = np.where(contact, -2e-4 * w1**2 * np.sin(w1 * s) - 5e-5 * w2**2 * np.sin(w2 * s), 0.0)
    force = np.where(contact, M * a + B * v + K * x, 0.0)
    noise = SIGMA * rng.standard_normal(len(t)) + line_amplitude * np.sin(
        2 * np.pi * 480.0 * t + 0.3)
    velocity = np.zeros((len(t), 3))
    velocity[:, 0] = v
    log = {"t": t, "contact_force_true": force, "force_measured": force + noise,
           "tip_velocity_true": velocity, "penetration_true": x,
           "true_impedance": np.tile([M, B, K], (len(t), 1))}
    return log, np.column_stack([a, v, x])[contact]


def test_white_noise_bound_is_the_time_domain_one():
    log, phi = synthetic_log()
    bound = identifiability_bound(log, 8.0, 1.0)
    # Time domain, the offset's column included: sigma^2 (Phi^T Phi)^-1.
    design = np.column_stack([phi, np.ones(len(phi))])
    expected = SIGMA * np.sqrt(np.diag(np.linalg.inv(design.T @ design)))[:3]
    got = np.array([bound["std"][k] for k in ("mass", "damping", "stiffness")])
    # The PSD is estimated from 7 s of rest: a few % of scatter.
    np.testing.assert_allclose(got, expected, rtol=0.1)
    assert bound["contact_samples"] == 12000
    # The noise's PSD computed once and passed in (as the metrics do) gives the same bound.
    assert identifiability_bound(log, 8.0, 1.0, psd=noise_psd(log, 1.0)) == bound
    assert abs(bound["relative"]["damping"] - expected[1] / B) < 0.1 * expected[1] / B


def test_a_spectral_line_far_above_the_motion_does_not_widen_the_bound():
    quiet, _ = synthetic_log(seed=1)
    lined, _ = synthetic_log(seed=1, line_amplitude=5.0)  # 12.5 N^2 at 480 Hz vs 0.49
    b_quiet = identifiability_bound(quiet, 8.0, 1.0)["std"]["damping"]
    b_lined = identifiability_bound(lined, 8.0, 1.0)["std"]["damping"]
    assert abs(b_lined / b_quiet - 1) < 0.1
    # A bound from the total variance would be sqrt(13) = 3.6 times wider.
    total = np.var(lined["force_measured"][(lined["t"] >= 1.0) & (lined["t"] < 7.95)])
    assert total > 10 * SIGMA**2


def test_fisher_information_of_white_noise_is_phi_t_phi_over_sigma2():
    rng = np.random.default_rng(3)
    phi = rng.standard_normal((4001, 2)) + [[3.0, -1.0]]
    freqs = np.linspace(0.5, 500.0, 50)
    got = fisher_information(phi, freqs, np.full(len(freqs), 2.0))
    centred = phi - phi.mean(axis=0)
    np.testing.assert_allclose(got, centred.T @ centred / 2.0, rtol=1e-9)


def test_no_bound_without_rest_or_contact():
    log, _ = synthetic_log()
    assert identifiability_bound(log, 19.95, 1.0) is None  # 50 samples in contact
    assert identifiability_bound(log, 8.0, 1.0, until=1.0)["contact_samples"] == 1000
    assert identifiability_bound(log, 8.0, 7.5) is None   # 0.45 s of rest
