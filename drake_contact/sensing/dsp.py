"""The DSP's force input at 1 kHz (thesis chapter 3-4, SPEC §4).

    sensor voltage --[optional 2nd-order RC, analog]--> 16-bit ADC (+-10 V)
      --> x (-200 N/V) --> tare --> force_measured
      --> 120 Hz 2nd-order Butterworth (LinearSystem) --> force_filtered

The tare averages the reading over the first ``tare_window_s`` seconds
(the arm is at rest in front of the wall) and subtracts that offset from then
on; while the window is open the running mean is subtracted. The thesis's code
reads the offset once at start-up; an average is the same idea with less noise.

The 190 Hz RC anti-aliasing filter (Fig 3.6) has three modes: ``off`` (the
thesis's experiments), ``in_loop`` (the DSP reads the filtered signal) and
``probe`` (a second ADC channel records the filtered signal beside the raw one,
as for Fig 3.5; controllers still read the raw channel).

``force_measured`` is computed where it is read (a direct-feedthrough output
of the sampled voltage): the 1 kHz consumers (filter, controllers, loggers)
read it at the sample instants, so raw and filtered force come from the same
sample, as in the thesis's interrupt routine.
"""

import dataclasses as dc

import numpy as np
from pydrake.systems.framework import DiagramBuilder, LeafSystem
from pydrake.systems.primitives import Demultiplexer, Multiplexer, PassThrough

from drake_contact.blocks import AddSubdiagram
from drake_contact.plant.arm import CONTROL_PERIOD
from drake_contact.errors import ScenarioError
from drake_contact.sensing.filters import (
    butterworth_digital, digital_filter_system, lifted_analog_filter_system, rc_lowpass_analog)

ANTI_ALIASING_MODES = ("off", "in_loop", "probe")


@dc.dataclass
class AntiAliasingConfig:
    """The optional 2nd-order RC low-pass of Fig 3.6 (about 190 Hz)."""

    # off | in_loop | probe (a second recorded channel, for Fig 3.5).
    mode: str = "off"
    # Component values (ohm, ohm, F, F).
    R1: float = 100.0
    R2: float = 1.5
    C1: float = 470e-6
    C2: float = 10e-6

    def validate(self, prefix="dsp.anti_aliasing"):
        if self.mode not in ANTI_ALIASING_MODES:
            raise ScenarioError(f"{prefix}.mode = '{self.mode}' is unknown: choose one of "
                                f"{', '.join(ANTI_ALIASING_MODES)}")
        for field in ("R1", "R2", "C1", "C2"):
            value = getattr(self, field)
            if not (np.isfinite(value) and value > 0):
                raise ScenarioError(f"{prefix}.{field} = {value} is out of range: must be > 0")


@dc.dataclass
class DspConfig:
    """The DSP's force input and force filter."""

    # ADC resolution (bits) and input range +- (V).
    adc_bits: int = 16
    adc_range_v: float = 10.0
    # Scale (N/V); the DSP flips the sign (pushing reads positive).
    scale_n_per_v: float = 200.0
    # Tare: average the reading over this window from t = 0 (s).
    tare_window_s: float = 2.0
    # Force filter: digital Butterworth, 2nd order, cut-off (Hz) at 1 kHz.
    force_filter_cutoff_hz: float = 120.0
    anti_aliasing: AntiAliasingConfig = dc.field(default_factory=AntiAliasingConfig)

    def validate(self, prefix="dsp"):
        if not (2 <= self.adc_bits <= 24):
            raise ScenarioError(f"{prefix}.adc_bits = {self.adc_bits} is out of range: must be in 2..24")
        if not (self.adc_range_v > 0):
            raise ScenarioError(f"{prefix}.adc_range_v = {self.adc_range_v} is out of range: must be > 0 V")
        if not (self.scale_n_per_v > 0):
            raise ScenarioError(
                f"{prefix}.scale_n_per_v = {self.scale_n_per_v} is out of range: must be > 0 N/V")
        if not (self.tare_window_s >= CONTROL_PERIOD):
            raise ScenarioError(f"{prefix}.tare_window_s = {self.tare_window_s} is out of range: "
                                "must be >= 0.001 s")
        if not (0 < self.force_filter_cutoff_hz < 500):
            raise ScenarioError(f"{prefix}.force_filter_cutoff_hz = {self.force_filter_cutoff_hz} "
                                "is out of range: must be in (0, 500) Hz")
        self.anti_aliasing.validate(f"{prefix}.anti_aliasing")


class DspForceInput(LeafSystem):
    """16-bit ADC, scale, sign flip and tare on ``channels`` voltages, 1 kHz.

    Input ports:
      voltage (channels): the sensor's analog output(s) (V).
    Output ports:
      force (channels): -scale * ADC(voltage) - offset (N).
    State (discrete): tare sum (channels), sample count (1), offset (channels).
    """

    def __init__(self, config: DspConfig, channels=1):
        super().__init__()
        self._config = config
        self._k = channels
        self._lsb = 2.0 * config.adc_range_v / 2 ** config.adc_bits
        self._voltage = self.DeclareVectorInputPort("voltage", channels)
        self.DeclareDiscreteState(2 * channels + 1)
        self.DeclarePeriodicDiscreteUpdateEvent(CONTROL_PERIOD, 0.0, self._tare)
        self.DeclareVectorOutputPort(
            "force", channels, self._calc_force,
            prerequisites_of_calc={self._voltage.ticket(), self.xd_ticket()})

    def _reading(self, context):
        """The ADC reading in N (before tare)."""
        v = np.clip(self._voltage.Eval(context), -self._config.adc_range_v,
                    self._config.adc_range_v - self._lsb)
        return -self._config.scale_n_per_v * np.floor(v / self._lsb + 0.5) * self._lsb

    def _tare(self, context, discrete_state):
        k = self._k
        state = context.get_discrete_state_vector().value().copy()
        if context.get_time() < self._config.tare_window_s - 1e-9:
            state[:k] += self._reading(context)
            state[k] += 1
            state[k + 1:] = state[:k] / state[k]
        discrete_state.set_value(state)

    def _calc_force(self, context, output):
        k = self._k
        state = context.get_discrete_state_vector().value()
        reading = self._reading(context)
        if state[k] == 0:
            # Before the first tare sample: the offset is this very reading.
            output.SetFromVector(np.zeros(k))
        else:
            output.SetFromVector(reading - state[k + 1:])


def AddDspForceInput(builder: DiagramBuilder, config: DspConfig, fine_period, ticks, *,
                     name="dsp"):
    """Adds the anti-aliasing option, the ADC/tare and the force filter as
    the sub-diagram ``name``; returns it.

    The RC filter is analog: it runs on the sensor's fine clock, lifted to
    frames of ``ticks`` ticks of ``fine_period`` (see filters.py).

    Ports: ``voltage`` (input, 1, the sensor's output at the sample
    instant), ``voltage_frame`` (input, ticks, the sensor's output over the
    last frame; only with the RC filter in), ``force_measured`` (output, 1,
    N), ``force_filtered`` (output, 1, N) and, in ``probe`` mode,
    ``force_measured_antialiased`` (output, 1, N).
    """
    config.validate()

    def build(builder):
        mode = config.anti_aliasing.mode
        aa = config.anti_aliasing
        entry = builder.AddNamedSystem(f"{name}_input", PassThrough(1))
        ports = {"voltage": entry.get_input_port()}
        if mode != "off":
            rc = builder.AddNamedSystem(
                f"{name}_anti_aliasing",
                lifted_analog_filter_system(*rc_lowpass_analog(aa.R1, aa.R2, aa.C1, aa.C2),
                                            fine_period, ticks))
            ports["voltage_frame"] = rc.get_input_port()
        channels = 2 if mode == "probe" else 1
        adc = builder.AddNamedSystem(f"{name}_force_input", DspForceInput(config, channels))
        if mode == "probe":
            mux = builder.AddNamedSystem(f"{name}_channels", Multiplexer(2))
            builder.Connect(entry.get_output_port(), mux.get_input_port(0))
            builder.Connect(rc.get_output_port(), mux.get_input_port(1))
            builder.Connect(mux.get_output_port(), adc.GetInputPort("voltage"))
        else:
            source = rc if mode == "in_loop" else entry
            builder.Connect(source.get_output_port(), adc.GetInputPort("voltage"))
        b, a = butterworth_digital(config.force_filter_cutoff_hz, 1.0 / CONTROL_PERIOD)
        force_filter = builder.AddNamedSystem(
            f"{name}_force_filter", digital_filter_system(b, a, CONTROL_PERIOD, channels=channels))
        builder.Connect(adc.GetOutputPort("force"), force_filter.get_input_port())
        if channels == 1:
            ports["force_measured"] = adc.GetOutputPort("force")
            ports["force_filtered"] = force_filter.get_output_port()
        else:
            raw = builder.AddNamedSystem(f"{name}_raw_channels", Demultiplexer(2))
            filtered = builder.AddNamedSystem(f"{name}_filtered_channels", Demultiplexer(2))
            builder.Connect(adc.GetOutputPort("force"), raw.get_input_port())
            builder.Connect(force_filter.get_output_port(), filtered.get_input_port())
            ports["force_measured"] = raw.get_output_port(0)
            ports["force_measured_antialiased"] = raw.get_output_port(1)
            ports["force_filtered"] = filtered.get_output_port(0)
        return ports
    return AddSubdiagram(builder, name, build)
