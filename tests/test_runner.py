"""The runner's log buffers: samples move out of Drake's logs as the run
goes, into arrays allocated once, and come out identical."""

import numpy as np
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder

import drake_contact as dc


def build(duration=0.3):
    scenario = dc.load_scenario("push_constant", ["simulation.settle_window=0.1"],
                                duration=duration, seed=2)
    builder = DiagramBuilder()
    station = builder.AddSystem(dc.MakeContactDiagram(scenario))
    loggers = dc.AddSignalLoggers(builder, station)
    return builder.Build(), loggers


def test_simulate_leaves_drakes_logs_empty_and_holds_each_sample_once():
    diagram, loggers = build()
    result = dc.simulate(diagram, loggers)
    context = result.simulator.get_context()
    assert loggers.sink.FindLog(context).num_samples() == 0
    assert len(result.log["t"]) == 301
    # The log's arrays are views of the preallocated buffers, not copies.
    assert np.may_share_memory(result.log["tip_pose_true"], result.log["tip_velocity_true"])


def test_draining_in_chunks_and_growing_past_the_reserve_gives_the_same_log():
    diagram, loggers = build()
    simulator = Simulator(diagram)
    dc.SeedNoise(diagram, simulator.get_mutable_context())
    loggers.reserve(50)  # far too small: drain must grow the arrays
    for t in (0.05, 0.1, 0.2, 0.3):
        simulator.AdvanceTo(t)
        loggers.drain(simulator.get_context())
    chunked = loggers.collect(simulator.get_context())

    diagram, loggers = build()
    whole = dc.simulate(diagram, loggers).log
    assert chunked.keys() == whole.keys()
    for key in whole:
        np.testing.assert_array_equal(chunked[key], whole[key], err_msg=key)



def test_a_window_baseline_stops_after_the_scoring_window_and_scores_it(tmp_path):
    from drake_contact.app.runner import run
    scenario = dc.load_scenario("nn_styrofoam", ["scoring.window_start_s=0.5",
                                                 "scoring.window_end_s=1.5"], duration=12.0)
    full = run(scenario, tmp_path / "full", figures=False, baseline=True).metrics
    short = run(scenario, tmp_path / "short", figures=False, baseline="window").metrics
    t_base = np.load(tmp_path / "short" / "baseline" / "log.npz")["t"]
    assert abs(t_base[-1] - (short["contact_time_s"] + 1.5 + 1.0)) < 2e-3
    assert short["baseline_force_rmse_n"] == full["baseline_force_rmse_n"]


def test_a_spooled_log_holds_a_bounded_buffer_and_gives_the_same_log_and_metrics(
        tmp_path, monkeypatch):
    from drake_contact import simulation
    from drake_contact.app import runner
    monkeypatch.setattr(simulation, "SPOOL_BUFFER_SAMPLES", 37)  # many flushes, a partial last one
    diagram, loggers = build()
    whole = dc.simulate(diagram, loggers)

    diagram, loggers = build()
    loggers.spool = tmp_path / "spool"
    spooled = dc.simulate(diagram, loggers)
    # Never more in memory than the buffer or one drain (a 0.1 s chunk here).
    assert len(loggers._times) == 101
    assert isinstance(spooled.log, simulation.SpooledLog)
    assert sorted(spooled.log) == sorted(whole.log)
    for key in whole.log:
        assert spooled.log[key].shape == whole.log[key].shape, key
        np.testing.assert_array_equal(spooled.log[key], whole.log[key], err_msg=key)
    for key in whole.metrics:
        if key not in ("wall_time_s", "realtime_factor", "us_per_step"):
            assert repr(spooled.metrics[key]) == repr(whole.metrics[key]), key

    # run() spools into the run folder, writes log.npz key by key, then
    # reads from there and removes the spool.
    scenario = loggers.station.scenario
    result = runner.run(scenario, tmp_path / "run", figures=False)
    assert not (tmp_path / "run" / ".log_spool").exists()
    assert isinstance(result.log, simulation.NpzLog)
    with np.load(tmp_path / "run" / "log.npz") as npz:
        assert sorted(npz.keys()) == sorted(whole.log)
        for key in whole.log:
            np.testing.assert_array_equal(npz[key], whole.log[key], err_msg=key)
    assert result.log["t"][-1] == whole.log["t"][-1]


def test_a_spooled_log_is_cut_at_the_divergence_like_an_in_memory_one(tmp_path):
    from drake_contact import simulation
    # The wall at the tip from the start, far too stiff: the force runs away
    # within 0.2 s (as in test_diagram's runaway test).
    scenario = dc.load_scenario("push_constant", ["environment.stiffness=1e9",
                                                  "controller.push.start_time=0"], seed=2)
    in_memory = simulation.simulate_scenario(scenario)
    spooled = simulation.simulate_scenario(scenario, spool=tmp_path / "spool")
    assert in_memory.status == spooled.status == "diverged"
    assert spooled.message == in_memory.message
    assert isinstance(spooled.log, simulation.SpooledLog)
    for key in in_memory.log:
        np.testing.assert_array_equal(spooled.log[key], in_memory.log[key], err_msg=key)


def test_drakes_own_errors_are_divergence_and_a_callbacks_are_failures():
    """simulation.drake_raised: a NaN torque reaching the plant raises in
    Drake's C++ (a divergence); a RuntimeError raised by a Python system's
    update is a failure, even though its type is the same."""
    from pathlib import Path

    import pytest
    from pydrake.multibody.parsing import Parser
    from pydrake.multibody.plant import AddMultibodyPlantSceneGraph
    from pydrake.systems.framework import LeafSystem
    from pydrake.systems.primitives import ConstantVectorSource
    from drake_contact.simulation import advance_in_chunks, drake_raised

    class Loggers:
        def drain(self, context):
            pass

    class Raises(LeafSystem):
        def __init__(self):
            super().__init__()
            self.DeclareDiscreteState(1)
            self.DeclarePeriodicDiscreteUpdateEvent(1e-3, 0.0, self.update)

        def update(self, context, state):
            raise RuntimeError("a bug in a callback")

    builder = DiagramBuilder()
    plant, _ = AddMultibodyPlantSceneGraph(builder, 1e-3)
    Parser(plant).AddModels(str(Path(__file__).resolve().parents[1] / "models" / "arm3dof.urdf"))
    plant.Finalize()
    nan = builder.AddSystem(ConstantVectorSource(np.full(3, np.nan)))
    builder.Connect(nan.get_output_port(), plant.get_actuation_input_port())
    for diagram, expected in ((builder.Build(), True), (_one(Raises()), False)):
        simulator = Simulator(diagram)
        with pytest.raises(RuntimeError) as raised:
            list(advance_in_chunks(simulator, simulator.get_context(), Loggers(), 0.01))
        assert drake_raised(raised.value) is expected, raised.value


def _one(system):
    builder = DiagramBuilder()
    builder.AddSystem(system)
    return builder.Build()
