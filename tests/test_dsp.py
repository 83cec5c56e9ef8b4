"""The DSP force input: 16-bit ADC, 200 N/V, sign flip, tare; RC modes."""


import numpy as np
import pytest
from pydrake.systems.framework import DiagramBuilder

from drake_contact.sensing.dsp import AddDspForceInput, DspConfig, DspForceInput
from drake_contact.errors import ScenarioError


def run_input(system, volts_at):
    context = system.CreateDefaultContext()
    out = []
    for n in range(len(volts_at)):
        system.GetInputPort("voltage").FixValue(context, [volts_at[n]])
        out.append(system.GetOutputPort("force").Eval(context)[0])
        context.SetDiscreteState(system.EvalUniquePeriodicDiscreteUpdate(context)
                                 .get_vector().value().copy())
        context.SetTime((n + 1) * 1e-3)
    return np.array(out)


def test_scale_sign_and_16_bit_quantization():
    config = DspConfig(tare_window_s=0.001)
    dsp = DspForceInput(config)
    # Tare on a zero volt first sample, then -0.1 V reads +20 N.
    out = run_input(dsp, [0.0] + [-0.1] * 5)
    lsb_n = 200.0 * 20.0 / 2 ** 16
    assert out[-1] == pytest.approx(20.0, abs=lsb_n / 2 + 1e-9)
    assert abs(out[-1] / lsb_n - round(out[-1] / lsb_n)) < 1e-6


def test_tare_averages_the_window_then_holds_the_offset():
    config = DspConfig(tare_window_s=0.1)
    dsp = DspForceInput(config)
    rng = np.random.default_rng(0)
    offset_v = 0.015  # -3 N
    volts = offset_v + 0.004 * rng.normal(size=400)
    volts[200:] += -0.05  # +10 N of real force after the window
    out = run_input(dsp, volts)
    window_mean = -200.0 * np.mean(volts[:100])
    # During the window the running mean is subtracted; afterwards a fixed offset.
    lsb_n = 200.0 * 20.0 / 2 ** 16  # one ADC count: quantization of reading and mean
    np.testing.assert_allclose(out[150:200] + window_mean, -200.0 * volts[150:200], atol=lsb_n)
    expected = np.mean(-200.0 * volts[200:]) - window_mean
    assert expected == pytest.approx(10.0, abs=0.3)
    assert np.mean(out[200:]) == pytest.approx(expected, abs=lsb_n)


def test_modes_build_the_expected_channels():
    for mode, probe in (("off", False), ("in_loop", False), ("probe", True)):
        builder = DiagramBuilder()
        config = DspConfig()
        config.anti_aliasing.mode = mode
        dsp = AddDspForceInput(builder, config, 1 / 12000, 12)
        assert dsp.get_name() == "dsp"
        assert dsp.HasOutputPort("force_measured_antialiased") == probe
        assert dsp.HasInputPort("voltage_frame") == (mode != "off")
        assert dsp.HasOutputPort("force_filtered") and dsp.HasOutputPort("force_measured")


class ReferenceDsp:
    """The ADC and tare in numpy, operation for operation: DspForceInput (a
    SymbolicVectorSystem) must match it bit for bit (zeros of either sign
    alike)."""

    def __init__(self, config, channels):
        self.config, self.k = config, channels
        self.lsb = 2.0 * config.adc_range_v / 2 ** config.adc_bits
        self.state = np.zeros(2 * channels + 1)

    def reading(self, voltage):
        v = np.clip(voltage, -self.config.adc_range_v, self.config.adc_range_v - self.lsb)
        return (-self.config.scale_n_per_v * self.lsb) * np.floor(v / self.lsb + 0.5)

    def force(self, voltage):
        if self.state[self.k] == 0:
            return np.zeros(self.k)
        return self.reading(voltage) - self.state[self.k + 1:]

    def update(self, t, voltage):
        k, state = self.k, self.state.copy()
        if t < self.config.tare_window_s - 1e-9:
            state[:k] += self.reading(voltage)
            state[k] += 1
            state[k + 1:] = state[:k] / state[k]
        self.state = state


def bits(values):
    """The values' bits, a zero of either sign as +0 (the sign of a zero
    force is no measurement)."""
    return (np.asarray(values, dtype=float) + 0.0).view(np.int64)


def bit_identity_cases():
    rng = np.random.default_rng(1)
    for trial in range(16):
        channels = 1 + trial % 2
        config = DspConfig()
        if trial >= 4:
            config.adc_bits = int(rng.integers(2, 25))
            config.adc_range_v = float(rng.choice([10.0, 3.3, rng.uniform(0.1, 20.0)]))
            config.scale_n_per_v = float(rng.choice([200.0, 123.456, rng.uniform(1.0, 500.0)]))
            config.tare_window_s = float(rng.choice([0.001, 0.05, rng.uniform(0.001, 0.1)]))
        lsb = 2.0 * config.adc_range_v / 2 ** config.adc_bits
        shape = (150, channels)
        kind = trial % 4
        if kind == 0:  # at rest: offset plus noise
            volts = 0.015 + 0.004 * rng.normal(size=shape)
        elif kind == 1:  # over the whole range and beyond (clipping)
            volts = rng.uniform(-1.5, 1.5, size=shape) * config.adc_range_v
        elif kind == 2:  # on and half-way between the ADC's levels; signed zeros
            half = 2 ** (config.adc_bits - 1)
            volts = (rng.integers(-half - 3, half + 3, size=shape)
                     + rng.choice([0.0, 0.5, -0.5], size=shape)) * lsb
            volts[rng.random(size=shape) < 0.2] = 0.0
            volts[rng.random(size=shape) < 0.1] = -0.0
        else:  # zero force (a zero offset), infinities, NaN
            volts = np.zeros(shape)
            volts[::3] = -0.0
            volts[60:] = 0.01 * rng.normal(size=(shape[0] - 60, channels))
            volts[70], volts[80], volts[90] = np.inf, -np.inf, np.nan
        yield config, channels, volts


@pytest.mark.parametrize("case", range(16))
def test_bit_identical_to_the_python_reference(case):
    config, channels, volts = list(bit_identity_cases())[case]
    dsp = DspForceInput(config, channels)
    reference = ReferenceDsp(config, channels)
    context = dsp.CreateDefaultContext()
    for n, voltage in enumerate(volts):
        t = n * 1e-3
        context.SetTime(t)
        dsp.GetInputPort("voltage").FixValue(context, voltage)
        force = dsp.GetOutputPort("force").Eval(context)
        assert np.array_equal(bits(force), bits(reference.force(voltage))), (n, force)
        state = dsp.EvalUniquePeriodicDiscreteUpdate(context).get_vector().value().copy()
        reference.update(t, voltage)
        assert np.array_equal(bits(state), bits(reference.state)), (n, state)
        context.SetDiscreteState(state)


def test_no_python_runs_per_step():
    # A Drake system throughout (no Python LeafSystem), 1 kHz, like the original.
    dsp = DspForceInput(DspConfig(), 2)
    assert dsp.num_input_ports() == 1 and dsp.GetInputPort("voltage").size() == 2
    assert dsp.num_output_ports() == 1 and dsp.GetOutputPort("force").size() == 2
    for system in dsp.GetSystems():
        assert type(system).__module__.startswith("pydrake"), system.get_name()
    event = dsp.GetUniquePeriodicDiscreteUpdateAttribute()
    assert (event.period_sec(), event.offset_sec()) == (1e-3, 0.0)
    assert dsp.HasDirectFeedthrough(0, 0)


@pytest.mark.parametrize("path,value,words", [
    ("anti_aliasing.mode", "always", "dsp.anti_aliasing.mode = 'always' is unknown"),
    ("anti_aliasing.R1", -1.0, "dsp.anti_aliasing.R1 = -1.0 is out of range"),
    ("tare_window_s", 0.0, "dsp.tare_window_s = 0.0 is out of range"),
    ("force_filter_cutoff_hz", 600.0, "dsp.force_filter_cutoff_hz = 600.0 is out of range"),
])
def test_bad_dsp_settings_name_the_field(path, value, words):
    config = DspConfig()
    target = config.anti_aliasing if path.startswith("anti_aliasing.") else config
    setattr(target, path.split(".")[-1], value)
    with pytest.raises(ScenarioError, match=words.replace("(", r"\(").replace(")", r"\)")):
        config.validate()
