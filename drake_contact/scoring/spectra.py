"""Sensor noise and spectra of a run (Figs 3.5, 3.7, 4.4), as numbers.

Windows are read off the log: *rest* is after the tare window and before
the first contact (true force zero); *pressing* starts 1 s after the first
contact. Spectra are Welch PSDs (Hann, 1024 samples, 50 % overlap) of 1 kHz
signals, one-sided, in N^2/Hz.
"""

import numpy as np
from scipy import signal

RATE_HZ = 1000.0
LINE_HZ = 480.0


def welch_psd(x, rate_hz=RATE_HZ, nperseg=1024):
    """(frequencies Hz, PSD N^2/Hz) of ``x`` with the mean removed."""
    return signal.welch(np.asarray(x) - np.mean(x), fs=rate_hz, window="hann",
                        nperseg=min(nperseg, len(x)), noverlap=None, detrend="constant")


def line_above_floor_db(freqs, psd, line_hz=LINE_HZ, half_width_hz=3.0, floor_from_hz=20.0):
    """How far the spectral line at ``line_hz`` stands above the floor next to
    it (dB): the peak within +-half_width vs the median over the bands
    [line - floor_from - 30, line - floor_from] and [line + floor_from, Nyquist)."""
    near = np.abs(freqs - line_hz) <= half_width_hz
    low = (freqs >= line_hz - floor_from_hz - 30) & (freqs <= line_hz - floor_from_hz)
    high = (freqs >= line_hz + floor_from_hz) & (freqs < freqs[-1])
    floor = np.median(psd[low | high])
    return 10 * np.log10(psd[near].max() / floor)


def windows(log, tare_window_s):
    """Boolean masks (rest, pressing) over the log's samples."""
    t = log["t"]
    touching = log["contact_force_true"] > 0
    first_contact = t[np.argmax(touching)] if touching.any() else t[-1] + 1.0
    rest = (t >= tare_window_s) & (t < first_contact - 0.05)
    pressing = touching & (t >= first_contact + 1.0)
    return rest, pressing


def sensor_metrics(log, tare_window_s) -> dict:
    """Noise at rest, tare error and, when the log has the RC probe channel,
    the spectral comparisons of Fig 3.5."""
    rest, pressing = windows(log, tare_window_s)
    out = {}
    error = log["force_measured"] - log["contact_force_true"]
    if rest.sum() >= 200:
        out["rest_noise_p99_n"] = float(np.percentile(np.abs(error[rest]), 99))
        out["rest_noise_std_n"] = float(np.std(error[rest]))
        out["tare_mean_error_n"] = float(np.mean(error[rest]))
    if pressing.sum() >= 2048:
        f, p_raw = welch_psd(error[pressing])
        _, p_filtered = welch_psd((log["force_filtered"] - log["contact_force_true"])[pressing])
        at_line = np.argmin(np.abs(f - LINE_HZ))
        out["line_480hz_above_floor_db"] = float(line_above_floor_db(f, p_raw))
        out["force_filter_attenuation_480hz_db"] = float(
            10 * np.log10(p_raw[at_line] / p_filtered[at_line]))
        if "force_measured_antialiased" in log:
            _, p_a = welch_psd(log["force_measured"][pressing])
            _, p_b = welch_psd(log["force_measured_antialiased"][pressing])
            band = (f > 0) & (f <= 100.0)
            out["psd_max_difference_below_100hz_db"] = float(
                np.max(np.abs(10 * np.log10(p_a[band] / p_b[band]))))
    return out
