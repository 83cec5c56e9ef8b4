"""Every bundled scenario against its golden log (tests/golden_logs.py),
and the comparison's teeth: small changes of physics that it must catch.

A fixture passes on any CPU and any patch release of the locked packages
when every signal stays within its allowance: MARGIN times what the
recording machine measured when it disturbed the run's rounding from the
first contact on (golden_logs.SENSITIVITY_RUNS, KERNEL_RUNS), and never
less than FLOOR of the signal's scale; before the contact switch, where
rounding is not amplified, that is a tolerance of about 1e-9 of the scale.
``python tests/golden_logs.py --compare`` prints each scenario's largest
deviation as a fraction of its allowance.
"""

import numpy as np
import pytest

import golden_logs
from drake_contact.control.controller_model import ArmModel
from drake_contact.resources import bundled_scenario_names
from golden_logs import GOLDEN_DIR, check, golden_log, load_golden

#: The scenario the guard's teeth are tested on: the force loop and every
#: identifier, whose allowances are the loosest of the fixtures.
GUARDED = "identify_styrofoam"


def test_every_bundled_scenario_has_a_golden_log():
    assert sorted(p.stem for p in GOLDEN_DIR.glob("*.npz")) == bundled_scenario_names()


def test_every_golden_log_has_its_sensitivity():
    for name in bundled_scenario_names():
        golden = load_golden(name)
        signals = {k[len("log/"):] for k in golden if k.startswith("log/") and k != "log/t"}
        measured = {k[len("sensitivity/"):] for k in golden if k.startswith("sensitivity/")}
        assert signals == measured, f"{name}: no sensitivity for {sorted(signals - measured)}"


def test_every_golden_log_is_guarded_tightly_past_its_switch():
    """Every signal's allowance stays within golden_logs.TIGHT (1e-3) of its
    scale before the switch and for 50 ms after it: the sensitivity runs
    move nothing before the first contact, and diverge only later."""
    for name in bundled_scenario_names():
        golden = load_golden(name)
        t = golden["log/t"]
        switch = golden_logs.switch_index(golden["log/mode"]) if "log/mode" in golden else -1
        needed = t[-1] if switch < 0 else min(t[switch] + 0.05, t[-1])
        assert golden_logs.tight_until(golden) >= needed - 1e-9, name


@pytest.mark.parametrize("name", bundled_scenario_names())
def test_golden_log(name):
    checks, problems = check(name, golden_log(name))
    assert not problems, "\n".join(problems)


@pytest.fixture(scope="session")
def guarded_run():
    return golden_log(GUARDED)


def _fails(log, *, expect: str):
    checks, problems = check(GUARDED, log)
    assert problems, f"the comparison missed {expect}: largest deviation " \
                     f"{checks[0].worst:.3g} of its allowance ('{checks[0].signal}')"
    return problems


@pytest.mark.parametrize("override, what", [
    ("environment.stiffness=7007.0", "K_e 1e-3 higher"),
    ("dsp.force_filter_cutoff_hz=120.12", "the force filter's cut-off 1e-3 higher"),
])
def test_the_comparison_catches_a_small_change_of_parameter(override, what):
    _fails(golden_log(GUARDED, [override]), expect=what)


def test_the_comparison_catches_a_sign(monkeypatch):
    """The controller model's velocity-product terms h(q, qdot) negated."""
    evaluate_rows = ArmModel.evaluate_rows

    def flipped(self, q, qdot):
        J, jdot_qdot, M, h = evaluate_rows(self, q, qdot)
        return J, jdot_qdot, M, [-x for x in h]

    monkeypatch.setattr(ArmModel, "evaluate_rows", flipped)
    _fails(golden_log(GUARDED), expect="h(q, qdot) with its sign flipped")


@pytest.mark.parametrize("signal", ["force_filtered", "impedance_rls", "tip_velocity_measured"])
@pytest.mark.xdist_group("guarded_run")
def test_the_comparison_catches_a_one_sample_delay(guarded_run, signal):
    t = guarded_run["t"]
    window = np.flatnonzero(t >= t[-1] - golden_logs.WINDOW_S + 1e-9)
    delayed = dict(guarded_run)
    delayed[signal] = np.array(guarded_run[signal], copy=True)
    delayed[signal][window[1:]] = guarded_run[signal][window[:-1]]
    problems = _fails(delayed, expect=f"'{signal}' one sample late")
    assert any(f"'{signal}'" in p for p in problems)


@pytest.mark.xdist_group("guarded_run")
def test_the_comparison_catches_a_moved_switch(guarded_run):
    moved = dict(guarded_run, mode=np.roll(guarded_run["mode"], 1))
    assert any("contact switch moved" in p for p in _fails(moved, expect="the switch moved"))


@pytest.mark.xdist_group("guarded_run")
def test_the_unperturbed_run_passes_with_a_margin(guarded_run):
    checks, problems = check(GUARDED, guarded_run)
    assert not problems
    assert checks[0].worst < 0.5, golden_logs.report(GUARDED, checks, problems)


# The comparison itself, on a synthetic fixture: a switch at sample 5 of 10.


def _fixture(sensitivity):
    t = np.arange(10) * 1e-3
    return {"log/t": t, "log/mode": (t >= 5e-3).astype(float),
            "log/x": np.linspace(1.0, 2.0, 10),
            "log/joint_positions_measured": np.repeat([[0.0], [0.1]], 5, axis=0),
            "sensitivity/mode": np.zeros((10, 1), np.float32),
            "sensitivity/x": np.asarray(sensitivity, np.float32).reshape(10, 1),
            "sensitivity/joint_positions_measured": np.zeros((10, 1), np.float32)}


def _log(golden, **changes):
    log = {k[len("log/"):]: np.array(v, copy=True) for k, v in golden.items()
           if k.startswith("log/")}
    return log | changes


def test_the_allowance_grows_with_the_measured_sensitivity_and_leads_it():
    golden = _fixture([0, 0, 0, 0, 0, 0, 0, 0, 1e-6, 0])
    allowance = golden_logs.allowance(golden, "x")[:, 0]
    # LEAD_S (20 ms) reaches the sample at 8 ms from every earlier one.
    assert np.allclose(allowance, golden_logs.MARGIN * np.float32(1e-6))
    golden["log/t"] = np.arange(10) * 0.1
    allowance = golden_logs.allowance(golden, "x")[:, 0]
    assert np.allclose(allowance[:8], golden_logs.FLOOR)
    assert np.allclose(allowance[8:], golden_logs.MARGIN * np.float32(1e-6))


def test_a_deviation_beyond_the_allowance_fails_and_within_it_passes():
    golden = _fixture(np.full(10, 1e-6))
    allowed = golden_logs.MARGIN * 1e-6 * 2.0  # the scale of x is 2
    x = golden["log/x"].copy()
    x[7] += 0.9 * allowed
    assert not check("synthetic", _log(golden, x=x), golden)[1]
    x[7] += 0.2 * allowed
    assert check("synthetic", _log(golden, x=x), golden)[1]


def test_a_quantized_signal_may_be_one_quantum_off_on_a_few_samples_after_the_switch():
    golden = _fixture(np.zeros(10))
    golden["log/t"] = np.arange(10) * 1.0
    golden = {k: (np.tile(v, (20,) + (1,) * (v.ndim - 1)) if k != "log/t" else
                  np.arange(200) * 1e-3) for k, v in golden.items()}
    golden["log/mode"] = (np.arange(200) >= 100).astype(float)
    counts = golden["log/joint_positions_measured"].copy()
    counts[150] += 0.1
    assert not check("synthetic", _log(golden, joint_positions_measured=counts), golden)[1]
    counts[40] += 0.1  # before the switch: no quantum allowed
    assert check("synthetic", _log(golden, joint_positions_measured=counts), golden)[1]
    counts[40] -= 0.1
    counts[151:160] += 0.1  # more than QUANTIZED_FRACTION of the samples after it
    assert check("synthetic", _log(golden, joint_positions_measured=counts), golden)[1]
