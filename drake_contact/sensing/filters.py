"""Filter design: transfer functions to Drake ``LinearSystem``s.

Digital filters are Butterworth designs from a cut-off and a sample rate
(bilinear transform with pre-warping, as the thesis's DSP code: -3 dB
exactly at the cut-off). Analog filters are simulated on a fine clock,
discretized exactly for inputs held over each fine tick (ZOH); the fine clock
is a common multiple of every rate in the sensor chain (12 kHz for 480 Hz and
1 kHz), so the 480 Hz hold and the 1 kHz sampling fall on ticks and aliasing
emerges from the model. To avoid 12 simulator steps per millisecond, analog
stages are *lifted*: advanced a 1 ms frame of fine ticks at a time, which is
the same fine-grid model computed in blocks.
"""

import numpy as np
from pydrake.systems.primitives import LinearSystem
from scipy import signal


def butterworth_digital(cutoff_hz, rate_hz, order=2):
    """(b, a) of a digital Butterworth low-pass, a[0] = 1."""
    b, a = signal.butter(order, cutoff_hz, btype="low", fs=rate_hz)
    return b, a


def butterworth_analog(cutoff_hz, order):
    """(num, den) of an analog Butterworth low-pass (s in rad/s)."""
    return signal.butter(order, 2 * np.pi * cutoff_hz, btype="low", analog=True)


def rc_lowpass_analog(R1, R2, C1, C2):
    """(num, den) of the thesis's 2nd-order RC low-pass (Fig 3.6):
    T(s) = w^2 / (s^2 + (R1 + R2)/(R1 R2 C1) s + w^2), w^2 = 1/(R1 R2 C1 C2)."""
    w2 = 1.0 / (R1 * R2 * C1 * C2)
    return np.array([w2]), np.array([1.0, (R1 + R2) / (R1 * R2 * C1), w2])


def first_order_analog(cutoff_hz):
    """(num, den) of 1 / (s / w_c + 1)."""
    wc = 2 * np.pi * cutoff_hz
    return np.array([wc]), np.array([1.0, wc])


def _block_diagonal(systems):
    """Stacks SISO (A, B, C, D) into one MIMO system, channel by channel."""
    n = sum(A.shape[0] for A, *_ in systems)
    k = len(systems)
    A = np.zeros((n, n))
    B = np.zeros((n, k))
    C = np.zeros((k, n))
    D = np.zeros((k, k))
    i = 0
    for ch, (a, b, c, d) in enumerate(systems):
        m = a.shape[0]
        A[i:i + m, i:i + m] = a
        B[i:i + m, ch] = b[:, 0]
        C[ch, i:i + m] = c[0]
        D[ch, ch] = d[0, 0]
        i += m
    return A, B, C, D


def discretize_analog(num, den, fine_period):
    """(A, B, C, D) of num/den sampled exactly for inputs held over each fine
    tick (zero-order hold)."""
    Ad, Bd, Cd, Dd, _ = signal.cont2discrete(signal.tf2ss(num, den), fine_period, method="zoh")
    return Ad, Bd, Cd, Dd


def lifted_analog_filter_system(num, den, fine_period, ticks):
    """The analog filter num/den on the fine clock, advanced a frame of
    ``ticks`` fine ticks at a time: a LinearSystem with period
    ``ticks * fine_period`` whose input is the frame [u_0, ..., u_{ticks-1}]
    (the input held over each tick) and whose output is the filter's value at
    the frame's end, i.e. at the sample instant where it is read.

    Exact on the fine grid: x_end = A^N x + sum_i A^(N-1-i) B u_i.
    """
    A, B, C, D = discretize_analog(num, den, fine_period)
    if np.any(D):
        raise ValueError("lifting needs a strictly proper filter")
    powers = [np.linalg.matrix_power(A, k) for k in range(ticks + 1)]
    A_lift = powers[ticks]
    B_lift = np.hstack([powers[ticks - 1 - i] @ B for i in range(ticks)])
    return LinearSystem(A_lift, B_lift, C @ A_lift, C @ B_lift, ticks * fine_period)


def digital_filter_system(b, a, period, channels=1):
    """A discrete LinearSystem applying the digital filter b/a to each of
    ``channels`` inputs (direct feedthrough b[0] u[n]). b and a are in powers
    of z^-1 (scipy.signal.lfilter's convention); leading zeros of b are pure
    delays."""
    n = max(len(b), len(a))
    b = np.pad(np.asarray(b, dtype=float), (0, n - len(b)))
    a = np.pad(np.asarray(a, dtype=float), (0, n - len(a)))
    # In tf2ss's descending powers of z, equal lengths with leading zeros in b
    # are a strictly proper filter: strip them there instead of letting scipy
    # warn and strip them.
    ss = signal.tf2ss(np.trim_zeros(b, "f"), a)
    return LinearSystem(*_block_diagonal([ss] * channels), period)


def differencing_filter_system(b, a, period, channels=1):
    """Velocity and acceleration of each input by backward differences, each
    through the filter b/a (the thesis's estimator): per channel, outputs
    [v, a] with v = F(z) (1 - z^-1)/T x and a = F(z) ((1 - z^-1)/T)^2 x.
    Outputs are ordered [v_0..v_{k-1}, a_0..a_{k-1}]."""
    diff = np.array([1.0, -1.0]) / period
    b_v = np.polymul(b, diff)
    b_a = np.polymul(b_v, diff)
    a_v = np.polymul(a, [1.0, 0.0])       # one sample of differencing delay state
    a_a = np.polymul(a, [1.0, 0.0, 0.0])
    ss_v = signal.tf2ss(b_v, a_v)
    ss_a = signal.tf2ss(b_a, a_a)
    A, B, C, D = _block_diagonal([ss_v] * channels + [ss_a] * channels)
    # Both blocks of channel i read input i.
    B = B[:, :channels] + B[:, channels:]
    D = D[:, :channels] + D[:, channels:]
    return LinearSystem(A, B, C, D, period)
