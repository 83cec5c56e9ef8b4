"""The thesis's checkable claims, pre-registered, and their scorer.

Each :class:`ThesisClaim` is one sentence of the thesis (its line numbers in
``shared/thesis/kiguchi-1993-thesis.txt``, its words), the runs and the
thesis's own forms that test it, and a criterion that restates it: the
thesis's numbers with a stated tolerance, its qualitative words ("realistic",
"follows acceptable well", "can not reach", "small positive", "after a few
minutes") as a reading with the reason for that reading. The criteria were
written before the results were seen; one changes only with its reason in
the commit that changes it.

The claims are read in the thesis's own terms: what the thesis could
measure (the measured force, f / x from the 5 N switch point, an
estimate's own settling), on its own forms (``rls``, ``rls_raw``, ``nn``,
``nn_slow``; the neural controller against its hybrid part alone), never
against a ground truth the thesis did not have. Our forms scored against
the ground truth are the reproduction's second table
(:data:`drake_contact.app.reproduce.RESULTS`).

A claim *holds* on a seed when its criterion does; it is *reproduced* when
it holds on every seed. Rows that a calibration fits, or that are tied to a
fitted parameter algebraically, are marked ``calibration``: shown, never
counted as reproduced. A claim the model does not reproduce is a *documented
deviation* only with its cause (:attr:`ThesisClaim.deviation`): the
ablation that shows it, or "cause not isolated" with what was tried.
"""

import csv
import dataclasses as dc
import math
from collections.abc import Callable
from pathlib import Path

import numpy as np

#: Where the thesis's line numbers point, relative to the project's root.
THESIS_TEXT = "../shared/thesis/kiguchi-1993-thesis.txt"

#: The figures of the identification runs span the first 4 s after the
#: switch (Figs 6.1, 6.4, 6.7, 6.9): "identified" is read against the value
#: an estimate holds at their end.
FIGURE_SPAN_S = 4.0
#: An estimate is "practically identified" once it stays within this of its
#: value at the end of the figure's span.
IDENTIFIED_TOLERANCE = 0.10
#: "About" a time the thesis reads off a figure: within this fraction of it.
ABOUT = 0.5
#: "Almost same" for two stiffness readings (line 742: "less than 6 %").
ALMOST_SAME = 0.06
#: A thesis reading of f / x reproduced: within this of its value.
READING_TOLERANCE = 0.05
#: "Realistic" damping: positive, and within this factor of the wall's.
REALISTIC_FACTOR = 3.0
#: "Small positive" mass (kg): above 0 and at most this.
SMALL_MASS_KG = 0.5
#: "Follows": the measured force's RMSE about f_d in the figure's 4 s slot is
#: at most this fraction of the hybrid part alone's in the same slot.
FOLLOWS_FRACTION = 0.5
#: The 4 s slot of Figs 6.11, 6.16 starts "about 10 seconds" in (s after contact).
SLOT_START_S = 10.0
SLOT_S = 4.0
#: "Can not reach": the measured force's mean over the last second of a
#: level misses the level by more than this (N), on the short side.
REACH_MARGIN_N = 1.0
#: "Almost zero" network output error: its 100 ms moving RMS at most this (N),
#: about the filtered force's own noise.
ALMOST_ZERO_N = 1.0


class Missing(Exception):
    """A run a claim needs is missing or did not complete."""


class Seed:
    """One seed's runs: ``metrics(name)``, ``log(name)`` and
    ``baseline_log(name)`` of ``out/<name>/seed_<seed>/``; a missing or
    unfinished run raises :class:`Missing`. Logs are loaded once."""

    def __init__(self, out: Path, seed: int, metrics: Callable[[str], dict]):
        self.out, self.seed, self._metrics = Path(out), seed, metrics
        self._logs = {}

    def metrics(self, name) -> dict:
        return self._metrics(name)

    def _load(self, folder: Path) -> dict:
        if folder not in self._logs:
            path = folder / "log.npz"
            if not path.exists():
                raise Missing(str(folder))
            with np.load(path) as data:
                self._logs[folder] = {key: data[key] for key in data.files}
        return self._logs[folder]

    def log(self, name) -> dict:
        self.metrics(name)
        return self._load(self.out / name / f"seed_{self.seed}")

    def scenario(self, name):
        """The run's scenario as it ran (its ``scenario.yaml``)."""
        from drake_contact.scenario import load_scenario
        self.metrics(name)
        return load_scenario(self.out / name / f"seed_{self.seed}" / "scenario.yaml")

    def baseline_log(self, name) -> dict:
        self.metrics(name)
        return self._load(self.out / name / f"seed_{self.seed}" / "baseline")


# Measures on one seed's runs -------------------------------------------------------------


def switch_time(log) -> float:
    """The time of the first switch to hybrid control (s)."""
    info = log["contact_info"]
    if not np.any(info[:, 0] >= 0):
        raise Missing("no contact")
    return float(info[-1, 0])


def identified_after(seed: Seed, run: str, form: str, column: int = 2):
    """Time from the switch after which the form's estimate (column 2: K_e)
    stays within :data:`IDENTIFIED_TOLERANCE` of its value
    :data:`FIGURE_SPAN_S` after the switch (s), in the figure's span."""
    log = seed.log(run)
    t, t_c = log["t"], switch_time(log)
    estimate = log[f"impedance_{form}"][:, column]
    span = (t >= t_c) & (t <= t_c + FIGURE_SPAN_S + 1e-9)
    reference = estimate[np.flatnonzero(span)[-1]]
    within = np.abs(estimate / reference - 1) < IDENTIFIED_TOLERANCE
    outside = np.flatnonzero(span & ~within)
    return 0.0 if len(outside) == 0 else float(t[outside[-1] + 1] - t_c)


def error_near_zero_after(seed: Seed, run: str, form: str):
    """Time from the switch after which the 100 ms moving RMS of the
    network's output error (filtered force - its estimate, Fig 6.8) stays at
    most :data:`ALMOST_ZERO_N`, within the figure's span (s; None: never)."""
    log = seed.log(run)
    t, t_c = log["t"], switch_time(log)
    error = log["force_filtered"] - log[f"force_estimate_{form}"]
    span = np.flatnonzero((t >= t_c) & (t <= t_c + FIGURE_SPAN_S + 1e-9))
    width = 100
    squares = np.convolve(error[span] ** 2, np.ones(width) / width, mode="full")[:len(span)]
    outside = np.flatnonzero(np.sqrt(squares) > ALMOST_ZERO_N)
    if len(outside) and outside[-1] == len(span) - 1:
        return None
    return 0.0 if len(outside) == 0 else float(t[span[outside[-1] + 1]] - t_c)


def impedance(seed: Seed, run: str, form: str) -> dict:
    """The form's final (M_e, B_e, K_e) by name."""
    return seed.metrics(run)[f"identified_impedance_{form}"]


def stiffness_ratio(seed: Seed, run: str) -> float:
    """f / x as the thesis computed it (filtered force over the displacement
    from the 5 N switch point), mean over the run's last second (N/m)."""
    value = seed.metrics(run).get("stiffness_ratio_final_n_per_m")
    if value is None:
        raise Missing(run)
    return value


def slot_rmse(log, start_s: float, width_s: float = SLOT_S) -> float:
    """RMSE of the measured (filtered) force about f_d over ``width_s`` from
    ``start_s`` after the switch (N)."""
    t, t_c = log["t"], switch_time(log)
    slot = (t >= t_c + start_s) & (t < t_c + start_s + width_s)
    if not slot.any() or t[-1] < t_c + start_s + width_s - 0.01:
        raise Missing("slot past the run's end")
    return float(np.sqrt(np.mean((log["force_filtered"][slot]
                                  - log["force_desired"][slot]) ** 2)))


def follows_ratio(seed: Seed, run: str, start_s: float = SLOT_START_S) -> float:
    """The run's slot RMSE over its hybrid part alone's in the same slot."""
    return slot_rmse(seed.log(run), start_s) / slot_rmse(seed.baseline_log(run), start_s)


def level_shortfalls(seed: Seed, run: str) -> float:
    """How far the measured force falls short of f_d over the last second of
    each completed level, the smallest over the levels (N): positive when it
    stays below a raised level and above a lowered one."""
    log = seed.log(run)
    t, t_c, f_d = log["t"], switch_time(log), log["force_desired"]
    after = np.flatnonzero(t >= t_c)
    changes = after[np.flatnonzero(np.diff(f_d[after]) != 0) + 1]
    shortfalls = []
    for begin, end in zip(changes[:-1], changes[1:]):
        last = slice(max(begin, end - 1000), end)
        level, previous = f_d[begin], f_d[begin - 1]
        mean = float(np.mean(log["force_filtered"][last]))
        shortfalls.append((level - mean) if level > previous else (mean - level))
    if not shortfalls:
        raise Missing("no completed level")
    return min(shortfalls)


def psd_difference_db(seed: Seed, run: str, band_hz: float = 120.0) -> float:
    """Largest |difference| of the unfiltered and the 190 Hz RC-filtered
    force's PSDs at 0 < f <= band_hz while pressing (dB)."""
    from drake_contact.scoring.spectra import welch_psd, windows
    log = seed.log(run)
    _, pressing = windows(log, 0.0)
    f, raw = welch_psd(log["force_measured"][pressing])
    _, filtered = welch_psd(log["force_measured_antialiased"][pressing])
    band = (f > 0) & (f <= band_hz)
    return float(np.max(np.abs(10 * np.log10(raw[band] / filtered[band]))))


def filtered_line_db(seed: Seed, run: str) -> float:
    """The 480 Hz line of the RC-filtered force's PSD above its floor (dB)."""
    from drake_contact.scoring.spectra import line_above_floor_db, welch_psd, windows
    log = seed.log(run)
    _, pressing = windows(log, 0.0)
    f, filtered = welch_psd(log["force_measured_antialiased"][pressing])
    return float(line_above_floor_db(f, filtered))


def filtered_force_at_rest(seed: Seed, run: str) -> float:
    """Largest |filtered force| at rest, after the tare and before contact (N)."""
    from drake_contact.scoring.spectra import windows
    log = seed.log(run)
    rest, _ = windows(log, seed.scenario(run).dsp.tare_window_s)
    if rest.sum() < 200:
        raise Missing("no rest window")
    return float(np.max(np.abs(log["force_filtered"][rest])))


# The claims ----------------------------------------------------------------------------


@dc.dataclass(frozen=True)
class ThesisClaim:
    """One checkable claim of the thesis and its pre-registered criterion."""

    # A short stable id: S sensor, R least squares, N network identification,
    # H force control by the network, K conclusions.
    id: str
    # Line numbers in the thesis's text, e.g. "742" or "804, 806".
    lines: str
    # The thesis's figure(s), "" for none.
    figures: str
    # The claim in the thesis's words (a quote from those lines).
    claim: str
    # The runs and the thesis's forms that test it.
    runs: str
    # The criterion, restating the claim; the reading of a qualitative word
    # and its reason.
    criterion: str
    # One seed's named values (raising Missing when a run is absent).
    measure: Callable[[Seed], dict]
    # Whether one seed's values meet the criterion.
    test: Callable[[dict], bool]
    # Scored by ``reproduce --quick`` too (False: a run or baseline it needs
    # is shortened or skipped there).
    quick: bool = True
    # What a calibration fits to this row, or ties to it algebraically; such
    # a row is shown and never counted as reproduced.
    calibration: str = ""
    # A claim the model does not reproduce: its cause (an ablation, or
    # "cause not isolated" and what was tried).
    deviation: str = ""


def _values(**named):
    return named


def _positive_within_factor(value, truth, factor=REALISTIC_FACTOR):
    return value is not None and value > 0 and truth / factor <= value <= truth * factor


def _near(value, target, tolerance):
    return value is not None and abs(value / target - 1) <= tolerance


def _about(value, target):
    return value is not None and (1 - ABOUT) * target <= value <= (1 + ABOUT) * target


def _small_positive(mass):
    return mass is not None and 0 < mass <= SMALL_MASS_KG


STYRO, RUBBER = "identify_styrofoam", "identify_rubber"


def _rls_settles(run, seconds, lines, quote, figures, claim_id):
    return ThesisClaim(
        claim_id, lines, figures, quote, f"{run}: rls",
        f"rls K_e stays within {IDENTIFIED_TOLERANCE:.0%} of its value {FIGURE_SPAN_S:g} s "
        f"after the switch (the figure's end) from at most {seconds * (1 + ABOUT):g} s after "
        f"the switch ({seconds:g} s + {ABOUT:.0%}); \"practically identified\" read as settled "
        "to within 10 % of the value the figure ends on, since the thesis had no truth",
        lambda s: _values(settled_s=identified_after(s, run, "rls")),
        lambda v: v["settled_s"] <= seconds * (1 + ABOUT))


def _fx_reading(claim_id, run, lines, quote, figures, reading_n_per_m, calibration="",
                role=""):
    return ThesisClaim(
        claim_id, lines, figures, quote, f"{run}: f / x (stiffness_ratio)",
        f"f / x (filtered force over the displacement from the 5 N switch point, mean over "
        f"the run's last second) within {READING_TOLERANCE:.0%} of "
        f"{reading_n_per_m / 1e3:g} kN/m" + (f"; {role}" if role else ""),
        lambda s: _values(fx_n_per_m=stiffness_ratio(s, run)),
        lambda v: _near(v["fx_n_per_m"], reading_n_per_m, READING_TOLERANCE),
        calibration=calibration)


#: Why an RLS's K_e against f / x is a calibration row: with xe from the
#: switch point and no offset, at rest its K_e is the least-squares f / x.
RLS_TIED = ("tied to the fitted stiffness algebraically: with xe from the switch point and "
            "no force offset, the RLS's K_e at rest is a least-squares f / x")


def _k_matches_fx(claim_id, run, form, lines, quote, figures, tolerance, why, calibration=""):
    return ThesisClaim(
        claim_id, lines, figures, quote, f"{run}: {form}, f / x",
        f"{form} K_e (final) within {tolerance:.0%} of f / x (mean over the run's last second); "
        + why,
        lambda s: _values(k_e=impedance(s, run, form)["stiffness"],
                          fx_n_per_m=stiffness_ratio(s, run)),
        lambda v: _near(v["k_e"], v["fx_n_per_m"], tolerance), calibration=calibration)


def _realistic_damping(claim_id, run, form, lines, quote, figures):
    return ThesisClaim(
        claim_id, lines, figures, quote, f"{run}: {form}",
        f"{form} B_e (final) positive and within a factor {REALISTIC_FACTOR:g} of the wall's "
        "damping; \"realistic\" read as physically possible for a passive material (B_e > 0) "
        "and of the right order (the one reading that needs the truth, which the thesis "
        "lacked: it could only judge plausibility)",
        lambda s: _values(b_e=impedance(s, run, form)["damping"],
                          true_b_e=s.metrics(run)["true_impedance"]["damping"]),
        lambda v: _positive_within_factor(v["b_e"], v["true_b_e"]))


def _negative_mass(claim_id, run, form, lines, quote, figures):
    return ThesisClaim(
        claim_id, lines, figures, quote, f"{run}: {form}",
        f"{form} M_e (final) < 0",
        lambda s: _values(m_e=impedance(s, run, form)["mass"]),
        lambda v: v["m_e"] < 0)


def _small_positive_mass(claim_id, run, form, lines, quote, figures):
    return ThesisClaim(
        claim_id, lines, figures, quote, f"{run}: {form}",
        f"0 < {form} M_e (final) <= {SMALL_MASS_KG:g} kg; \"small\" read against the arm's "
        "effective mass at the tip (several kg), of which a slab's moving part is a sliver",
        lambda s: _values(m_e=impedance(s, run, form)["mass"]),
        lambda v: _small_positive(v["m_e"]))


def _nn_learns(claim_id, run, lines, quote, figures):
    return ThesisClaim(
        claim_id, lines, figures, quote, f"{run}: nn",
        f"nn K_e stays within {IDENTIFIED_TOLERANCE:.0%} of its value {FIGURE_SPAN_S:g} s after "
        f"the switch from between {0.6 * (1 - ABOUT):g} and {0.6 * (1 + ABOUT):g} s after the "
        f"switch (\"about 0.6 sec\": +-{ABOUT:.0%})",
        lambda s: _values(settled_s=identified_after(s, run, "nn")),
        lambda v: _about(v["settled_s"], 0.6))


def _follows(claim_id, run, lines, quote, figures, start_s=SLOT_START_S, why=""):
    return ThesisClaim(
        claim_id, lines, figures, quote, f"{run} and its hybrid part alone (baseline)",
        f"the measured force's RMSE about f_d over the {SLOT_S:g} s slot from {start_s:g} s "
        f"after contact is at most {FOLLOWS_FRACTION:.0%} of the hybrid part alone's in the "
        "same slot; \"follows\" read against what the same wall gives without the network, "
        "the comparison the thesis draws with Fig 6.10" + why,
        lambda s: _values(ratio=follows_ratio(s, run, start_s)),
        lambda v: v["ratio"] <= FOLLOWS_FRACTION, quick=False)


def _late_follows(seed: Seed):
    """The worst slot ratio over the 4 s slots from 2 min after contact to the
    run's end, and the contact losses there."""
    log, base = seed.log("nn_small_lr"), seed.baseline_log("nn_small_lr")
    t, t_c = log["t"], switch_time(log)
    reference = slot_rmse(base, SLOT_START_S)
    starts = np.arange(120.0, t[-1] - t_c - SLOT_S + 1e-9, SLOT_S)
    if len(starts) == 0:
        raise Missing("nn_small_lr ends before 2 min after contact")
    worst = max(slot_rmse(log, start) for start in starts) / reference
    late = t >= t_c + 120.0
    losses = int(np.count_nonzero(np.diff(log["mode"][late]) != 0))
    return _values(worst_ratio=worst, mode_changes=losses)


#: The thesis's checkable claims in its order: chapter 3-4 (the sensor),
#: 6.1, 6.2, 6.3, 7.1.
CLAIMS: list[ThesisClaim] = [
    ThesisClaim(
        "S1", "322", "3.5",
        "We can see the signals are almost same under 120Hz.",
        "sensor_spectrum: force_measured, force_measured_antialiased (190 Hz RC)",
        "the PSDs of the unfiltered and the 190 Hz RC-filtered force (Welch, pressing) differ "
        "by at most 3 dB at every frequency in (0, 120] Hz; \"almost same\" read as within "
        "half power (the RC filter's own gain is within 0.3 dB there)",
        lambda s: _values(max_difference_db=psd_difference_db(s, "sensor_spectrum")),
        lambda v: v["max_difference_db"] <= 3.0,
        calibration="the DAC ripple's waveform, a sinusoid, is chosen so that this row holds "
        "(a pulse train's 960 Hz harmonic aliases to 40 Hz in the raw channel alone)"),
    ThesisClaim(
        "S2", "322", "3.5",
        "The spikes of filtered signals are caused by excited internal dynamics of the filter "
        "by 480Hz.",
        "sensor_spectrum: force_measured_antialiased",
        "the RC-filtered force's PSD has a line at 480 Hz at least 6 dB (4x) above the floor "
        "beside it: a spike visible on the thesis's plot",
        lambda s: _values(line_db=filtered_line_db(s, "sensor_spectrum")),
        lambda v: v["line_db"] >= 6.0),
    ThesisClaim(
        "S3", "344", "4.4",
        "Since the noise of the force sensor is almost $\\pm 2\\text{N}$",
        "sensor_spectrum: force_measured at rest",
        "the 99th percentile of |raw measured force - true force| at rest is 2 N +-25 % "
        "(1.5-2.5 N); \"almost +-2 N\" read as the band that holds nearly every sample",
        lambda s: _values(p99_n=s.metrics("sensor_spectrum")["rest_noise_p99_n"]),
        lambda v: 1.5 <= v["p99_n"] <= 2.5,
        calibration="the DAC ripple's amplitude is fitted to this reading (2 N, mean of "
        "seeds 0-2)"),
    ThesisClaim(
        "S4", "1894, 1896", "",
        "if (uff > 0.80){ ... s = 1;  (Appendix E: contact declared when the filtered "
        "force passes 0.8 N)",
        "identify_styrofoam, identify_rubber: force_filtered at rest",
        "the filtered force at rest (after the tare, before contact) never exceeds 0.8 N, so "
        "Appendix E's switch cannot fire before contact",
        lambda s: _values(styrofoam_n=filtered_force_at_rest(s, STYRO),
                          rubber_n=filtered_force_at_rest(s, RUBBER)),
        lambda v: max(v["styrofoam_n"], v["rubber_n"]) < 0.8,
        calibration="the gauge noise's level is chosen so that this row holds, the rest of "
        "the +-2 N being the DAC ripple, which the 120 Hz filter removes"),
    _rls_settles(STYRO, 0.12, "689", "The results in Figure 6.1 show that the coefficients are "
                 "practically identified during first 0.12 seconds.", "6.1", "R1"),
    _fx_reading("R2", STYRO, "742", "the estimated values of K_e in (c) is 6.8K(N/m)", "6.2",
                6.8e3, calibration="the styrofoam wall's stiffness is fitted to this reading"),
    _k_matches_fx("R3", STYRO, "rls", "742, 770", "(c) is 6.8K(N/m) and (f) is 7.2K(N/m) which are "
                  "almost same (less than 6% difference)", "6.2", ALMOST_SAME,
                  "the thesis's own tolerance", calibration=RLS_TIED),
    _realistic_damping("R4", STYRO, "rls", "770", "The damping coefficient B_e seems "
                       "realistic.", "6.2"),
    _negative_mass("R5", STYRO, "rls", "770", "The value of the inertia coefficient M_e is "
                   "unrealistic as it results negative.", "6.2"),
    ThesisClaim(
        "R6", "772", "6.3",
        "if we use all raw input signals (unfiltered input signals) ... both the inertia "
        "coefficient M_e and the damping coefficient B_e result negative.",
        f"{STYRO}: rls_raw",
        "rls_raw M_e < 0 and B_e < 0 (final)",
        lambda s: _values(m_e=impedance(s, STYRO, "rls_raw")["mass"],
                          b_e=impedance(s, STYRO, "rls_raw")["damping"]),
        lambda v: v["m_e"] < 0 and v["b_e"] < 0),
    _k_matches_fx("R7", STYRO, "rls_raw", "777", "as far as the spring coefficient K_e is "
                  "concerned, the estimated value is realistic since it is always almost the "
                  "same as the calculated spring coefficient", "6.3", ALMOST_SAME,
                  "\"almost the same\" as line 742's", calibration=RLS_TIED),
    _rls_settles(RUBBER, 0.05, "786", "The coefficients are practically identified during "
                 "first 0.05 seconds.", "6.4", "R8"),
    _fx_reading("R9", RUBBER, "786", "the values of K_e in (c) is 44K(N/m)", "6.5", 44e3,
                calibration="the rubber wall's stiffness is fitted to this reading (its other "
                            "reading, 62 kN/m, is N9's prediction)"),
    _k_matches_fx("R10", RUBBER, "rls", "786", "(c) is 44K(N/m) and (f) is also 44K(N/m)",
                  "6.5", ALMOST_SAME, "\"also 44K\" read with line 742's tolerance",
                  calibration=RLS_TIED),
    _realistic_damping("R11", RUBBER, "rls", "786", "The damping coefficient B_e seems "
                       "realistic.", "6.5"),
    _negative_mass("R12", RUBBER, "rls", "786", "The value of the inertia coefficient M_e is "
                   "unrealistic as it is negative.", "6.5"),
    ThesisClaim(
        "N1", "790", "6.6",
        "If the learning rate becomes smaller, the neural networks take more time to learn",
        f"{STYRO}: nn (1e-4) and nn_slow (2e-5)",
        "nn_slow K_e settles (as in N2) later than nn K_e",
        lambda s: _values(slow_s=identified_after(s, STYRO, "nn_slow"),
                          fast_s=identified_after(s, STYRO, "nn")),
        lambda v: v["slow_s"] > v["fast_s"]),
    _nn_learns("N2", STYRO, "804", "after about 0.6sec the environment impedance is "
               "practically identified", "6.7"),
    ThesisClaim(
        "N3", "806", "6.8",
        "it takes about 0.6sec for the error to become almost zero",
        f"{STYRO}: nn (force_estimate_nn)",
        f"the 100 ms moving RMS of the network's output error (filtered force - estimate) "
        f"stays at most {ALMOST_ZERO_N:g} N from between 0.3 and 0.9 s after the switch; "
        "\"almost zero\" read as down to the filtered force's own noise, which no network "
        "can learn",
        lambda s: _values(near_zero_s=error_near_zero_after(s, STYRO, "nn")),
        lambda v: _about(v["near_zero_s"], 0.6)),
    _fx_reading("N4", STYRO, "806", "calculated K_e from (c) is 6.7K(N/m)", "6.7", 6.7e3,
                role="a prediction of the wall fitted to R2's 6.8 kN/m (the tolerance written "
                     "before the fit)"),
    _k_matches_fx("N5", STYRO, "nn", "806", "calculated K_e from (c) is 6.7K(N/m) and "
                  "estimated K_e from (f) is 6.6K(N/m)", "6.7", ALMOST_SAME,
                  "\"almost same\" as line 742's"),
    ThesisClaim(
        "N6", "806", "6.7",
        "The damping coefficient B_e is similar to the value which is estimated by the least "
        "square method",
        f"{STYRO}: nn and rls",
        "nn B_e / rls B_e (final) between 0.5 and 2; \"similar\" read as the same sign and "
        "within a factor of 2",
        lambda s: _values(nn_b_e=impedance(s, STYRO, "nn")["damping"],
                          rls_b_e=impedance(s, STYRO, "rls")["damping"]),
        lambda v: v["rls_b_e"] != 0 and 0.5 <= v["nn_b_e"] / v["rls_b_e"] <= 2.0),
    _small_positive_mass("N7", STYRO, "nn", "806", "the inertia coefficient M_e is a small "
                         "positive value", "6.7"),
    _nn_learns("N8", RUBBER, "844", "it also takes about 0.6sec to identify environment "
               "impedance", "6.9"),
    _fx_reading("N9", RUBBER, "844", "calculated K_e from (c) is 62K(N/m)", "6.9", 62e3,
                role="a prediction of the wall fitted to R9's 44 kN/m (the tolerance written "
                     "before the fit)"),
    _k_matches_fx("N10", RUBBER, "nn", "844", "The identified spring coefficient K_e ... seems "
                  "realistic since calculated K_e from (c) is 62K(N/m) and estimated K_e from "
                  "(f) is 56K(N/m)", "6.9", 0.15,
                  "the thesis calls its own 10 % gap realistic: 10 % + 5 %"),
    ThesisClaim(
        "N11", "844",
        "6.9", "The damping coefficient B_e results smaller than the value which is estimated "
        "by the least square method.",
        f"{RUBBER}: nn and rls",
        "nn B_e < rls B_e (final)",
        lambda s: _values(nn_b_e=impedance(s, RUBBER, "nn")["damping"],
                          rls_b_e=impedance(s, RUBBER, "rls")["damping"]),
        lambda v: v["nn_b_e"] < v["rls_b_e"]),
    _small_positive_mass("N12", RUBBER, "nn", "844", "The inertia coefficient M_e also seems "
                         "realistic since it is a small positive value.", "6.9"),
    ThesisClaim(
        "H1", "882, 887", "6.10",
        "Since the gain for force control is low and there is no error integral ..., the "
        "applied force (measured force) can not reach the desired force.",
        "hybrid_p_only_styrofoam",
        f"over the last second of every completed level, the mean measured force misses f_d "
        f"by more than {REACH_MARGIN_N:g} N on the short side (below a raised level, above a "
        "lowered one); \"can not reach\" read as a steady shortfall beyond the filtered "
        "force's noise",
        lambda s: _values(smallest_shortfall_n=level_shortfalls(s, "hybrid_p_only_styrofoam")),
        lambda v: v["smallest_shortfall_n"] > REACH_MARGIN_N),
    _follows("H2", "nn_styrofoam", "889", "Figure 6.11 shows a 4sec time slot ... about 10 "
             "seconds after the experiment is started ... the robot manipulator follows "
             "acceptable well the desired force.", "6.11"),
    _follows("H3", "nn_styrofoam_sine", "899", "The result also shows that the robot "
             "manipulator follows acceptable well the desired force.", "6.12"),
    ThesisClaim(
        "H4", "901", "6.13",
        "with a small learning rate ($\\eta = 0.00001$). It can be seen that the force response can "
        "not follow the desired force immediately.",
        "nn_small_lr and its hybrid part alone",
        f"the slot ratio of H2 (from {SLOT_START_S:g} s after contact) is above "
        f"{FOLLOWS_FRACTION:.0%}: by H2's reading, it does not follow yet",
        lambda s: _values(ratio=follows_ratio(s, "nn_small_lr")),
        lambda v: v["ratio"] > FOLLOWS_FRACTION, quick=False),
    ThesisClaim(
        "H5", "901", "6.14",
        "the force output of the robot manipulator is able to follow the desired force after "
        "a few minutes",
        "nn_small_lr (250 s) and its hybrid part alone",
        f"every {SLOT_S:g} s slot from 2 min after contact to the run's end meets H2's bound "
        "(RMSE at most 50 % of the hybrid part alone's), with no change of mode (no contact "
        "lost); \"after a few minutes\" read as from 2 min on, and \"is able to follow\" as "
        "keeps following (\"the desired force response can be obtained at a later time\")",
        _late_follows,
        lambda v: v["worst_ratio"] <= FOLLOWS_FRACTION and v["mode_changes"] == 0,
        quick=False),
    ThesisClaim(
        "H6", "909", "6.15",
        "It can be seen, however, that the measured y position and angle are not zero.",
        "nn_styrofoam",
        "the largest |y| over the scoring window is at least 0.1 mm and the largest |phi| at "
        "least 1 mrad; \"not zero\" read as visible on the thesis's plot (a tenth of the 1 mm "
        "approach step, and its angular equivalent)",
        lambda s: _values(y_max_m=s.metrics("nn_styrofoam")["y_max_abs_error_m"],
                          phi_max_rad=s.metrics("nn_styrofoam")["phi_max_abs_error_rad"]),
        lambda v: v["y_max_m"] >= 1e-4 and v["phi_max_rad"] >= 1e-3),
    _follows("H7", "nn_rubber", "929", "This result also shows the robot manipulator follows "
             "pretty well to the desired force.", "6.16"),
    _follows("H8", "nn_rubber_sine", "931", "Figure 6.17 shows the beginning of another "
             "experiment ... The result also shows that the robot manipulator follows well to "
             "the desired force.", "6.17", start_s=5.0,
             why="; the slot starts 5 s after contact, since the figure shows the beginning "
                 "and line 939 reads adaptation off it as almost 5 s"),
    ThesisClaim(
        "H9", "939", "6.16, 6.17",
        "This experimental results also show that the neural network controller can adapt in "
        "almost 5 seconds.",
        "nn_rubber, nn_rubber_sine",
        "adaptation time (to the end of the first 5 s window whose true-force RMSE about f_d "
        "is under 1.5 N, the scenario's scoring) at most 7.5 s on both runs (\"almost 5\": "
        "5 s + 50 %)",
        lambda s: _values(square_s=s.metrics("nn_rubber").get("adaptation_time_s"),
                          sine_s=s.metrics("nn_rubber_sine").get("adaptation_time_s")),
        lambda v: all(x is not None and x <= 7.5 for x in v.values())),
    ThesisClaim(
        "H10", "939", "6.13",
        "if the learning rate is small, it takes more time for adaptation.",
        "nn_small_lr (1e-5) and nn_styrofoam (5e-5)",
        "nn_small_lr's adaptation time (as H9) is later than nn_styrofoam's",
        lambda s: _values(small_s=s.metrics("nn_small_lr").get("adaptation_time_s"),
                          nominal_s=s.metrics("nn_styrofoam").get("adaptation_time_s")),
        lambda v: v["nominal_s"] is not None
        and (v["small_s"] is None or v["small_s"] > v["nominal_s"])),
    ThesisClaim(
        "K1", "947", "",
        "The coefficients with the least square method are obtained, however, faster than "
        "with neural network method.",
        f"{STYRO}, {RUBBER}: rls and nn",
        "rls K_e settles (as in R1) earlier than nn K_e (as in N2) on both materials",
        lambda s: _values(**{f"{m}_{form}_s": identified_after(s, run, form)
                             for m, run in (("styrofoam", STYRO), ("rubber", RUBBER))
                             for form in ("rls", "nn")}),
        lambda v: v["styrofoam_rls_s"] < v["styrofoam_nn_s"]
        and v["rubber_rls_s"] < v["rubber_nn_s"]),
]


#: Measured causes of the claims the faithful model does not reproduce, by
#: claim id (measured at seeds 0-2; a cause is an ablation that removes it,
#: or "cause not isolated" with what was tried).
DEVIATIONS = {
    'R5': (
        'rls M_e reads +0.42, +0.41 and +0.39 kg on seeds 0-2. Cause not isolated. Ablation, '
        'seeds 0-2: the same RLS with a force-offset regressor (not in eq. 5.2) reads -0.48 to '
        "-0.49 kg, the thesis's sign; with the 35 Hz velocity in place of line 675's unfiltered"
        ' one, +0.97 to +1.00 kg. So the 5 N at the switch point, which eq. 5.2 leaves to the '
        "other regressors, sets the sign here; why the thesis's RLS, with the same switch "
        'point, read negative is not known'
    ),
    'R6': (
        'rls_raw reads M_e +0.06 to +0.14 kg and B_e +104 to +106 N s/m on seeds 0-2: neither '
        'negative. Cause not isolated; the raw velocity and acceleration (backward differences '
        "of the estimated pose) are the only reading of 'raw' tried"
    ),
    'R11': (
        "rls B_e reads -45 to -51 N s/m on rubber over seeds 0-2 (the wall's 150). Cause not "
        'isolated. Ablation, seeds 0-2: with a force-offset regressor -58 to -64, with the 35 '
        'Hz velocity -49 to -56: neither removes it; rls_matched (one common filter on every '
        "signal, ours) reads +95 to +102, which points at the force's lag behind the kinematics"
        " on the stiffer wall's faster transient, but that ablation changes every signal at "
        'once'
    ),
    'R12': (
        'rls M_e reads +1.17 to +1.27 kg on rubber over seeds 0-2. Cause not isolated; as R5, a'
        ' force-offset regressor turns it negative (-0.34 to -0.41 kg)'
    ),
    'N1': (
        'nn_slow (2e-5) settles 0.015 and 0.040 s after nn (1e-4) on seeds 0 and 1 and 0.044 s '
        'before it on seed 2 (the two differ in the rate alone: the same options and initial '
        "weights). Cause shown by an ablation, seeds 0-2: with K_fi read as eq. 4.15's integral"
        ' in seconds (departure 3 in docs/modelling.md; force_integral_gain 1000 times smaller)'
        ' nn_slow settles after nn on every seed (0.176 / 0.247 / 0.129 s against 0.070 / 0.161'
        " / 0.075 s) and the row holds. The per-sample reading's integral acts within the "
        "switch transient the networks learn from; it is kept because the thesis's remark on "
        'Fig 6.10 needs an integral that acts within a level (departure 3)'
    ),
    'N2': (
        'nn K_e settles 0.14-0.18 s after the switch on seeds 0-2, about four times sooner than'
        " the thesis's 0.6 s. Cause not isolated. Tried: the text's sigmoid output (S = 40 N) "
        'in place of the linear one, which settled in 0.14-0.16 s (70957cd): the output unit is'
        ' not it'
    ),
    'N3': (
        "the output error's moving RMS stays under 1 N from 0.18, 0.25 and 0.18 s after the "
        "switch on seeds 0-2, far sooner than the thesis's. Cause not isolated; as N2"
    ),
    'N5': (
        'nn K_e reads 8.9-9.6 kN/m against f / x 6.8 kN/m (+32 to +41 %) on seeds 0-2. Cause '
        "not isolated: the network is probed at the thesis's 2 mm, where it has learned little "
        '(the tip rests 2.9 mm past the switch point), and its secant through the origin '
        "carries the switch point's 5 N"
    ),
    'N6': (
        'nn B_e reads 112, 472 and 212 N s/m against rls B_e 91-92 N s/m: similar on seed 0 '
        "only. Cause not isolated; the network's B_e rests on the switch transient alone and "
        'moves with its initial weights'
    ),
    'N7': (
        'nn M_e reads -0.48 to -0.67 kg on styrofoam over seeds 0-2, never small and positive. '
        'Cause not isolated; as N6, it rests on the transient and the initial weights. Section '
        "7.1's preference for the network (line 945) rests on this claim"
    ),
    'N8': (
        'nn K_e settles 0.076 s after the switch on rubber on seeds 0-2, far sooner than about '
        '0.6 s. Cause not isolated; as N2'
    ),
    'N9': (
        "the wall fitted to R9's 44 kN/m reads f / x 43.8-44.2 kN/m, 29 % under this reading. "
        "The thesis's own two rubber readings, one wall in two experiments, disagree by 41 % "
        '(44 kN/m, line 786; 62 kN/m, line 844), so no one wall meets both: the cause is that '
        'disagreement, shown by the fit'
    ),
    'N10': (
        'nn K_e reads 74-84 kN/m against f / x 44 kN/m (+68 to +92 %) on rubber over seeds 0-2.'
        " Cause not isolated; the thesis's 0.2 mm probe lies well below where the tip rests on "
        'this wall (0.46 mm past the switch point), and a secant through the switch point reads'
        ' high'
    ),
    'N11': (
        "rls B_e is negative on rubber (R11, -45 to -51 N s/m), so the network's B_e (2, -90 "
        "and 61 N s/m) is smaller on seed 1 only. Cause not isolated; it follows R11's and N6's"
    ),
    'N12': (
        'nn M_e reads +0.04, +1.44 and -0.85 kg on rubber over seeds 0-2: small and positive on'
        ' seed 0 only. Cause not isolated; as N7'
    ),
    'H1': (
        'the measured force settles past each level (above 20 N, below 10 N) by 4.36-4.38 N on '
        'seeds 0-2: it reaches and passes f_d. Ablation, seeds 0-2, 20 s runs on the calibrated'
        ' wall: without the joint-2 drive error (arm.motor_torque_scale 1.2 -> 1.0, a parameter'
        ' the thesis does not give) it passes f_d by 1.07-1.08 N, and also without the '
        "controller's model errors (mass and inertia scales 1.0) by 0.82-0.87 N. So the drive "
        'error makes most of it; what keeps the force past f_d without it is not isolated'
    ),
    'H2': (
        'the slot ratio is 0.52, 0.51 and 0.51 on seeds 0-2, just over the bound (0.5). '
        'Ablation, seeds 0-2: the same runs and their hybrid part alone on the uncalibrated '
        'wall (7000 N/m, nothing else changed) read 0.478, 0.478 and 0.491 and hold. The cause '
        'is the softer, calibrated wall; the margin is thin on either'
    ),
    'H5': (
        "it adapts 60.5 s after contact on seed 2 and never on seeds 0 and 1 (by the scenario's"
        ' 1.5 N window), and loses contact from 68 s after contact on (179-189 changes of mode '
        "in the run); its worst 4 s slot after 2 min is 2.3-2.4 times the hybrid part alone's. "
        "Cause not isolated: Appendix E's weight update has no bound, as modelled, and the "
        'weights keep drifting after adapting'
    ),
}
CLAIMS = [dc.replace(claim, deviation=DEVIATIONS[claim.id]) if claim.id in DEVIATIONS else claim
          for claim in CLAIMS]


# Scoring -------------------------------------------------------------------------------


@dc.dataclass
class ClaimRow:
    """One claim scored over the seeds."""

    claim: ThesisClaim
    # Per seed: its values (None: not run) and whether the criterion held.
    values: dict[int, dict | None]
    holds: dict[int, bool | None]
    # Why a seed could not be scored.
    problems: dict[int, str] = dc.field(default_factory=dict)
    # Not scored in --quick (the claim needs a full run).
    skipped: bool = False
    # Scored on every seed its deviation was documented on: only then does a
    # deviation that holds count as unexpected (one that fails on one seed
    # of three may hold on that seed's neighbours alone).
    strict: bool = True

    @property
    def reproduced(self) -> bool | None:
        """True when it holds on every seed, None when a seed is not scored."""
        if self.skipped or any(h is None for h in self.holds.values()):
            return None
        return all(self.holds.values())

    @property
    def verdict(self) -> str:
        if self.skipped:
            return "not scored in --quick"
        if self.reproduced is None:
            return "not run"
        if self.claim.calibration:
            return "calibration (holds)" if self.reproduced else "calibration (does not hold)"
        if self.claim.deviation:
            return ("documented deviation" if not self.reproduced else
                    "not as expected (a documented deviation now holds)" if self.strict else
                    "holds on these seeds (a documented deviation over seeds "
                    + ", ".join(map(str, DOCUMENTED_SEEDS)) + ")")
        return "reproduced" if self.reproduced else "not as expected (does not hold)"

    @property
    def as_expected(self) -> bool:
        if self.skipped or self.claim.calibration:
            return True
        if self.reproduced is None:
            return False
        if self.claim.deviation:
            return not self.reproduced or not self.strict
        return self.reproduced


#: The seeds the deviations were documented on.
DOCUMENTED_SEEDS = (0, 1, 2)


def score_claims(out: Path, seeds, metrics: Callable[[Path, str, int], dict], *,
                 quick=False, claims=None) -> list[ClaimRow]:
    """Scores each claim of ``claims`` (default :data:`CLAIMS`) on each seed's
    runs under ``out``; ``metrics(out, name, seed)`` reads one run's metrics
    (raising :class:`Missing`)."""
    rows = []
    strict = set(DOCUMENTED_SEEDS) <= set(seeds)
    by_seed = {seed: Seed(out, seed, lambda name, seed=seed: metrics(out, name, seed))
               for seed in seeds}
    for claim in claims if claims is not None else CLAIMS:
        if quick and not claim.quick:
            rows.append(ClaimRow(claim, dict.fromkeys(seeds), dict.fromkeys(seeds),
                                 skipped=True))
            continue
        values, holds, problems = {}, {}, {}
        for seed in seeds:
            try:
                values[seed] = claim.measure(by_seed[seed])
            except (Missing, KeyError) as missing:
                values[seed], holds[seed] = None, None
                problems[seed] = f"not run: {missing}"
                continue
            try:
                holds[seed] = bool(claim.test(values[seed]))
            except (TypeError, ZeroDivisionError):
                holds[seed] = False
        rows.append(ClaimRow(claim, values, holds, problems, strict=strict))
    return rows


def format_value(value) -> str:
    if value is None:
        return "never"
    if isinstance(value, (int, np.integer)) and not isinstance(value, bool):
        return str(value)
    if not math.isfinite(value):
        return str(value)
    return f"{value:.4g}"


def seed_values(row: ClaimRow, seed) -> str:
    values = row.values.get(seed)
    if values is None:
        return row.problems.get(seed, "not run") if not row.skipped else "-"
    mark = {True: "holds", False: "fails", None: "?"}[row.holds.get(seed)]
    return ", ".join(f"{k} {format_value(v)}" for k, v in values.items()) + f" ({mark})"


def counts(rows: list[ClaimRow]) -> dict:
    """Reproduced, documented deviations, calibration rows, not as expected,
    not scored; claims counted over every seed."""
    return {
        "reproduced": sum(r.reproduced is True and not r.claim.calibration
                          and not r.claim.deviation for r in rows),
        "deviations": sum(r.reproduced is False and bool(r.claim.deviation)
                          and not r.claim.calibration for r in rows),
        "calibration": sum(bool(r.claim.calibration) for r in rows),
        "unexpected": sum(not r.as_expected for r in rows),
        "not_scored": sum(r.reproduced is None for r in rows),
        "claims": len(rows),
    }


def summary(rows: list[ClaimRow]) -> str:
    c = counts(rows)
    counted = c["claims"] - c["calibration"]
    return (f"{c['reproduced']} of {counted} thesis claims reproduced on every seed, "
            f"{c['deviations']} documented deviations, {c['unexpected']} not as expected, "
            f"{c['calibration']} calibration rows" +
            (f", {c['not_scored']} not scored" if c["not_scored"] else ""))


#: claims.csv's columns.
CSV_COLUMNS = ["id", "thesis_lines", "figures", "claim", "runs", "criterion", "seed",
               "values", "holds", "verdict", "cause"]


def write_claims_csv(path: Path, rows: list[ClaimRow], seeds) -> None:
    """One line per claim and seed: the claim's fields, that seed's values
    and whether they hold, the claim's verdict and cause."""
    with open(path, "w", newline="") as stream:
        writer = csv.writer(stream)
        writer.writerow(CSV_COLUMNS)
        for row in rows:
            c = row.claim
            for seed in seeds:
                values = row.values.get(seed)
                writer.writerow([
                    c.id, c.lines, c.figures, c.claim, c.runs, c.criterion, seed,
                    "" if values is None else "; ".join(
                        f"{k}={format_value(v)}" for k, v in values.items()),
                    "" if row.holds.get(seed) is None else row.holds[seed],
                    row.verdict, c.deviation or c.calibration])


#: The claims table's columns: the claim's own (rendered from the code in
#: the docs) and the scored ones.
TABLE_COLUMNS = ["id", "lines", "figure", "the thesis says", "runs (its forms)", "criterion"]


def claim_cells(claim: ThesisClaim) -> list[str]:
    return [claim.id, claim.lines, claim.figures, claim.claim, claim.runs, claim.criterion]


def markdown_table(rows: list[ClaimRow] | None, seeds=()) -> list[str]:
    """The claims table as Markdown lines: the claims' columns, and with
    ``rows`` each seed's values and the verdict."""
    header = TABLE_COLUMNS + ([f"seed {s}" for s in seeds] + ["verdict"] if rows else [])
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for item in rows if rows else CLAIMS:
        claim = item.claim if rows else item
        cells = claim_cells(claim)
        if rows:
            cells += [seed_values(item, s) for s in seeds] + [item.verdict]
        lines.append("| " + " | ".join(c.replace("|", "\\|").replace("\n", " ")
                                       for c in cells) + " |")
    return lines
