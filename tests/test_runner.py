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
