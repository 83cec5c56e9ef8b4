"""Time-varying environments: the tracking metrics on hand-made
logs against hand computations, the wall's logged truth under the
stiffness ramp and step against their closed forms, and one short closed
loop across a material change."""

import json

import numpy as np
import pytest
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import ConstantVectorSource

import drake_contact
from drake_contact.scoring.metrics import identification_metrics, identification_tracking
from drake_contact.faults import ChainFaults, FaultClock, FaultConfig
from drake_contact.identification.identifiers import IdentifierConfig
from drake_contact.plant.compliant_wall import CompliantWall, EnvironmentConfig

#: One worker runs this module and its fixture is session-scoped, so the fixture
#: runs once (-n auto; docs/developer/testing.md, "Shared runs").
pytestmark = pytest.mark.xdist_group("test_environment_change")

DT = 1e-3  # the logs' sample period (s)


def stepped_wall_log(estimate_error, *, duration_s=6.0, t_contact=1.0, t_step=3.0):
    """Truth M_e = 0.01, B_e = 100, K_e = 1000 doubling at ``t_step``; the
    K_e estimate is the truth times 1 + ``estimate_error(t)``, B_e exact."""
    t = np.arange(round(duration_s / DT)) * DT
    K = np.where(t >= t_step - 1e-9, 2000.0, 1000.0)
    truth = np.column_stack([np.full(len(t), 0.01), np.full(len(t), 100.0), K])
    estimate = truth.copy()
    estimate[:, 2] = K * (1 + estimate_error(t))
    info = np.zeros((len(t), 4))
    info[:, 0] = np.where(t >= t_contact - 1e-9, t_contact, -1.0)
    return {"t": t, "contact_info": info, "true_impedance": truth, "impedance_step": estimate}


def test_tracking_scores_the_current_truth_from_1s_after_the_switch():
    # +10 % before the switch + 1 s (not scored) and until 3.5 s (over the
    # step at 3 s), then +2 %: scored from 2 s to 6 s, 1.5 s at 10 %, 2.5 s at 2 %.
    log = stepped_wall_log(lambda t: np.where(t < 3.5 - 1e-9, 0.10, 0.02))
    log["impedance_step"][log["t"] < 2.0, 2] = 0.0  # before the window: ignored
    out = identification_tracking(log, [IdentifierConfig(name="step")], 1.0)
    entry = out["identification_tracking_step"]
    assert entry["from_s"] == pytest.approx(2.0)
    assert entry["step_times_s"] == [pytest.approx(3.0)]
    assert entry["stiffness_max_abs_error"] == pytest.approx(0.10)
    assert entry["stiffness_rms_error"] == pytest.approx(np.sqrt((1.5 * 0.1**2 + 2.5 * 0.02**2) / 4))
    assert entry["stiffness_within_5pct"] == pytest.approx(2.5 / 4)
    assert entry["stiffness_settling_after_step_s"] == pytest.approx(0.5)
    assert entry["damping_max_abs_error"] == 0.0
    assert entry["damping_within_5pct"] == 1.0
    json.dumps(out, allow_nan=False)


def test_tracking_after_a_step_never_settles_if_the_last_sample_is_outside():
    log = stepped_wall_log(lambda t: np.where(t < 5.0, 0.0, -0.5))
    entry = identification_tracking(log, [IdentifierConfig(name="step")], 1.0)[
        "identification_tracking_step"]
    assert entry["stiffness_settling_after_step_s"] is None
    assert entry["stiffness_max_abs_error"] == pytest.approx(0.5)
    assert entry["stiffness_within_5pct"] == pytest.approx(3.0 / 4)


def test_tracking_with_a_non_finite_estimate_has_no_max_and_counts_it_outside():
    log = stepped_wall_log(lambda t: np.where(np.abs(t - 4.0) < 0.5, np.nan, 0.0))
    entry = identification_tracking(log, [IdentifierConfig(name="step")], 1.0)[
        "identification_tracking_step"]
    assert entry["stiffness_max_abs_error"] is None
    assert entry["stiffness_rms_error"] is None
    assert entry["stiffness_within_5pct"] == pytest.approx(3.0 / 4, abs=1e-3)
    assert entry["stiffness_settling_after_step_s"] == pytest.approx(1.5)


def test_tracking_of_a_ramp_has_no_step():
    # K_e +20 % over 3-5 s; the estimate stays at +3 % of the start.
    log = stepped_wall_log(lambda t: 0.0)
    t = log["t"]
    log["true_impedance"][:, 2] = 1000.0 * (1 + 0.2 * np.clip((t - 3.0) / 2.0, 0, 1))
    log["impedance_step"][:, 2] = 1000.0 * 1.03
    entry = identification_tracking(log, [IdentifierConfig(name="step")], 1.0)[
        "identification_tracking_step"]
    assert entry["step_times_s"] == []
    assert entry["stiffness_settling_after_step_s"] is None
    # |1.03 / (1 + 0.2 s) - 1| < 5 % while 1 + 0.2 s < 1.03 / 0.95, s the
    # ramp's share: 1 s before the ramp and 2 s_in of it, of the 4 s scored.
    s_in = (1.03 / 0.95 - 1) / 0.2
    assert entry["stiffness_within_5pct"] == pytest.approx((1.0 + 2.0 * s_in) / 4, abs=1e-3)
    assert entry["stiffness_max_abs_error"] == pytest.approx(1 - 1.03 / 1.2)


def test_a_constant_wall_adds_no_tracking_metrics():
    log = stepped_wall_log(lambda t: 0.0, t_step=100.0)
    assert identification_tracking(log, [IdentifierConfig(name="step")], 1.0) == {}
    assert not [k for k in identification_metrics(log, [IdentifierConfig(name="step")])
                if k.startswith("identification_tracking")]
    # A change before the switch does not count either.
    log = stepped_wall_log(lambda t: 0.0, t_step=0.5)
    assert identification_tracking(log, [IdentifierConfig(name="step")], 1.0) == {}


# The wall's truth under the environment faults: K_e (t) in closed form.

def wall_with_fault(fault: FaultConfig, environment: EnvironmentConfig):
    """The wall behind the fault's stiffness scale, its tip fixed 3 mm into
    the surface; returns (diagram, clock, wall)."""
    builder = DiagramBuilder()
    wall = builder.AddNamedSystem("wall", CompliantWall(environment, 1e-3,
                                                        stiffness_scale_input=True))
    tip = builder.AddNamedSystem("tip", ConstantVectorSource(
        [environment.surface_x + 3e-3, 0, 0, 0, 0, 0]))
    builder.Connect(tip.get_output_port(), wall.GetInputPort("tip_state"))
    clock = builder.AddNamedSystem("fault_clock", FaultClock())
    builder.Connect(wall.GetOutputPort("contact_force"), clock.get_input_port())
    one = builder.AddNamedSystem("stiffness_nominal", ConstantVectorSource([1.0]))
    scale, _ = ChainFaults(builder, [fault], "stiffness", one.get_output_port(), 1,
                           clock.get_output_port())
    builder.Connect(scale, wall.GetInputPort("stiffness_scale"))
    builder.ExportOutput(wall.GetOutputPort("true_impedance"), "true_impedance")
    return builder.Build(), clock, wall


def true_stiffness(diagram, clock, t, t_contact):
    """K_e logged at time t, the clock holding a contact at ``t_contact``
    (None: no contact yet)."""
    context = diagram.CreateDefaultContext()
    context.SetTime(t)
    clock_context = clock.GetMyMutableContextFromRoot(context)
    clock_context.SetDiscreteState([0.0 if t_contact is None else t_contact + 1.0])
    return diagram.GetOutputPort("true_impedance").Eval(context)[2]


@pytest.mark.parametrize("t", [0.5, 2.0, 2.4999, 2.5, 3.0, 17.5, 32.5, 40.0])
def test_true_stiffness_follows_the_ramp_from_contact(t):
    env = EnvironmentConfig(stiffness=7000.0, damping=100.0)
    fault = FaultConfig(kind="stiffness_ramp", start_from="contact", start_s=1.5,
                        duration_s=30.0, magnitude=1.2)
    diagram, clock, _ = wall_with_fault(fault, env)
    t_contact = 1.0
    share = np.clip((t - t_contact - 1.5) / 30.0, 0.0, 1.0)
    assert true_stiffness(diagram, clock, t, t_contact) == pytest.approx(
        7000.0 * (1 + 0.2 * share), rel=1e-12)
    assert true_stiffness(diagram, clock, t, None) == 7000.0  # no contact, no ramp


@pytest.mark.parametrize("t", [0.5, 2.999, 3.0, 3.001, 100.0])
def test_true_stiffness_steps_for_good_after_contact(t):
    env = EnvironmentConfig(stiffness=50000.0, damping=150.0)
    fault = FaultConfig(kind="stiffness_step", start_from="contact", start_s=2.0,
                        duration_s=np.inf, magnitude=0.5)
    diagram, clock, _ = wall_with_fault(fault, env)
    expected = 25000.0 if t >= 3.0 else 50000.0
    assert true_stiffness(diagram, clock, t, 1.0) == expected


# The closed loop across a material change: identify_step, its step 0.5 s
# after contact instead of 2 s, and 2 s of the stiffer wall.

STEP_AFTER_S = 0.5


@pytest.fixture(scope="session")
def step_run():
    scenario = drake_contact.load_scenario(
        "identify_step", [f"faults=[{{kind: stiffness_step, start_from: contact, "
                          f"start_s: {STEP_AFTER_S}, duration_s: .inf, magnitude: 2.0}}]"],
        duration=10.8)
    return scenario, drake_contact.simulate_scenario(scenario)


def test_the_controller_keeps_contact_and_the_wall_doubles(step_run):
    scenario, result = step_run
    assert result.status == "completed"
    log, m = result.log, result.metrics
    t, K = log["t"], log["true_impedance"][:, 2]
    t_clock = float(log["fault_contact_time"][-1])
    assert 7.5 < t_clock < 9.5
    # The logged truth is the current K_e: 7 kN/m, then 14 kN/m from the step.
    assert np.all(K[t < t_clock + STEP_AFTER_S - 1e-9] == 7000.0)
    assert np.all(K[t >= t_clock + STEP_AFTER_S + DT] == 14000.0)
    assert m["contact_losses"] == 0
    # The force jumps with the spring and comes back to f_d (20 N and the
    # probing sine) on the stiffer wall, at half the penetration: means over
    # the last two periods of the sine.
    assert m["peak_force_n"] > 30.0
    periods = 2.0 / scenario.force_reference.probe_frequencies_hz[0]
    last = np.arange(len(t)) >= len(t) - round(periods / DT)
    force = log["contact_force_true"][last].mean()
    assert force == pytest.approx(log["force_desired"][last].mean(), abs=1.0)
    assert force == pytest.approx(20.0, abs=1.0)
    assert force / log["penetration_true"][last].mean() == pytest.approx(14000.0, rel=0.02)
    # Every identifier is scored against the step.
    for config in scenario.identifiers:
        entry = m[f"identification_tracking_{config.name}"]
        assert entry["step_times_s"] == [pytest.approx(t_clock + STEP_AFTER_S, abs=2 * DT)]
        assert 0.0 <= entry["stiffness_within_5pct"] <= 1.0
    json.dumps({k: v for k, v in m.items() if k.startswith("identification_tracking")},
               allow_nan=False)


def test_rls_robust_resets_on_the_jump_and_follows_the_doubled_wall(step_run):
    """The change detector resets rls_robust's covariance just after the
    jump: within 5 % of the new K_e within 1 s of it and to the run's end
    (the random walk alone ends 11-14 % off, docs/studies/identification.md)."""
    scenario, result = step_run
    entry = result.metrics["identification_tracking_rls_robust"]
    assert entry["stiffness_settling_after_step_s"] is not None
    assert entry["stiffness_settling_after_step_s"] < 1.0
    log = result.log
    assert abs(log["impedance_rls_robust"][-1, 2] / log["true_impedance"][-1, 2] - 1) < 0.05
