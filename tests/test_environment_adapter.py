"""The one adapter for roles that are not batched
(drake_contact.blocks.AddEnvironments, EnvironmentCopies) and the station's
explicit map from each noise source to its environment
(ContactStation.noise_sources): at N = 1 the adapter is the system alone;
at N > 1 its ports are environment-major, and every environment behind it
(its fault chain's random spikes, its safety supervisor, its DSP with the
anti-aliasing filter in) gives its single run's log bit for bit."""

import numpy as np
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import Gain, RandomSource

import drake_contact as dc
from drake_contact.blocks import AddEnvironments, EnvironmentCopies, system_ports
from drake_contact.diagram import MakeEnsembleDiagram
from drake_contact.simulation import simulate_ensemble


def _gains(builder, count):
    return AddEnvironments(builder, "gain", count, lambda b, i: system_ports(
        b.AddNamedSystem("gain", Gain(k=float(i + 2), size=2))))


def test_one_environment_is_the_system_alone():
    builder = DiagramBuilder()
    ports = _gains(builder, 1)
    assert [s.get_name() for s in builder.GetSystems()] == ["gain"]
    assert ports["u0"].size() == 2 and ports["y0"].size() == 2


def test_n_environments_are_one_system_with_environment_major_ports():
    builder = DiagramBuilder()
    ports = _gains(builder, 3)
    (copies,) = builder.GetSystems()
    assert isinstance(copies, EnvironmentCopies)
    assert [b.get_name() for b in copies.environments] == ["gain_0", "gain_1", "gain_2"]
    builder.ExportInput(ports["u0"], "u")
    builder.ExportOutput(ports["y0"], "y")
    diagram = builder.Build()
    context = diagram.CreateDefaultContext()
    diagram.get_input_port().FixValue(context, np.arange(6.0))
    np.testing.assert_array_equal(diagram.get_output_port().Eval(context),
                                  [0.0, 2.0, 6.0, 9.0, 16.0, 20.0])


#: Roles behind the adapter in one run: a fault chain with random spikes,
#: the safety supervisor, and the DSP with its anti-aliasing filter in.
ADAPTED = ["controller.push.start_time=0", "safety.enabled=true",
           "dsp.anti_aliasing.mode=in_loop"]


def _adapted(seed, magnitude):
    return dc.load_scenario("push_constant", ADAPTED + [
        f"faults=[{{kind: force_spikes, start_s: 0.2, magnitude: {magnitude}}}]"],
        duration=0.6, seed=seed)


def test_each_noise_source_belongs_to_its_environment_by_an_explicit_map():
    station = MakeEnsembleDiagram([_adapted(3, 10.0), _adapted(4, 20.0)])
    sources = {(env, key) for env, key, _ in station.noise_sources}
    assert sources == {(env, key) for env in (0, 1)
                       for key in ("force_sensor_gauge_noise", "fault_0_force_spikes_draws")}
    assert all(isinstance(s, RandomSource) for _, _, s in station.noise_sources)
    alone = dc.MakeContactDiagram(_adapted(3, 10.0))
    assert {(env, key) for env, key, _ in alone.noise_sources} == {
        (0, "force_sensor_gauge_noise"), (0, "fault_0_force_spikes_draws")}


def test_environments_behind_the_adapter_give_their_single_runs_bit_for_bit():
    scenarios = [_adapted(3, 10.0), _adapted(4, 20.0)]
    results = simulate_ensemble(scenarios)
    for scenario, result in zip(scenarios, results):
        alone = dc.simulate_scenario(scenario)
        assert result.status == alone.status
        assert set(result.log) == set(alone.log)
        assert {"fault_active", "safety_state"} <= set(result.log)
        for key in alone.log:
            np.testing.assert_array_equal(np.asarray(result.log[key]),
                                          np.asarray(alone.log[key]), err_msg=key)
    # The spikes are each environment's own: its seed's draws.
    assert not np.array_equal(np.asarray(results[0].log["force_measured"]),
                              np.asarray(results[1].log["force_measured"]))
