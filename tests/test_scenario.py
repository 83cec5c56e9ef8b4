"""Scenario loading, overrides and the errors a user sees."""

import pytest

from drake_contact.errors import ScenarioError
from drake_contact.resources import bundled_scenario_names, scenarios_dir
from drake_contact.scenario import Scenario, dump_scenario, load_scenario


def test_every_bundled_scenario_loads_and_validates():
    names = bundled_scenario_names()
    assert "push_constant" in names
    for name in names:
        assert isinstance(load_scenario(name), Scenario)


def test_overrides_duration_and_seed_apply_and_round_trip(tmp_path):
    scenario = load_scenario("push_constant", ["environment.stiffness=6.2e4",
                                               "joint_friction.levels=[1, 0.5, 0.1]"],
                             duration=1.5, seed=7)
    assert scenario.environment.stiffness == 62000.0
    assert scenario.joint_friction.levels == [1.0, 0.5, 0.1]
    assert scenario.simulation.duration == 1.5 and scenario.simulation.seed == 7
    path = tmp_path / "resolved.yaml"
    path.write_text(dump_scenario(scenario))
    assert load_scenario(str(path)) == scenario


def test_a_path_or_a_name_both_work():
    path = scenarios_dir() / "push_constant.yaml"
    assert load_scenario(str(path)) == load_scenario("push_constant")


@pytest.mark.parametrize("override,message", [
    ("environment.stiffness=0", "environment.stiffness = 0.0 is out of range: must be > 0 N/m"),
    ("environment.stiffness=-7e3", "environment.stiffness = -7000.0 is out of range"),
    ("environment.damping=-1", "environment.damping = -1.0 is out of range: must be >= 0 N s/m"),
    ("environment.mass=-0.5", "environment.mass = -0.5 is out of range: must be >= 0 kg"),
    ("arm.time_step=0.0003", "arm.time_step = 0.0003 is out of range: must be 0.001 / 2**k s"),
    ("arm.time_step=0.002", "arm.time_step = 0.002 is out of range: must be in (0, 0.001] s"),
    ("environment.stifness=3", "environment.stifness is not a scenario key"),
    ("bogus=1", "bogus is not a scenario key"),
    ("controller.name=pid", "controller.name = 'pid' is unknown: choose one of"),
    ("environment.stiffness=soft", "environment.stiffness = 'soft' must be a number"),
    ("simulation.seed=1.5", "simulation.seed = 1.5 must be a whole number"),
    ("environment=3", "environment must be a mapping of keys"),
    ("force_reference.hold_s=-2", "force_reference.hold_s = -2.0 is out of range: must be >= 0 s"),
    ("scoring.level_settle_s=0", "scoring.level_settle_s = 0.0 is out of range: must be > 0 s"),
])
def test_bad_overrides_name_the_field(override, message):
    with pytest.raises(ScenarioError) as info:
        load_scenario("push_constant", [override])
    assert message in str(info.value)
    assert "\n" not in str(info.value)


@pytest.mark.parametrize("override,message", [
    ("controller.hybrid.stiffness_bounds=[3e5, 1e3]",
     "controller.hybrid.stiffness_bounds = [300000.0, 1000.0] is out of range"),
    ("controller.hybrid.pose_integral_gain=-1",
     "controller.hybrid.pose_integral_gain = -1.0 is out of range: must be >= 0"),
    ("controller.hybrid.decoupled_force_integral_gain=-0.1",
     "controller.hybrid.decoupled_force_integral_gain = -0.1 is out of range: must be >= 0"),
    ("controller.hybrid.stiffness_halving_time_s=-0.01",
     "controller.hybrid.stiffness_halving_time_s = -0.01 is out of range: must be >= 0"),
    ("controller.hybrid.force_coupling_cancellation=1.5",
     "controller.hybrid.force_coupling_cancellation = 1.5 is out of range: must be in [0, 1]"),
    ("controller.hybrid.pose_joint_stiffness=[0, 0, -8]",
     "controller.hybrid.pose_joint_stiffness = [0.0, 0.0, -8.0] is out of range: must be 3 "
     "values >= 0 N m/rad"),
    ("controller.hybrid.force_error_friction_compensation=2",
     "controller.hybrid.force_error_friction_compensation = 2.0 is out of range: must be in "
     "[0, 1]"),
    ("controller.hybrid.force_integral_hold_s=-0.2",
     "controller.hybrid.force_integral_hold_s = -0.2 is out of range: must be >= 0"),
])
def test_bad_adaptive_hybrid_fields_name_the_field(override, message):
    with pytest.raises(ScenarioError) as info:
        load_scenario("adaptive_hybrid", [override])
    assert message in str(info.value)


def test_malformed_and_unknown_files(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("environment: {stiffness: [1,\n")
    with pytest.raises(ScenarioError, match=r"bad.yaml: malformed YAML at line \d+"):
        load_scenario(str(bad))
    listed = tmp_path / "list.yaml"
    listed.write_text("- 1\n- 2\n")
    with pytest.raises(ScenarioError, match="must be a YAML mapping"):
        load_scenario(str(listed))
    with pytest.raises(ScenarioError, match="'no_such' is neither a file nor a bundled "
                       "scenario: choose a path or one of .*push_constant"):
        load_scenario("no_such")
