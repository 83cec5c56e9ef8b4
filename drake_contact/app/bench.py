"""Speed: µs per simulated plant step of a scenario, against two floors.

Three diagrams are timed in one process, each over the same simulated time:

* the **plant floor** (:func:`MakePlantFloorDiagram`): Drake's
  MultibodyPlant of the arm alone, a constant torque into its actuation
  input, no Python system at all. No run of this arm can be cheaper;
* the **physics** (:func:`drake_contact.diagram.MakeFloorDiagram`): the
  plant with the wall, the joint friction and the tip kinematics (C++
  symbolic systems), a
  constant torque and no sensors or controller: what any contact run of
  this arm costs;
* the **scenario**: the full run (:func:`simulate_scenario`: station,
  controller, identifiers, loggers and divergence checks).

The ratio scenario / physics is what the thesis's signal chain, controllers
and logging add; physics / plant floor is what our Python physics adds to
Drake. :func:`profile_scenario` then says which system the time goes to.
Timings depend on the machine and its load; this is a measurement, not a
test (:class:`BenchResult` records the load average beside the numbers).
"""

import cProfile
import copy
import dataclasses as dc
import inspect
import os
import time
import types
from collections import defaultdict
from pathlib import Path

from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import ConstantVectorSource

from drake_contact.simulation import (
    MakeRunDiagram, advance_in_chunks, simulate, simulate_ensemble, simulate_scenario)
from drake_contact.diagram import MakeFloorDiagram, leaf_systems
from drake_contact.errors import SimulationDiverged
from drake_contact.plant.arm import AddArmPlant
from drake_contact.scenario import Scenario, load_scenario

#: Simulated time (s) a benchmark runs when no duration is asked for and the
#: scenario's own is longer: enough for a stable µs/step, and the contact
#: phase of every bundled scenario has begun by then.
DEFAULT_MAX_DURATION_S = 20.0

#: A scenario run at least this long (simulated s) is timed once: its wall
#: time is long enough that a second run would not change the picture.
SINGLE_RUN_DURATION_S = 10.0

#: Python functions simulate() calls outside AdvanceTo that cost less than
#: this (µs per plant step) share one "other" row of the profile.
OUTSIDE_ROW_MIN_US = 0.05

#: Motor torque (N m) of the plant floor: MakeFloorDiagram's default, so
#: both floors are driven alike.
FLOOR_JOINT_TORQUE = (4.0, 0.0, 0.0)


def load_bench_scenario(source, duration=None, overrides=()) -> Scenario:
    """Loads ``source`` (a bundled name, file or YAML text) for a benchmark:
    ``duration`` (s) if given, else the scenario's own capped at
    :data:`DEFAULT_MAX_DURATION_S`. Raises ScenarioError for bad input."""
    scenario = load_scenario(source, overrides, duration=duration)
    if duration is None and scenario.simulation.duration > DEFAULT_MAX_DURATION_S:
        scenario = load_scenario(source, overrides, duration=DEFAULT_MAX_DURATION_S)
    return scenario


def MakePlantFloorDiagram(scenario: Scenario, joint_torque=FLOOR_JOINT_TORQUE):
    """The plant floor: the arm's MultibodyPlant (and its SceneGraph) from
    :func:`AddArmPlant`, with a constant motor torque (N m) into its
    actuation input. Only Drake C++ systems: nothing calls Python."""
    scenario.validate()
    builder = DiagramBuilder()
    plant, _ = AddArmPlant(builder, scenario.arm)
    torque = builder.AddNamedSystem("joint_torque", ConstantVectorSource(list(joint_torque)))
    builder.Connect(torque.get_output_port(), plant.get_actuation_input_port())
    diagram = builder.Build()
    diagram.set_name("plant_floor_diagram")
    return diagram


@dc.dataclass(frozen=True)
class DiagramTiming:
    """The speed of one timed diagram."""

    # "plant floor", "physics" or "scenario".
    name: str
    # What the diagram holds, for the table.
    contents: str
    # Wall time per plant step (µs), the best of ``runs``.
    us_per_step: float
    # Simulated s per wall s.
    realtime_factor: float
    # us_per_step over the plant floor's.
    ratio_to_plant_floor: float
    # How many runs the best was taken of.
    runs: int


@dc.dataclass(frozen=True)
class BenchResult:
    """What :func:`bench` measured."""

    # The scenario's name or source.
    scenario_name: str
    # Simulated time of every timed run (s).
    duration_s: float
    # Plant time step (s).
    time_step_s: float
    plant_floor: DiagramTiming
    physics: DiagramTiming
    scenario: DiagramTiming
    # os.getloadavg() when the timing ended (1, 5, 15 min), and the cores.
    load_average: tuple
    cpu_count: int

    @property
    def steps(self) -> int:
        return int(round(self.duration_s / self.time_step_s))

    @property
    def scenario_over_physics(self) -> float:
        return self.scenario.us_per_step / self.physics.us_per_step

    @property
    def rows(self):
        return (self.plant_floor, self.physics, self.scenario)

    def format(self) -> str:
        """The table ``drake-contact bench`` prints."""
        load = " ".join(f"{x:.2f}" for x in self.load_average)
        lines = [f"{self.scenario_name}: {self.duration_s:g} s simulated, {self.steps} plant "
                 f"steps of {self.time_step_s * 1e3:g} ms; load average {load} "
                 f"on {self.cpu_count} cores",
                 f"{'diagram':<58} {'us/step':>9} {'real-time':>10} {'x plant':>8}  timed",
                 f"{'':<58} {'':>9} {'factor':>10} {'floor':>8}"]
        for row in self.rows:
            label = f"{row.name} ({row.contents})"
            timed = "once" if row.runs == 1 else f"best of {row.runs}"
            lines.append(f"{label:<58} {row.us_per_step:9.1f} {row.realtime_factor:10.2f} "
                         f"{row.ratio_to_plant_floor:8.2f}  {timed}")
        lines.append(f"scenario / physics = {self.scenario_over_physics:.2f}")
        return "\n".join(lines)


def _us_per_step(wall_s, scenario):
    return wall_s / (scenario.simulation.duration / scenario.arm.time_step) * 1e6


def _time_diagram(make, scenario, runs):
    """Best wall time (s) of Initialize + AdvanceTo(duration) of ``make(scenario)``,
    built anew for each run (building is not timed)."""
    best = float("inf")
    for _ in range(runs):
        simulator = Simulator(make(scenario))
        start = time.perf_counter()
        simulator.Initialize()
        simulator.AdvanceTo(scenario.simulation.duration)
        best = min(best, time.perf_counter() - start)
    return best


def time_plant_floor(scenario: Scenario, runs=2) -> float:
    """µs per plant step of :func:`MakePlantFloorDiagram` (best of ``runs``)."""
    return _us_per_step(_time_diagram(MakePlantFloorDiagram, scenario, runs), scenario)


def time_physics(scenario: Scenario, runs=2) -> float:
    """µs per plant step of :func:`MakeFloorDiagram` (best of ``runs``)."""
    return _us_per_step(_time_diagram(MakeFloorDiagram, scenario, runs), scenario)


def time_scenario(scenario: Scenario, runs=1) -> float:
    """µs per plant step of full runs of ``scenario`` (:func:`simulate_scenario`,
    logging and divergence checks included; best of ``runs``). Raises
    SimulationDiverged if a run does not complete: its time would mean
    nothing."""
    best = float("inf")
    for _ in range(runs):
        result = _completed(simulate_scenario(scenario))
        best = min(best, result.wall_s)
    return _us_per_step(best, scenario)


def _completed(result):
    # A run that stopped early has no meaningful time per step.
    if result.status == "interrupted":
        raise KeyboardInterrupt
    if result.status != "completed":
        t = float(result.log["t"][-1]) if len(result.log["t"]) else 0.0
        raise SimulationDiverged(f"the benchmark run did not complete: {result.message}",
                                 time_s=t, where="benchmark")
    return result


def bench(scenario: Scenario, *, runs=2, scenario_runs=None, name=None) -> BenchResult:
    """Times the plant floor, the physics and the scenario in this process,
    each over ``scenario.simulation.duration``, best of ``runs``.

    ``scenario_runs`` (default: once if the scenario runs at least
    :data:`SINGLE_RUN_DURATION_S`, else ``runs``) is how often the full
    scenario is timed. ``name`` labels the table (default: the scenario's
    "scenario")."""
    if scenario_runs is None:
        scenario_runs = 1 if scenario.simulation.duration >= SINGLE_RUN_DURATION_S else runs
    plant_us = time_plant_floor(scenario, runs)
    physics_us = time_physics(scenario, runs)
    scenario_us = time_scenario(scenario, scenario_runs)
    step_us = scenario.arm.time_step * 1e6

    def timing(label, contents, us, n):
        return DiagramTiming(label, contents, us, step_us / us, us / plant_us, n)

    return BenchResult(
        scenario_name=name or "scenario",
        duration_s=scenario.simulation.duration,
        time_step_s=scenario.arm.time_step,
        plant_floor=timing("plant floor", "MultibodyPlant alone, constant torque",
                           plant_us, runs),
        physics=timing("physics", "plant, wall, friction, tip kinematics", physics_us, runs),
        scenario=timing("scenario", "full run, logging included", scenario_us, scenario_runs),
        load_average=tuple(os.getloadavg()),
        cpu_count=os.cpu_count() or 1)


# --- Ensembles -------------------------------------------------------------------


@dc.dataclass(frozen=True)
class EnsembleTiming:
    """One ensemble size's timing: µs per environment-step (one environment
    advanced by one plant step) and the memory it took."""

    size: int
    # Simulating (logging and divergence checks included), as a run alone
    # is timed.
    us_per_env_step: float
    # Resident memory the ensemble's build and run added to this process (MB).
    memory_mb: float
    # The whole simulate_ensemble call: building the diagram and the
    # metrics too.
    whole_us_per_env_step: float = float("nan")

    @property
    def env_steps_per_s(self) -> float:
        return 1e6 / self.us_per_env_step


def ensemble_scenarios(scenario: Scenario, size: int) -> list:
    """``size`` copies of ``scenario`` with seeds 0, 1, ... (the
    environments of a timed ensemble)."""
    out = []
    for seed in range(size):
        each = copy.deepcopy(scenario)
        each.simulation.seed = seed
        out.append(each)
    return out


def time_ensemble(scenario: Scenario, size: int) -> EnsembleTiming:
    """Times one :func:`simulate_ensemble` of ``size`` copies of
    ``scenario``: its simulation, logging and divergence checks, as
    :func:`time_scenario` times a run alone (each result's ``wall_s``),
    and apart from that its whole call (building the diagram and the
    metrics too). Raises SimulationDiverged if an environment does not
    complete."""
    before = _resident_mb()
    scenarios = ensemble_scenarios(scenario, size)
    start = time.perf_counter()
    results = simulate_ensemble(scenarios)
    whole = time.perf_counter() - start
    for result in results:
        _completed(result)
    memory = _resident_mb() - before
    simulated = results[0].wall_s  # the ensemble's simulation time over N
    del results
    return EnsembleTiming(size, _us_per_step(simulated, scenario),
                          memory, _us_per_step(whole, scenario) / size)


def _resident_mb() -> float:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20


def format_ensembles(timings, single_us: float, name: str, duration_s: float) -> str:
    """The table of ``drake-contact bench --ensemble``."""
    lines = [f"{name}: ensembles of {duration_s:g} s simulated, against one run alone "
             f"({single_us:.1f} us/step)",
             f"{'N':>5} {'us per env-step':>16} {'env-steps/s':>12} {'speed-up':>9} "
             f"{'memory (MB)':>12} {'with build and metrics':>23}"]
    for t in timings:
        lines.append(f"{t.size:5d} {t.us_per_env_step:16.1f} {t.env_steps_per_s:12.0f} "
                     f"{single_us / t.us_per_env_step:9.2f} {t.memory_mb:12.0f} "
                     f"{t.whole_us_per_env_step:16.1f} us/step")
    return "\n".join(lines)


# --- Where the time goes -------------------------------------------------------


@dc.dataclass(frozen=True)
class SystemCost:
    """The Python callbacks of one system class, per plant step."""

    # Path of the system in the run diagram ("station/wall"); several
    # comma-separated paths when systems share the class.
    path: str
    # The system's class (qualified name).
    class_name: str
    # How many systems of the run diagram have this class.
    instances: int
    # Time in its callbacks (µs per plant step), under the profiler.
    us_per_step: float
    # Callbacks entered from outside the class per plant step.
    calls_per_step: float


@dc.dataclass(frozen=True)
class ProfileResult:
    """Where one profiled run's time went (:func:`profile_scenario`); every
    time is µs per plant step under cProfile, which inflates Python calls."""

    scenario_name: str
    # Plant steps of the run.
    steps: int
    # One per Python system class, most expensive first.
    systems: list
    # simulate()'s own time: Drake's simulator and its C++ systems (loggers
    # included), inside AdvanceTo (and Initialize) and not in Python.
    simulator_us: float
    # (label, µs per step) of the Python functions simulate() calls besides
    # the systems' callbacks: divergence checks between AdvanceTo chunks,
    # log collection and metrics after the run, seeding.
    outside_us: list
    # The whole profiled simulate() call.
    total_us: float

    @property
    def systems_us(self) -> float:
        return sum(s.us_per_step for s in self.systems)

    def format(self) -> str:
        """The table ``drake-contact bench --profile`` prints."""
        def shown(cost):
            first = cost.path.split(", ")[0]
            return first if cost.instances == 1 else f"{first} (+{cost.instances - 1})"

        width = max([52] + [len(shown(s)) for s in self.systems])
        cls_width = max([26] + [len(s.class_name) for s in self.systems])
        lines = [f"{self.scenario_name} under cProfile: {self.steps} plant steps, "
                 f"{self.total_us:.1f} us/step in all (the profiler inflates Python calls)",
                 "Python systems, one row per class: systems sharing a class are one row "
                 "(their instances are not told apart)",
                 f"{'system':<{width}} {'class':<{cls_width}} {'us/step':>9} {'share':>6} "
                 f"{'calls/step':>10}"]

        def share(us):
            return f"{100 * us / self.total_us:5.1f}%" if self.total_us > 0 else "    -"

        for s in self.systems:
            lines.append(f"{shown(s):<{width}} {s.class_name:<{cls_width}} {s.us_per_step:9.1f} "
                         f"{share(s.us_per_step)} {s.calls_per_step:10.2f}")
        other = [("Python systems, all", self.systems_us),
                 ("Drake simulator + C++ systems (inside AdvanceTo, not in a Python system)",
                  self.simulator_us)]
        other += [(f"outside AdvanceTo: {label}", us) for label, us in self.outside_us]
        other.append(("total (the profiled simulate call)", self.total_us))
        for label, us in other:
            lines.append(f"{label:<{width + cls_width + 1}} {us:9.1f} {share(us)}")
        for cost in self.systems:
            if cost.instances > 1:
                lines.append(f"{cost.class_name}: one row for its {cost.instances} systems, "
                             f"{cost.path}")
        return "\n".join(lines)


def _python_functions(attribute):
    """The plain Python functions behind a class attribute."""
    if isinstance(attribute, (staticmethod, classmethod)):
        attribute = attribute.__func__
    if isinstance(attribute, property):
        candidates = [attribute.fget, attribute.fset, attribute.fdel]
    else:
        candidates = [getattr(attribute, "func", None), attribute]  # functools.cached_property
    found = []
    for f in candidates:
        while inspect.isfunction(f):
            found.append(f)
            f = getattr(f, "__wrapped__", None)  # decorators that used functools.wraps
    return found


def _profile_key(code):
    # cProfile's key of a Python function: (file, first line, name).
    return (code.co_filename, code.co_firstlineno, code.co_name)


def class_code_keys(cls) -> set:
    """cProfile keys of every function defined in the body of ``cls`` or of
    its Python (non-pydrake) bases, with the functions and lambdas nested in
    them (callbacks declared in ``__init__``)."""
    stack = []
    for klass in cls.__mro__:
        if klass.__module__.startswith(("pydrake", "pybind11")) or klass is object:
            continue
        for attribute in vars(klass).values():
            stack.extend(f.__code__ for f in _python_functions(attribute))
    keys = set()
    while stack:
        code = stack.pop()
        keys.add(_profile_key(code))
        stack.extend(c for c in code.co_consts if isinstance(c, types.CodeType))
    return keys


def _system_path(system):
    # "::run::station::wall" -> "station/wall" (the root diagram's name dropped).
    parts = system.GetSystemPathname().strip(":").split("::")
    return "/".join(parts[1:]) or parts[0]


def _contexts(stats, owner):
    """For each profiled function, the share of its time spent in each
    system's context: {group or None: weight}, weights summing to 1.

    A system callback is in its own system's context. Any other function
    inherits its callers' contexts, weighted by the time each caller spends
    calling it; one with no caller is outside every system (None). Solved
    by iteration: call cycles through helpers converge (the system
    callbacks, whose context is fixed, anchor every cycle through Drake)."""
    weights = {f: {owner.get(f): 1.0} for f in stats}
    for _ in range(100):
        change = 0.0
        for f, (_, _, _, _, callers) in stats.items():
            if f in owner or not callers:
                continue
            total_ct = sum(edge[3] for edge in callers.values())
            total_nc = sum(edge[0] for edge in callers.values())
            mixed = defaultdict(float)
            for caller, edge in callers.items():
                share = edge[3] / total_ct if total_ct > 0 else edge[0] / max(total_nc, 1)
                for group, w in weights.get(caller, {None: 1.0}).items():
                    mixed[group] += share * w
            change = max(change, max(abs(mixed[g] - weights[f].get(g, 0.0))
                                     for g in set(mixed) | set(weights[f])))
            weights[f] = dict(mixed)
        if change < 1e-12:
            break
    return weights


#: The library's layers: their functions only run inside the simulator.
LIBRARY_LAYERS = ("plant", "sensing", "control", "identification")


def attribute_profile(stats: dict, diagram, root_key, more_roots=()):
    """Splits a cProfile run of ``simulate`` over the diagram's Python systems.

    ``stats`` is ``pstats.Stats(...).stats`` of a profile taken with
    ``builtins=False`` (so that a Python callback that Drake calls from
    inside an ``Eval`` made by another Python callback has that callback,
    not the C ``Eval``, as its recorded caller); ``root_key`` is the key of
    the profiled ``simulate`` function (``more_roots``: the keys of the
    functions it runs the simulator through). Returns ({group: (seconds, calls)},
    {group: [systems]}) with a group per Python system class.

    The rule. A function belongs to a system class if it is defined in the
    class body (or a Python base's), nested functions and lambdas included,
    and in no other system class. Entering a class's functions from any
    other context (Drake's simulator, or another system's callback through
    an Eval) is an *entry*: the cumulative time of that call edge counts to
    the class, and so do its calls. Helpers (module-level functions such as
    CalcTipPoseAndJacobian, numpy, the controller's ArmModel) are not
    entries: their time is inside the cumulative time of the callback that
    called them. An entry from another system's context is *nested*: its
    time is subtracted from that system, so that each instant counts once,
    to the innermost system whose callback is running. Calls between a
    class's own functions (a port calc evaluating its own cache entry) are
    neither. A helper called from several contexts passes its callees on
    in proportion to the time each context spends calling it (exact when a
    helper that Evals another system's port is only ever called from one
    system, as in this package). C++ work a callback triggers through Eval
    (a Drake filter it reads, the plant's kinematics) counts to that
    callback's system; C++ work the simulator does on its own counts to
    none. Hence the groups sum to the time inside the callbacks Drake's
    simulator entered itself, which is at most the profiled total.
    """
    systems = defaultdict(list)
    for system in leaf_systems(diagram):
        if not type(system).__module__.startswith("pydrake"):
            systems[type(system)].append(system)
    claims = defaultdict(set)
    for cls in systems:
        for key in class_code_keys(cls):
            claims[key].add(cls)
    owner = {key: next(iter(classes)) for key, classes in claims.items() if len(classes) == 1}
    owner = {key: cls for key, cls in owner.items() if key in stats}
    weights = _contexts(stats, owner)
    for key in (root_key, *more_roots):
        weights[key] = {None: 1.0}
    seconds, calls = defaultdict(float), defaultdict(float)
    for f, cls in owner.items():
        _, nc, _, ct, callers = stats[f]
        if not callers:
            seconds[cls] += ct
            calls[cls] += nc
            continue
        for caller, (edge_nc, _, _, edge_ct) in callers.items():
            context = weights.get(caller, {None: 1.0})
            entering = 1.0 - context.get(cls, 0.0)
            seconds[cls] += edge_ct * entering
            calls[cls] += edge_nc * entering
            for other, w in context.items():
                if other is not None and other is not cls:
                    seconds[other] -= edge_ct * w
    return ({cls: (seconds[cls], calls[cls]) for cls in systems}, dict(systems))


def profile_scenario(scenario: Scenario, *, name=None) -> ProfileResult:
    """Runs ``scenario`` once more (:func:`MakeRunDiagram` and
    :func:`simulate`) under cProfile and says which system the time went to
    (see :func:`attribute_profile` for the rule). Building the diagram is
    not profiled."""
    import pstats
    diagram, loggers = MakeRunDiagram(scenario)
    profiler = cProfile.Profile(builtins=False)
    _completed(profiler.runcall(simulate, diagram, loggers))
    stats = pstats.Stats(profiler).stats
    root_key = _profile_key(simulate.__code__)
    # The chunk loop (simulation.advance_in_chunks) is simulate's own: its time
    # outside Drake counts to the simulator, its callees are outside rows.
    chunks = _profile_key(advance_in_chunks.__code__)
    roots = [root_key] + ([chunks] if chunks in stats else [])
    steps = int(round(scenario.simulation.duration / scenario.arm.time_step))
    costs, members = attribute_profile(stats, diagram, root_key, roots[1:])
    us = 1e6 / steps
    systems = []
    for cls, (seconds, calls) in costs.items():
        paths = [_system_path(s) for s in members[cls]]
        systems.append(SystemCost(", ".join(paths), cls.__qualname__, len(paths),
                                  seconds * us, calls / steps))
    systems.sort(key=lambda s: -s.us_per_step)
    _, _, _, root_ct, _ = stats[root_key]
    root_tt = sum(stats[key][2] for key in roots)
    system_keys = set().union(*(class_code_keys(cls) for cls in members))
    outside = defaultdict(float)
    library = [str(Path(__file__).resolve().parents[1] / layer) for layer in LIBRARY_LAYERS]
    glue_s = 0.0
    for f, (_, _, _, _, callers) in stats.items():
        # Library functions that Drake calls (e.g. the sampled-update
        # wrapper of plant/arm.py) run inside AdvanceTo; the systems they
        # enter already count their time.
        if f in system_keys or f in roots:
            continue
        from_root = [key for key in roots if key in callers]
        if f[0].startswith(tuple(library)):
            if from_root:
                glue_s += stats[f][2]  # its own time is the simulator's glue
            continue
        if from_root:
            us_f = sum(callers[key][3] for key in from_root) * us
            label = f"{Path(f[0]).stem}.{f[2]}()" if us_f >= OUTSIDE_ROW_MIN_US else "other"
            outside[label] += us_f
    outside_us = sorted(outside.items(), key=lambda item: (item[0] == "other", -item[1]))
    return ProfileResult(
        scenario_name=name or "scenario", steps=steps, systems=systems,
        simulator_us=(root_tt + glue_s) * us, outside_us=outside_us, total_us=root_ct * us)

