"""Metrics for parameter sweeps: contact losses, the final force RMSE, the
``stable`` rule and the identification error 1 s after the switch, on
hand-made logs against hand computations, and on one short real run."""

import json

import numpy as np
import pytest

import drake_contact
from drake_contact.scoring.metrics import (
    STABLE_RMSE_N, compute_metrics, identification_metrics, level_metrics, stability_metrics)
from drake_contact.identification.identifiers import IdentifierConfig
from drake_contact.scenario import ScoringConfig

#: One worker runs this module and its fixture is session-scoped, so the fixture
#: runs once (-n auto; docs/developer/testing.md, "Shared runs").
pytestmark = pytest.mark.xdist_group("test_metrics")

DT = 1e-3  # the logs' sample period (s)


def stepped_log(duration_s, segments, *, f_desired=20.0, error=0.0):
    """A log at 1 kHz whose ``mode`` is ``value`` from each ``(start_s,
    value)`` on, and whose true force is f_d + ``error`` (N; a scalar or an
    array over the samples)."""
    t = np.arange(round(duration_s / DT)) * DT
    mode = np.zeros(len(t))
    for start, value in segments:
        mode[t >= start - 1e-9] = value
    desired = np.full(len(t), f_desired)
    return {"t": t, "mode": mode, "force_desired": desired,
            "contact_force_true": desired + error}


# Contact losses.

def test_contact_losses_are_counted_from_a_hand_made_mode_sequence():
    # 0..0 1..1 0..0 1..1 0: contact at 1.0 s, lost at 2.5 s, regained at
    # 3.0 s, lost again on the last sample (3.999 s).
    log = stepped_log(4.0, [(1.0, 1), (2.5, 0), (3.0, 1), (3.999, 0)])
    m = stability_metrics(log, ScoringConfig())
    assert m["contact_losses"] == 2
    assert m["first_contact_loss_s"] == pytest.approx(1.5, abs=1e-12)
    assert m["stable"] is False


@pytest.mark.parametrize("segments", [[], [(3.0, 1)]], ids=["never", "no_loss"])
def test_no_contact_loss_without_a_return_to_approach(segments):
    # Approach before the first switch is not a loss.
    m = stability_metrics(stepped_log(4.0, segments), ScoringConfig())
    assert m["contact_losses"] == 0 and m["first_contact_loss_s"] is None


def test_a_run_that_never_switches_has_no_final_rmse_and_is_not_stable():
    m = stability_metrics(stepped_log(4.0, []), ScoringConfig(rmse_window_s=1.0))
    assert m == {"contact_losses": 0, "first_contact_loss_s": None,
                 "final_force_rmse_n": None, "stable": False}


def test_without_a_mode_log_only_stable_is_reported_as_none():
    log = stepped_log(4.0, [(1.0, 1)])
    del log["mode"]
    assert stability_metrics(log, ScoringConfig()) == {"stable": None}


# The final force RMSE.

def test_final_force_rmse_is_over_the_last_full_window():
    # 6 s, switch at 1 s, 2 s windows: the last window is [4, 6) s, where the
    # error alternates +-3 N (RMSE 3 N); elsewhere it is 10 N, so one sample
    # too many or a window aligned to the switch gives another number.
    log = stepped_log(6.0, [(1.0, 1)])
    last = log["t"] >= 4.0 - 1e-9
    error = np.where(last, 3.0 * (-1.0) ** np.arange(len(log["t"])), 10.0)
    log["contact_force_true"] = log["force_desired"] + error
    m = stability_metrics(log, ScoringConfig(rmse_window_s=2.0))
    assert np.count_nonzero(last) == 2000
    assert m["final_force_rmse_n"] == pytest.approx(3.0, rel=1e-12)
    # Hand computation with a ramp: RMSE of e_k = k / 2000 over k < 2000.
    k = np.arange(len(log["t"])) - np.argmax(last)
    log["contact_force_true"] = log["force_desired"] + np.where(last, k / 2000, 10.0)
    hand = np.sqrt(sum((j / 2000) ** 2 for j in range(2000)) / 2000)
    m = stability_metrics(log, ScoringConfig(rmse_window_s=2.0))
    assert m["final_force_rmse_n"] == pytest.approx(hand, rel=1e-12)


@pytest.mark.parametrize("switch_s, full", [(4.0, True), (4.001, False), (5.0, False)])
def test_final_force_rmse_needs_a_whole_window_after_the_switch(switch_s, full):
    # A 6 s run with 2 s windows has one only if the switch is by 4 s.
    m = stability_metrics(stepped_log(6.0, [(switch_s, 1)], error=1.0),
                          ScoringConfig(rmse_window_s=2.0))
    assert (m["final_force_rmse_n"] is not None) == full
    if full:
        assert m["final_force_rmse_n"] == pytest.approx(1.0)


# The stable rule.

@pytest.mark.parametrize("segments, error, stable", [
    ([(1.0, 1)], 0.99 * STABLE_RMSE_N, True),
    ([(1.0, 1)], 1.01 * STABLE_RMSE_N, False),      # tracks badly
    ([(1.0, 1), (1.5, 0), (1.6, 1)], 0.1, False),   # bounced off, then tracked
    ([(4.5, 1)], 0.1, False),                       # too short to judge after the switch
    ([], 0.1, False),                               # never touched
], ids=["tracks", "rmse_too_high", "contact_lost", "no_full_window", "no_switch"])
def test_stable_rule_on_crafted_logs(segments, error, stable):
    m = stability_metrics(stepped_log(6.0, segments, error=error),
                          ScoringConfig(rmse_window_s=2.0))
    assert m["stable"] is stable
    json.dumps(m, allow_nan=False)


# The identification error 1 s after the switch.

def ramp_identification_log(duration_s, t_contact=1.0):
    """Truth M_e = 0 (no relative error), B_e = 100, K_e = 1000 stepping to
    2000 at 3 s; the estimates ramp from the switch: B_e by +10 %/s, K_e
    from +50 % by -20 %/s (relative to the truth before the step)."""
    t = np.arange(round(duration_s / DT)) * DT
    since = np.maximum(t - t_contact, 0.0)
    truth = np.column_stack([np.zeros(len(t)), np.full(len(t), 100.0),
                             np.where(t >= 3.0, 2000.0, 1000.0)])
    estimate = np.column_stack([np.full(len(t), 0.05), 100.0 * (1 + 0.1 * since),
                                1000.0 * (1.5 - 0.2 * since)])
    info = np.zeros((len(t), 4))
    info[:, 0] = np.where(t >= t_contact - 1e-9, t_contact, -1.0)
    return {"t": t, "contact_info": info, "true_impedance": truth,
            "impedance_ramp": estimate}


def test_identification_error_1s_reads_the_estimate_1s_after_the_switch():
    out = identification_metrics(ramp_identification_log(5.0), [IdentifierConfig(name="ramp")])
    early = out["identification_error_1s_ramp"]
    assert early["mass"] is None  # the truth is 0
    assert early["damping"] == pytest.approx(0.1, abs=1e-9)
    assert early["stiffness"] == pytest.approx(0.3, abs=1e-9)
    # The final error differs (later estimate, stepped truth): 4 s after the switch.
    final = out["identification_error_ramp"]
    assert final["damping"] == pytest.approx(0.3999, abs=1e-9)
    assert final["stiffness"] == pytest.approx(1000 * (1.5 - 0.2 * 3.999) / 2000 - 1, abs=1e-9)


def test_identification_error_1s_is_none_when_the_log_ends_sooner():
    out = identification_metrics(ramp_identification_log(1.9), [IdentifierConfig(name="ramp")])
    assert out["identification_error_1s_ramp"] == {
        "mass": None, "damping": None, "stiffness": None}
    assert out["identification_error_ramp"]["stiffness"] is not None


# One real run.

@pytest.fixture(scope="session")
def styrofoam_run():
    # 15 s: the switch is near 9.1 s, and a full 5 s RMSE window after it
    # (which ``stable`` needs) ends the run (the scenario's own 14 s has 4.9 s).
    scenario = drake_contact.load_scenario("identify_styrofoam", duration=15.0)
    return scenario, drake_contact.simulate_scenario(scenario)


def test_identify_styrofoam_is_stable_and_identifies_early(styrofoam_run):
    _, result = styrofoam_run
    m = result.metrics
    assert result.status == "completed"
    assert 8.5 < m["contact_time_s"] < 9.5
    assert m["contact_losses"] == 0 and m["first_contact_loss_s"] is None
    assert m["final_force_rmse_n"] <= STABLE_RMSE_N and m["stable"] is True
    assert abs(m["identification_error_1s_rls_matched"]["stiffness"]) < 0.10
    json.dumps(m)


def test_identify_styrofoam_bound_on_the_impedance(styrofoam_run):
    # The run's only excitation is the switch transient: K_e is bounded at
    # about 2.3 % (one standard deviation), the 10 g M_e not at all (over
    # 1000 %). rls_matched's K_e error (-2.2 % at seed 0) is within three
    # of them, as an efficient estimator's would be.
    _, result = styrofoam_run
    m = result.metrics
    bound = m["identifiability_bound"]["relative"]
    assert 0.005 < bound["stiffness"] < 0.05
    assert bound["mass"] > 1.0
    assert abs(m["identification_error_rls_matched"]["stiffness"]) < 3 * bound["stiffness"]
    assert m["identifiability_bound"]["contact_samples"] > 5000


def test_a_10s_styrofoam_run_is_too_short_to_be_stable(styrofoam_run):
    # The same run cut at 10.5 s (the log is causal): 1.4 s after the switch,
    # no full window, so not stable; the 1 s identification is unchanged.
    scenario, result = styrofoam_run
    keep = result.log["t"] <= 10.5 + 1e-9
    short = {k: v[keep] for k, v in result.log.items()}
    m = compute_metrics(drake_contact.load_scenario("identify_styrofoam", duration=10.5),
                        short, wall_s=1.0)
    assert m["contact_losses"] == 0
    assert m["final_force_rmse_n"] is None and m["stable"] is False
    for name in ("rls_matched", "rls"):
        assert m[f"identification_error_1s_{name}"] == \
            result.metrics[f"identification_error_1s_{name}"]


# Levels of a stepwise reference.

def test_level_error_is_the_worst_100ms_mean_from_settling_to_the_next_change():
    # f_d: 20 N from the switch at 1 s, 10 N from 4 s, 20 N from 6 s to 8 s.
    log = stepped_log(8.0, [(1.0, 1)])
    t = log["t"]
    desired = np.where((t >= 4.0 - 1e-9) & (t < 6.0 - 1e-9), 10.0, 20.0)
    force = desired.copy()
    force[(t >= 4.0 - 1e-9) & (t < 4.5 - 1e-9)] = 14.0       # settling: not scored
    force[(t >= 5.0 - 1e-9) & (t < 5.05 - 1e-9)] = 10.0 + 3.0  # 50 ms at +3 N: 1.5 N in 100 ms
    force[(t >= 7.9 - 1e-9)] = 20.0 - 0.4                     # the last 100 ms: -0.4 N
    log.update(force_desired=desired, contact_force_true=force)
    scoring = ScoringConfig()
    out = level_metrics(log, 1.0, scoring)
    assert out["level_count"] == 3
    assert out["level_max_error_n"] == pytest.approx(1.5, abs=1e-9)
    # A deviation before level_settle_s is not counted; a longer settling skips more.
    force[(t >= 5.0 - 1e-9) & (t < 5.05 - 1e-9)] = 10.0
    assert level_metrics(log, 1.0, scoring)["level_max_error_n"] == pytest.approx(0.4, abs=1e-9)
    force[(t >= 1.5 - 1e-9) & (t < 1.6 - 1e-9)] = 21.0
    assert level_metrics(log, 1.0, scoring)["level_max_error_n"] == pytest.approx(1.0, abs=1e-9)
    late = ScoringConfig(level_settle_s=0.7)
    assert level_metrics(log, 1.0, late)["level_max_error_n"] == pytest.approx(0.4, abs=1e-9)
