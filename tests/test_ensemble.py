"""Ensembles (drake_contact.diagram.MakeEnsembleDiagram): N environments in
one diagram give each environment's single-run log bit for bit, and one
diverging environment does not stop the others."""

import numpy as np
import pytest

import drake_contact as dc
from drake_contact.diagram import MakeEnsembleDiagram
from drake_contact.errors import ScenarioError
from drake_contact.simulation import simulate_ensemble

#: A quick approach: the tip reaches the wall within about 1 s.
QUICK_APPROACH = ["controller.hybrid.approach.hold_time_s=0.1",
                  "controller.hybrid.approach.step_period_s=0.15"]

#: Each family of bundled scenarios, with environments that differ in wall,
#: seed and gains (and the duration that takes them into contact: about
#: 0.75 s with the quick approach).
FAMILIES = {
    "hybrid": ("hybrid_p_only_styrofoam", 0.9, QUICK_APPROACH, [
        [], ["environment.stiffness=12000", "controller.hybrid.force_gain=0.2"],
        ["environment.damping=250", "force_reference.levels=[15.0, 8.0]"]]),
    "nn": ("nn_styrofoam", 0.9, QUICK_APPROACH, [
        [], ["environment.stiffness=4000", "controller.nn.learning_rate=2e-5"],
        ["environment.damping=40", "controller.hybrid.force_gain=0.3"]]),
    "identify": ("identify_styrofoam", 0.9, QUICK_APPROACH, [
        [], ["environment.stiffness=20000"], ["environment.damping=300"]]),
    "adaptive": ("adaptive_hybrid", 0.9, QUICK_APPROACH, [
        [], ["environment.stiffness=9000"], ["environment.stiffness=30000"]]),
    "push": ("push_constant", 0.8, ["controller.push.start_time=0"], [
        [], ["environment.stiffness=5000"], ["environment.damping=20"]]),
    "sensor": ("sensor_spectrum", 0.6, ["simulation.settle_window=0.5"], [
        [], ["force_sensor.noise_scale=2.0"], ["environment.stiffness=3000"]]),
    # Faults chain per environment between the roles: the station's other
    # wiring, one system per role and environment.
    "faults": ("push_constant", 0.8, ["controller.push.start_time=0"], [
        ["faults=[{kind: force_bias, start_s: 0.3, magnitude: 2.0}]"],
        ["faults=[{kind: force_bias, start_s: 0.5, magnitude: -3.0}]",
         "environment.stiffness=5000"]]),
}


def _scenarios(family, seeds=(3, 4, 5), count=2):
    """The family's first ``count`` environments."""
    name, duration, common, variants = FAMILIES[family]
    return [dc.load_scenario(name, common + variant, duration=duration, seed=seed)
            for variant, seed in list(zip(variants, seeds))[:count]]


def _assert_same_logs(ensemble, alone):
    assert ensemble.status == alone.status, (ensemble.message, alone.message)
    assert ensemble.message == alone.message
    assert set(ensemble.log) == set(alone.log)
    for key in alone.log:
        np.testing.assert_array_equal(np.asarray(ensemble.log[key]), np.asarray(alone.log[key]),
                                      err_msg=key)


@pytest.mark.parametrize("family", sorted(FAMILIES))
def test_each_environment_of_an_ensemble_gives_its_single_run_bit_for_bit(family):
    scenarios = _scenarios(family)
    results = simulate_ensemble(scenarios)
    assert len(results) == len(scenarios)
    for scenario, result in zip(scenarios, results):
        _assert_same_logs(result, dc.simulate_scenario(scenario))


def _contenders():
    from drake_contact.app.benchmark import contender_names
    return contender_names(None)


@pytest.mark.parametrize("contender", _contenders())
def test_every_benchmark_contender_runs_in_an_ensemble_as_alone(contender):
    """Each contender the benchmark packs (the baselines and the plug-ins
    serve N environments as per-environment copies behind the adapter):
    without a safety supervisor its force_fault input reads zeros, and each
    environment's log is its run alone, bit for bit."""
    from drake_contact.app.benchmark import contender_scenario
    scenarios = [dc.load_scenario(contender_scenario(contender),
                                  [f"environment.stiffness={k}", "simulation.settle_window=0.3"],
                                  duration=0.4, seed=seed)
                 for seed, k in ((3, 7000.0), (4, 20000.0))]
    for scenario, result in zip(scenarios, simulate_ensemble(scenarios)):
        _assert_same_logs(result, dc.simulate_scenario(scenario))


def test_a_diverging_environment_stops_alone_and_the_other_15_run_on():
    # Environment 5's wall is far too stiff: its force runs away within
    # 0.05 s, and its arm's torques then turn non-finite. The other 15
    # complete with their single runs' logs.
    common = ["controller.push.start_time=0"]
    walls = [3000.0 + 1000.0 * i for i in range(16)]
    walls[5] = 1e9
    scenarios = [dc.load_scenario("push_constant", common + [f"environment.stiffness={k}"],
                                  duration=0.6, seed=7 + i) for i, k in enumerate(walls)]
    results = simulate_ensemble(scenarios)
    assert [r.status for r in results] == ["completed"] * 5 + ["diverged"] + ["completed"] * 10
    assert "exceeds simulation.force_limit" in results[5].message
    assert " at t = " in results[5].message
    for scenario, result in zip(scenarios, results):
        _assert_same_logs(result, dc.simulate_scenario(scenario))


@pytest.mark.parametrize("family", ["nn", "identify"])
def test_every_role_but_the_noise_serves_all_environments_in_one_system(family):
    # One system per role: the per-environment ones are the noise sources,
    # each seeded as alone. The diagram's size does not grow with N.
    from drake_contact.diagram import leaf_systems
    sizes = []
    for count in (2, 3):
        station = MakeEnsembleDiagram(_scenarios(family, count=count))
        systems = list(leaf_systems(station))
        per_env = {s.get_name().split("@")[0] for s in systems if "@" in s.GetSystemPathname()}
        assert per_env == {"force_sensor_gauge_noise"}, per_env
        sizes.append(len(systems) - count)
    assert sizes[0] == sizes[1]


def test_an_ensemble_station_carries_an_arm_axis():
    scenarios = _scenarios("nn", count=3)
    station = MakeEnsembleDiagram(scenarios)
    assert station.num_envs == 3 and station.scenarios == scenarios
    for name, signal in station.signals.items():
        if signal.size:
            assert station.GetOutputPort(name).size() == 3 * signal.size, name


def test_environments_must_share_a_structure():
    scenarios = [dc.load_scenario("nn_styrofoam"),
                 dc.load_scenario("nn_styrofoam", ["arm.time_step=0.0005"])]
    with pytest.raises(ScenarioError, match="arm.time_step"):
        MakeEnsembleDiagram(scenarios)
    with pytest.raises(ScenarioError, match="controller.name"):
        MakeEnsembleDiagram([dc.load_scenario("nn_styrofoam"),
                             dc.load_scenario("hybrid_p_only_styrofoam")])
