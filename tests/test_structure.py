"""The ensemble's structure key (drake_contact.structure): one hashable key
says what an ensemble's environments share; MakeEnsembleDiagram refuses
environments that differ in it with one line naming the environment and the
field, before it builds anything; campaigns pack by it, so that a pack never
mixes structures and every run keeps its whole log and metrics.

The three defects of issue 50 (reproduced at 70957cd): safety off beside
safety on built a station without any safety signal; no fault beside one
fault built one without the fault's signals; different fault counts raised
Drake's RuntimeError instead of a ScenarioError."""

import json

import numpy as np
import pytest

import drake_contact as dc
from drake_contact import diagram
from drake_contact.diagram import MakeEnsembleDiagram
from drake_contact.errors import ScenarioError
from drake_contact.structure import (
    check_ensemble_structure, ensemble_structure, first_difference)

ONE_FAULT = "faults=[{kind: force_bias, start_s: 0.3, magnitude: 2.0}]"
TWO_FAULTS = ("faults=[{kind: force_bias, start_s: 0.3, magnitude: 2.0}, "
              "{kind: force_bias, start_s: 0.5, magnitude: -1.0}]")


def _refused_before_building(monkeypatch, scenarios, *fragments):
    """MakeEnsembleDiagram(scenarios) raises a one-line ScenarioError holding
    ``fragments`` without adding the plant (nothing is built)."""
    def no_plant(*args, **kwargs):
        raise AssertionError("the station was being built")
    monkeypatch.setattr(diagram, "AddArmPlant", no_plant)
    with pytest.raises(ScenarioError) as raised:
        MakeEnsembleDiagram(scenarios)
    message = str(raised.value)
    assert "\n" not in message
    for fragment in fragments:
        assert fragment in message, message
    return message


@pytest.mark.parametrize("order", [(False, True), (True, False)])
def test_safety_on_beside_safety_off_is_refused_in_either_order(monkeypatch, order):
    scenarios = [dc.load_scenario("nn_robust", [f"safety.enabled={str(on).lower()}"])
                 for on in order]
    _refused_before_building(monkeypatch, scenarios, "safety.enabled", "environment 1",
                             "share a structure")


@pytest.mark.parametrize("faults", [([], [ONE_FAULT]), ([ONE_FAULT], []),
                                    ([ONE_FAULT], [TWO_FAULTS])])
def test_environments_with_other_fault_counts_are_refused_with_a_scenario_error(
        monkeypatch, faults):
    scenarios = [dc.load_scenario("push_constant", overrides) for overrides in faults]
    message = _refused_before_building(monkeypatch, scenarios, "faults", "environment 1")
    signals = [tuple(f.signal for f in s.faults) for s in scenarios]
    assert f"faults = {signals[1]!r} in environment 1" in message
    assert f"({signals[0]!r} in environment 0)" in message


def test_the_first_differing_field_is_named_with_its_environment(monkeypatch):
    scenarios = [dc.load_scenario("nn_styrofoam"), dc.load_scenario("nn_styrofoam"),
                 dc.load_scenario("nn_styrofoam", ["controller.nn.reference_time_constant_s=0.1",
                                                   "safety.enabled=true"])]
    _refused_before_building(monkeypatch, scenarios, "controller.nn.reference_time_constant_s "
                             "= True in environment 2", "(False in environment 0)")
    # The compensator's robust modifications switch one path together.
    scenarios[2] = dc.load_scenario("nn_styrofoam", ["controller.nn.weight_bound=5.0"])
    _refused_before_building(monkeypatch, scenarios, "controller.nn.robust = True in "
                             "environment 2")


def test_the_key_is_hashable_and_ignores_numbers():
    base = dc.load_scenario("nn_styrofoam", [ONE_FAULT])
    numbers = dc.load_scenario("nn_styrofoam", [
        "faults=[{kind: force_bias, start_s: 0.9, magnitude: -4.0}]",
        "environment.stiffness=12000", "controller.hybrid.force_gain=0.3",
        "controller.nn.learning_rate=2e-5", "force_sensor.noise_scale=2.0",
        "safety.force_limit_n=50"], seed=9, duration=2.0)
    assert ensemble_structure(base) == ensemble_structure(numbers)
    assert len({ensemble_structure(base), ensemble_structure(numbers)}) == 1
    assert check_ensemble_structure([base, numbers]) == ensemble_structure(base)
    for change, field in [("safety.enabled=true", "safety.enabled"),
                          ("faults=[]", "faults"),
                          ("arm.time_step=0.0005", "arm.time_step"),
                          ("controller.hybrid.pose_integral_gain=100",
                           "controller.hybrid.pose_integral_gain"),
                          ("dsp.anti_aliasing.mode=probe", "dsp.anti_aliasing.mode"),
                          ("joint_friction.model=regularized", "joint_friction.model")]:
        other = dc.load_scenario("nn_styrofoam", [ONE_FAULT, change])
        found = first_difference(ensemble_structure(other), ensemble_structure(base))
        assert found is not None and found[0] == field, (change, found)


def test_identifiers_enter_the_key_with_what_they_switch_on():
    base = dc.load_scenario("identify_styrofoam")
    offset = dc.load_scenario("identify_styrofoam")
    offset.identifiers[0].rls.force_offset = True
    assert first_difference(ensemble_structure(offset), ensemble_structure(base))[0] == \
        "identifiers[0].rls.force_offset"
    fewer = dc.load_scenario("identify_styrofoam", ["identifiers=[]"])
    assert first_difference(ensemble_structure(fewer), ensemble_structure(base))[0] == \
        "identifiers"


def test_environments_with_the_same_faults_and_safety_give_every_signal():
    scenarios = [dc.load_scenario("push_constant", [ONE_FAULT, "safety.enabled=true"],
                                  seed=seed) for seed in (1, 2)]
    station = MakeEnsembleDiagram(scenarios)
    for name in ("fault_active", "fault_contact_time", "safety_state", "joint_torque_supervised"):
        assert station.GetOutputPort(name).size() == 2 * station.signals[name].size, name


# --- campaigns -------------------------------------------------------------

#: Points that differ in the safety supervisor and in their number of
#: faults: packs of two where they share a structure, one alone.
MIXED = {"plain_a": [], "plain_b": ["environment.stiffness=5000"],
         "safe_a": ["safety.enabled=true"],
         "safe_b": ["safety.enabled=true", "environment.stiffness=5000"],
         "fault_a": [ONE_FAULT], "fault_b": [ONE_FAULT.replace("2.0", "-3.0")],
         "faults_two": [TWO_FAULTS]}


#: Metrics that time the run, not its physics.
TIMING = ("realtime_factor", "us_per_step", "wall_time_s")


def _mixed_campaign():
    from drake_contact.app.campaign import Campaign, Point, finished_metrics

    class Mixed(Campaign):
        name = "mixed"
        columns = {"runs": ["name", "status"]}

        def points(self):
            return [Point(name, "push_constant",
                          ("controller.push.start_time=0", "simulation.duration=0.8", *extra),
                          seed=i)
                    for i, (name, extra) in enumerate(MIXED.items())]

        def score(self, point, run_dir):
            metrics = {k: v for k, v in (finished_metrics(run_dir) or {}).items()
                       if k not in TIMING}
            return {"runs": [{"name": point.name, "status": metrics.get("status", "failed"),
                              "metrics": json.dumps(metrics, sort_keys=True)}]}
    return Mixed()


def test_a_campaign_packs_by_structure_and_every_run_keeps_its_log_and_metrics(
        tmp_path, monkeypatch):
    from drake_contact.app import campaign
    from drake_contact.app.campaign import ensemble_packs, run_campaign
    monkeypatch.setattr(campaign, "MIN_ENSEMBLE", 2)
    plan = _mixed_campaign()
    packs = ensemble_packs([(p, tmp_path / p.name) for p in plan.points()], 16)
    assert [[p.name for p, _ in pack] for pack in packs] == [
        ["plain_a", "plain_b"], ["safe_a", "safe_b"], ["fault_a", "fault_b"], ["faults_two"]]
    packed = run_campaign(plan, tmp_path / "packed", workers=1, ensemble=16)
    alone = run_campaign(plan, tmp_path / "alone", workers=1, ensemble=1)
    assert packed.failed == {} and alone.failed == {}
    assert packed.tables["runs"] == alone.tables["runs"]
    assert [r["status"] for r in packed.tables["runs"]] == ["completed"] * len(MIXED)
    assert "ensemble of 2" in (tmp_path / "packed/runs/safe_a/run.log").read_text()
    for name in MIXED:
        with np.load(tmp_path / "packed/runs" / name / "log.npz") as a, \
                np.load(tmp_path / "alone/runs" / name / "log.npz") as b:
            assert a.files == b.files, name
            assert ("safety_state" in a.files) == name.startswith("safe"), name
            assert ("fault_active" in a.files) == name.startswith("fault"), name
            for key in a.files:
                np.testing.assert_array_equal(a[key], b[key], err_msg=f"{name} {key}")
        metrics = json.loads((tmp_path / "packed/runs" / name / "metrics.json").read_text())
        assert ("safety_events" in metrics) == name.startswith("safe"), name
