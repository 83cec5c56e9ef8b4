"""The DSP's force input at 1 kHz (thesis chapters 3-4).

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
from pydrake.symbolic import Variable, floor, if_then_else
from pydrake.symbolic import max as sym_max, min as sym_min
from pydrake.systems.framework import Diagram, DiagramBuilder
from pydrake.systems.primitives import (
    Demultiplexer, Multiplexer, PassThrough)

from drake_contact.arm_axis import LinearSystemBank, StackedSymbolicSystem
from drake_contact.blocks import AddSubdiagram, environment_configs
from drake_contact.plant.arm import CONTROL_PERIOD, TIME_TOLERANCE_S
from drake_contact.errors import ScenarioError
from drake_contact.faults import ChainFaults
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
        # Components a circuit could have (the filter's discretization
        # overflows for, e.g., a capacitor of 1e-300 F).
        for field, low, high, unit in (("R1", 1e-3, 1e9, "ohm"), ("R2", 1e-3, 1e9, "ohm"),
                                       ("C1", 1e-15, 1.0, "F"), ("C2", 1e-15, 1.0, "F")):
            value = getattr(self, field)
            if not (low <= value <= high):
                raise ScenarioError(f"{prefix}.{field} = {value} is out of range: must be in "
                                    f"[{low:g}, {high:g}] {unit}")


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
        if not (np.isfinite(self.adc_range_v) and self.adc_range_v > 0):
            raise ScenarioError(f"{prefix}.adc_range_v = {self.adc_range_v} is out of range: must be > 0 V")
        if not (np.isfinite(self.scale_n_per_v) and self.scale_n_per_v > 0):
            raise ScenarioError(
                f"{prefix}.scale_n_per_v = {self.scale_n_per_v} is out of range: must be > 0 N/V")
        if not (self.tare_window_s >= CONTROL_PERIOD):
            raise ScenarioError(f"{prefix}.tare_window_s = {self.tare_window_s} is out of range: "
                                "must be >= 0.001 s")
        if not (0.01 <= self.force_filter_cutoff_hz < 500):
            raise ScenarioError(f"{prefix}.force_filter_cutoff_hz = {self.force_filter_cutoff_hz} "
                                "is out of range: must be in [0.01, 500) Hz")
        self.anti_aliasing.validate(f"{prefix}.anti_aliasing")


class DspForceInput(Diagram):
    """16-bit ADC, scale, sign flip and tare on ``channels`` voltages, 1 kHz.

    Input ports:
      voltage (channels): the sensor's analog output(s) (V).
    Output ports:
      force (channels): -scale * ADC(voltage) - offset (N).
    State (discrete): tare sum (channels), sample count (1), offset (channels).

    A Drake ``SymbolicVectorSystem`` (inside this diagram, named
    ``adc_tare``) computes it: no Python runs per step. A reading is the
    count n times the force per count, ``(-scale * lsb) * n`` (one constant:
    Drake folds the constant factors of a product); ``tests/test_dsp.py``
    checks every operation against the same arithmetic in numpy, bit for bit.
    """

    def __init__(self, config, channels=1):
        super().__init__()
        configs = environment_configs(config, DspConfig, "dsp")
        self._config = configs[0]
        pieces = [_adc_tare_expressions(c, channels) for c in configs]
        builder = DiagramBuilder()
        adc = builder.AddNamedSystem("adc_tare", StackedSymbolicSystem(
            pieces, time_period=CONTROL_PERIOD))
        builder.ExportInput(adc.get_input_port(), "voltage")
        builder.ExportOutput(adc.get_output_port(), "force")
        builder.BuildInto(self)


def _adc_tare_expressions(config: DspConfig, k):
    """One environment's ADC and tare on ``k`` channels as
    :func:`StackedSymbolicSystem`'s piece."""
    lsb = 2.0 * config.adc_range_v / 2 ** config.adc_bits
    t = Variable("t")
    voltage = [Variable(f"voltage_{i}") for i in range(k)]
    total = [Variable(f"tare_sum_{i}") for i in range(k)]
    count = Variable("tare_count")
    offset = [Variable(f"tare_offset_{i}") for i in range(k)]
    hi = config.adc_range_v - lsb
    # The count n = floor(clip(v) / lsb + 0.5), times the force per count.
    per_count = -config.scale_n_per_v * lsb
    reading = [per_count * floor(sym_min(sym_max(v, -config.adc_range_v), hi) / lsb + 0.5)
               for v in voltage]
    taring = t < config.tare_window_s - TIME_TOLERANCE_S
    dynamics = ([if_then_else(taring, s + r, s) for s, r in zip(total, reading)]
                + [if_then_else(taring, count + 1, count)]
                + [if_then_else(taring, (s + r) / (count + 1), o)
                   for s, r, o in zip(total, reading, offset)])
    # Before the first tare sample (count 0) the offset is this very
    # reading: 0 N.
    output = [if_then_else(count == 0, 0.0, r - o) for r, o in zip(reading, offset)]
    return {"time": t, "state": total + [count] + offset, "input": voltage,
            "dynamics": dynamics, "output": output}


def AddDspForceInput(builder: DiagramBuilder, config, fine_period, ticks, *,
                     name="dsp", faults=()):
    """Adds the anti-aliasing option, the ADC/tare and the force filter as
    the sub-diagram ``name``; returns it.

    The RC filter is analog: it runs on the sensor's fine clock, lifted to
    frames of ``ticks`` ticks of ``fine_period`` (see filters.py).

    Ports: ``voltage`` (input, 1, the sensor's output at the sample
    instant), ``voltage_frame`` (input, ticks, the sensor's output over the
    last frame; only with the RC filter in), ``force_measured`` (output, 1,
    N), ``force_filtered`` (output, 1, N) and, in ``probe`` mode,
    ``force_measured_antialiased`` (output, 1, N).

    ``faults`` (a scenario's FaultConfig list; those on the force sensor are
    used) are chained on the reading after ADC and tare, before the filter
    (:mod:`drake_contact.faults`); then the block also has the input
    ``contact_time`` (1, the FaultClock's) and an output ``fault_active_<i>``
    (1) per force fault i.

    With a list of N configs, the DSPs of N environments on the arm axis
    (every port N times its size, environment i's at ``[i, i + 1)``), each
    as alone: the anti-aliasing filter off and no force faults.
    """
    configs = environment_configs(config, DspConfig, "dsp")
    for c in configs:
        c.validate()
    count = len(configs)
    config = configs[0]
    if count > 1 and (any(c.anti_aliasing.mode != "off" for c in configs) or any(
            f.signal == "force" for f in faults)):
        raise ScenarioError("dsp.anti_aliasing.mode: the DSPs of an ensemble serve its "
                            "environments together with the filter off and no force faults")

    def build(builder):
        mode = config.anti_aliasing.mode
        aa = config.anti_aliasing
        entry = builder.AddNamedSystem(f"{name}_input", PassThrough(count))
        ports = {"voltage": entry.get_input_port()}
        if mode != "off":
            rc = builder.AddNamedSystem(
                f"{name}_anti_aliasing",
                lifted_analog_filter_system(*rc_lowpass_analog(aa.R1, aa.R2, aa.C1, aa.C2),
                                            fine_period, ticks))
            ports["voltage_frame"] = rc.get_input_port()
        channels = 2 if mode == "probe" else 1
        adc = builder.AddNamedSystem(f"{name}_force_input", DspForceInput(configs, channels))
        if mode == "probe":
            mux = builder.AddNamedSystem(f"{name}_channels", Multiplexer(2))
            builder.Connect(entry.get_output_port(), mux.get_input_port(0))
            builder.Connect(rc.get_output_port(), mux.get_input_port(1))
            builder.Connect(mux.get_output_port(), adc.GetInputPort("voltage"))
        else:
            source = rc if mode == "in_loop" else entry
            builder.Connect(source.get_output_port(), adc.GetInputPort("voltage"))
        filters = [digital_filter_system(
            *butterworth_digital(c.force_filter_cutoff_hz, 1.0 / CONTROL_PERIOD),
            CONTROL_PERIOD, channels=channels) for c in configs]
        force_filter = builder.AddNamedSystem(
            f"{name}_force_filter", filters[0] if count == 1 else LinearSystemBank(filters))
        reading = adc.GetOutputPort("force")
        if any(f.signal == "force" for f in faults):
            clock = builder.AddNamedSystem(f"{name}_contact_time", PassThrough(1))
            ports["contact_time"] = clock.get_input_port()
            reading, active = ChainFaults(builder, faults, "force", reading, channels,
                                          clock.get_output_port())
            ports |= {f"fault_active_{i}": port for i, port in active.items()}
        builder.Connect(reading, force_filter.get_input_port())
        if channels == 1:
            ports["force_measured"] = reading
            ports["force_filtered"] = force_filter.get_output_port()
        else:
            raw = builder.AddNamedSystem(f"{name}_raw_channels", Demultiplexer(2))
            filtered = builder.AddNamedSystem(f"{name}_filtered_channels", Demultiplexer(2))
            builder.Connect(reading, raw.get_input_port())
            builder.Connect(force_filter.get_output_port(), filtered.get_input_port())
            ports["force_measured"] = raw.get_output_port(0)
            ports["force_measured_antialiased"] = raw.get_output_port(1)
            ports["force_filtered"] = filtered.get_output_port(0)
        return ports
    return AddSubdiagram(builder, name, build)
