"""The whole diagram: push_constant physics, repeatability, divergence."""

import json
import re

import numpy as np
import pytest

from drake_contact.diagram import ContactStation, MakeContactDiagram
from drake_contact.errors import ScenarioError
from drake_contact.app.runner import run
from drake_contact.scenario import load_scenario


#: push_constant pushing from t = 0 (inside the tare window): for tests of
#: the plant and the wall that read only the ground truth.
PUSH_AT_ONCE = "controller.push.start_time=0"


def test_diagram_exports_its_named_outputs():
    diagram = MakeContactDiagram(load_scenario("push_constant"))
    assert isinstance(diagram, ContactStation) and diagram.get_name() == "station"
    assert diagram.num_output_ports() == len(diagram.signals)
    for name, signal in diagram.signals.items():
        assert diagram.GetOutputPort(name).size() == signal.size
        assert signal.meaning
    names = {diagram.GetSubsystemByName(n).get_name() for n in (
        "plant", "wall", "tip_kinematics", "controller", "torque_saturation",
        "joint_friction", "encoders")}
    assert len(names) == 7


@pytest.mark.parametrize("stiffness", [7e3, 6.2e4])
def test_push_constant_settles_at_force_over_penetration_equal_to_stiffness(tmp_path, stiffness):
    scenario = load_scenario("push_constant", [f"environment.stiffness={stiffness}"])
    result = run(scenario, tmp_path, figures=False)
    m = result.metrics
    assert result.status == "completed"
    assert abs(m["steady_stiffness_ratio_n_per_m"] / stiffness - 1) < 0.02
    # A real push, not a graze: the joints' stiction (LuGre) holds the arm
    # short of the 20 N the harness commands, by up to about 6 N.
    assert 12.0 < m["steady_force_n"] < 21.0
    # The tip is at rest in the settle window.
    settle = result.log["t"] > scenario.simulation.duration - scenario.simulation.settle_window
    assert np.max(np.abs(result.log["tip_velocity_true"][settle, 0])) < 1e-3
    # The push starts after the tare: the measured force is the true one.
    true_force = np.mean(result.log["contact_force_true"][settle])
    assert abs(np.mean(result.log["force_filtered"][settle]) / true_force - 1) < 0.02
    assert "warnings" not in m
    # Outputs on disk.
    for name in ("scenario.yaml", "log.npz", "metrics.json"):
        assert (tmp_path / name).is_file()
    on_disk = json.loads((tmp_path / "metrics.json").read_text())
    assert on_disk["true_impedance"]["stiffness"] == stiffness
    for key in ("wall_time_s", "realtime_factor", "peak_force_n"):
        assert on_disk[key] > 0
    log = np.load(tmp_path / "log.npz")
    n = len(log["t"])
    assert n == 1 + round(scenario.simulation.duration / 1e-3)
    assert log["tip_pose_true"].shape == (n, 3)
    assert log["joint_torque_commanded"].shape == (n, 3)
    required = {"t", "tip_pose_true", "contact_force_true", "penetration_true",
                "joint_torque_commanded", "force_measured", "force_filtered",
                "tip_pose_measured", "tip_velocity_measured", "tip_acceleration_measured"}
    logged = {key for s in MakeContactDiagram(scenario).signals.values() for key in s.log_as}
    assert required <= set(log.files) <= logged | {"t"}


@pytest.mark.parametrize("overrides", [
    ["environment.stiffness=1e6", "environment.mass=1.0"],
    ["environment.stiffness=1e3", "environment.mass=0", "environment.damping=0"],
    ["environment.stiffness=1e6", "environment.mass=0", "environment.damping=0"],
    ["arm.time_step=1.25e-4", "environment.stiffness=6.2e4"],
])
def test_arm_on_wall_is_stable_at_the_extremes(tmp_path, overrides):
    scenario = load_scenario("push_constant", overrides + [PUSH_AT_ONCE], duration=2.0)
    result = run(scenario, tmp_path, figures=False)
    assert result.status == "completed"
    K = scenario.environment.stiffness
    settle = result.log["t"] > 1.5
    ratio = result.log["contact_force_true"][settle] / result.log["penetration_true"][settle]
    assert np.all(np.abs(ratio / K - 1) < 0.02)


def test_same_scenario_and_seed_give_bit_identical_logs(tmp_path):
    scenario = load_scenario("push_constant", duration=1.0, seed=3)
    run(scenario, tmp_path / "a", figures=False)
    run(scenario, tmp_path / "b", figures=False)
    a, b = np.load(tmp_path / "a" / "log.npz"), np.load(tmp_path / "b" / "log.npz")
    for key in a.files:
        assert a[key].tobytes() == b[key].tobytes(), key


def test_runaway_force_stops_with_time_and_keeps_the_logs(tmp_path):
    scenario = load_scenario("push_constant", ["environment.stiffness=1e9", PUSH_AT_ONCE])
    result = run(scenario, tmp_path, figures=False)
    assert result.status == "diverged"
    when = float(re.search(r"diverged at t = ([\d.]+) s", result.message).group(1))
    assert "exceeds simulation.force_limit = 500.0 N" in result.message
    log = np.load(tmp_path / "log.npz")
    assert 0.01 < when < 0.2 and log["t"][-1] == pytest.approx(when, abs=1e-9)
    assert log["contact_force_true"][-1] > 500.0
    assert np.all(log["contact_force_true"][:-1] <= 500.0)
    metrics = json.loads((tmp_path / "metrics.json").read_text())
    assert metrics["status"] == "diverged" and f"t = {when:.3f}" in metrics["message"]


def test_non_finite_force_stops_with_time(tmp_path):
    scenario = load_scenario("push_constant", [PUSH_AT_ONCE, "environment.stiffness=1e308",
                                               "simulation.force_limit=.inf"])
    result = run(scenario, tmp_path, figures=False)
    assert result.status == "diverged"
    # Our check ("... is not finite (where)") or Drake's, which names the port.
    assert re.search(r"diverged at t = 0\.\d+ s", result.message)
    assert "is not finite" in result.message or "NaN in applied generalized force" in result.message
    assert len(np.load(tmp_path / "log.npz")["t"]) > 20  # the logs up to the divergence


def test_unstable_friction_setting_is_refused_before_simulating():
    scenario = load_scenario("push_constant", ["joint_friction.model=regularized",
                                               "joint_friction.levels=[4.41, 0.98, 0.05]",
                                               "joint_friction.regularization_velocity=0.002"])
    with pytest.raises(ScenarioError, match="joint 1 needs"):
        MakeContactDiagram(scenario)


def test_contact_inside_the_tare_window_is_warned_about_with_the_numbers(tmp_path):
    scenario = load_scenario("push_constant", [PUSH_AT_ONCE], duration=1.0)
    result = run(scenario, tmp_path, figures=False)
    (warning,) = result.metrics["warnings"]
    assert re.search(r"contact began at t = 0\.04\d s, inside the DSP's tare window "
                     r"\(dsp.tare_window_s = 2 s\): the tare averaged a true force of 1\d\.\d\d N",
                     warning), warning
    # What it warns about: the measured force misses the true one.
    late = result.log["t"] > 0.5
    assert np.mean(result.log["contact_force_true"][late]) > 15.0
    assert abs(np.mean(result.log["force_filtered"][late])) < 3.0
