"""The DSP force input: 16-bit ADC, 200 N/V, sign flip, tare; RC modes."""

import dataclasses as dc

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
