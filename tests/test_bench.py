"""drake-contact bench: the three timed diagrams, the per-system profile and
its attribution rule, the command line."""

import cProfile
import pstats
import subprocess
import sys
import time

import pytest
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import BasicVector, DiagramBuilder, LeafSystem

from drake_contact.app.bench import (
    DEFAULT_MAX_DURATION_S, MakePlantFloorDiagram, attribute_profile, bench,
    load_bench_scenario, profile_scenario)
from drake_contact.diagram import leaf_systems

#: One worker runs this module and its fixture is session-scoped, so the fixture
#: runs once (-n auto; docs/developer/testing.md, "Shared runs").
pytestmark = pytest.mark.xdist_group("test_bench")

#: Long enough for the contact switch to be near, short enough for CI.
DURATION = 0.5


@pytest.fixture(scope="session")
def nn_scenario():
    return load_bench_scenario("nn_styrofoam", duration=DURATION)


@pytest.fixture(scope="session")
def bench_result(nn_scenario):
    return bench(nn_scenario, name="nn_styrofoam")


@pytest.fixture(scope="session")
def profile(nn_scenario):
    return profile_scenario(nn_scenario, name="nn_styrofoam")


def test_the_table_has_the_three_diagrams_and_the_plant_floor_is_fastest(bench_result):
    rows = bench_result.rows
    assert [row.name for row in rows] == ["plant floor", "physics", "scenario"]
    for row in rows:
        assert row.us_per_step > 0 and row.realtime_factor > 0 and row.runs == 2
        assert row.realtime_factor == pytest.approx(1e3 / row.us_per_step)
        assert row.ratio_to_plant_floor == pytest.approx(
            row.us_per_step / bench_result.plant_floor.us_per_step)
    assert bench_result.plant_floor.us_per_step < bench_result.physics.us_per_step
    assert bench_result.plant_floor.us_per_step < bench_result.scenario.us_per_step
    assert bench_result.scenario_over_physics == pytest.approx(
        bench_result.scenario.us_per_step / bench_result.physics.us_per_step)
    assert bench_result.steps == 500 and len(bench_result.load_average) == 3
    table = bench_result.format()
    for text in ("plant floor", "physics", "scenario (full run", "scenario / physics",
                 "load average"):
        assert text in table


def test_the_plant_floor_has_no_python_system(nn_scenario):
    systems = list(leaf_systems(MakePlantFloorDiagram(nn_scenario)))
    assert {s.get_name() for s in systems} >= {"plant", "joint_torque"}
    for system in systems:
        assert type(system).__module__.startswith("pydrake"), system.get_name()


def test_a_long_scenario_is_capped_unless_a_duration_is_asked_for():
    assert load_bench_scenario("nn_styrofoam").simulation.duration == DEFAULT_MAX_DURATION_S
    assert load_bench_scenario("push_constant").simulation.duration == 4.0
    assert load_bench_scenario("nn_styrofoam", duration=30.0).simulation.duration == 30.0


def test_the_profile_lists_the_station_python_systems(profile):
    by_path = {s.path: s for s in profile.systems}
    for path, cls in [("station/force_sensor/force_sensor", "ForceSensor"),
                      ("station/controller/hybrid/law", "HybridControlLaw"),
                      ("station/controller/nn_compensator/law", "NnCompensationLaw")]:
        assert by_path[path].class_name == cls
        assert by_path[path].calls_per_step > 0 and by_path[path].us_per_step > 0
    # The law's output and its sampled update: twice per 1 ms plant step
    # (the law itself is evaluated once, cached).
    assert by_path["station/controller/hybrid/law"].calls_per_step == pytest.approx(2.0, abs=0.01)
    # The tip kinematics, the wall and the friction run in C++
    # (SymbolicVectorSystems): the profile, which lists Python systems only,
    # has no row for them.
    assert not any(path.startswith(("station/tip_kinematics", "station/wall",
                                    "station/joint_friction")) for path in by_path)
    times = [s.us_per_step for s in profile.systems]
    assert times == sorted(times, reverse=True)
    assert 0 < profile.systems_us <= profile.total_us
    assert 0 < profile.simulator_us < profile.total_us
    assert profile.systems_us + profile.simulator_us + sum(
        us for _, us in profile.outside_us) == pytest.approx(profile.total_us, rel=1e-6)
    assert any("_check_divergence" in label for label, _ in profile.outside_us)
    table = profile.format()
    assert "station/force_sensor/force_sensor" in table
    assert "Drake simulator + C++ systems (inside AdvanceTo, not in a Python system)" in table


# A diagram whose time is known: Reader's 1 kHz update reads, through a
# module-level helper, the output of Slow, whose calc spins for SPIN_S. Two
# Slows share the class. The whole spin must count to Slow, not also (or
# instead) to Reader, whose cumulative time holds it.

SPIN_S = 200e-6


class Slow(LeafSystem):
    def __init__(self):
        super().__init__()
        self.DeclareVectorOutputPort("y", 1, self._calc)

    def _calc(self, context, output: BasicVector):
        end = time.perf_counter() + SPIN_S
        while time.perf_counter() < end:
            pass
        output.SetAtIndex(0, context.get_time())


def _read(port, context):
    return port.Eval(context)[0]


class Reader(LeafSystem):
    def __init__(self):
        super().__init__()
        self._inputs = [self.DeclareVectorInputPort(f"u{i}", 1) for i in range(2)]
        self.DeclareDiscreteState(1)
        self.DeclarePeriodicDiscreteUpdateEvent(1e-3, 0.0, self._update)

    def _update(self, context, state):
        state.set_value([sum(_read(port, context) for port in self._inputs)])


def _advance(simulator, t):
    simulator.AdvanceTo(t)


def test_nested_callbacks_count_once_to_the_innermost_system():
    builder = DiagramBuilder()
    reader = builder.AddNamedSystem("reader", Reader())
    for i in range(2):
        slow = builder.AddNamedSystem(f"slow{i}", Slow())
        builder.Connect(slow.get_output_port(), reader.get_input_port(i))
    diagram = builder.Build()
    simulator = Simulator(diagram)
    simulator.Initialize()
    profiler = cProfile.Profile(builtins=False)
    steps = 100
    profiler.runcall(_advance, simulator, steps * 1e-3)
    stats = pstats.Stats(profiler).stats
    root = (_advance.__code__.co_filename, _advance.__code__.co_firstlineno, "_advance")
    costs, members = attribute_profile(stats, diagram, root)
    assert {cls: len(systems) for cls, systems in members.items()} == {Reader: 1, Slow: 2}
    slow_s, slow_calls = costs[Slow]
    reader_s, reader_calls = costs[Reader]
    assert slow_calls == pytest.approx(2 * steps, abs=2)
    assert reader_calls == pytest.approx(steps, abs=1)
    assert slow_s >= 2 * steps * SPIN_S
    assert 0 < reader_s < 0.2 * slow_s
    assert slow_s + reader_s <= stats[root][3]


def drake_contact(*args, cwd):
    return subprocess.run([sys.executable, "-m", "drake_contact", *args], cwd=cwd,
                          capture_output=True, text=True, timeout=300)


def test_cli_prints_the_table_and_the_profile(tmp_path):
    result = drake_contact("bench", "push_constant", "--duration", "0.5", "--profile",
                           cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    assert result.stderr == ""
    out = result.stdout
    for text in ("plant floor (MultibodyPlant alone", "physics (plant, wall, friction",
                 "scenario (full run", "scenario / physics = ",
                 "station/force_sensor/force_sensor", "ForceSensor",
                 "Drake simulator + C++ systems"):
        assert text in out


@pytest.mark.parametrize("duration,message", [
    ("-1", "simulation.duration = -1.0 is out of range"),
    ("soon", "argument --duration: invalid float value"),
])
def test_cli_bad_duration_exits_2_with_one_line(tmp_path, duration, message):
    result = drake_contact("bench", "push_constant", "--duration", duration, cwd=tmp_path)
    assert result.returncode == 2
    assert result.stdout == ""
    assert result.stderr.count("\n") == 1 and message in result.stderr
