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

#: One worker runs this module and its fixture is session-scoped, so the fixture
#: runs once (-n auto; docs/developer/testing.md, "Shared runs").
pytestmark = pytest.mark.xdist_group("test_sensor_chain")


@pytest.fixture(scope="session")
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
    (noise, ripple, glitch and offset off)."""
    config = ForceSensorConfig(noise_std=[0.0, 0.0, 0.0], dac_glitch_n=0.0, dac_ripple_n=0.0,
                               offset_n=0.0)
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


def sine_response(frequency_hz, output):
    """A 3 N sine at ``frequency_hz`` on 20 N through sensor + DSP (noise,
    glitch and offset off): (sample times, ``output``)."""
    from pydrake.systems.primitives import Adder, Sine
    config = ForceSensorConfig(noise_std=[0.0, 0.0, 0.0], dac_glitch_n=0.0, dac_ripple_n=0.0,
                               offset_n=0.0)
    builder = DiagramBuilder()
    sensor = AddForceSensor(builder, config)
    dsp = AddDspForceInput(builder, DspConfig(tare_window_s=0.05), config.fine_period, 12)
    sine = builder.AddSystem(Sine(np.array([-3.0, 0.0, 0.0]),
                                  np.full(3, 2 * np.pi * frequency_hz), np.zeros(3)))
    level = builder.AddSystem(ConstantVectorSource(np.array([-20.0, 0.0, 0.0])))
    wrench = builder.AddSystem(Adder(2, 3))
    builder.Connect(sine.get_output_port(0), wrench.get_input_port(0))
    builder.Connect(level.get_output_port(), wrench.get_input_port(1))
    pose = builder.AddSystem(ConstantVectorSource(np.zeros(6)))
    builder.Connect(wrench.get_output_port(), sensor.GetInputPort("wrench"))
    builder.Connect(pose.get_output_port(), sensor.GetInputPort("tip_state"))
    builder.Connect(sensor.GetOutputPort("voltage"), dsp.GetInputPort("voltage"))
    logger = LogVectorOutput(dsp.GetOutputPort(output), builder, 1e-3)
    simulator = Simulator(builder.Build())
    simulator.AdvanceTo(3.0)
    log = logger.FindLog(simulator.get_context())
    return log.sample_times(), log.data()[0]


def phase_delay(t, y, frequency_hz, start=1.0):
    """The delay (s) of y's component at ``frequency_hz`` behind sin(w t)."""
    w = 2 * np.pi * frequency_hz
    keep = t >= start
    design = np.column_stack([np.sin(w * t[keep]), np.cos(w * t[keep]), np.ones(keep.sum())])
    (s, c, _), *_ = np.linalg.lstsq(design, y[keep], rcond=None)
    return -np.arctan2(c, s) / w


@pytest.mark.parametrize("output", ["force_filtered", "force_measured"])
@pytest.mark.parametrize("frequency_hz", [1.7, 20.0])
def test_zoh_chain_model_has_the_simulated_chain_s_delay(output, frequency_hz):
    """chain_model zoh: the analog stages see the force held over each 1 ms
    plant step, as the simulation does, so its delay at 1.7 and 20 Hz is
    within 0.2 ms of the simulated chain's (what is left: the 480 Hz hold,
    1.04 ms on average, taken as one sample, and its beat with the sine);
    bilinear (Tustin) lags it by about half a sample more (0.5-0.65 ms)."""
    from scipy import signal

    from drake_contact.identification.identifiers import nominal_force_chain
    t, y = sine_response(frequency_hz, output)
    true = 20.0 + 3.0 * np.sin(2 * np.pi * frequency_hz * t)
    simulated = phase_delay(t, y, frequency_hz)
    dsp = DspConfig() if output == "force_filtered" else None
    lags = {}
    for model in ("bilinear", "zoh"):
        b, a = nominal_force_chain(ForceSensorConfig(), dsp, discretization=model)
        assert np.sum(b) / np.sum(a) == pytest.approx(1.0, rel=1e-9)
        lags[model] = simulated - phase_delay(t, signal.lfilter(b, a, true), frequency_hz)
    assert abs(lags["zoh"]) < 0.2e-3
    assert 0.45e-3 < lags["bilinear"] < 0.7e-3


def test_an_unknown_chain_model_is_refused_in_one_line(tmp_path):
    """A scenario whose identifier names an unknown chain model fails to load
    with one line naming the field and the choices."""
    from drake_contact import ScenarioError, load_scenario
    path = tmp_path / "bad_chain.yaml"
    path.write_text("identifiers:\n  - {name: rls_zoh, kind: rls, signals: raw_matched,"
                    " chain_model: foh}\n")
    with pytest.raises(ScenarioError) as info:
        load_scenario(str(path))
    assert str(info.value) == ("identifiers[0].chain_model = 'foh' is unknown: choose one of "
                               "bilinear, zoh")
