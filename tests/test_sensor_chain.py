"""The whole force path: sensor_spectrum's noise and spectra (Figs 3.5,
3.7, 4.4) and the chain's delay and rise time on a force step."""

import re

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import ConstantVectorSource, LogVectorOutput
from pydrake.trajectories import PiecewisePolynomial
from pydrake.systems.primitives import TrajectorySource

import drake_contact.sensing.force_sensor as force_sensor_module
from drake_contact.sensing.dsp import AddDspForceInput, DspConfig
from drake_contact.sensing.force_sensor import AddForceSensor, ForceSensorConfig
from drake_contact.app.runner import run
from drake_contact.scenario import load_scenario


@pytest.fixture(scope="module")
def spectrum(tmp_path_factory):
    out = tmp_path_factory.mktemp("sensor_spectrum")
    return run(load_scenario("sensor_spectrum"), out), out


def test_raw_noise_at_rest_spans_about_2_n_and_tare_removes_the_offset(spectrum):
    result, _ = spectrum
    m = result.metrics
    assert 1.0 < m["rest_noise_p99_n"] < 3.0
    assert abs(m["tare_mean_error_n"]) < 0.1


def test_480_hz_line_filter_attenuation_and_uncorrupted_bandwidth(spectrum):
    m = spectrum[0].metrics
    assert m["line_480hz_above_floor_db"] >= 10.0
    assert m["force_filter_attenuation_480hz_db"] >= 20.0
    assert m["psd_max_difference_below_100hz_db"] <= 1.0


def test_sensor_figures_are_written(spectrum):
    _, out = spectrum
    for name in ("fig3_5_psd.png", "fig3_7_rc_gain.png", "fig4_4_raw_force.png"):
        assert (out / name).stat().st_size > 10_000


def step_response():
    """20 N step of the true normal force at t = 0.1 s through sensor + DSP
    (noise, glitch and offset off)."""
    config = ForceSensorConfig(noise_std=[0.0, 0.0, 0.0], dac_glitch_n=0.0, offset_n=0.0)
    builder = DiagramBuilder()
    sensor = AddForceSensor(builder, config)
    dsp = AddDspForceInput(builder, DspConfig(tare_window_s=0.05), config.fine_period, 12)
    step = builder.AddSystem(TrajectorySource(PiecewisePolynomial.ZeroOrderHold(
        [0.0, 0.1, 1.0], np.array([[0.0, -20.0, -20.0], [0.0] * 3, [0.0] * 3]))))
    pose = builder.AddSystem(ConstantVectorSource(np.zeros(6)))
    builder.Connect(step.get_output_port(), sensor.GetInputPort("wrench"))
    builder.Connect(pose.get_output_port(), sensor.GetInputPort("tip_state"))
    builder.Connect(sensor.GetOutputPort("voltage"), dsp.GetInputPort("voltage"))
    logs = {name: LogVectorOutput(dsp.GetOutputPort(name), builder, 1e-3)
            for name in ("force_measured", "force_filtered")}
    diagram = builder.Build()
    simulator = Simulator(diagram)
    simulator.AdvanceTo(0.2)
    context = simulator.get_context()
    result = {}
    for name, logger in logs.items():
        log = logger.FindLog(context)
        t, f = log.sample_times(), log.data()[0]

        def crossing(level):
            i = np.argmax(f >= level)
            # Linear interpolation between samples.
            return t[i - 1] + (level - f[i - 1]) / (f[i] - f[i - 1]) * (t[i] - t[i - 1])
        result[name] = (crossing(10.0) - 0.1, crossing(18.0) - crossing(2.0))
    return result


def test_step_delay_and_rise_time_are_the_documented_ones():
    measured = step_response()
    doc = force_sensor_module.__doc__.replace("\n", " ")
    for name in ("force_measured", "force_filtered"):
        documented = re.search(
            rf"``{name}``[^.]*? reaches 50 % after ([\d.]+) ms and rises\s+10-90 % in ([\d.]+) ms",
            re.sub(r"\s+", " ", doc))
        assert documented, f"the docstring must state {name}'s delay and rise time"
        delay_ms, rise_ms = (float(x) for x in documented.groups())
        assert measured[name][0] * 1e3 == pytest.approx(delay_ms, abs=0.1)
        assert measured[name][1] * 1e3 == pytest.approx(rise_ms, abs=0.1)


@pytest.mark.parametrize("output", ["force_filtered", "force_measured"])
def test_nominal_force_chain_of_the_matched_identifiers_has_the_chain_s_delay(output):
    """The identifiers' ``matched`` signals model the chain as a 1 kHz linear
    filter (identification.nominal_force_chain), ``raw_matched`` the chain
    without the DSP's filter; each step response crosses 50 % and rises
    10-90 % within half a sample of the simulated chain's."""
    from scipy import signal

    from drake_contact.sensing.dsp import DspConfig
    from drake_contact.identification.identifiers import nominal_force_chain
    b, a = nominal_force_chain(ForceSensorConfig(),
                               DspConfig() if output == "force_filtered" else None)
    t = np.arange(0.0, 0.1, 1e-3)
    f = 20.0 * signal.lfilter(b, a, np.ones_like(t))
    assert f[-1] == pytest.approx(20.0, rel=1e-6)

    def crossing(level):
        i = np.argmax(f >= level)
        return t[i - 1] + (level - f[i - 1]) / (f[i] - f[i - 1]) * 1e-3
    measured_delay, measured_rise = step_response()[output]
    # The step in the simulation lands between samples: compare up to half a sample.
    assert crossing(10.0) == pytest.approx(measured_delay, abs=0.6e-3)
    assert crossing(18.0) - crossing(2.0) == pytest.approx(measured_rise, abs=0.6e-3)
