"""Filter design against the thesis's DSP Butterworth filter, and the lifted
analog filters."""

import numpy as np
import pytest
from scipy import signal

from drake_contact.sensing.filters import (
    butterworth_analog, butterworth_digital, differencing_filter_system, discretize_analog,
    lifted_analog_filter_system, rc_lowpass_analog)


@pytest.mark.parametrize("cutoff,b_spec,a_spec", [
    (120.0, [0.0913, 0.1826, 0.0913], [0.9824, -0.3477]),
    (35.0, [0.0104, 0.0209, 0.0104], [1.691, -0.7327]),
])
def test_designed_coefficients_equal_the_thesis_and_cut_at_minus_3_db(cutoff, b_spec, a_spec):
    b, a = butterworth_digital(cutoff, 1000.0)
    # The DSP's difference equation is y = b0 u + b1 u1 + b2 u2 + a1 y1 + a2 y2: a1 = -a[1].
    np.testing.assert_allclose(b, b_spec, atol=5e-4)
    np.testing.assert_allclose(-a[1:], a_spec, atol=5e-4)
    _, h = signal.freqz(b, a, worN=[cutoff], fs=1000.0)
    assert 20 * np.log10(abs(h[0])) == pytest.approx(-3.0103, abs=0.01)


def test_analog_butterworth_cuts_at_minus_3_db():
    num, den = butterworth_analog(120.0, 3)
    _, h = signal.freqs(num, den, worN=[2 * np.pi * 120.0])
    assert 20 * np.log10(abs(h[0])) == pytest.approx(-3.0103, abs=0.01)


def test_rc_filter_is_the_thesis_190_hz_design():
    num, den = rc_lowpass_analog(100.0, 1.5, 470e-6, 10e-6)
    assert np.sqrt(den[2]) / (2 * np.pi) == pytest.approx(189.55, abs=0.01)
    _, h = signal.freqs(num, den, worN=[1e-3, 2 * np.pi * 100.0])
    assert abs(h[0]) == pytest.approx(1.0)
    assert 20 * np.log10(abs(h[1])) < 0.5  # flat to within 0.5 dB at 100 Hz


def test_lifted_filter_equals_stepping_every_fine_tick():
    num, den = rc_lowpass_analog(100.0, 1.5, 470e-6, 10e-6)
    fine, ticks = 1 / 12000, 12
    lifted = lifted_analog_filter_system(num, den, fine, ticks)
    A, B, C, _ = discretize_analog(num, den, fine)
    rng = np.random.default_rng(0)
    context = lifted.CreateDefaultContext()
    x = np.zeros(A.shape[0])
    for _ in range(20):
        frame = rng.normal(size=ticks)
        for u in frame:
            x = A @ x + B[:, 0] * u
        lifted.get_input_port().FixValue(context, frame)
        # The output is the value at the frame's end, read with the pre-update state.
        assert lifted.get_output_port().Eval(context)[0] == pytest.approx(C[0] @ x, abs=1e-12)
        context.SetDiscreteState(lifted.EvalUniquePeriodicDiscreteUpdate(context)
                                 .get_vector().value().copy())


def test_differencing_filter_recovers_ramp_velocity_and_parabola_acceleration():
    b, a = butterworth_digital(35.0, 1000.0)
    system = differencing_filter_system(b, a, 1e-3, channels=2)
    context = system.CreateDefaultContext()
    for n in range(600):
        t = n * 1e-3
        system.get_input_port().FixValue(context, [0.3 * t, 0.5 * t * t])
        v1, v2, a1, a2 = system.get_output_port().Eval(context)
        context.SetDiscreteState(system.EvalUniquePeriodicDiscreteUpdate(context)
                                 .get_vector().value().copy())
    assert v1 == pytest.approx(0.3, rel=1e-9)
    assert a2 == pytest.approx(1.0, rel=1e-9)
    assert a1 == pytest.approx(0.0, abs=1e-9)
    # Velocity of the parabola lags by the backward difference's half sample
    # plus the filter's DC group delay.
    _, gd = signal.group_delay((b, a), w=[0.0], fs=1000.0)
    t = 599e-3
    assert v2 == pytest.approx(t - 0.5e-3 - gd[0] * 1e-3, abs=1e-9)
