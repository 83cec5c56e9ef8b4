"""The desired normal force f_d (thesis chapter 6 and Appendix E).

f_d is a function of the time since the first contact switch: constant, or
a square wave cycling through ``levels`` every ``half_period_s`` (the thesis:
20 N, then 10 N after 2.5 s, back to 20 N at 5 s, ...), plus an optional
sine A sin(2 pi f tau). As in the thesis's code, tau restarts with every
square-wave cycle (its counter resets every 5 s). Before contact f_d is the
first level. The option ``hold_s`` (ours, for the ``adaptive_hybrid``
scenario) holds the first level for that long after contact before the
cycle starts (its clock then starts at 0).

The option ``probe_amplitude_n`` (ours) adds a small probing
signal in contact, for identification: a multisine over
``probe_frequencies_hz`` with Schroeder's phases (M. R. Schroeder, "Synthesis
of low-peak-factor signals and binary sequences with low autocorrelation",
IEEE Trans. Information Theory 16(1):85-89, 1970), each of the N components
of amplitude A / N, so that |probe| <= A whatever the frequencies:

    probe(tau) = A / N sum_k sin(2 pi f_k tau + phi_k),
    phi_k = -pi k (k - 1) / N,  k = 1..N,

with tau the time since the first contact. Its steady force rises and falls
with the wall's speed (B_e) and acceleration (M_e) as well as its
displacement (K_e), so that the identifiers see more than the ~100 ms
switch transient; see docs/studies/identification.md for what it buys and costs.

One :class:`ForceReference` serves N environments (an ensemble; one config
each, a single config for one): :class:`ForceSchedule` evaluates the law
above once for all of them, on arrays over the arm axis, each environment
bit for bit what it computes alone. The configs may differ in every number,
the count of levels included, but not in whether the probe is on.
"""

import dataclasses as dc
from collections.abc import Sequence

import numpy as np
from pydrake.systems.framework import LeafSystem

from drake_contact.blocks import environment_configs
from drake_contact.plant.arm import (
    CONTROL_PERIOD, RATIO_TOLERANCE, TIME_TOLERANCE_S, DeclareSampledUpdate, is_sample_time)
from drake_contact.errors import ScenarioError


@dc.dataclass
class ForceReferenceConfig:
    """The desired force schedule."""

    # Force levels (N) cycled through; one level = a constant reference.
    levels: list[float] = dc.field(default_factory=lambda: [20.0])
    # Time on each level (s).
    half_period_s: float = 2.5
    # Added sine: amplitude (N) and frequency (Hz); the thesis: 4 sin(pi t).
    sine_amplitude_n: float = 0.0
    sine_frequency_hz: float = 0.5
    # Hold the first level (no sine) for this long after contact before the
    # cycle starts (s); 0 = the thesis's schedule.
    hold_s: float = 0.0
    # Probing multisine in contact (ours): its bound A (N; 0 = off)
    # and frequencies (Hz); see the module doc.
    probe_amplitude_n: float = 0.0
    probe_frequencies_hz: list[float] = dc.field(
        default_factory=lambda: [1.7])

    def validate(self, prefix="force_reference"):
        if not self.levels or not all(np.isfinite(x) and x >= 0 for x in self.levels):
            raise ScenarioError(f"{prefix}.levels = {self.levels} is out of range: "
                                "must be one or more forces >= 0 N")
        if not (self.half_period_s > 0):
            raise ScenarioError(f"{prefix}.half_period_s = {self.half_period_s} is out of range: "
                                "must be > 0 s")
        if not np.isfinite(self.sine_amplitude_n):
            raise ScenarioError(f"{prefix}.sine_amplitude_n = {self.sine_amplitude_n} is out of "
                                "range: must be finite (N)")
        if not (np.isfinite(self.sine_frequency_hz) and self.sine_frequency_hz >= 0):
            raise ScenarioError(f"{prefix}.sine_frequency_hz = {self.sine_frequency_hz} is out of "
                                "range: must be >= 0 Hz")
        if not (np.isfinite(self.hold_s) and self.hold_s >= 0):
            raise ScenarioError(f"{prefix}.hold_s = {self.hold_s} is out of range: must be >= 0 s")
        if not (np.isfinite(self.probe_amplitude_n) and 0 <= self.probe_amplitude_n <= 10):
            raise ScenarioError(f"{prefix}.probe_amplitude_n = {self.probe_amplitude_n} is out of "
                                "range: must be in [0, 10] N")
        if not (1 <= len(self.probe_frequencies_hz) <= 20 and all(
                np.isfinite(x) and 0 < x <= 100 for x in self.probe_frequencies_hz)):
            raise ScenarioError(f"{prefix}.probe_frequencies_hz = {self.probe_frequencies_hz} is "
                                "out of range: must be 1 to 20 frequencies in (0, 100] Hz")

    def at(self, since_contact):
        """f_d (N) at ``since_contact`` seconds after the first contact
        (negative: before contact); :class:`ForceSchedule`'s law."""
        return float(ForceSchedule([self]).at(np.array([float(since_contact)]))[0])


def _configs(config):
    return environment_configs(config, ForceReferenceConfig, "force_reference")


class ForceSchedule:
    """f_d of N environments (one config each), as arrays over the arm
    axis: :meth:`at` maps the (N,) times since the first contact to the
    (N,) desired forces, with the IEEE operations of the module doc's law
    in its order, elementwise. The configs may differ in their numbers
    (levels, their count, periods, hold, sine, the probe's amplitude and
    frequencies), not in whether the probe is on or how many frequencies it
    sums."""

    def __init__(self, configs):
        configs = _configs(configs)
        probe = configs[0].probe_amplitude_n != 0
        count = len(configs[0].probe_frequencies_hz)
        for i, c in enumerate(configs):
            if (c.probe_amplitude_n != 0) != probe:
                raise ScenarioError(
                    f"force_reference.probe_amplitude_n: environment {i} switches the probe "
                    f"{'on' if not probe else 'off'} and environment 0 "
                    f"{'on' if probe else 'off'}: the configs must share their structure")
            if probe and len(c.probe_frequencies_hz) != count:
                raise ScenarioError(
                    f"force_reference.probe_frequencies_hz: environment {i} has "
                    f"{len(c.probe_frequencies_hz)} frequencies and environment 0 {count}: "
                    "the configs must share their structure")
        size = max(len(c.levels) for c in configs)
        self.size = count_envs = len(configs)
        # Levels, padded to a common count (the padding is never indexed),
        # flat: environment i's level k at i * size + k.
        levels = np.array([[float(x) for x in c.levels] + [0.0] * (size - len(c.levels))
                           for c in configs])
        self._levels = levels.ravel()
        self._level_rows = np.arange(count_envs, dtype=float) * size if count_envs > 1 else None
        self.first_levels = np.ascontiguousarray(levels[:, 0])
        self._count = np.array([len(c.levels) for c in configs], dtype=float)
        # Parts no environment uses are skipped where that changes no bit:
        # one level (k = 0); no sine (level + 0 sin(.) is the level unless
        # the level is -0.0); no hold (since - 0 is since, and since >= 0 is
        # never below -TIME_TOLERANCE_S).
        self._square = size > 1
        self._sine = any(np.signbit(c.sine_amplitude_n) or c.sine_amplitude_n != 0
                         or any(np.signbit(x) for x in c.levels) for c in configs)
        self._hold = any(c.hold_s != 0 for c in configs)
        # since / [half period (square wave), cycle (sine)], floored in one
        # call ((N,) for one of them, (N, 2) for both).
        self._divisors = np.array(
            [[c.half_period_s] * self._square + [c.half_period_s * len(c.levels)] * self._sine
             for c in configs], dtype=float).reshape(count_envs, -1)
        self._columns = self._divisors.shape[1]
        if self._columns == 1:
            self._divisors = self._divisors[:, 0].copy()
        self._tolerance = np.full_like(self._divisors, RATIO_TOLERANCE)
        self._ratios = np.empty_like(self._divisors)
        self._floors = np.empty_like(self._divisors)
        self._cycle = np.array([c.half_period_s * len(c.levels) for c in configs], dtype=float)
        self._hold_s = np.array([c.hold_s for c in configs], dtype=float)
        self._hold_end = np.array([c.hold_s - TIME_TOLERANCE_S for c in configs], dtype=float)
        self._sine_amplitude = np.array([c.sine_amplitude_n for c in configs], dtype=float)
        self._sine_omega = np.array([2 * np.pi * c.sine_frequency_hz for c in configs])
        self._probe = probe
        if probe:
            # probe = A / n sum_k sin(2 pi f_k tau - pi k (k - 1) / n), the
            # terms summed in k's order from 0 (Python's sum).
            self._probe_scale = np.array([c.probe_amplitude_n / count for c in configs])
            self._probe_omega = [np.array([2 * np.pi * c.probe_frequencies_hz[k] for c in configs])
                                 for k in range(count)]
            self._probe_phase = [np.full(count_envs, np.pi * k * (k - 1) / count)
                                 for k in range(1, count + 1)]
        # Work buffers (numpy's per-call cost dominates on (N,) arrays).
        self._index = np.empty(count_envs)

    def at(self, since):
        """f_d (N, one per environment) at ``since`` (N) seconds after each
        one's first contact (negative: before contact, the first level)."""
        return np.where(since < 0, self.first_levels, self.in_contact(since))

    def in_contact(self, since):
        """f_d (N) at ``since`` (N) >= 0 s after the first contact (for a
        negative one, a number to be discarded). May return a buffer that
        the next call overwrites, or ``first_levels``."""
        shifted = since - self._hold_s if self._hold else since
        force = self.first_levels
        if self._square or self._sine:
            # k = floor(t / half period + tol) mod (levels); tau = t - cycle
            # floor(t / cycle + tol), the sine's time within the cycle.
            ratios, floors = self._ratios, self._floors
            np.divide(shifted if self._columns == 1 else shifted[:, None], self._divisors,
                      ratios)
            np.add(ratios, self._tolerance, floors)
            np.floor(floors, ratios)
            if self._square:
                index, k = self._index, ratios if self._columns == 1 else ratios[:, 0]
                np.remainder(k, self._count, index)
                if self._level_rows is not None:
                    np.add(index, self._level_rows, index)
                force = self._levels.take(index.astype(np.intp))
            if self._sine:
                tau = shifted - self._cycle * (ratios if self._columns == 1 else ratios[:, 1])
                force = force + self._sine_amplitude * np.sin(self._sine_omega * tau)
        if self._hold:
            force = np.where(since < self._hold_end, self.first_levels, force)
        if self._probe:
            total = 0.0
            for omega, phase in zip(self._probe_omega, self._probe_phase):
                total = total + np.sin(omega * since - phase)
            force = force + self._probe_scale * total
        return force


class ForceReference(LeafSystem):
    """The desired force of N environments (one config each, see
    :class:`ForceSchedule`; a single config: N = 1).

    Input port: contact_info (4 N, env-major: environment i's [time of first
    contact or -1, x, y, phi at the switch] at [4 i, 4 i + 4)). Output port:
    force_desired (N, one per environment; N), updated every 1 ms: at each
    sample it computes the value of the next one (a state output, so the
    controller that reads it and whose contact_info it reads sample in the
    same event without an algebraic loop)."""

    def __init__(self, config: ForceReferenceConfig | Sequence[ForceReferenceConfig]):
        super().__init__()
        configs = _configs(config)
        for i, c in enumerate(configs):
            c.validate("force_reference" if len(configs) == 1 else f"force_reference[{i}]")
        self._schedule = ForceSchedule(configs)
        size = self._schedule.size
        self._contact = self.DeclareVectorInputPort("contact_info", 4 * size)
        force = self.DeclareDiscreteState(self._schedule.first_levels)
        self._zeros = np.zeros(size)
        self._since = np.empty(size)
        self._earliest = np.empty(size)
        self._valid = np.empty(size, dtype=bool)
        DeclareSampledUpdate(self, self._update)
        self.DeclareStateOutputPort("force_desired", force)

    def _update(self, context, discrete_state):
        if not is_sample_time(context.get_time()):
            return  # t = 0: the first sample is at 1 ms
        # The value for the next sample (the controller reads it then), at
        # since = t - t_contact for the environments in contact (t_contact
        # >= 0; since >= 0 then, unless the input says otherwise); the
        # first level for the others.
        t_contact = self._contact.Eval(context)[::4]
        since = np.subtract(context.get_time() + CONTROL_PERIOD, t_contact, self._since)
        valid = np.greater_equal(np.minimum(since, t_contact, out=self._earliest), self._zeros,
                                 self._valid)
        touching = np.count_nonzero(valid)
        schedule = self._schedule
        if not touching:  # no environment in contact yet
            discrete_state.set_value(schedule.first_levels)
        elif touching == len(valid):
            discrete_state.set_value(schedule.in_contact(since))
        else:
            discrete_state.set_value(np.where(valid, schedule.in_contact(since),
                                              schedule.first_levels))
