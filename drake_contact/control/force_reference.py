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
"""

import dataclasses as dc

import numpy as np
from pydrake.systems.framework import LeafSystem

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

    def probe(self, since_contact):
        """The probing multisine (N) at ``since_contact`` s after contact."""
        n = len(self.probe_frequencies_hz)
        return self.probe_amplitude_n / n * sum(
            np.sin(2 * np.pi * f * since_contact - np.pi * k * (k - 1) / n)
            for k, f in enumerate(self.probe_frequencies_hz, start=1))

    def at(self, since_contact):
        """f_d (N) at ``since_contact`` seconds after the first contact
        (negative: before contact)."""
        if since_contact < 0:
            return self.levels[0]
        if self.probe_amplitude_n:
            return self._at(since_contact) + self.probe(since_contact)
        return self._at(since_contact)

    def _at(self, since_contact):
        """f_d without the probe, in contact."""
        if self.hold_s:
            if since_contact < self.hold_s - TIME_TOLERANCE_S:
                return self.levels[0]
            since_contact -= self.hold_s
        cycle = self.half_period_s * len(self.levels)
        k = int(np.floor(since_contact / self.half_period_s + RATIO_TOLERANCE)) % len(self.levels)
        tau = since_contact - cycle * np.floor(since_contact / cycle + RATIO_TOLERANCE)
        return self.levels[k] + self.sine_amplitude_n * np.sin(
            2 * np.pi * self.sine_frequency_hz * tau)


class ForceReference(LeafSystem):
    """Input port: contact_info (4, [time of first contact or -1, x, y, phi at
    the switch]). Output port: force_desired (1, N), updated every 1 ms: at
    each sample it computes the value of the next one (a state output, so
    the controller that reads it and whose contact_info it reads sample in
    the same event without an algebraic loop)."""

    def __init__(self, config: ForceReferenceConfig):
        super().__init__()
        config.validate()
        self._config = config
        self._contact = self.DeclareVectorInputPort("contact_info", 4)
        force = self.DeclareDiscreteState([config.levels[0]])
        DeclareSampledUpdate(self, self._update)
        self.DeclareStateOutputPort("force_desired", force)

    def _update(self, context, discrete_state):
        if not is_sample_time(context.get_time()):
            return  # t = 0: the first sample is at 1 ms
        t_contact = self._contact.Eval(context)[0]
        # The value for the next sample (the controller reads it then).
        t = context.get_time() + CONTROL_PERIOD
        since = t - t_contact if t_contact >= 0 else -1.0
        discrete_state.set_value([self._config.at(since)])
