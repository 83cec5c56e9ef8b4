"""The FS6-120A system: the lifted (1 ms frame) model against a plain
tick-by-tick reference, quantization, calibration, hold and noise level."""

import dataclasses as dc

import numpy as np
import pytest

from drake_contact.errors import ScenarioError
from drake_contact.sensing.filters import butterworth_analog, discretize_analog
from drake_contact.sensing.force_sensor import ForceSensor, ForceSensorConfig, noise_input_gain

TICKS = 12


def make_sensor(**fields):
    config = dc.replace(ForceSensorConfig(), **fields)
    sensor = ForceSensor(config)
    return config, sensor, sensor.CreateDefaultContext()


def step(sensor, context, n, wrench, phi=0.0, noise=None):
    sensor.GetInputPort("wrench").FixValue(context, wrench)
    sensor.GetInputPort("tip_state").FixValue(context, [0.45, 0, phi, 0, 0, 0])
    sensor.GetInputPort("gauge_noise").FixValue(
        context, np.zeros(3 * TICKS) if noise is None else noise)
    new = sensor.EvalUniquePeriodicDiscreteUpdate(context)
    for group in range(new.num_groups()):
        context.SetDiscreteState(group, new.get_vector(group).value().copy())
    context.SetTime((n + 1) * 1e-3)
    return (sensor.GetOutputPort("voltage").Eval(context)[0],
            sensor.GetOutputPort("voltage_frame").Eval(context).copy())


class Reference:
    """The same model written the plain way: every fine tick in turn."""

    def __init__(self, c: ForceSensorConfig):
        self.c = c
        A, B, C, _ = discretize_analog(*butterworth_analog(c.analog_cutoff_hz, c.analog_order),
                                       c.fine_period)
        self.A, self.B, self.C = A, B, C
        self.x = [np.zeros(A.shape[0]) for _ in range(3)]
        Ao, Bo, Co, _ = discretize_analog(*butterworth_analog(c.output_bandwidth_hz, 2),
                                          c.fine_period)
        self.Ao, self.Bo, self.Co = Ao, Bo[:, 0], Co[0]
        v0 = c.offset_n / c.output_scale_n_per_v
        self.xo = np.linalg.solve(np.eye(2) - Ao, self.Bo * v0)
        self.held, self.glitch_left, self.tick = v0, 0, 0
        self.gain = noise_input_gain(c)

    def frame(self, wrench, phi, noise):
        c = self.c
        out = []
        for i in range(TICKS):
            if self.tick % round(c.fine_rate_hz / c.adc_rate_hz) == 0:
                g = np.array([self.C[0] @ x for x in self.x])
                w = np.array([np.cos(phi) * g[0] + np.sin(phi) * g[1],
                              -np.sin(phi) * g[0] + np.cos(phi) * g[1], g[2]])
                w[0] += c.offset_n
                lsb = 2 * np.array(c.adc_full_scale) / 2 ** c.adc_bits
                q = np.round(w / lsb) * lsb
                self.held = (np.array(c.calibration_matrix) @ q)[0] / c.output_scale_n_per_v
                self.glitch_left = max(1, round(c.dac_glitch_duration_s * c.fine_rate_hz))
            every = round(c.fine_rate_hz / c.adc_rate_hz)
            dac = self.held + (c.dac_glitch_n / c.output_scale_n_per_v if self.glitch_left else 0)
            dac += (c.noise_scale * c.dac_ripple_n / c.output_scale_n_per_v
                    * np.sin(2 * np.pi * (self.tick % every) / every))
            self.glitch_left = max(self.glitch_left - 1, 0)
            out.append(self.Co @ self.xo)
            self.xo = self.Ao @ self.xo + self.Bo * dac
            for ch in range(3):
                u = wrench[ch] + self.gain[ch] * noise[3 * i + ch]
                self.x[ch] = self.A @ self.x[ch] + self.B[:, 0] * u
            self.tick += 1
        return self.Co @ self.xo, np.array(out)


def test_lifted_sensor_equals_the_tick_by_tick_reference():
    config, sensor, context = make_sensor(
        calibration_matrix=[[1.0, 0.02, 0.5], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    reference = Reference(config)
    rng = np.random.default_rng(3)
    for n in range(60):
        wrench = [-20.0 + 5 * np.sin(0.1 * n), 3.0 * np.cos(0.2 * n), 0.4]
        phi = 0.01 * np.sin(0.05 * n)
        noise = rng.normal(size=3 * TICKS)
        v, frame = step(sensor, context, n, wrench, phi, noise)
        v_ref, frame_ref = reference.frame(wrench, phi, noise)
        np.testing.assert_allclose(frame, frame_ref, atol=1e-9)
        assert v == pytest.approx(v_ref, abs=1e-9)


class FirstWrittenSensor(ForceSensor):
    """ForceSensor with its update as first written (numpy throughout, ``@``,
    arrays built per call): the tuned update must match it bit for bit."""

    def _update(self, context, state):
        nx, N = self._nx, self._ticks
        internal = context.get_discrete_state(self._internal).value()
        x0 = internal[:nx]
        held, glitch_left = internal[nx], int(internal[nx + 1])
        xo0 = internal[nx + 2:nx + 4]
        u = self._wrench.Eval(context)
        noise = self._noise.Eval(context) * self._noise_gain
        t0 = context.get_time()
        first_tick = round(t0 * self._config.fine_rate_hz)
        dac = np.full(N, held)
        glitch = np.zeros(N)
        glitch[:min(glitch_left, N)] = self._glitch_v
        adc_ticks = range(-first_tick % self._adc_every, N, self._adc_every)
        if adc_ticks:
            phi = self._tip.Eval(context)[2]
            for i in adc_ticks:
                x_i = self._gauge_P[i] @ x0 + self._gauge_L[i] @ noise + self._gauge_U[i] @ u
                held = self._adc_reference(self._gauge_C @ x_i, phi,
                                           t0 + i * self._config.fine_period)
                dac[i:] = held
                glitch[i:i + self._glitch_ticks] = self._glitch_v
            glitch_left = max(adc_ticks[-1] + self._glitch_ticks - N, 0)
        else:
            glitch_left = max(glitch_left - N, 0)
        ticks = (first_tick + np.arange(N)) % self._adc_every
        dac += glitch + self._ripple_v[0] * np.sin(2.0 * np.pi * ticks / self._adc_every)
        frame = self._out_F @ xo0 + self._out_G @ dac
        xo_end = self._out_E @ xo0 + self._out_H @ dac
        x_end = self._gauge_P[N] @ x0 + self._gauge_L[N] @ noise + self._gauge_U[N] @ u
        state.get_mutable_vector(self._voltage).SetAtIndex(0, self._out_C @ xo_end)
        state.get_mutable_vector(self._frame).SetFromVector(frame)
        state.get_mutable_vector(self._internal).SetFromVector(
            np.concatenate([x_end, [held, glitch_left], xo_end]))


def run_states(sensor, frames, seed, t_start, bad_inputs=False):
    """Every discrete state after each of ``frames`` updates on random
    inputs (with inf and NaN in some frames if ``bad_inputs``)."""
    context = sensor.CreateDefaultContext()
    rng = np.random.default_rng(seed)
    states = []
    for n in range(frames):
        context.SetTime(t_start + n * 1e-3)
        wrench = rng.normal(size=3) * [20.0, 20.0, 1.0]
        tip = rng.normal(size=6)
        if bad_inputs and n in (10, 20, 30):
            wrench[1] = np.inf if n == 10 else wrench[1]
            wrench[0] = np.nan if n == 20 else wrench[0]
            tip[2] = np.nan if n == 30 else tip[2]
        sensor.GetInputPort("wrench").FixValue(context, wrench)
        sensor.GetInputPort("tip_state").FixValue(context, tip)
        sensor.GetInputPort("gauge_noise").FixValue(
            context, rng.normal(size=3 * sensor.ticks_per_frame))
        new = sensor.EvalUniquePeriodicDiscreteUpdate(context)
        values = [new.get_vector(g).value().copy() for g in range(new.num_groups())]
        for group, value in enumerate(values):
            context.SetDiscreteState(group, value)
        states.append(np.concatenate(values))
    return np.array(states)


@pytest.mark.parametrize("fields", [
    {},
    {"offset_drift_n_per_s": 0.37,
     "calibration_matrix": [[1.0, 0.02, -0.01], [0.03, 0.98, 0.0], [0.0, 0.01, 1.01]]},
    {"adc_full_scale": [5.0, 5.0, 0.5]},  # clipping
    {"adc_full_scale": [5.0, 5.0, 0.5],
     "calibration_matrix": [[0.9, 0.1, 0.3], [0, 1, 0], [0, 0, 1]]},
    {"dac_glitch_duration_s": 5 / 12000, "dac_glitch_n": 1.5},
    {"dac_glitch_n": 1.5, "dac_ripple_n": 0.0},
    {"fine_rate_hz": 24000.0, "dac_glitch_duration_s": 3 / 24000},
    {"adc_rate_hz": 2000.0},  # two ADC ticks per frame
    {"adc_rate_hz": 100.0, "dac_glitch_duration_s": 30 / 12000},  # glitch over frames
    {"adc_bits": 4, "adc_full_scale": [30.0, 30.0, 2.0], "noise_scale": 0.0, "offset_n": -2.0},
    {"analog_order": 5, "output_bandwidth_hz": 800.0, "output_scale_n_per_v": 123.0,
     "dac_glitch_n": -0.7},
])
@pytest.mark.parametrize("bad_inputs", [False, True])
@pytest.mark.filterwarnings("ignore:invalid value encountered:RuntimeWarning")
def test_update_is_bit_identical_to_the_first_written_one(fields, bad_inputs):
    config = dc.replace(ForceSensorConfig(), **fields)
    for seed, t_start in ((0, 0.0), (1, 0.137)):
        expected = run_states(FirstWrittenSensor(config), 60, seed, t_start, bad_inputs)
        actual = run_states(ForceSensor(config), 60, seed, t_start, bad_inputs)
        assert np.array_equal(actual.view(np.int64), expected.view(np.int64)), fields


def adjacent_floats_where(f, lo, hi):
    """Adjacent floats a < b in [lo, hi] (positive) with f(a) != f(b),
    by bisection on the floats' bit patterns, given f(lo) != f(hi)."""
    ia, ib = (int(np.float64(x).view(np.int64)) for x in (lo, hi))
    fa = f(lo)
    assert f(hi) != fa
    while ib - ia > 1:
        mid = (ia + ib) // 2
        if f(float(np.int64(mid).view(np.float64))) == fa:
            ia = mid
        else:
            ib = mid
    return float(np.int64(ia).view(np.float64)), float(np.int64(ib).view(np.float64))


@pytest.mark.parametrize("fields", [
    {"offset_drift_n_per_s": 0.37},
    {"offset_drift_n_per_s": -1.1, "adc_bits": 16,
     "calibration_matrix": [[0.97, 0.05, -0.3], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]},
])
def test_adc_matches_the_numpy_adc_on_both_sides_of_every_quantization_step(fields):
    # Rounding a value near a quantization step one ulp differently would
    # change the count: probe the ADC at the steps themselves.
    sensor = ForceSensor(dc.replace(ForceSensorConfig(), **fields))
    rng = np.random.default_rng(7)
    for _ in range(40):
        phi, t = np.float64(rng.uniform(-0.3, 0.3)), float(rng.uniform(0.0, 5.0))
        fx, fy, tz = rng.uniform(5.0, 50.0), rng.uniform(5.0, 50.0), rng.uniform(0.1, 5.0)
        for channel in (0, 1):
            def gauges(value):
                return np.array([value, fy, tz] if channel == 0 else [fx, value, tz])

            def reference(value):
                return sensor._adc_reference(gauges(value), phi, t)
            a, b = adjacent_floats_where(reference, 5.0, 50.0)
            for value in (a, b):
                assert sensor._adc(gauges(value), phi, t) == reference(value)


def test_static_force_reads_through_sign_offset_and_12_bit_quantization():
    config, sensor, context = make_sensor(dac_glitch_n=0.0, dac_ripple_n=0.0, offset_n=3.0)
    for n in range(100):
        v, _ = step(sensor, context, n, [-20.0, 0.0, 0.0])
    lsb = 2 * 500.0 / 4096
    expected = np.round((-20.0 + 3.0) / lsb) * lsb / 200.0
    assert v == pytest.approx(expected, abs=1e-7)
    assert abs(v * 200 - (-17.0)) <= lsb / 2 + 1e-6


def test_calibration_cross_talk_leaks_fy_into_fx():
    config, sensor, context = make_sensor(dac_glitch_n=0.0, dac_ripple_n=0.0, offset_n=0.0,
                                          calibration_matrix=[[1, 0.1, 0], [0, 1, 0], [0, 0, 1]])
    for n in range(100):
        v, _ = step(sensor, context, n, [0.0, 50.0, 0.0])
    assert v * 200 == pytest.approx(5.0, abs=0.25)


def test_dac_holds_each_sample_for_25_fine_ticks():
    # A ramp in force: the output (glitch and reconstruction filter off-ish)
    # changes in steps 1/480 s apart.
    config, sensor, context = make_sensor(dac_glitch_n=0.0, dac_ripple_n=0.0, offset_n=0.0,
                                          output_bandwidth_hz=5000.0, adc_bits=24)
    frames = []
    for n in range(30):
        _, frame = step(sensor, context, n, [-(5.0 * n), 0.0, 0.0])
        frames.append(frame)
    levels = np.concatenate(frames)[120:]
    jumps = np.flatnonzero(np.abs(np.diff(levels)) > 1e-3)
    # One big jump per ADC update (the 5 kHz stage settles within two ticks).
    starts = jumps[np.insert(np.diff(jumps) > 3, 0, True)]
    assert np.all(np.diff(starts) == 25)


def test_gauge_noise_has_the_configured_level():
    config, sensor, context = make_sensor(dac_glitch_n=0.0, dac_ripple_n=0.0, offset_n=0.0,
                                          adc_bits=24,
                                          noise_std=[0.75, 0.0, 0.0])
    rng = np.random.default_rng(1)
    volts = [step(sensor, context, n, [0.0, 0.0, 0.0], noise=rng.normal(size=3 * TICKS))[0]
             for n in range(6000)]
    # The held (480 Hz) noise keeps the gauge noise's variance.
    assert np.std(np.array(volts[200:]) * 200) == pytest.approx(0.75, rel=0.08)


@pytest.mark.parametrize("field,value,words", [
    ("fine_rate_hz", 10000.0, "force_sensor.fine_rate_hz = 10000.0 is out of range: "
                              "must be a whole multiple of adc_rate_hz"),
    ("adc_bits", 1, "force_sensor.adc_bits = 1 is out of range"),
    ("calibration_matrix", [[1, 0], [0, 1]], "must be a finite 3 x 3 matrix"),
    ("noise_std", [-1.0, 0.0, 0.0], "force_sensor.noise_std"),
])
def test_bad_sensor_settings_name_the_field(field, value, words):
    with pytest.raises(ScenarioError, match=words.replace("(", r"\(").replace(")", r"\)")):
        make_sensor(**{field: value})
