"""What a run's excitation allows any identifier to know: the Cramér-Rao
bound on M_e, B_e and K_e.

The wall's force is linear in its parameters,

    f_k = M_e a_k + B_e v_k + K_e x_k + f_0 + e_k,

with a, v, x the tip's true acceleration, velocity and penetration along x
and e the force sensor's noise. Whatever the identifier, no unbiased
estimate of (M_e, B_e, K_e) from the samples in contact can have a smaller
covariance than the inverse of the Fisher information of this model
(Ljung 1999, section 7.4; Kay 1993, ch. 3). For stationary Gaussian noise of
power spectral density P(f) the information over N samples is, in the
frequency domain (Whittle's approximation; Kay 1993, section 15.9),

    I = sum_k Re(Phi_k^H Phi_k) / (N P(f_k)),

Phi_k the DFT of the regressors [a, v, x] at f_k = k / (N T). The unknown
offset f_0 takes the zero-frequency bin, which is left out. With white noise
this is Phi^T Phi / sigma^2. The sensor's noise is not white (the 480 Hz
line of the motor drive stands far above its floor), so P is the noise's
Welch PSD at rest, before the first contact: the low-frequency floor,
where the motion is, decides the bound, not the noise's total power.

The bound is optimistic for every real identifier: it assumes the true
kinematics (the identifiers measure them through encoders and filters) and
the true model. A relative bound (std / truth) above the bar means no
identifier can meet the bar on that run; one below it says only that the
data would allow it.
"""

import numpy as np

from drake_contact.scoring.spectra import RATE_HZ, welch_psd, windows
from drake_contact.plant.arm import CONTROL_PERIOD, TIME_TOLERANCE_S

#: Samples of rest noise and of contact needed for a bound.
MIN_REST_SAMPLES = 1024
MIN_CONTACT_SAMPLES = 100

#: The noise PSD: Welch segments of this many samples (3.9 Hz bins at 1 kHz),
#: then a running mean over this many bins.
PSD_SEGMENT = 256
PSD_SMOOTH_BINS = 5

PARAMETERS = ("mass", "damping", "stiffness")


def contact_window(log, t_contact, until=None):
    """Mask of the samples from the switch at ``t_contact`` to the first
    sample out of contact (true force 0) after it, or the end (or, with
    ``until``, the samples before that long after the switch)."""
    t = log["t"]
    after = t >= t_contact - TIME_TOLERANCE_S
    if until is not None:
        after &= t < t_contact + until - TIME_TOLERANCE_S
    touching = np.asarray(log["contact_force_true"]).ravel() > 0
    lost = after & ~touching
    # The switch fires on the filtered force, some ms into the contact.
    end = np.argmax(lost) if lost.any() else len(t)
    window = after.copy()
    window[end:] = False
    return window


def noise_psd(log, tare_window_s):
    """(frequencies Hz, two-sided PSD per sample, N^2) of the measured force's
    error at rest, or None if the rest is shorter than MIN_REST_SAMPLES.

    Welch's PSD in PSD_SEGMENT-sample segments, averaged over PSD_SMOOTH_BINS
    neighbouring bins: the bound hangs on the few bins the motion occupies,
    and one bin of a few seconds' Welch estimate scatters by tens of %."""
    rest, _ = windows(log, tare_window_s)
    if rest.sum() < MIN_REST_SAMPLES:
        return None
    error = (np.asarray(log["force_measured"]).ravel()
             - np.asarray(log["contact_force_true"]).ravel())[rest]
    freqs, one_sided = welch_psd(error, nperseg=PSD_SEGMENT)
    # The zero-frequency bin is dropped (Welch's detrending empties it);
    # below the first bin the PSD is taken as there.
    freqs, one_sided = freqs[1:], one_sided[1:]
    kernel = np.ones(PSD_SMOOTH_BINS)
    smooth = (np.convolve(one_sided, kernel, mode="same")
              / np.convolve(np.ones(len(one_sided)), kernel, mode="same"))
    # One-sided density (N^2/Hz) to a two-sided spectrum per sample, whose
    # mean over the band is the variance.
    return freqs, smooth * RATE_HZ / 2


def fisher_information(regressors, freqs, psd):
    """The Whittle information of the columns of ``regressors`` (N x p,
    samples at 1 kHz) under noise of two-sided per-sample PSD ``psd`` at
    ``freqs`` (Hz), the zero-frequency bin left out."""
    phi = np.asarray(regressors, dtype=float)
    n = len(phi)
    spectrum = np.fft.rfft(phi - phi.mean(axis=0), axis=0)
    f = np.fft.rfftfreq(n, d=1.0 / RATE_HZ)
    weight = np.full(len(f), 2.0)  # the negative frequencies' mirror
    weight[0] = 0.0
    if n % 2 == 0:
        weight[-1] = 1.0
    weight /= n * np.interp(f, freqs, psd)
    scaled = spectrum * weight[:, None]
    return np.real(spectrum.conj().T @ scaled)


def identifiability_bound(log, t_contact, tare_window_s, until=None, *, psd=None):
    """The Cramér-Rao bound of (M_e, B_e, K_e) from this run's contact
    samples (with ``until``, those before that long after the switch):
    ``{"std": {mass, damping, stiffness}, "relative": {...},
    "contact_samples": n}`` (one standard deviation; relative to the truth
    at the end, None where it is 0), or None if the run has no rest before
    contact long enough for the noise's PSD, or too few samples in contact.
    ``psd``: :func:`noise_psd`'s result for this log, if already computed
    (several bounds of one run share it)."""
    if psd is None:
        psd = noise_psd(log, tare_window_s)
    window = contact_window(log, t_contact, until)
    if psd is None or window.sum() < MIN_CONTACT_SAMPLES:
        return None
    velocity = np.asarray(log["tip_velocity_true"])[:, 0]
    acceleration = np.gradient(velocity, CONTROL_PERIOD)
    penetration = np.asarray(log["penetration_true"]).ravel()
    regressors = np.column_stack([acceleration, velocity, penetration])[window]
    information = fisher_information(regressors, *psd)
    std = np.sqrt(np.diag(np.linalg.inv(information)))
    truth = np.asarray(log["true_impedance"])[-1]
    relative = {key: float(s / abs(v)) if v != 0 else None
                for key, s, v in zip(PARAMETERS, std, truth)}
    return {"std": {key: float(s) for key, s in zip(PARAMETERS, std)}, "relative": relative,
            "contact_samples": int(window.sum())}
