"""The FS6-120A wrist force sensor (thesis chapter 3), as analog.

Signal chain per channel (we model the planar channels Fx, Fy, Tz; the DSP
reads only Fx):

1. strain gauges: the tip wrench plus gauge noise (white, Gaussian), through
   a 3rd-order analog Butterworth low-pass at 120 Hz;
2. the sensor's internal 12-bit ADC samples every 1/480 s (2.08 ms loop),
   rotates into the sensor frame, multiplies by the calibration matrix
   (decoupling; identity by default, cross-talk configurable) and adds the
   sensor's offset and its optional slow drift;
3. a DAC holds the Fx value for 1/480 s (zero-order hold; analog output mode,
   digital filter bypassed). Each DAC update also emits a short glitch (the
   update strobe's digital feed-through, a standard DAC artefact), and the
   analog output passes a reconstruction filter (2nd-order, 500 Hz).

Everything analog runs on a fine clock (``fine_rate_hz``, a common multiple
of 480 Hz and 1 kHz: 12 kHz by default), discretized exactly for inputs held
over a fine tick. The model is advanced one 1 ms frame of 12 ticks per update
(lifted, see ``filters.py``), and the 480 Hz ADC sample and DAC update happen
on the tick where they fall. So the 480 Hz staircase, the glitch train and
their aliasing when the DSP samples at 1 kHz come out of the model: no tone
is added anywhere. Gauge noise comes from Drake's ``RandomSource`` (seeded by
the scenario). The glitch's deterministic part makes the spectral line at
480 Hz (its harmonics alias to multiples of 40 Hz at 1 kHz sampling); the
held gauge noise makes the +-2 N seen at rest (Fig 4.4).

The output is a voltage, force / ``output_scale_n_per_v`` (200 N/V), with the
sensor's sign: pushing the wall gives a negative Fx; the DSP flips it.

Delay and rise time of the whole chain (sensor, DSP ADC, tare, filter) on a
20 N step of the true force at t = 0.1 s, in phase with an ADC sample
(measured by ``tests/test_sensor_chain.py``, noise, glitch and offset off):
``force_measured`` reaches 50 % after 4.42 ms and rises 10-90 % in 3.82 ms;
``force_filtered`` (after the 120 Hz digital filter) reaches 50 % after
6.22 ms and rises 10-90 % in 4.12 ms. The 120 Hz analog filter (group delay
about 2.7 ms), the 480 Hz hold, the 500 Hz reconstruction filter and the
1 kHz sampling make these up.
"""

import dataclasses as dc
import math

import numpy as np
from pydrake.common import RandomDistribution
from pydrake.systems.framework import DiagramBuilder, LeafSystem
from pydrake.systems.primitives import RandomSource
from scipy import signal

from drake_contact.blocks import AddSubdiagram
from drake_contact.plant.arm import CONTROL_PERIOD, RATIO_TOLERANCE
from drake_contact.errors import ScenarioError
from drake_contact.sensing.filters import butterworth_analog, discretize_analog


@dc.dataclass
class ForceSensorConfig:
    """The FS6-120A and its analog output."""

    # Analog anti-aliasing low-pass before the internal ADC: cut-off (Hz), order.
    analog_cutoff_hz: float = 120.0
    analog_order: int = 3
    # Internal ADC/DAC loop rate (Hz): 480 Hz, a 2.08 ms loop (chapter 3).
    adc_rate_hz: float = 480.0
    # Internal ADC resolution (bits) and full scale +- per channel [Fx, Fy, Tz]
    # (N, N, N m). The FS6-120A's ranges are not in the thesis; ours: 500 N, 20 N m.
    adc_bits: int = 12
    adc_full_scale: list[float] = dc.field(default_factory=lambda: [500.0, 500.0, 20.0])
    # Calibration (decoupling) matrix on [Fx, Fy, Tz]: the planar rows and
    # columns of the 6 x 6. Identity = perfect decoupling.
    calibration_matrix: list[list[float]] = dc.field(
        default_factory=lambda: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    # Standard deviation of the gauge noise after the analog filter, per
    # channel (N, N, N m): sets the +-2 N raw noise at rest (Fig 4.4).
    noise_std: list[float] = dc.field(default_factory=lambda: [0.75, 0.75, 0.01])
    # Multiplier of noise_std on every channel (1 = the +-2 N of Fig 4.4): one
    # number to sweep the noise level with.
    noise_scale: float = 1.0
    # Sensor offset on Fx (N), removed by the DSP's tare, and its drift (N/s).
    offset_n: float = 3.0
    offset_drift_n_per_s: float = 0.0
    # DAC update glitch on the output (N-equivalent height, duration in s; the
    # duration is rounded to whole fine ticks, at least one).
    dac_glitch_n: float = 1.5
    dac_glitch_duration_s: float = 1.0 / 12000.0
    # Cut-off of the analog output stage (Hz): the DAC's reconstruction
    # filter, a 2nd-order Butterworth. Not in the thesis; 500 Hz passes the
    # 480 Hz staircase (-2.7 dB) and keeps its harmonics from aliasing below
    # 120 Hz, which is what the thesis observed (Fig 3.5).
    output_bandwidth_hz: float = 500.0
    # Analog output scale (N/V).
    output_scale_n_per_v: float = 200.0
    # Fine clock of the analog simulation (Hz): a multiple of adc_rate_hz and 1 kHz.
    fine_rate_hz: float = 12000.0

    def validate(self, prefix="force_sensor"):
        def bad(field, allowed):
            raise ScenarioError(f"{prefix}.{field} = {getattr(self, field)} is out of range: "
                                f"{allowed}")
        if not (0 < self.fine_rate_hz <= 100000):
            bad("fine_rate_hz", "must be in (0, 100000] Hz (at most 100 ticks per 1 ms frame)")
        if not (10 <= self.analog_cutoff_hz < self.fine_rate_hz / 10):
            bad("analog_cutoff_hz", f"must be in [10, fine_rate_hz / 10 = {self.fine_rate_hz / 10}) Hz")
        if not (1 <= self.analog_order <= 8):
            bad("analog_order", "must be in 1..8")
        if not (1 <= self.adc_rate_hz <= self.fine_rate_hz):
            bad("adc_rate_hz", f"must be in [1, fine_rate_hz = {self.fine_rate_hz}] Hz")
        if not (2 <= self.adc_bits <= 24):
            bad("adc_bits", "must be in 2..24")
        if len(self.adc_full_scale) != 3 or not all(np.isfinite(x) and x >= 1e-6
                                                    for x in self.adc_full_scale):
            bad("adc_full_scale", "must be 3 finite values >= 1e-06 (N, N, N m)")
        cal = self.calibration_matrix
        if len(cal) != 3 or any(len(row) != 3 for row in cal) or not np.all(np.isfinite(cal)):
            bad("calibration_matrix", "must be a finite 3 x 3 matrix")
        if len(self.noise_std) != 3 or not all(np.isfinite(x) and x >= 0 for x in self.noise_std):
            bad("noise_std", "must be 3 finite values >= 0")
        if not (np.isfinite(self.noise_scale) and self.noise_scale >= 0):
            bad("noise_scale", "must be >= 0")
        for field in ("offset_n", "offset_drift_n_per_s", "dac_glitch_n"):
            if not np.isfinite(getattr(self, field)):
                bad(field, "must be finite")
        if not (self.dac_glitch_duration_s > 0):
            bad("dac_glitch_duration_s", "must be > 0 s")
        if self.dac_glitch_duration_s >= 0.5 / self.adc_rate_hz:
            bad("dac_glitch_duration_s", "must be < half the ADC period, 0.5 / adc_rate_hz = "
                f"{0.5 / self.adc_rate_hz:.4g} s")
        if not (1 <= self.output_bandwidth_hz < self.fine_rate_hz / 2):
            bad("output_bandwidth_hz", "must be in [1, fine_rate_hz / 2) Hz")
        if not (np.isfinite(self.output_scale_n_per_v) and self.output_scale_n_per_v >= 1e-6):
            bad("output_scale_n_per_v", "must be finite and >= 1e-06 N/V")
        for rate, name in ((self.adc_rate_hz, "adc_rate_hz"), (1000.0, "the 1 kHz DSP rate")):
            ratio = self.fine_rate_hz / rate
            if not (self.fine_rate_hz > 0) or abs(ratio - round(ratio)) > RATIO_TOLERANCE * ratio:
                bad("fine_rate_hz", f"must be a whole multiple of {name} ({rate} Hz)")

    @property
    def fine_period(self):
        return 1.0 / self.fine_rate_hz


class ForceSensor(LeafSystem):
    """The FS6-120A on the fine clock, advanced one 1 ms frame per update.

    Each update at t_n simulates the fine ticks of [t_n, t_n + 1 ms): the
    gauge filter (exact, by precomputed powers of its tick matrix), the 480 Hz
    ADC sample and DAC hold on the tick where it falls, the glitch, and the
    output stage. The wrench is the wall's force at t_n, which the plant holds
    over the same interval (at a 1 ms plant step; finer plant steps are seen
    at 1 kHz by the sensor).

    Input ports:
      wrench (3): [Fx, Fy, Tz] on the tip in world axes (N, N, N m).
      tip_state (6): the tip's [x, y, phi, ...]; phi rotates into the sensor frame.
      gauge_noise (3 * ticks): standard normal samples, one per tick and channel.
    Output ports (state outputs, no Python when read):
      voltage (1): the analog Fx output (V) at the end of the frame, i.e. at
        the instant the DSP samples it.
      voltage_frame (ticks): the output at each fine tick of the frame (V),
        for analog filters downstream (see lifted_analog_filter_system).
    """

    def __init__(self, config: ForceSensorConfig):
        super().__init__()
        config.validate()
        c = self._config = config
        self._ticks = round(c.fine_rate_hz * CONTROL_PERIOD)
        self._adc_every = round(c.fine_rate_hz / c.adc_rate_hz)
        self._glitch_ticks = max(1, round(c.dac_glitch_duration_s * c.fine_rate_hz))
        self._glitch_v = c.dac_glitch_n / c.output_scale_n_per_v
        self._cal = np.asarray(c.calibration_matrix, dtype=float)
        self._full = np.asarray(c.adc_full_scale, dtype=float)
        self._lsb = 2.0 * self._full / 2 ** c.adc_bits
        self._noise_gain = np.tile(noise_input_gain(c), round(c.fine_rate_hz * CONTROL_PERIOD))
        self._fine_rate = c.fine_rate_hz
        self._fine_period = c.fine_period
        # Per channel: lsb and the lowest and highest counts (whole numbers).
        self._adc_channels = tuple(zip(self._lsb.tolist(), (-self._full / self._lsb).tolist(),
                                       (self._full / self._lsb - 1).tolist()))
        self._cal_row0_unit = self._cal[0].tolist() == [1.0, 0.0, 0.0]

        # Gauge filter, 3 channels, on the fine clock; lifted to any tick j.
        A, B, C, _ = discretize_analog(*butterworth_analog(c.analog_cutoff_hz, c.analog_order),
                                       c.fine_period)
        eye3 = np.eye(3)
        A, B, C = np.kron(eye3, A), np.kron(eye3, B), np.kron(eye3, C)
        N = self._ticks
        powers = [np.linalg.matrix_power(A, k) for k in range(N + 1)]
        self._gauge_C = C
        self._gauge_P = powers
        # x_j = P_j x_0 + sum_{m<j} A^(j-1-m) B (u + g * noise_m)
        self._gauge_U = [sum((powers[j - 1 - m] @ B for m in range(j)), np.zeros_like(B))
                         for j in range(N + 1)]
        self._gauge_L = [np.hstack([powers[j - 1 - m] @ B if m < j else np.zeros_like(B)
                                    for m in range(N)]) for j in range(N + 1)]
        self._nx = A.shape[0]
        # Output stage (2nd order) on the fine clock, lifted to the frame:
        # frame = F xo_0 + G dac and xo_N = E xo_0 + H dac, where dac holds
        # the DAC's output over the frame's N ticks (one matrix product per
        # frame instead of a loop over ticks).
        Ao, Bo, Co, _ = discretize_analog(*butterworth_analog(c.output_bandwidth_hz, 2),
                                          c.fine_period)
        powers_o = [np.linalg.matrix_power(Ao, k) for k in range(N + 1)]
        self._out_F = np.vstack([Co @ powers_o[i] for i in range(N)])
        self._out_G = np.array([[(Co @ powers_o[i - 1 - m] @ Bo)[0, 0] if m < i else 0.0
                                 for m in range(N)] for i in range(N)])
        self._out_E = powers_o[N]
        self._out_H = np.hstack([powers_o[N - 1 - m] @ Bo for m in range(N)])
        self._out_C = Co[0]

        self._wrench = self.DeclareVectorInputPort("wrench", 3)
        self._tip = self.DeclareVectorInputPort("tip_state", 6)
        self._noise = self.DeclareVectorInputPort("gauge_noise", 3 * N)
        # The sensor has been on for a while: start at its offset, at rest.
        v0 = c.offset_n / c.output_scale_n_per_v
        self._voltage = self.DeclareDiscreteState([v0])
        self._frame = self.DeclareDiscreteState(np.full(N, v0))
        # [gauge filter state (nx), held volts, glitch ticks left,
        #  output-stage state (2)], at the DC steady state of the offset.
        xo0 = np.linalg.solve(np.eye(2) - Ao, Bo[:, 0] * v0)
        self._internal = self.DeclareDiscreteState(
            np.concatenate([np.zeros(self._nx), [v0, 0.0], xo0]))
        # The frame plans by tick phase and glitch carry, each made when first
        # met (not all up front: a slow ADC with a long glitch has millions).
        self._plans = {}
        self.DeclarePeriodicDiscreteUpdateEvent(CONTROL_PERIOD, 0.0, self._update)
        self.DeclareStateOutputPort("voltage", self._voltage)
        self.DeclareStateOutputPort("voltage_frame", self._frame)

    @property
    def ticks_per_frame(self):
        return self._ticks

    # The update runs once per 1 ms step in Python, so it is written for
    # numpy's per-call cost: ndarray.dot (the same BLAS gemv/dot as ``@``,
    # with less dispatch), the ADC's scalar arithmetic on Python floats, and
    # the frame's ADC ticks and glitch train looked up by the tick phase. Every
    # floating-point operation is the one of the straightforward version
    # (kept as ``_adc_reference`` and in tests/test_force_sensor.py), in the
    # same order: the results are bit-identical.

    def _plan(self, phase, glitch_left):
        """The frame's ADC ticks (the first at -first_tick mod adc_every),
        its glitch train (glitch_ticks ticks after each DAC update, carried
        across frames) and the glitch ticks left after it, for a frame whose
        first fine tick is ``phase`` modulo the ADC period, with
        ``glitch_left`` glitch ticks carried in. They repeat: the plans of
        every phase are made once."""
        N = self._ticks
        glitch = np.zeros(N)
        glitch[:min(glitch_left, N)] = self._glitch_v
        adc_ticks = tuple(range(-phase % self._adc_every, N, self._adc_every))
        for i in adc_ticks:
            glitch[i:i + self._glitch_ticks] = self._glitch_v
        if adc_ticks:
            glitch_left = max(adc_ticks[-1] + self._glitch_ticks - N, 0)
        else:
            glitch_left = max(glitch_left - N, 0)
        glitch.flags.writeable = False  # shared by every update of the plan
        return adc_ticks, glitch, glitch_left

    def _adc(self, gauges, phi, t):
        """Sample, rotate into the sensor frame, offset, quantize, calibrate:
        ``_adc_reference`` on Python floats (the same IEEE operations)."""
        c = self._config
        cos, sin = float(np.cos(phi)), float(np.sin(phi))
        fx, fy, tz = gauges.tolist()
        wrench = (cos * fx + sin * fy + (c.offset_n + c.offset_drift_n_per_s * t),
                  -sin * fx + cos * fy, tz)
        volts = []
        for w, (lsb, lowest, highest) in zip(wrench, self._adc_channels):
            try:
                count = float(math.floor(w / lsb + 0.5))
            except (ValueError, OverflowError):  # NaN or inf: numpy's way
                return self._adc_reference(gauges, phi, t)
            # Clip to the ADC's counts (whole numbers, so after the floor).
            volts.append((lowest if count < lowest else highest if count > highest
                          else count) * lsb)
        if self._cal_row0_unit:
            # Row 0 of the calibration is [1, 0, 0]: the product is the Fx
            # value exactly (the other terms are signed zeros: finite counts).
            return volts[0] / c.output_scale_n_per_v
        return float(self._cal.dot(np.array(volts))[0]) / c.output_scale_n_per_v

    def _adc_reference(self, gauges, phi, t):
        """The ADC in numpy, as first written."""
        c = self._config
        fx, fy, tz = gauges
        cos, sin = np.cos(phi), np.sin(phi)
        wrench = np.array([cos * fx + sin * fy, -sin * fx + cos * fy, tz])
        wrench[0] += c.offset_n + c.offset_drift_n_per_s * t
        counts = np.clip(np.floor(wrench / self._lsb + 0.5),
                         -self._full / self._lsb, self._full / self._lsb - 1)
        return float((self._cal @ (counts * self._lsb))[0]) / c.output_scale_n_per_v

    def _update(self, context, state):
        nx, N = self._nx, self._ticks
        internal = context.get_discrete_state(self._internal).value()
        x0 = internal[:nx]
        held, glitch_left = internal[nx], int(internal[nx + 1])
        xo0 = internal[nx + 2:nx + 4]
        u = self._wrench.Eval(context)
        noise = self._noise.Eval(context) * self._noise_gain
        t0 = context.get_time()
        first_tick = round(t0 * self._fine_rate)
        key = (first_tick % self._adc_every, glitch_left)
        plan = self._plans.get(key)
        if plan is None:
            plan = self._plans[key] = self._plan(*key)
        adc_ticks, glitch, glitch_left = plan
        # The DAC over the frame: the held value, replaced at each ADC tick,
        # plus the update glitch (glitch + held is held + glitch: commutative).
        dac = glitch + held
        if adc_ticks:
            phi = self._tip.Eval(context)[2]
            P, L, U, C = self._gauge_P, self._gauge_L, self._gauge_U, self._gauge_C
            for i in adc_ticks:
                x_i = P[i].dot(x0) + L[i].dot(noise) + U[i].dot(u)
                held = self._adc(C.dot(x_i), phi, t0 + i * self._fine_period)
                np.add(glitch[i:], held, out=dac[i:])
        xo_end = self._out_E.dot(xo0) + self._out_H.dot(dac)
        x_end = self._gauge_P[N].dot(x0) + self._gauge_L[N].dot(noise) + self._gauge_U[N].dot(u)
        state.get_mutable_value(self._voltage)[0] = self._out_C.dot(xo_end)
        np.add(self._out_F.dot(xo0), self._out_G.dot(dac), out=state.get_mutable_value(self._frame))
        updated = state.get_mutable_value(self._internal)
        updated[:nx] = x_end
        updated[nx] = held
        updated[nx + 1] = glitch_left
        updated[nx + 2:] = xo_end


def noise_input_gain(config: ForceSensorConfig):
    """Standard deviation of the white gauge noise per fine tick such that
    the analog filter's output has ``noise_std`` times ``noise_scale`` (from
    the energy of the filter's impulse response at the fine rate)."""
    A, B, C, D = discretize_analog(
        *butterworth_analog(config.analog_cutoff_hz, config.analog_order), config.fine_period)
    _, (h,) = signal.dimpulse((A, B, C, D, config.fine_period),
                              n=int(20 * config.fine_rate_hz / config.analog_cutoff_hz))
    energy = float(np.sum(np.asarray(h)[:, 0] ** 2))
    return config.noise_scale * np.asarray(config.noise_std) / np.sqrt(energy)


def AddForceSensor(builder: DiagramBuilder, config: ForceSensorConfig, *, name="force_sensor"):
    """Adds the FS6-120A and its gauge-noise source as the sub-diagram
    ``name``; returns it. Ports: ``wrench`` (input, 3: world [Fx, Fy, Tz] on
    the tip, N and N m), ``tip_state`` (input, 6), ``voltage`` (output, 1, V)
    and ``voltage_frame`` (output, ticks per 1 ms frame, V). The noise source
    is named ``<name>_gauge_noise`` (its seed derives from that name)."""
    def build(inner):
        sensor = inner.AddNamedSystem(name, ForceSensor(config))
        noise = inner.AddNamedSystem(
            f"{name}_gauge_noise",
            RandomSource(RandomDistribution.kGaussian, 3 * sensor.ticks_per_frame, CONTROL_PERIOD))
        inner.Connect(noise.get_output_port(), sensor.GetInputPort("gauge_noise"))
        return {port: sensor.GetInputPort(port) for port in ("wrench", "tip_state")} | {
            port: sensor.GetOutputPort(port) for port in ("voltage", "voltage_frame")}
    return AddSubdiagram(builder, name, build)
