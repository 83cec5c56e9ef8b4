"""Scenarios: what to simulate, as typed dataclasses loaded from YAML.

A scenario file is YAML matching :class:`Scenario`; any field left out keeps
its default (the thesis's value where there is one). Load with
:func:`load_scenario`, which resolves a bundled name or a path, applies
``dotted.key=value`` overrides, checks every key and type, and validates every
range, raising :class:`ScenarioError` with one line naming the field.
"""

import dataclasses as dc
from pathlib import Path

import numpy as np
import yaml
from pydrake.common.yaml import yaml_dump_typed, yaml_load_typed

from drake_contact.plant.arm import ArmConfig
from drake_contact.plant.compliant_wall import EnvironmentConfig
from drake_contact.sensing.dsp import DspConfig
from drake_contact.sensing.estimator import EstimatorConfig
from drake_contact.control.force_reference import ForceReferenceConfig
from drake_contact.sensing.force_sensor import ForceSensorConfig
from drake_contact.control.hybrid_controller import HybridControllerConfig
from drake_contact.identification.identifiers import IdentifierConfig, validate_identifiers
from drake_contact.errors import ScenarioError, did_you_mean
from drake_contact.faults import FaultConfig, validate_faults
from drake_contact.control.safety_supervisor import SafetyConfig
from drake_contact.control.nn_compensator import NnCompensatorConfig
from drake_contact.control.policy import PolicyConfig
from drake_contact.plant.joint_physics import (
    THESIS_TORQUE_LIMITS, EncoderConfig, JointFrictionConfig)
from drake_contact.control.push_controller import PushConfig
from drake_contact.options import YAML12_FLOAT as _YAML12_FLOAT, check_schema as _check_schema
from drake_contact.plugins import (
    check_configuration, check_options_mapping, configured_options, controller_declaration,
    installed_controllers)
from drake_contact.resources import bundled_scenario_names, scenarios_dir

class _Loader(yaml.SafeLoader):
    """PyYAML's safe loader, reading YAML 1.2 floats such as ``6.2e4`` or
    ``1e-3`` as numbers (YAML 1.1 reads them as strings), as Drake's own
    ``yaml_load_typed`` does."""


_Loader.add_implicit_resolver("tag:yaml.org,2002:float", _YAML12_FLOAT, list("-+0123456789."))


def _yaml_load(text):
    return yaml.load(text, Loader=_Loader)


def yaml_load(text):
    """YAML text as plain data, numbers read as YAML 1.2 (``6.2e4`` is a
    number), as scenarios are."""
    return _yaml_load(text)


@dc.dataclass
class ControllerConfig:
    """Which controller commands the joints, and its parameters."""

    # An installed controller (drake_contact.plugins.installed_controllers():
    # the built-ins push, hybrid, nn, the baselines, and any plug-in).
    name: str = "push"
    # Constant-force pushing law (name: push), a test harness.
    push: PushConfig = dc.field(default_factory=PushConfig)
    # The thesis's approach, 5 N switch and hybrid control (name: hybrid).
    hybrid: HybridControllerConfig = dc.field(default_factory=HybridControllerConfig)
    # The neural-network compensator added to ``hybrid`` (name: nn, section 4.5).
    nn: NnCompensatorConfig = dc.field(default_factory=NnCompensatorConfig)
    # A learned policy driving ``hybrid`` (name: policy; drake_contact.control.policy).
    policy: PolicyConfig = dc.field(default_factory=PolicyConfig)

    # Options of any other controller (names to numbers, lists or strings),
    # handed to its factory and checked as it declares. The thesis's
    # controllers take their sections above.
    options: dict[str, float] = dc.field(default_factory=dict)
    # Name of an identifier whose [M_e, B_e, K_e] feeds the controller's
    # ``impedance_estimate`` input ('' = none; the thesis's decoupled law names
    # its own in hybrid.stiffness_source).
    impedance_source: str = ""

    def validate(self, prefix="controller"):
        installed = installed_controllers()
        if self.name not in installed:
            raise ScenarioError(
                f"{prefix}.name = '{self.name}' is unknown{did_you_mean(self.name, installed)}: "
                f"choose one of {', '.join(sorted(installed))}")
        check_configuration(self, controller_declaration(self.name, f"{prefix}.name"), prefix,
                            self.name)

    def factory_options(self) -> dict:
        """The options mapping the controller's factory gets: its declared
        sections (:class:`drake_contact.plugins.Declaration`), else ``options``."""
        return configured_options(self, controller_declaration(self.name))

    def impedance_source_name(self) -> str:
        """The identifier feeding ``impedance_estimate`` ('' = none)."""
        declared = controller_declaration(self.name).impedance_source
        if declared:
            section, field = declared.split(".")
            return getattr(getattr(self, section), field)
        return self.impedance_source


@dc.dataclass
class ScoringConfig:
    """Where the tracking metrics are computed, relative to the first
    contact switch (s)."""

    # Window [start, end) after the switch; end 0 means the end of the run.
    window_start_s: float = 1.0
    window_end_s: float = 0.0
    # The switch's impact is the peak force within this time after it (s).
    impact_window_s: float = 0.5
    # force_rmse_windows_n: RMSE per window of this length from the switch (s).
    rmse_window_s: float = 5.0
    # adaptation_time_s: from the switch to the end of the first window of
    # rmse_window_s (sliding by 0.5 s) whose force RMSE is below this (N).
    adaptation_rmse_n: float = 1.5
    # level_max_error_n: over each level of a stepwise f_d (no sine), from
    # level_settle_s after the change to the next, the largest |mean true
    # force over level_average_s - f_d| (s, s).
    level_settle_s: float = 0.5
    level_average_s: float = 0.1

    def validate(self, prefix="scoring"):
        if not (self.window_start_s >= 0):
            raise ScenarioError(f"{prefix}.window_start_s = {self.window_start_s} is out of "
                                "range: must be >= 0 s")
        if self.window_end_s != 0 and not (self.window_end_s > self.window_start_s):
            raise ScenarioError(f"{prefix}.window_end_s = {self.window_end_s} is out of range: "
                                f"must be 0 (to the end) or > window_start_s")
        if not (self.rmse_window_s > 0):
            raise ScenarioError(f"{prefix}.rmse_window_s = {self.rmse_window_s} is out of "
                                "range: must be > 0 s")
        if not (self.adaptation_rmse_n > 0):
            raise ScenarioError(f"{prefix}.adaptation_rmse_n = {self.adaptation_rmse_n} is out "
                                "of range: must be > 0 N")
        for field in ("level_settle_s", "level_average_s"):
            if not (getattr(self, field) > 0):
                raise ScenarioError(f"{prefix}.{field} = {getattr(self, field)} is out of "
                                    "range: must be > 0 s")
        if not (self.impact_window_s > 0):
            raise ScenarioError(f"{prefix}.impact_window_s = {self.impact_window_s} is out of "
                                "range: must be > 0 s")


@dc.dataclass
class SimulationConfig:
    """How long and how the run goes."""

    # Simulated time (s).
    duration: float = 5.0
    # Seed of every random source in the diagram; same seed, same logs.
    seed: int = 0
    # The run stops when the true contact force exceeds this (N).
    force_limit: float = 500.0
    # Steady-state metrics average over this final window (s).
    settle_window: float = 0.5

    def validate(self, prefix="simulation"):
        if not (np.isfinite(self.duration) and self.duration > 0):
            raise ScenarioError(
                f"{prefix}.duration = {self.duration} is out of range: must be > 0 s")
        if not (0 <= self.seed < 2**64):
            raise ScenarioError(f"{prefix}.seed = {self.seed} is out of range: "
                                "must be in [0, 2**64 - 1]")
        if not (self.force_limit > 0):
            raise ScenarioError(
                f"{prefix}.force_limit = {self.force_limit} is out of range: must be > 0 N")
        if not (0 < self.settle_window <= self.duration):
            raise ScenarioError(
                f"{prefix}.settle_window = {self.settle_window} is out of range: "
                f"must be in (0, duration = {self.duration}] s")


@dc.dataclass
class Scenario:
    """Everything one run needs. Units are SI throughout."""

    # What this scenario shows (free text).
    description: str = ""
    # The thesis figures it reproduces, e.g. "6.11, 6.15" (titles and file names).
    thesis_figures: str = ""
    simulation: SimulationConfig = dc.field(default_factory=SimulationConfig)
    arm: ArmConfig = dc.field(default_factory=ArmConfig)
    joint_friction: JointFrictionConfig = dc.field(default_factory=JointFrictionConfig)
    # Controller torque limits per joint (N m), Appendix E.
    torque_limits: list[float] = dc.field(default_factory=lambda: list(THESIS_TORQUE_LIMITS))
    encoders: EncoderConfig = dc.field(default_factory=EncoderConfig)
    environment: EnvironmentConfig = dc.field(default_factory=EnvironmentConfig)
    force_sensor: ForceSensorConfig = dc.field(default_factory=ForceSensorConfig)
    dsp: DspConfig = dc.field(default_factory=DspConfig)
    estimator: EstimatorConfig = dc.field(default_factory=EstimatorConfig)
    controller: ControllerConfig = dc.field(default_factory=ControllerConfig)
    force_reference: ForceReferenceConfig = dc.field(default_factory=ForceReferenceConfig)
    # Online identifiers, run side by side from the first contact switch.
    identifiers: list[IdentifierConfig] = dc.field(default_factory=list)
    scoring: ScoringConfig = dc.field(default_factory=ScoringConfig)
    # Injected faults (drake_contact.faults), none in the thesis's scenarios.
    faults: list[FaultConfig] = dc.field(default_factory=list)
    # The safety supervisor between controller and motors (off in the thesis's).
    safety: SafetyConfig = dc.field(default_factory=SafetyConfig)

    def validate(self):
        self.simulation.validate()
        self.arm.validate()
        self.joint_friction.validate()
        if len(self.torque_limits) != 3 or not all(
                np.isfinite(x) and x > 0 for x in self.torque_limits):
            raise ScenarioError(
                f"torque_limits = {self.torque_limits} is out of range: "
                "must be 3 values > 0 N m")
        self.encoders.validate()
        self.environment.validate(duration=self.simulation.duration)
        self.force_sensor.validate()
        self.dsp.validate()
        self.estimator.validate()
        self.controller.validate()
        self.force_reference.validate()
        validate_identifiers(self.identifiers)
        source = self.controller.impedance_source
        if source and source not in {c.name for c in self.identifiers}:
            raise ScenarioError(f"controller.impedance_source = '{source}' names no "
                                f"identifier: choose one of the scenario's identifiers or ''")
        source = self.controller.hybrid.stiffness_source
        if source and source not in {c.name for c in self.identifiers}:
            raise ScenarioError(f"controller.hybrid.stiffness_source = '{source}' names no "
                                f"identifier: choose one of the scenario's identifiers or ''")
        self.scoring.validate()
        validate_faults(self.faults)
        self.safety.validate()
        for i, fault in enumerate(self.faults):
            if fault.kind == "encoder_missed_counts" \
                    and self.encoders.counts_per_revolution[fault.joint] <= 0:
                raise ScenarioError(
                    f"faults[{i}].joint = {fault.joint}: encoder_missed_counts needs a counting "
                    f"encoder, but encoders.counts_per_revolution[{fault.joint}] is 0")


def _looks_like_yaml(text) -> bool:
    if not (isinstance(text, str) and ("\n" in text or ":" in text.split("#")[0])):
        return False
    try:
        return not Path(text).is_file()
    except OSError:  # e.g. longer than any path can be: a whole scenario's text
        return True


def resolve_scenario_path(name_or_path) -> Path:
    """A path to an existing file, or the bundled scenario of that name."""
    path = Path(name_or_path)
    if path.is_file():
        return path
    bundled = scenarios_dir() / f"{name_or_path}.yaml"
    if bundled.is_file():
        return bundled
    names = bundled_scenario_names()
    raise ScenarioError(
        f"scenario '{name_or_path}' is neither a file nor a bundled scenario"
        f"{did_you_mean(name_or_path, names)}: choose a path or one of {', '.join(names)}")


def load_scenario(source, overrides=(), *, duration=None, seed=None) -> Scenario:
    """Loads, overrides and validates a scenario.

    ``source`` is a bundled scenario's name (``"push_constant"``), a path to
    a YAML file, YAML text (``"environment: {stiffness: 6.2e4}"``; any
    text with a newline or a ``key:``), or a mapping. Fields left out keep
    their defaults. ``overrides`` are strings ``dotted.key=value`` (value
    parsed as YAML); ``duration`` and ``seed`` set ``simulation.duration``
    and ``.seed``. Numbers follow YAML 1.2, as Drake's ``yaml_load_typed``
    reads them (``6.2e4`` is a number). Raises ScenarioError naming the
    field for anything unknown, mistyped or out of range.
    """
    if isinstance(source, dict):
        text, origin = yaml.safe_dump(source), "scenario"
    elif _looks_like_yaml(source):
        text, origin = source, "scenario text"
    else:
        path = resolve_scenario_path(source)
        text, origin = path.read_text(), str(path)
    try:
        data = _yaml_load(text)
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark else ""
        problem = getattr(e, "problem", None) or str(e).splitlines()[0]
        raise ScenarioError(f"{origin}: malformed YAML{where}: {problem}") from None
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise ScenarioError(f"{origin}: a scenario must be a YAML mapping of keys, "
                            f"not a {type(data).__name__}")
    overrides = list(overrides)
    if duration is not None:
        overrides.append(f"simulation.duration={duration}")
    if seed is not None:
        overrides.append(f"simulation.seed={seed}")
    for item in overrides:
        _apply_override(data, item)
    return scenario_from_data(data, source=origin)


def scenario_from_data(data: dict, *, source="scenario") -> Scenario:
    """Checks keys and types of a plain mapping (e.g. from ``yaml.safe_load``:
    a float field given as the string ``"6.2e4"`` is read as YAML 1.2 would),
    then loads and validates it."""
    simulation = data.get("simulation")
    if isinstance(simulation, dict) and "sample_hold" in simulation:
        raise ScenarioError(
            "simulation.sample_hold is gone: every sampled system now reads the sample taken "
            "at t_n (the thesis's timing, the only one); delete the line")
    _check_schema(Scenario, data, prefix="")
    # A plug-in's options are free-form (Drake's typed YAML has no "any"):
    # they bypass the typed load and are checked as their factory declares.
    controller = data.get("controller")
    options = controller.pop("options", {}) if isinstance(controller, dict) else {}
    identifiers = data.get("identifiers") or []
    identifier_options = [entry.pop("options", {}) if isinstance(entry, dict) else {}
                          for entry in identifiers]
    try:
        scenario = yaml_load_typed(schema=Scenario, data=yaml.safe_dump(data))
    except (RuntimeError, ValueError, TypeError) as e:
        raise ScenarioError(f"{source}: {str(e).splitlines()[0]}") from None
    if options is None:
        options = {}
    scenario.controller.options = options
    if isinstance(controller, dict) and isinstance(options, dict):
        controller["options"] = options  # the caller's mapping, unchanged
    for i, (entry, config) in enumerate(zip(identifiers, scenario.identifiers)):
        config.options = identifier_options[i] or {}
        if identifier_options[i]:
            entry["options"] = identifier_options[i]
        check_options_mapping(config.options, f"identifiers[{i}].options")
    scenario.validate()
    return scenario


def dump_scenario(scenario: Scenario) -> str:
    """The fully resolved scenario as YAML (what a run writes)."""
    options = scenario.controller.options
    identifier_options = [config.options for config in scenario.identifiers]
    if not options and not any(identifier_options):
        return yaml_dump_typed(scenario)
    # Drake's typed dump has no free-form mapping: dump without the options,
    # then put them back in place.
    bare = dc.replace(scenario, controller=dc.replace(scenario.controller, options={}),
                      identifiers=[dc.replace(c, options={}) for c in scenario.identifiers])
    data = _yaml_load(yaml_dump_typed(bare))
    if options:
        data["controller"]["options"] = options
    for entry, extra in zip(data.get("identifiers") or [], identifier_options):
        if extra:
            entry["options"] = extra
    return yaml.safe_dump(data, sort_keys=False)


def _apply_override(data: dict, item: str):
    key, sep, text = item.partition("=")
    if not sep or not key.strip():
        raise ScenarioError(f"--set '{item}' is malformed: write dotted.key=value")
    try:
        value = _yaml_load(text)
    except yaml.YAMLError:
        raise ScenarioError(f"--set '{item}': the value is not valid YAML") from None
    parts = key.strip().split(".")
    node = data
    for part in parts[:-1]:
        child = node.setdefault(part, {})
        if not isinstance(child, dict):
            raise ScenarioError(f"--set '{item}': '{part}' is a value, not a section")
        node = child
    node[parts[-1]] = value
