"""A run's metrics: numbers against the ground truth, from its log.

:func:`compute_metrics` is what ``metrics.json`` holds: timing, peak force,
steady-state stiffness, sensor noise and spectra, force and position tracking
after the contact switch, adaptation, identification (each identifier's final
M_e, B_e, K_e, its relative errors and settling times), and warnings.

Identification: each identifier's estimate is logged as ``impedance_<name>``
(N x 3: M_e, B_e, K_e) and scored as ``identified_impedance_<name>``,
``identification_time_<name>_s`` (time after the switch from which the K_e
estimate stays within 5 % of the truth), ``identification_error_<name>``
(relative errors), and the same time for 10 % as
``identification_time_10pct_<name>_s`` (the neural identifier's bar).
``identification_error_1s_<name>`` is the same relative error of the
estimate 1 s after the switch (against the truth at that sample; each entry
None where the truth is 0 or the log ends sooner).
``stiffness_ratio`` is the thesis's "measured" stiffness f / xe from the
filtered force and the estimated displacement since the switch.
``identifiability_bound`` (runs with identifiers) is the Cramér-Rao bound on
M_e, B_e, K_e from the run's contact samples (see
:mod:`drake_contact.scoring.identifiability`): ``std`` and ``relative`` (to the
truth), one standard deviation, what no unbiased identifier can beat;
``identifiability_bound_1s`` the same from the first second after the switch.

Time-varying environments (a K_e or B_e that changes after the switch, e.g.
the ``stiffness_ramp`` and ``stiffness_step`` faults): ``identification_tracking_<name>``
scores each identifier against the *current* truth at every sample from
``TRACKING_START_S`` (1 s) after the switch to the end of the run (see
:func:`identification_tracking`). It is emitted only when the truth changes
after the switch, so runs on a constant wall keep their metrics.

Stability (for parameter sweeps), in runs with a ``mode`` log:
``contact_losses`` counts the controller's returns from contact (mode 1) to
approach (mode 0), all of which follow the first switch;
``first_contact_loss_s`` is the first one's time after the switch (None if
none). ``final_force_rmse_n`` is the force RMSE (true force vs f_d) over the
run's last ``scoring.rmse_window_s``, [t_end - width, t_end), provided that
window starts at or after the switch (else None). The rule:

    stable  <=>  a contact switch happened,
                 contact_losses == 0, and
                 final_force_rmse_n <= STABLE_RMSE_N (2 N).

A run too short for a full window after the switch is therefore not stable:
unknown is not stable. ``stable`` is None without a ``mode`` log. It is
computed from the log alone, before the runner sets ``status``; a diverged
run's log is truncated at the bad sample and usually fails the rule, but a
diverged run is never stable: a sweep must read ``status == "completed" and
stable``.
"""

import copy
import dataclasses as dc
from importlib.metadata import entry_points

import numpy as np

from drake_contact.scoring.identifiability import identifiability_bound, noise_psd
from drake_contact.scoring.spectra import sensor_metrics
from drake_contact.control.safety_supervisor import (
    CLAMPED, REFLEX, SAFETY_STATES, STOP_REASONS)
from drake_contact.plant.arm import CONTROL_PERIOD, RATIO_TOLERANCE, TIME_TOLERANCE_S
from drake_contact.scenario import Scenario

@dc.dataclass(frozen=True)
class Score:
    """How the benchmark ranks one metric: its ``runs.csv`` column (the
    ``metrics.json`` value of ``key`` times ``scale``), that column's median
    and worst over the walls in ``leaderboard.csv``, and a leaderboard
    Markdown column headed ``header`` showing the aggregates of ``show``
    (``"median"``, ``"worst"``; joined by " / ") with ``digits`` decimals
    (``show`` empty: in the CSV files only)."""

    column: str
    key: str
    header: str = ""
    show: tuple = ()
    digits: int = 2
    scale: float = 1


#: The benchmark's scores, in its columns' order (:func:`register_metric`
#: adds more).
SCORES = [
    Score("force_rmse_n", "force_rmse_n", "force RMSE median / worst (N)", ("median", "worst")),
    Score("worst_window_rmse_n", "worst_window_rmse_n", "worst 5 s window (N)", ("worst",)),
    Score("step_overshoot_pct", "step_overshoot_pct", "overshoot median (%)", ("median",), 0),
    Score("step_settling_s", "step_settling_s", "settling median (s)", ("median",)),
    Score("step_unsettled", "step_unsettled", "unsettled steps", ("worst",), 0),
    Score("contact_losses", "contact_losses"),
    Score("impact_peak_force_n", "impact_peak_force_n"),
    Score("y_max_abs_error_mm", "y_max_abs_error_m", "y max (mm)", ("worst",), scale=1e3),
    Score("phi_max_abs_error_mrad", "phi_max_abs_error_rad", "phi max (mrad)", ("worst",), 1,
          scale=1e3),
    Score("torque_rms_nm", "torque_rms_nm", "torque RMS (N m)", ("median",)),
]
#: Metric functions ``(log, scenario) -> dict`` that :func:`compute_metrics`
#: runs after its own (:func:`register_metric`).
METRIC_FUNCTIONS = []
#: Entry-point group of modules that register metrics from other packages.
METRIC_GROUP = "drake_contact.metrics"


def register_metric(*scores: Score):
    """Decorates a function ``(log, scenario) -> dict`` of new metrics:
    ``metrics.json`` then holds them (so do sweeps' ``results.csv``), and
    each of ``scores`` (on one of its keys) ranks the benchmark's
    contenders. A score's column must be new (the same score again is
    taken)."""
    def add(function):
        for score in scores:
            taken = next((s for s in SCORES if s.column == score.column), None)
            if taken is not None and taken != score:
                raise ValueError(f"register_metric: the score column '{score.column}' is taken")
        if function not in METRIC_FUNCTIONS:
            METRIC_FUNCTIONS.append(function)
        SCORES.extend(s for s in scores if s not in SCORES)
        function.scores = scores
        return function
    return add


def unregister_metric(function):
    """Removes a metric function and its scores (e.g. a test's)."""
    if function in METRIC_FUNCTIONS:
        METRIC_FUNCTIONS.remove(function)
    for score in getattr(function, "scores", ()):
        if score in SCORES:
            SCORES.remove(score)


#: Identification settling bars: K_e within 5 % (RLS), 10 % (the neural
#: identifier).
SETTLE_TOLERANCE = 0.05
SETTLE_TOLERANCE_NN = 0.10

#: A true contact force above this (N) inside the DSP's tare window is
#: tared away as if it were the sensor's offset.
TARE_CONTACT_FORCE_N = 0.5

#: ``stable`` needs ``final_force_rmse_n`` at or below this (N).
STABLE_RMSE_N = 2.0

#: ``identification_error_1s_<name>`` scores the estimate this long after
#: the switch (s).
EARLY_IDENTIFICATION_S = 1.0

#: ``identification_tracking_<name>`` scores from this long after the
#: switch (s), and counts a change of the truth by more than
#: TRACKING_STEP_MIN (relative) between two samples as a step.
TRACKING_START_S = 1.0
TRACKING_STEP_MIN = 0.01


def compute_metrics(scenario: Scenario, log: dict, wall_s: float) -> dict:
    """Timing, peak force, ground truth and steady-state contact numbers."""
    t = log["t"]
    simulated = float(t[-1]) if len(t) else 0.0
    steps = simulated / scenario.arm.time_step
    env = scenario.environment
    force = log["contact_force_true"]
    penetration = log["penetration_true"]
    metrics = {
        "simulated_time_s": simulated,
        "wall_time_s": wall_s,
        "realtime_factor": simulated / wall_s if wall_s > 0 else float("nan"),
        "us_per_step": wall_s / steps * 1e6 if steps > 0 else float("nan"),
        "plant_time_step_s": scenario.arm.time_step,
        "peak_force_n": float(np.max(force)) if len(force) else 0.0,
        "true_impedance": {"mass": env.mass, "damping": env.damping, "stiffness": env.stiffness},
    }
    window = t >= simulated - scenario.simulation.settle_window
    contact = window & (penetration > 0)
    if contact.any():
        f_mean = float(np.mean(force[contact]))
        x_mean = float(np.mean(penetration[contact]))
        K_true = float(np.mean(log["true_impedance"][contact, 2]))
        metrics["steady_force_n"] = f_mean
        metrics["steady_penetration_m"] = x_mean
        metrics["steady_stiffness_ratio_n_per_m"] = f_mean / x_mean
        metrics["steady_stiffness_error"] = f_mean / x_mean / K_true - 1.0
    metrics.update(sensor_metrics(log, scenario.dsp.tare_window_s))
    metrics.update(tracking_metrics(log, scenario))
    metrics.update(stability_metrics(log, scenario.scoring))
    metrics.update(identification_metrics(log, scenario.identifiers))
    t_contact = _switch_time(log)
    if scenario.identifiers and t_contact is not None:
        psd = noise_psd(log, scenario.dsp.tare_window_s)  # the rest's noise, once
        for key, until in (("identifiability_bound", None),
                           ("identifiability_bound_1s", EARLY_IDENTIFICATION_S)):
            bound = identifiability_bound(log, t_contact, scenario.dsp.tare_window_s, until,
                                          psd=psd)
            if bound is not None:
                metrics[key] = bound
    metrics.update(fault_metrics(log, scenario))
    metrics.update(safety_metrics(log, scenario))
    for function in METRIC_FUNCTIONS:
        metrics.update(function(log, scenario))
    warnings = tare_warnings(log, scenario)
    if warnings:
        metrics["warnings"] = warnings
    return metrics


def tare_warnings(log: dict, scenario: Scenario) -> list[str]:
    """A warning, with the numbers, when the tip already presses the wall
    during the DSP's tare window: the measured force is then offset by the
    force tared away."""
    t, force = log["t"], log["contact_force_true"]
    window = scenario.dsp.tare_window_s
    pressed = (t < window) & (force > TARE_CONTACT_FORCE_N)
    if not pressed.any():
        return []
    during = force[t < window]
    return [f"contact began at t = {t[np.argmax(pressed)]:.3f} s, inside the DSP's tare window "
            f"(dsp.tare_window_s = {window:g} s): the tare averaged a true force of "
            f"{np.mean(during):.2f} N (up to {np.max(during):.2f} N) into the offset, so "
            "force_measured and force_filtered read low by about that much; start the "
            "contact after the window or shorten it"]


def tracking_metrics(log: dict, scenario: Scenario) -> dict:
    """Contact switch and force/position tracking against ground truth, in
    the scoring window after the first switch (runs with a ``mode`` log)."""
    if "mode" not in log or not np.any(log["mode"] > 0):
        return {"contact_time_s": None} if "mode" in log else {}
    t = log["t"]
    i_contact = int(np.argmax(log["mode"] > 0))
    t_contact = float(t[i_contact])
    s = scenario.scoring
    end = t[-1] + 1.0 if s.window_end_s == 0 else t_contact + s.window_end_s
    window = (t >= t_contact + s.window_start_s) & (t < end)
    out = {
        "contact_time_s": t_contact,
        "mode_switches": int(np.sum(np.abs(np.diff(log["mode"])) > 0)),
        "impact_peak_force_n": float(np.max(log["contact_force_true"][
            (t >= t_contact) & (t < t_contact + s.impact_window_s)])),
        "scoring_window_s": [float(t_contact + s.window_start_s), float(min(end, t[-1]))],
    }
    if window.sum() > 0:
        force = log["contact_force_true"][window]
        error = force - log["force_desired"][window]
        hybrid = scenario.controller.hybrid
        out.update({
            "force_mean_n": float(np.mean(force)),
            "force_desired_mean_n": float(np.mean(log["force_desired"][window])),
            "force_rmse_n": float(np.sqrt(np.mean(error**2))),
            "force_mean_abs_error_n": float(np.mean(np.abs(error))),
            "y_max_abs_error_m": float(np.max(np.abs(log["tip_pose_true"][window, 1]
                                                      - hybrid.y_desired))),
            "phi_max_abs_error_rad": float(np.max(np.abs(log["tip_pose_true"][window, 2]
                                                         - hybrid.phi_desired))),
        })
    out.update(adaptation_metrics(log, t_contact, s))
    if window.sum() > 0:
        out.update(step_metrics(log, window))
        if "joint_torque_applied" in log:
            torque = log["joint_torque_applied"][window]
            np.square(torque, out=torque)  # in place: a long run's is tens of MB
            out["torque_rms_nm"] = float(np.sqrt(np.mean(np.sum(torque, axis=1))))
    if scenario.force_reference.sine_amplitude_n == 0:
        out.update(level_metrics(log, t_contact, s))
    return out


def level_metrics(log: dict, t_contact: float, scoring) -> dict:
    """For a stepwise f_d: ``level_max_error_n``, the largest deviation of
    the true force, averaged over ``level_average_s``, from each level of
    f_d, counted from ``level_settle_s`` after each change (the first level
    from the switch) to the next change; ``level_count``, the levels
    scored (a level shorter than the settling and one average is not)."""
    t = log["t"]
    force, desired = log["contact_force_true"], log["force_desired"]
    i_contact = int(np.searchsorted(t, t_contact))
    changes = [i_contact] + [int(i) + 1 for i in np.flatnonzero(np.diff(desired[i_contact:]))
                             + i_contact] + [len(t)]
    width = max(1, int(round(scoring.level_average_s / CONTROL_PERIOD)))
    sums = np.concatenate([[0.0], np.cumsum(force)])
    worst, count = None, 0
    for start, stop in zip(changes[:-1], changes[1:]):
        first = int(np.searchsorted(t, t[start] + scoring.level_settle_s - TIME_TOLERANCE_S))
        if stop - first < width:
            continue
        means = (sums[first + width:stop + 1] - sums[first:stop + 1 - width]) / width
        deviation = float(np.max(np.abs(means - desired[start])))
        worst = deviation if worst is None else max(worst, deviation)
        count += 1
    return {"level_max_error_n": worst, "level_count": count}


#: A change of f_d by more than this between two samples is a step (N);
#: the thesis's sine changes f_d by at most 0.013 N per sample.
STEP_MIN_N = 1.0
#: A step has settled once ``|f - f_d|`` stays within this share of its size,
#: or STEP_BAND_MIN_N if larger, to the next step.
STEP_BAND = 0.1
STEP_BAND_MIN_N = 1.0


def step_metrics(log: dict, window) -> dict:
    """The true force's response to each step of f_d inside ``window`` (a
    boolean mask), up to the next step or the window's end:
    ``step_overshoot_pct``, the median over steps of the largest excursion
    of f - f_d past the new level in the step's direction, in % of the
    step (0 if none), and ``step_overshoot_max_pct`` the largest;
    ``step_settling_s``, the median time from the step until ``|f - f_d|``
    stays within max(10 % of the step, 1 N) to the next one, over the steps
    that settle; ``step_unsettled``, the steps that never do; ``step_count``."""
    t, force, desired = log["t"], log["contact_force_true"], log["force_desired"]
    inside = np.flatnonzero(window)
    first, last = inside[0], inside[-1] + 1
    steps = [int(i) + 1 for i in np.flatnonzero(np.abs(np.diff(desired[first:last]))
                                                > STEP_MIN_N) + first]
    overshoots, settling, unsettled = [], [], 0
    for k, start in enumerate(steps):
        stop = steps[k + 1] if k + 1 < len(steps) else last
        size = desired[start] - desired[start - 1]
        error = force[start:stop] - desired[start:stop]
        overshoots.append(max(0.0, float(np.max(np.sign(size) * error))) / abs(size) * 100)
        outside = np.flatnonzero(np.abs(error) > max(STEP_BAND * abs(size), STEP_BAND_MIN_N))
        if len(outside) and outside[-1] == len(error) - 1:
            unsettled += 1
        else:
            settled = outside[-1] + 1 if len(outside) else 0
            settling.append(float(t[start + settled] - t[start]))
    return {
        "step_count": len(steps),
        "step_overshoot_pct": float(np.median(overshoots)) if overshoots else None,
        "step_overshoot_max_pct": float(np.max(overshoots)) if overshoots else None,
        "step_settling_s": float(np.median(settling)) if settling else None,
        "step_unsettled": unsettled,
    }


#: adaptation_time_s slides its window by this much (s).
ADAPTATION_STEP_S = 0.5


def adaptation_metrics(log: dict, t_contact: float, scoring) -> dict:
    """Force RMSE (true force vs f_d) per ``rmse_window_s`` window from the
    switch, the largest of those that lie inside the scoring window
    (``worst_window_rmse_n``, None if none does), and the time from the
    switch to the end of the first sliding window whose RMSE is below
    ``adaptation_rmse_n`` (None if none is)."""
    t = log["t"]
    error = log["contact_force_true"] - log["force_desired"]
    width = scoring.rmse_window_s

    def rmse(start):
        window = ((t >= t_contact + start - TIME_TOLERANCE_S)
                  & (t < t_contact + start + width - TIME_TOLERANCE_S))
        return float(np.sqrt(np.mean(error[window] ** 2)))

    span = t[-1] + CONTROL_PERIOD - t_contact  # logged time after the switch
    whole = int(np.floor(span / width + RATIO_TOLERANCE))
    windows = [rmse(k * width) for k in range(whole)]
    adaptation = None
    for k in range(int(np.floor((span - width) / ADAPTATION_STEP_S + RATIO_TOLERANCE)) + 1):
        if rmse(k * ADAPTATION_STEP_S) < scoring.adaptation_rmse_n:
            adaptation = k * ADAPTATION_STEP_S + width
            break
    inside = [w for k, w in enumerate(windows)
              if k * width >= scoring.window_start_s - TIME_TOLERANCE_S
              and (scoring.window_end_s == 0
                   or (k + 1) * width <= scoring.window_end_s + TIME_TOLERANCE_S)]
    return {"force_rmse_windows_n": windows, "adaptation_time_s": adaptation,
            "worst_window_rmse_n": max(inside) if inside else None}


def stability_metrics(log: dict, scoring) -> dict:
    """Contact losses after the first switch, the force RMSE over the run's
    last ``rmse_window_s`` and the ``stable`` verdict (see the module
    docstring); only ``stable`` (None) without a ``mode`` log."""
    if "mode" not in log:
        return {"stable": None}
    t = log["t"]
    in_contact = log["mode"] > 0
    if not in_contact.any():
        return {"contact_losses": 0, "first_contact_loss_s": None,
                "final_force_rmse_n": None, "stable": False}
    t_contact = float(t[np.argmax(in_contact)])
    # A loss is a sample in approach right after one in contact.
    losses = np.flatnonzero(in_contact[:-1] & ~in_contact[1:]) + 1
    end = t[-1] + CONTROL_PERIOD  # logged time, as in adaptation_metrics
    start = end - scoring.rmse_window_s
    final_rmse = None
    if start >= t_contact - TIME_TOLERANCE_S:
        window = (t >= start - TIME_TOLERANCE_S) & (t < end - TIME_TOLERANCE_S)
        error = log["contact_force_true"][window] - log["force_desired"][window]
        final_rmse = float(np.sqrt(np.mean(error**2)))
    return {
        "contact_losses": len(losses),
        "first_contact_loss_s": float(t[losses[0]] - t_contact) if len(losses) else None,
        "final_force_rmse_n": final_rmse,
        "stable": bool(len(losses) == 0 and final_rmse is not None
                       and final_rmse <= STABLE_RMSE_N),
    }


def add_stiffness_ratio(log: dict) -> None:
    """Adds ``stiffness_ratio`` (f / xe, N/m; NaN before contact or where xe
    is under 20 um) and ``displacement_measured`` (xe, m) to a log."""
    if "contact_info" not in log:
        return
    info = log["contact_info"]
    in_contact = info[:, 0] >= 0
    xe = np.where(in_contact, log["tip_pose_measured"][:, 0] - info[:, 1], np.nan)
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = np.where(np.abs(xe) > 2e-5, log["force_filtered"] / xe, np.nan)
    log["displacement_measured"] = xe
    log["stiffness_ratio"] = ratio


def settling_time(t, ratio, after, tolerance):
    """Time from the first ``after`` sample from which ``|ratio - 1|`` stays below
    ``tolerance`` (s); None if the last sample is outside."""
    within = np.abs(ratio - 1) < tolerance
    if not within[-1]:
        return None
    outside = np.flatnonzero(after & ~within)
    start = t[np.argmax(after)]
    return 0.0 if len(outside) == 0 else float(t[outside[-1] + 1] - start)


def relative_errors(estimate, truth) -> dict:
    """(estimate - truth) / truth per M_e, B_e, K_e; None where the truth is
    0 (or either is not finite)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        rel = (np.asarray(estimate) - truth) / np.where(truth != 0, truth, np.nan)
    return {key: float(r) if np.isfinite(r) else None
            for key, r in zip(("mass", "damping", "stiffness"), rel)}


def _switch_time(log: dict):
    """The time of the first switch to contact (s), or None."""
    if "contact_info" not in log or not np.any(log["contact_info"][:, 0] >= 0):
        return None
    return float(log["contact_info"][-1, 0])


def identification_metrics(log: dict, identifiers) -> dict:
    """Final estimates, settling times and relative errors against truth."""
    t_contact = _switch_time(log)
    if not identifiers or t_contact is None:
        return {}
    t = log["t"]
    truth = log["true_impedance"][-1]
    early = t >= t_contact + EARLY_IDENTIFICATION_S - TIME_TOLERANCE_S
    i_early = int(np.argmax(early)) if early.any() else None
    out = {}
    for config in identifiers:
        est = log[f"impedance_{config.name}"]
        final = est[-1]
        out[f"identified_impedance_{config.name}"] = {
            "mass": float(final[0]), "damping": float(final[1]), "stiffness": float(final[2])}
        out[f"identification_error_{config.name}"] = relative_errors(final, truth)
        out[f"identification_error_1s_{config.name}"] = (
            relative_errors(est[i_early], log["true_impedance"][i_early])
            if i_early is not None else dict.fromkeys(("mass", "damping", "stiffness")))
        after = t >= t_contact
        for tolerance, key in ((SETTLE_TOLERANCE, f"identification_time_{config.name}_s"),
                               (SETTLE_TOLERANCE_NN, f"identification_time_10pct_{config.name}_s")):
            out[key] = settling_time(t, est[:, 2] / log["true_impedance"][:, 2], after, tolerance)
    out.update(identification_tracking(log, identifiers, t_contact))
    ratio = log.get("stiffness_ratio")
    if ratio is not None:
        late = (t >= t[-1] - 1.0) & np.isfinite(ratio)
        if late.any():
            out["stiffness_ratio_final_n_per_m"] = float(np.mean(ratio[late]))
    return out


def _tracking_errors(relative_error, tolerance):
    """max |e|, RMS of e and the fraction of samples with |e| < tolerance;
    max and RMS None if any sample is not finite (it then counts as
    outside)."""
    finite = bool(np.all(np.isfinite(relative_error)))
    with np.errstate(invalid="ignore"):
        within = np.abs(relative_error) < tolerance
    return (float(np.max(np.abs(relative_error))) if finite else None,
            float(np.sqrt(np.mean(relative_error**2))) if finite else None,
            float(np.mean(within)))


def identification_tracking(log: dict, identifiers, t_contact: float) -> dict:
    """How each identifier follows an environment that changes after the
    switch: ``identification_tracking_<name>``, a dict over the samples from
    ``TRACKING_START_S`` after the switch ``t_contact`` to the end, the
    relative errors taken against the truth at the same sample::

        stiffness_max_abs_error   max |K_est / K_e - 1|
        stiffness_rms_error       RMS of K_est / K_e - 1
        stiffness_within_5pct     fraction of the samples with |.| < 5 %
        damping_max_abs_error, damping_rms_error, damping_within_5pct
                                  the same for B_e (None where B_e is 0)
        stiffness_settling_after_step_s
                                  from the last step of the true K_e (a
                                  change by more than TRACKING_STEP_MIN
                                  between two samples, after the switch)
                                  until K_est stays within 5 % (None if it
                                  never does, or without a step)

    max and RMS are None if an estimate is not finite. The window's start
    and each step's time are given as ``from_s`` and ``step_times_s``.
    Empty when the truth is constant after the switch or the run ends
    within TRACKING_START_S of it."""
    t = log["t"]
    truth = log["true_impedance"]
    after_switch = t >= t_contact - TIME_TOLERANCE_S
    window = t >= t_contact + TRACKING_START_S - TIME_TOLERANCE_S
    changes = np.ptp(truth[after_switch, 1:], axis=0) if after_switch.any() else [0, 0]
    if not window.any() or not np.any(changes > 0):
        return {}
    K, B = truth[:, 2], truth[:, 1]
    with np.errstate(divide="ignore", invalid="ignore"):
        jump = np.abs(np.diff(K)) / np.abs(K[:-1])
    steps = np.flatnonzero(after_switch[1:] & (jump > TRACKING_STEP_MIN)) + 1
    out = {}
    for config in identifiers:
        est = log[f"impedance_{config.name}"]
        with np.errstate(divide="ignore", invalid="ignore"):
            k_error = est[:, 2] / K - 1
            b_error = np.where(B != 0, est[:, 1] / B - 1, np.nan)
        entry = {"from_s": float(t[np.argmax(window)]),
                 "step_times_s": [float(t[i]) for i in steps]}
        (entry["stiffness_max_abs_error"], entry["stiffness_rms_error"],
         entry["stiffness_within_5pct"]) = _tracking_errors(
             k_error[window], SETTLE_TOLERANCE)
        if np.all(B[window] != 0):
            (entry["damping_max_abs_error"], entry["damping_rms_error"],
             entry["damping_within_5pct"]) = _tracking_errors(
                 b_error[window], SETTLE_TOLERANCE)
        else:
            entry.update(damping_max_abs_error=None, damping_rms_error=None,
                         damping_within_5pct=None)
        settle = None
        if len(steps):
            i = steps[-1]
            settle = settling_time(t[i:], est[i:, 2] / K[i:], np.ones(len(t) - i, bool),
                                   SETTLE_TOLERANCE)
            if settle is not None:
                settle = round(settle, 6)  # a difference of sample times
        entry["stiffness_settling_after_step_s"] = settle
        out[f"identification_tracking_{config.name}"] = entry
    return out


def baseline_scenario(scenario: Scenario) -> Scenario:
    """The hybrid part alone of a neural-controller scenario: the same arm,
    environment, seed and gains with the compensator removed (Fig 6.10)."""
    baseline = copy.deepcopy(scenario)
    baseline.controller.name = "hybrid"
    baseline.description = f"hybrid part alone of: {scenario.description}"
    return baseline


#: A fault's "after" is this long after its end (s).
FAULT_AFTER_S = 2.0
#: Tracking has recovered once the 100 ms mean of the true force is within
#: this of f_d (N) and stays so for RECOVERY_HOLD_S.
RECOVERY_BAND_N = 1.0
RECOVERY_HOLD_S = 0.5
#: A contact loss: the true force at zero for at least this long (s).
LOSS_MIN_S = 0.02
#: A run ends safe if, over its last END_WINDOW_S, the true force stays at or
#: below safety.force_limit_n and the tip speed below its limit.
END_WINDOW_S = 0.1


def _moving_mean(x, n):
    kernel = np.ones(n) / n
    return np.convolve(x, kernel, mode="full")[:len(x)]  # causal, over the last n samples


def _true_contact_losses(force, mask):
    """Zero-force stretches of at least LOSS_MIN_S that start inside ``mask``
    after the force was positive."""
    touching = force > 0
    n = int(round(LOSS_MIN_S / CONTROL_PERIOD))
    drops = np.flatnonzero(touching[:-1] & ~touching[1:]) + 1
    count = 0
    for i in drops:
        if mask[i] and not touching[i:i + n].any() and i + n <= len(force):
            count += 1
    return count


def fault_metrics(log: dict, scenario: Scenario) -> dict:
    """What each injected fault did (runs with ``faults``): ``faults`` is a
    list, one entry per fault in the scenario's order, with its kind, when it
    was on (s), the peak true force and tip speed during it and in the
    FAULT_AFTER_S after it, the contact losses (true force at zero for 20 ms
    or more) from its start to FAULT_AFTER_S after its end, and
    ``recovery_s``: from its end until the 100 ms mean true force is back
    within 1 N of f_d for 0.5 s (None if it never is, or without f_d)."""
    if not scenario.faults or "fault_active" not in log or not len(log["t"]):
        return {}
    t = log["t"]
    force = log["contact_force_true"]
    speed = np.hypot(log["tip_velocity_true"][:, 0], log["tip_velocity_true"][:, 1])
    active = np.asarray(log["fault_active"]).reshape(len(t), -1)
    tracking = None
    if "force_desired" in log:
        n = int(round(0.1 / CONTROL_PERIOD))
        tracking = np.abs(_moving_mean(force - log["force_desired"], n)) < RECOVERY_BAND_N
    hold = int(round(RECOVERY_HOLD_S / CONTROL_PERIOD))
    entries = []
    for i, fault in enumerate(scenario.faults):
        on = active[:, i] > 0.5
        entry = {"kind": fault.kind, "start_s": None, "end_s": None}
        if not on.any():
            entries.append(entry)
            continue
        first, last = int(np.argmax(on)), len(on) - 1 - int(np.argmax(on[::-1]))
        end = t[last] + CONTROL_PERIOD
        after = (t >= end - TIME_TOLERANCE_S) & (t < end + FAULT_AFTER_S - TIME_TOLERANCE_S)
        span = (t >= t[first] - TIME_TOLERANCE_S) & (t < end + FAULT_AFTER_S - TIME_TOLERANCE_S)
        entry.update(
            start_s=float(t[first]), end_s=float(end),
            peak_force_during_n=float(force[on].max()),
            peak_force_after_n=float(force[after].max()) if after.any() else None,
            peak_tip_speed_during_m_s=float(speed[on].max()),
            peak_tip_speed_after_m_s=float(speed[after].max()) if after.any() else None,
            contact_losses=_true_contact_losses(force, span),
            recovery_s=None)
        if tracking is not None:
            # Runs of `hold` samples in band, from the fault's end on.
            ok = tracking & (t >= end - TIME_TOLERANCE_S)
            runs = np.convolve(ok.astype(int), np.ones(hold, dtype=int), mode="valid")
            starts = np.flatnonzero(runs == hold)
            if len(starts):
                # to the microsecond: t - end is a difference of sample times
                entry["recovery_s"] = round(float(t[starts[0]] - end), 6)
        entries.append(entry)
    return {"faults": entries}


def safety_metrics(log: dict, scenario: Scenario) -> dict:
    """The supervisor's decisions (runs with ``safety_state``):
    ``safety_events`` lists each entry into a reflex, a hold or the stop
    ({"time_s", "state"}), ``safety_clamped_s`` the time the push clamp
    acted; and, for every run, ``ended_safe_log``: over the last 100 ms the
    true force stayed at or below ``safety.force_limit_n`` and the tip speed
    below ``safety.tip_speed_limit_m_s``, all finite (the runner's
    ``ended_safe`` also needs the run to have completed)."""
    t = log["t"]
    if not len(t):
        return {}
    safety = scenario.safety
    end = t >= t[-1] - END_WINDOW_S + TIME_TOLERANCE_S
    force = log["contact_force_true"][end]
    velocity = log["tip_velocity_true"][end]
    finite = bool(np.all(np.isfinite(force)) and np.all(np.isfinite(velocity)))
    metrics = {"ended_safe_log": finite and bool(
        np.max(force) <= safety.force_limit_n
        and np.max(np.hypot(velocity[:, 0], velocity[:, 1])) < safety.tip_speed_limit_m_s)}
    if "safety_state" in log:
        state = np.asarray(log["safety_state"]).round().astype(int)
        entered = np.flatnonzero(np.diff(state) != 0) + 1
        events = [{"time_s": float(t[i]), "state": SAFETY_STATES[state[i]]}
                  for i in entered if state[i] >= REFLEX]
        metrics.update(safety_events=events, safety_event_count=len(events),
                       safety_clamped_s=float(np.sum(state == CLAMPED) * CONTROL_PERIOD),
                       safety_final_state=SAFETY_STATES[int(state[-1])])
        if "safety_stop_reason" in log:
            reason = int(round(float(log["safety_stop_reason"][-1])))
            metrics["safety_stop_reason"] = STOP_REASONS[reason] if reason else None
    return metrics


# Other packages' metrics: importing each module named in the group registers them.
for _entry in entry_points(group=METRIC_GROUP):
    _entry.load()
