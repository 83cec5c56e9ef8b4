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
   digital filter bypassed). The D/A converting adds its noise around 480 Hz
   (line 322): a ripple at the loop rate, phase-locked to the DAC update, and
   optionally a short glitch at each update (the update strobe's digital
   feed-through, off by default). The analog output passes a reconstruction
   filter (2nd-order, 500 Hz).

Everything analog runs on a fine clock (``fine_rate_hz``, a common multiple
of 480 Hz and 1 kHz: 12 kHz by default), discretized exactly for inputs held
over a fine tick. The model is advanced one 1 ms frame of 12 ticks per update
(lifted, see ``filters.py``), and the 480 Hz ADC sample and DAC update happen
on the tick where they fall. So the 480 Hz staircase and its aliasing when
the DSP samples at 1 kHz come out of the model. Gauge noise comes from
Drake's ``RandomSource`` (seeded by the scenario).

The raw noise at rest, almost +-2 N (line 344), is mostly the ripple: the
DSP's 120 Hz filter passes a 480 Hz ripple at about 0.05 but the gauge
noise, which lies below 120 Hz, nearly whole. So the filtered force at rest
stays under Appendix E's 0.8 N contact switch (line 1894) only if the
gauge noise is small. The thesis gives the ripple's level and waveform
nowhere; a sinusoid is the waveform without harmonics. A pulse train's
harmonic at 960 Hz aliases to 40 Hz in the DSP's 1 kHz samples but not in
the 190 Hz RC channel, and then the two channels' spectra below 120 Hz,
which the thesis found "almost same" (line 322), differ (docs/modelling.md,
"Force sensor").

The output is a voltage, force / ``output_scale_n_per_v`` (200 N/V), with the
sensor's sign: pushing the wall gives a negative Fx; the DSP flips it.

One system serves N environments (the arm axis): every port is env-major,
each environment has its own config (one structure: the same
``analog_order``, ``fine_rate_hz`` and ``adc_rate_hz``) and its own noise
source, and the law is written once over the environments. Environment i is
the single sensor with configs[i], bit for bit; N = 1 is the thesis's sensor.

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
import functools
import math

import numpy as np
from pydrake.common import RandomDistribution
from pydrake.systems.framework import DiagramBuilder, LeafSystem
from pydrake.systems.primitives import Multiplexer, RandomSource
from scipy import signal

from drake_contact.blocks import AddSubdiagram
from drake_contact.plant.arm import CONTROL_PERIOD, RATIO_TOLERANCE
from drake_contact.errors import ScenarioError
from drake_contact.sensing.filters import butterworth_analog, discretize_analog

# The DAC ripple's amplitude (N): the level at which the raw force's 99th
# percentile at rest is 2 N over noise seeds 0-2 (claim S3 of
# drake_contact/app/claims.py, a calibration row).
RIPPLE_N = 2.25


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
    # channel (N, N, N m). Not in the thesis: with the ripple below it gives
    # the +-2 N raw noise at rest (Fig 4.4) and a filtered force at rest under
    # Appendix E's 0.8 N switch.
    noise_std: list[float] = dc.field(default_factory=lambda: [0.1875, 0.1875, 0.0025])
    # Multiplier of noise_std on every channel and of dac_ripple_n (1 = the
    # +-2 N of Fig 4.4): one number to sweep the noise level with.
    noise_scale: float = 1.0
    # Sensor offset on Fx (N), removed by the DSP's tare, and its drift (N/s).
    offset_n: float = 3.0
    offset_drift_n_per_s: float = 0.0
    # The DAC's ripple at the loop rate (N-equivalent amplitude at the DAC,
    # before the output stage): a sinusoid phase-locked to the DAC update,
    # zero at each update. Not in the thesis's numbers: its level gives the
    # raw noise at rest of almost +-2 N (line 344) with the gauge noise.
    dac_ripple_n: float = RIPPLE_N
    # DAC update glitch on the output (N-equivalent height, duration in s; the
    # duration is rounded to whole fine ticks, at least one). Off by default.
    dac_glitch_n: float = 0.0
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
        for field in ("offset_n", "offset_drift_n_per_s", "dac_glitch_n", "dac_ripple_n"):
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


# The fields that fix an ensemble's structure: the state's size
# (analog_order), the frame's fine ticks (fine_rate_hz, also the DSP's) and
# the ADC schedule, which every environment's frame shares (adc_rate_hz).
# Every other field may differ per environment.
_STRUCTURE = ("analog_order", "fine_rate_hz", "adc_rate_hz")


def _environments(config) -> tuple:
    """``config`` (one :class:`ForceSensorConfig` or a sequence of them) as
    one validated config per environment, all of one structure."""
    configs = (config,) if isinstance(config, ForceSensorConfig) else tuple(config)
    if not configs:
        raise ScenarioError("force_sensor: no environment (give one config per environment)")
    for i, c in enumerate(configs):
        c.validate("force_sensor" if len(configs) == 1 else f"force_sensor[{i}]")
    for field in _STRUCTURE:
        values = sorted({getattr(c, field) for c in configs})
        if len(values) > 1:
            raise ScenarioError(f"force_sensor.{field} differs between environments {values}: "
                                "it must be the same in all (one structure per ensemble)")
    return configs


def _lifted_chain(c: ForceSensorConfig, ticks: int) -> dict:
    """One environment's analog chain on the fine clock, lifted to a frame
    of ``ticks`` fine ticks: the gauge filter's state at tick j,
    x_j = P_j x_0 + L_j (g * noise) + U_j u (one matrix per j), the gauges
    C x, and the output stage, frame = F xo_0 + G dac and xo_N = E xo_0 +
    H dac, where dac holds the DAC's output over the frame's ticks (one
    matrix product per frame instead of a loop over ticks); the output is
    C_out xo, at rest at xo = rest * v for a constant DAC output v."""
    A, B, C, _ = discretize_analog(*butterworth_analog(c.analog_cutoff_hz, c.analog_order),
                                   c.fine_period)
    eye3 = np.eye(3)
    A, B, C = np.kron(eye3, A), np.kron(eye3, B), np.kron(eye3, C)
    N = ticks
    powers = [np.linalg.matrix_power(A, k) for k in range(N + 1)]
    # x_j = P_j x_0 + sum_{m<j} A^(j-1-m) B (u + g * noise_m)
    U = [sum((powers[j - 1 - m] @ B for m in range(j)), np.zeros_like(B)) for j in range(N + 1)]
    L = [np.hstack([powers[j - 1 - m] @ B if m < j else np.zeros_like(B) for m in range(N)])
         for j in range(N + 1)]
    Ao, Bo, Co, _ = discretize_analog(*butterworth_analog(c.output_bandwidth_hz, 2),
                                      c.fine_period)
    powers_o = [np.linalg.matrix_power(Ao, k) for k in range(N + 1)]
    return dict(
        gauge_P=powers, gauge_L=L, gauge_U=U, gauge_C=C,
        out_F=np.vstack([Co @ powers_o[i] for i in range(N)]),
        out_G=np.array([[(Co @ powers_o[i - 1 - m] @ Bo)[0, 0] if m < i else 0.0
                         for m in range(N)] for i in range(N)]),
        out_E=powers_o[N],
        out_H=np.hstack([powers_o[N - 1 - m] @ Bo for m in range(N)]),
        out_C=Co[0],
        out_rest=(np.eye(2) - Ao, Bo[:, 0]))

# The fields a lifted chain depends on.
_CHAIN_FIELDS = ("analog_cutoff_hz", "analog_order", "fine_rate_hz", "output_bandwidth_hz")


class ForceSensor(LeafSystem):
    """The FS6-120A on the fine clock, advanced one 1 ms frame per update,
    for N environments at once (the arm axis; N = 1 is the one sensor of the
    thesis's diagram).

    Each update at t_n simulates the fine ticks of [t_n, t_n + 1 ms): the
    gauge filter (exact, by precomputed powers of its tick matrix), the 480 Hz
    ADC sample and DAC hold on the tick where it falls, the DAC's ripple and
    glitch, and the
    output stage. The wrench is the wall's force at t_n, which the plant holds
    over the same interval (at a 1 ms plant step; finer plant steps are seen
    at 1 kHz by the sensor).

    ``config`` is one :class:`ForceSensorConfig`, or a sequence of N (one per
    environment) of one structure: the same ``analog_order``,
    ``fine_rate_hz`` and ``adc_rate_hz``; every other field may differ.
    Every port is env-major: environment i's k values sit at [k i, k (i + 1)).

    Input ports:
      wrench (3 N): [Fx, Fy, Tz] on the tip in world axes (N, N, N m).
      tip_state (6 N): the tip's [x, y, phi, ...]; phi rotates into the sensor frame.
      gauge_noise (3 ticks N): standard normal samples, one per tick and channel.
    Output ports (state outputs, no Python when read):
      voltage (N): the analog Fx output (V) at the end of the frame, i.e. at
        the instant the DSP samples it.
      voltage_frame (ticks N): the output at each fine tick of the frame (V),
        for analog filters downstream (see lifted_analog_filter_system).
    """

    def __init__(self, config):
        super().__init__()
        configs = _environments(config)
        c = configs[0]  # the structure, shared
        n = self._envs = len(configs)
        self._ticks = T = round(c.fine_rate_hz * CONTROL_PERIOD)
        self._adc_every = round(c.fine_rate_hz / c.adc_rate_hz)
        self._fine_rate = c.fine_rate_hz
        self._fine_period = c.fine_period

        # The per-environment numbers on the arm axis, each computed as the
        # single sensor computed it.
        def per_env(value):
            return np.array([value(c) for c in configs], dtype=float)
        self._glitch_lengths = per_env(  # in fine ticks
            lambda c: max(1, round(c.dac_glitch_duration_s * c.fine_rate_hz))).astype(int)
        self._glitch_v = per_env(lambda c: c.dac_glitch_n / c.output_scale_n_per_v)
        self._ripple_v = per_env(
            lambda c: c.noise_scale * c.dac_ripple_n / c.output_scale_n_per_v)
        self._offset = per_env(lambda c: c.offset_n)
        self._drift = per_env(lambda c: c.offset_drift_n_per_s)
        self._drifts = any(c.offset_drift_n_per_s != 0 for c in configs)
        self._scale = per_env(lambda c: c.output_scale_n_per_v)
        self._cal = per_env(lambda c: c.calibration_matrix)
        full = per_env(lambda c: c.adc_full_scale)
        # The ADC per channel [env, channel], and flat (env-major) for the
        # wrench's three channels; the lowest and highest counts are whole numbers.
        self._lsb = 2.0 * full / per_env(lambda c: 2 ** c.adc_bits)[:, None]
        self._lowest, self._highest = -full / self._lsb, full / self._lsb - 1
        self._adc_channels = tuple(a.reshape(-1) for a in (self._lsb, self._lowest, self._highest))
        self._fx_channel = tuple(np.ascontiguousarray(a[:, 0])
                                 for a in (self._lsb, self._lowest, self._highest))
        self._half = np.full(n, 0.5)  # rounds half up: floor(w / lsb + 0.5)
        # Row 0 of every calibration is [1, 0, 0]: the product's Fx is the Fx
        # value exactly (the other terms are signed zeros: finite counts).
        self._fx_passes_through = all(row.tolist() == [1.0, 0.0, 0.0] for row in self._cal[:, 0])
        self._noise_gain = np.concatenate([np.tile(noise_input_gain(c), T) for c in configs])

        made, chains = {}, []  # each distinct chain once: environments often share theirs
        for c in configs:
            key = tuple(getattr(c, field) for field in _CHAIN_FIELDS)
            if key not in made:
                made[key] = _lifted_chain(c, T)
            chains.append(made[key])

        def stacked(key, axis=0):
            return np.stack([chain[key] for chain in chains], axis=axis)
        # x -> M x per environment for every matrix M of the chain; the gauge
        # filter's for each tick of the frame.
        self._gauge_filter = tuple([_products(M) for M in stacked(key, axis=1)]
                                   for key in ("gauge_P", "gauge_L", "gauge_U"))
        self._gauges = _products(stacked("gauge_C"))
        self._output_stage = tuple(_products(stacked(key))
                                   for key in ("out_E", "out_H", "out_F", "out_G"))
        self._output = _products(stacked("out_C")[:, None])  # one row
        self._calibrate = _products(self._cal)
        self._nx = nx = chains[0]["gauge_P"][0].shape[0]
        # Env 0's chain by the single sensor's names, for the first-written
        # update in tests/test_force_sensor.py (a reference for N = 1).
        self._config, self._glitch_ticks = c, int(self._glitch_lengths[0])
        (self._gauge_P, self._gauge_L, self._gauge_U, self._gauge_C, self._out_F, self._out_G,
         self._out_E, self._out_H, self._out_C) = (
             chains[0][key] for key in ("gauge_P", "gauge_L", "gauge_U", "gauge_C", "out_F",
                                        "out_G", "out_E", "out_H", "out_C"))

        self._wrench = self.DeclareVectorInputPort("wrench", 3 * n)
        self._tip = self.DeclareVectorInputPort("tip_state", 6 * n)
        self._noise = self.DeclareVectorInputPort("gauge_noise", 3 * T * n)
        # The sensor has been on for a while: start at its offset, at rest.
        v0 = self._offset / self._scale
        self._voltage = self.DeclareDiscreteState(v0)
        self._frame = self.DeclareDiscreteState(np.repeat(v0, T))
        # Field-major, each field env-major: [gauge filter states (nx N),
        # held volts (N), glitch ticks left (N), output-stage states (2 N)],
        # at the DC steady state of the offset.
        self._gauge_field = slice(0, nx * n)
        self._held_field = slice(nx * n, (nx + 1) * n)
        self._glitch_field = slice((nx + 1) * n, (nx + 2) * n)
        self._output_field = slice((nx + 2) * n, (nx + 4) * n)
        self._internal = self.DeclareDiscreteState(np.concatenate(
            [np.zeros(nx * n), v0, np.zeros(n)]
            + [np.linalg.solve(chain["out_rest"][0], chain["out_rest"][1] * v)
               for v, chain in zip(v0, chains)]))
        # The frame plans by tick phase and glitch carry, each made when first
        # met (not all up front: a slow ADC with a long glitch has millions).
        self._plans = {}
        self.DeclarePeriodicDiscreteUpdateEvent(CONTROL_PERIOD, 0.0, self._update)
        self.DeclareStateOutputPort("voltage", self._voltage)
        self.DeclareStateOutputPort("voltage_frame", self._frame)

    @property
    def ticks_per_frame(self):
        return self._ticks

    @property
    def num_envs(self):
        return self._envs

    # The update runs once per 1 ms step in Python, for all environments. Its
    # vectors are flat and env-major, as the ports (for N = 1 the single
    # sensor's arrays), the products are one BLAS gemv (or dot) per
    # environment, the call the single sensor made (see _products), and the
    # ADC's numbers are per environment [env]. So every floating-point
    # operation of an environment is the one of the straightforward single
    # sensor (kept as ``_adc_reference`` and in tests/test_force_sensor.py),
    # in the same order: the results are bit-identical (NaN's sign bit
    # included for N = 1; for N > 1 the NaN of a diverged environment may
    # differ in sign from its single run's).

    def _plan(self, phase, glitch_left):
        """The frame's ADC ticks (the first at -first_tick mod adc_every),
        the lengths of the frame's spans between them (the DAC's holds, per
        environment), each environment's DAC artefacts over the frame's ticks
        (flat: its ripple plus its glitch train, glitch_ticks ticks after each
        DAC update, carried across frames) and glitch ticks left after it,
        for a frame whose first fine tick is ``phase`` modulo the ADC period,
        with ``glitch_left`` (per environment) glitch ticks carried in. They
        repeat: the plans of every phase are made once."""
        T = self._ticks
        adc_ticks = tuple(range(-phase % self._adc_every, T, self._adc_every))
        # Each environment's spans, env-major: the held value's and each sample's.
        holds = np.tile(np.diff((0,) + adc_ticks + (T,)), self._envs) if adc_ticks else T
        glitch_left = np.array(glitch_left, dtype=float).astype(int)
        tick = np.arange(T)
        on = tick < np.minimum(glitch_left, T)[:, None]
        for i in adc_ticks:
            on |= (tick >= i) & (tick < i + self._glitch_lengths[:, None])
        glitch = np.where(on, self._glitch_v[:, None], 0.0)
        # The ripple over the frame's ticks: sin of the tick's phase in the
        # ADC loop (0 at each DAC update), scaled per environment.
        ripple = np.sin(2.0 * np.pi * ((phase + tick) % self._adc_every) / self._adc_every)
        artefacts = (glitch + self._ripple_v[:, None] * ripple).reshape(-1)
        artefacts.flags.writeable = False  # shared by every update of the plan
        if adc_ticks:
            glitch_left = np.maximum(adc_ticks[-1] + self._glitch_lengths - T, 0)
        else:
            glitch_left = np.maximum(glitch_left - T, 0)
        return adc_ticks, holds, artefacts, glitch_left.astype(float)

    def _adc(self, gauges, phi, t):
        """Sample, rotate into the sensor frame, offset, quantize, calibrate:
        the held volts [env] of ``gauges`` (flat [env, channel]) at tip angles
        ``phi`` [env] and time ``t``."""
        fx, fy, tz = gauges[0::3], gauges[1::3], gauges[2::3]
        cos, sin = np.cos(phi), np.sin(phi)
        offset = self._offset + self._drift * t if self._drifts else self._offset
        fx_wrench = cos * fx + sin * fy + offset
        if self._fx_passes_through:
            # Fx alone: its count is the held value whenever the other
            # channels are finite, i.e. when fx_wrench and tz are (then their
            # dot product is finite, or overflows: the check below is exact
            # either way).
            lsb, lowest, highest = self._fx_channel
            counts = np.minimum(np.maximum(np.floor(fx_wrench / lsb + self._half), lowest),
                                highest)
            held = counts * lsb / self._scale
            finite = math.isfinite(fx_wrench.dot(tz))
        else:
            wrench = np.empty(len(gauges))
            wrench[0::3] = fx_wrench
            wrench[1::3] = -sin * fx + cos * fy
            wrench[2::3] = tz
            lsb, lowest, highest = self._adc_channels
            # Clip to the ADC's counts (whole numbers, so after the floor).
            counts = np.minimum(np.maximum(np.floor(wrench / lsb + 0.5), lowest), highest)
            held = self._calibrate(counts * lsb)[0::3] / self._scale
            # NaN in any channel carries into held; inf is clipped.
            finite = math.isfinite(held.dot(held))
        if not finite:
            # A sample that is not finite (a diverged environment) goes through
            # the numpy-scalar ADC, as the single sensor's did: the numbers
            # are the same either way, but which NaN comes out (its sign)
            # depends on the form of the arithmetic.
            suspect = fx_wrench + tz if self._fx_passes_through else held
            for env in np.flatnonzero(~np.isfinite(suspect)):
                held[env] = self._adc_reference(gauges[3 * env:3 * env + 3], phi[env], t, env)
        return held

    def _adc_reference(self, gauges, phi, t, env=0):
        """The ADC of environment ``env`` in numpy, as first written, on one
        sample: the same IEEE operations as ``_adc`` (with numpy scalars)."""
        fx, fy, tz = gauges
        cos, sin = np.cos(phi), np.sin(phi)
        wrench = np.array([cos * fx + sin * fy, -sin * fx + cos * fy, tz])
        wrench[0] += self._offset[env] + self._drift[env] * t
        lsb = self._lsb[env]
        counts = np.clip(np.floor(wrench / lsb + 0.5), self._lowest[env], self._highest[env])
        return float((self._cal[env] @ (counts * lsb))[0]) / self._scale[env]

    def _update(self, context, state):
        T = self._ticks
        internal = context.get_discrete_state(self._internal).value()
        x0, held = internal[self._gauge_field], internal[self._held_field]
        xo0 = internal[self._output_field]
        u = self._wrench.Eval(context)
        noise = self._noise.Eval(context) * self._noise_gain
        t0 = context.get_time()
        key = (round(t0 * self._fine_rate) % self._adc_every,
               *internal[self._glitch_field].tolist())
        plan = self._plans.get(key)
        if plan is None:
            plan = self._plans[key] = self._plan(key[0], key[1:])
        adc_ticks, holds, artefacts, glitch_left = plan
        P, L, U = self._gauge_filter
        E, H, F, G = self._output_stage
        # The DAC over the frame: the held value, replaced at each ADC tick by
        # its sample (values: each environment's, env-major, one per span),
        # plus the DAC's artefacts (artefacts + held is held + artefacts:
        # commutative).
        values = held
        if adc_ticks:
            spans = len(adc_ticks) + 1
            values = held.repeat(spans)
            phi = self._tip.Eval(context)[2::6]
            for span, i in enumerate(adc_ticks, 1):
                x_i = P[i](x0) + L[i](noise) + U[i](u)
                values[span::spans] = self._adc(self._gauges(x_i), phi,
                                                t0 + i * self._fine_period)
            held = values[spans - 1::spans]
        dac = artefacts + values.repeat(holds)
        updated = state.get_mutable_value(self._internal)
        x_end = updated[self._gauge_field]
        np.add(P[T](x0), L[T](noise), out=x_end)
        np.add(x_end, U[T](u), out=x_end)
        updated[self._held_field] = held
        updated[self._glitch_field] = glitch_left
        xo_end = updated[self._output_field]
        np.add(E(xo0), H(dac), out=xo_end)
        self._output(xo_end, out=state.get_mutable_value(self._voltage))
        np.add(F(xo0), G(dac), out=state.get_mutable_value(self._frame))


def _products(matrices):
    """x -> M x for each environment's matrix M, ``matrices`` [env, row,
    col]: x flat [env, col] gives M x flat [env, row] (into ``out`` if
    given). One BLAS gemv per environment (a dot for one row), the call the
    single sensor made: for one environment ``M.dot`` itself (so for N = 1
    the update's arrays and calls are the single sensor's), for N
    np.matvec on the [env, col] view."""
    if len(matrices) == 1:
        return matrices[0].dot
    n, rows, cols = matrices.shape

    def times(x, out=None):
        return np.matvec(matrices, x.reshape(n, cols),
                         out=None if out is None else out.reshape(n, rows)).reshape(-1)
    return times


def noise_input_gain(config: ForceSensorConfig):
    """Standard deviation of the white gauge noise per fine tick such that
    the analog filter's output has ``noise_std`` times ``noise_scale`` (from
    the energy of the filter's impulse response at the fine rate)."""
    energy = _impulse_energy(config.analog_cutoff_hz, config.analog_order, config.fine_rate_hz)
    return config.noise_scale * np.asarray(config.noise_std) / np.sqrt(energy)


@functools.lru_cache(maxsize=256)
def _impulse_energy(cutoff_hz, order, fine_rate_hz):
    """The energy of the analog filter's impulse response at the fine rate
    (a float; made once per filter, as every environment of an ensemble asks)."""
    fine_period = 1.0 / fine_rate_hz
    A, B, C, D = discretize_analog(*butterworth_analog(cutoff_hz, order), fine_period)
    _, (h,) = signal.dimpulse((A, B, C, D, fine_period), n=int(20 * fine_rate_hz / cutoff_hz))
    return float(np.sum(np.asarray(h)[:, 0] ** 2))


def AddForceSensor(builder: DiagramBuilder, config, *, name="force_sensor"):
    """Adds the FS6-120A and its gauge-noise sources as the sub-diagram
    ``name``, for one environment per config (``config``: one
    :class:`ForceSensorConfig` or a sequence of N); returns it. Ports,
    env-major: ``wrench`` (input, 3 N: world [Fx, Fy, Tz] on the tip, N and
    N m), ``tip_state`` (input, 6 N), ``voltage`` (output, N, V) and
    ``voltage_frame`` (output, ticks per 1 ms frame x N, V). Each
    environment has its own noise source, seeded from its name: for one
    environment ``<name>_gauge_noise``, for N ``<name>_gauge_noise@<i>``
    (environment i's), multiplexed into the sensor."""
    def build(inner):
        sensor = inner.AddNamedSystem(name, ForceSensor(config))
        n, size = sensor.num_envs, 3 * sensor.ticks_per_frame
        names = [f"{name}_gauge_noise"] if n == 1 else [
            f"{name}_gauge_noise@{i}" for i in range(n)]
        sources = [inner.AddNamedSystem(source, RandomSource(
            RandomDistribution.kGaussian, size, CONTROL_PERIOD)) for source in names]
        if n == 1:
            inner.Connect(sources[0].get_output_port(), sensor.GetInputPort("gauge_noise"))
        else:
            mux = inner.AddNamedSystem(f"{name}_gauge_noise_mux", Multiplexer([size] * n))
            for i, source in enumerate(sources):
                inner.Connect(source.get_output_port(), mux.get_input_port(i))
            inner.Connect(mux.get_output_port(), sensor.GetInputPort("gauge_noise"))
        return {port: sensor.GetInputPort(port) for port in ("wrench", "tip_state")} | {
            port: sensor.GetOutputPort(port) for port in ("voltage", "voltage_frame")}
    return AddSubdiagram(builder, name, build)
