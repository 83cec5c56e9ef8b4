"""Plug-in controllers and identifiers: any installed package can add one.

A controller is a Drake System. A package makes one available by naming a
*factory* in its ``pyproject.toml``::

    [project.entry-points."drake_contact.controllers"]
    jt_pi = "my_package:make_controller"

``make_controller(options: dict) -> System`` gets the scenario's
``controller.options`` (names to numbers, lists or strings) and returns the
system. A scenario selects it with ``controller.name: jt_pi``. The built-in
controllers (``push``, ``hybrid``, ``nn`` and the baselines) register the
same way, in this project's own ``pyproject.toml``.

The station (:func:`drake_contact.diagram.MakeContactDiagram`) connects the
controller's input ports **by name** from :func:`controller_inputs` and takes
its ``joint_torque_commanded`` output (3, N m); every other vector output is
logged (the ones of :data:`drake_contact.diagram.CONTROLLER_SIGNALS` and of
the factory's declared ``signals`` under their own names, others as
``controller_<port>``).

A factory may declare how it is configured and logged with :func:`declare`
(:class:`Declaration`): its options are then checked when the scenario
loads, and the scenario, the station and the benchmark read the rest from
there, so a new controller or identifier is its module plus one
entry-point line. A controller that has no
``contact_info`` output gets the station's :class:`ContactDetector`, which
tells contact from the filtered force for the force reference, the
identifiers and the metrics. Everything a controller needs that evolves in
time must live in its Context (discrete state): runs are repeatable.

Identifiers register under ``drake_contact.identifiers`` the same way
(the built-ins ``rls`` and ``nn`` too); a scenario's ``identifiers`` entry
names one by ``kind`` and configures it by ``options``. An identifier reads
measured signals and ``contact_info`` by name and outputs ``impedance``
(3: [M_e, B_e, K_e]), logged as ``impedance_<name>`` and scored against
the true wall; an output ``force_estimate`` (1) is logged too.

A plug-in that cannot be found, raises while being built, has an input the
station does not provide or lacks ``joint_torque_commanded`` (an
identifier: ``impedance``) is refused with a
:class:`~drake_contact.errors.ScenarioError` naming it (the CLI: one line,
exit status 2).
"""

import dataclasses as dc
import functools
import sys
from collections.abc import Callable
from importlib.metadata import entry_points

from pydrake.systems.framework import (
    BasicVector, Diagram, DiagramBuilder, LeafSystem, PortDataType, System)
from pydrake.systems.primitives import Demultiplexer

from drake_contact.constants import CONTACT_THRESHOLD_N
from drake_contact.errors import ScenarioError, did_you_mean
from drake_contact.measured import MEASUREMENTS
from drake_contact.options import config_from_options
from drake_contact.plant.arm import DeclareSampledUpdate, is_sample_time

#: Entry-point groups of controller and identifier factories.
CONTROLLER_GROUP = "drake_contact.controllers"
IDENTIFIER_GROUP = "drake_contact.identifiers"

#: Input ports a controller may declare besides the measured signals
#: (:func:`controller_inputs`): f_d, an identifier's estimate, and the true
#: state for test harnesses: (size, meaning).
STATION_INPUTS = {
    "force_desired": (1, "desired normal force f_d from the scenario's force reference (N)"),
    "impedance_estimate": (3, "[M_e, B_e, K_e] of the identifier named by "
                              "controller.impedance_source (kg, N s/m, N/m)"),
    "policy_action": (4, "a policy's action (drake_contact.control.policy_spaces.ACTION) "
                         "from the station's input port of that name (the Gymnasium "
                         "environment's action)"),
    "plant_state": (6, "TRUE arm state [q; v] (rad, rad/s): ground truth, for test "
                       "harnesses only (the built-in push)"),
    "force_fault": (1, "1 while the safety supervisor flags the force reading as "
                       "implausible (a stuck or dropped-out sensor), else 0: hold the "
                       "controller's state (unconnected without safety.enabled)"),
}


def controller_inputs() -> dict:
    """Every input port a controller may declare, by name: (size, meaning).
    The station connects each one the controller has: the measured signals
    (:data:`drake_contact.measured.MEASUREMENTS`, named as the station logs
    them), then :data:`STATION_INPUTS`."""
    return {name: (m.size, m.meaning) for name, m in MEASUREMENTS.items()
            if m.station} | STATION_INPUTS


def identifier_inputs() -> dict:
    """Every input port an identifier may declare: each measured signal by
    its role (``force``, ``tip_pose``, ``tip_velocity``, ``tip_acceleration``:
    the signals its ``signals`` option chooses; ``force_raw``,
    ``joint_positions``, ...), and ``contact_info``."""
    return ({m.role: (m.size, m.meaning) for m in MEASUREMENTS.values()} | {
        "contact_info": (4, "[time of the first contact switch (s) or -1, x, y, phi at the "
                            "switch]: the controller's or the station's detector's"),
        "force_fault": STATION_INPUTS["force_fault"]})


#: Output ports every controller must have: (size, meaning).
CONTROLLER_REQUIRED_OUTPUTS = {
    "joint_torque_commanded": (3, "motor command before saturation (N m)"),
}


#: Outputs an identifier must have.
IDENTIFIER_REQUIRED_OUTPUTS = {
    "impedance": (3, "the estimate [M_e, B_e, K_e] (kg, N s/m, N/m)"),
}


@dc.dataclass(frozen=True)
class Declaration:
    """What a controller's or identifier's factory says of itself, through
    :func:`declare`; every field is optional, and a factory without one
    gets the defaults (options checked only as names to values)."""

    # Called with the scenario's options mapping when the scenario loads;
    # raises ScenarioError naming the field, so a bad option fails there in
    # one line, before anything runs (see :func:`typed_options`).
    check_options: Callable | None = None
    # The typed sections of the scenario's entry that configure it instead
    # of ``options`` (the thesis's: ``controller.hybrid``, ``identifiers[i].rls``
    # ...); the factory gets the one section's fields, or {section: fields}.
    sections: tuple = ()
    # A controller: the section field naming the identifier whose estimate
    # feeds its ``impedance_estimate`` (else ``controller.impedance_source``).
    impedance_source: str = ""
    # A controller: outputs logged under their own name, with their meaning
    # (any other output is logged as ``controller_<port>``), and outputs not
    # logged at all.
    signals: dict = dc.field(default_factory=dict)
    unlogged: tuple = ()
    # A controller: ranked by ``drake-contact benchmark`` unless asked not
    # to be (test harnesses).
    contender: bool = True
    # An identifier: its options also carry the run's ``seed``.
    seeded: bool = False
    # A controller or an identifier: its factory also takes a list of N
    # options mappings (one per environment of an ensemble, sharing a
    # structure; an identifier's each with its environment's ``seed`` if
    # seeded) and returns one system serving all N, every port N times its
    # size, environment i's values at [k i, k (i + 1))
    # (drake_contact.diagram.MakeEnsembleDiagram, and for identifiers
    # drake_contact.identification.identifiers.AddIdentifiers). Without it
    # an ensemble runs one system per environment.
    ensemble: bool = False
    # A plug-in that declares ``ensemble``: what one environment's options
    # mapping switches on, {field: value} (hashable values), which an
    # ensemble's environments share while their numbers differ; the
    # structure key (drake_contact.structure.ensemble_structure) carries it,
    # so environments that differ in it never share an ensemble.
    structure: Callable | None = None


def declare(**fields):
    """Decorates a factory with its :class:`Declaration`, made from
    ``fields``::

        @declare(check_options=typed_options(MyConfig, "controller.options"))
        def make_controller(options: dict) -> System: ...
    """
    declaration = Declaration(**fields)

    def mark(factory):
        factory.declaration = declaration
        return factory
    return mark


def typed_options(schema, prefix: str) -> Callable:
    """An options check: the mapping must hold fields of the dataclass
    ``schema`` of their types, and pass its ``validate`` (errors name
    ``prefix.<field>``)."""
    return lambda options: config_from_options(schema, options, prefix)


def controller_declaration(name: str, field="controller.name") -> Declaration:
    """The installed controller ``name``'s declaration (ScenarioError if it
    is not installed or does not load)."""
    return _declaration(_load(installed_controllers(), "controller", name, field)[0])


def identifier_declaration(kind: str, field="identifiers[0].kind") -> Declaration:
    """The installed identifier ``kind``'s declaration."""
    return _declaration(_load(installed_identifiers(), "identifier", kind, field)[0])


def configured_options(entry, declared: Declaration) -> dict:
    """The options mapping a factory gets from its scenario ``entry`` (a
    ControllerConfig or IdentifierConfig): its declared section's fields,
    {section: fields} for several, else ``entry.options``."""
    if len(declared.sections) == 1:
        return dc.asdict(getattr(entry, declared.sections[0]))
    if declared.sections:
        return {section: dc.asdict(getattr(entry, section)) for section in declared.sections}
    return dict(entry.options)


def check_configuration(entry, declared: Declaration, prefix: str, what: str):
    """Validates what configures a scenario ``entry``'s factory: its declared
    sections (options then refused), else its options (names to values,
    then the declared check)."""
    if declared.sections:
        if entry.options:
            sections = " and ".join(f"{prefix}.{section}" for section in declared.sections)
            raise ScenarioError(f"{prefix}.options: the built-in '{what}' is configured by "
                                f"{sections}, not by options")
        for section in declared.sections:
            getattr(entry, section).validate(f"{prefix}.{section}")
    check_options_mapping(entry.options, f"{prefix}.options")
    if declared.check_options is not None:
        declared.check_options(dict(entry.options))


def check_options_mapping(options, prefix):
    """A plug-in's options: a mapping of names to numbers, strings, true or
    false, or lists of those."""
    if not isinstance(options, dict):
        raise ScenarioError(f"{prefix} must be a mapping of names to values, got {options!r}")
    scalar = (int, float, str, bool)
    for key, value in options.items():
        if not isinstance(key, str) or not key.isidentifier():
            raise ScenarioError(f"{prefix}: option name {key!r} is not a valid name")
        if not (isinstance(value, scalar)
                or isinstance(value, list) and all(isinstance(v, scalar) for v in value)):
            raise ScenarioError(f"{prefix}.{key} = {value!r} must be a number, a string, "
                                "true/false or a list of those")


def installed_controllers() -> dict:
    """{name: entry point} of every controller installed (built-ins too)."""
    return dict(_installed(CONTROLLER_GROUP, tuple(sys.path)))


def installed_identifiers() -> dict:
    """{kind: entry point} of every identifier installed (built-ins too)."""
    return dict(_installed(IDENTIFIER_GROUP, tuple(sys.path)))


@functools.lru_cache(maxsize=16)
def _installed(group, path) -> dict:
    """The group's entry points as found on ``path``: scanning the installed
    distributions takes about 9 ms, and a scenario asks dozens of times
    while it loads and builds; a changed ``sys.path`` scans again."""
    return {ep.name: ep for ep in entry_points(group=group)}


def _one_line(e: Exception) -> str:
    text = str(e).strip().splitlines()
    return f"{type(e).__name__}: {text[0]}" if text else type(e).__name__


def _load(found, kind, name, field):
    """(factory, where) of an installed plug-in."""
    if name not in found:
        raise ScenarioError(f"{field} = '{name}' is not an installed {kind}"
                            f"{did_you_mean(name, found)}: choose one of "
                            f"{', '.join(sorted(found))}")
    where = f"{kind} '{name}' ({found[name].value})"
    try:
        factory = found[name].load()
    except Exception as e:  # a broken plug-in must not take the CLI down
        raise ScenarioError(f"{where} could not be loaded: {_one_line(e)}") from None
    return factory, where


def _declaration(factory) -> Declaration:
    found = getattr(factory, "declaration", None)
    return found if isinstance(found, Declaration) else Declaration()


def _build(found, kind, name, options, field):
    factory, where = _load(found, kind, name, field)
    try:
        system = factory([dict(o) for o in options] if isinstance(options, list)
                         else dict(options))
    except ScenarioError:
        raise
    except Exception as e:
        raise ScenarioError(f"{where} raised while being built: {_one_line(e)}") from None
    if not isinstance(system, System):
        raise ScenarioError(f"{where}: its factory returned a {type(system).__name__}, "
                            "not a Drake System")
    return system, where


def MakeController(name: str, options, *, prefix="controller", count=1) -> System:
    """Builds the installed controller ``name`` from ``options`` and checks
    its ports against :func:`controller_inputs` and
    :data:`CONTROLLER_REQUIRED_OUTPUTS`. Raises ScenarioError naming the
    plug-in if it is not installed, fails to load or build, or does not fit
    the station. With a list of ``count`` options mappings (a plug-in that
    declares ``ensemble``), one system serving ``count`` environments."""
    system, where = _build(installed_controllers(), "controller", name, options,
                           f"{prefix}.name")
    check_controller_ports(system, where, count)
    return system


def MakeIdentifier(kind: str, options, *, prefix="identifiers[0]", count=1) -> System:
    """Builds the installed identifier ``kind`` from ``options``; its inputs
    must be measured signals or ``contact_info`` (:func:`identifier_inputs`),
    and it must output ``impedance`` (3). Raises ScenarioError naming it
    otherwise. With a list of ``count`` options mappings (a plug-in that
    declares ``ensemble``), one system serving ``count`` environments, every
    port ``count`` times its size."""
    system, where = _build(installed_identifiers(), "identifier", kind, options,
                           f"{prefix}.kind")
    _check_ports(system, where, identifier_inputs(), IDENTIFIER_REQUIRED_OUTPUTS, count)
    return system


def check_controller_ports(system: System, where: str, count=1):
    """Raises ScenarioError unless every input of ``system`` is one the
    station provides, at its size (times ``count``, the environments it
    serves), and its required outputs exist."""
    _check_ports(system, where, controller_inputs(), CONTROLLER_REQUIRED_OUTPUTS, count)


def _check_ports(system: System, where: str, inputs: dict, outputs: dict, count=1):
    renamed = {m.role: name for name, m in MEASUREMENTS.items() if m.role != name}
    for i in range(system.num_input_ports()):
        port = system.get_input_port(i)
        name = port.get_name()
        if name not in inputs and renamed.get(name) in inputs:
            raise ScenarioError(
                f"{where}: input port '{name}' is the station signal '{renamed[name]}' (its log "
                f"key) since 2026-11-27: rename the port '{renamed[name]}'")
        if name not in inputs:
            raise ScenarioError(
                f"{where}: input port '{name}' is not a station signal: the station provides "
                f"{', '.join(inputs)}")
        size = inputs[name][0] * count
        if port.get_data_type() != PortDataType.kVectorValued or port.size() != size:
            raise ScenarioError(f"{where}: input port '{name}' must be a vector of size {size}")
    for name, (size, meaning) in outputs.items():
        size *= count
        if not system.HasOutputPort(name):
            raise ScenarioError(f"{where} has no output port '{name}' ({size}: {meaning})")
        port = system.GetOutputPort(name)
        if port.get_data_type() != PortDataType.kVectorValued or port.size() != size:
            raise ScenarioError(f"{where}: output port '{name}' must be a vector of size {size}")


@dc.dataclass
class ContactDetectorConfig:
    """When the station's contact detector says the tip is in contact."""

    # Contact from above this filtered force (N), lost below the other (N):
    # the hybrid controller's switch (thesis section 4.4).
    contact_threshold_n: float = CONTACT_THRESHOLD_N
    contact_loss_threshold_n: float = 0.0


class ContactDetectorLaw(LeafSystem):
    """The switch of :class:`ContactDetector` as one leaf: its output
    ``detected`` (5: [mode, first switch time or -1, x, y, phi at the
    switch]) is evaluated once per sample and held between samples."""

    def __init__(self, config: ContactDetectorConfig = ContactDetectorConfig()):
        super().__init__()
        self._config = config
        self._force = self.DeclareVectorInputPort("force", 1)
        self._pose = self.DeclareVectorInputPort("tip_pose", 3)
        self._held = self.DeclareDiscreteState([0.0, -1.0, 0.0, 0.0, 0.0])
        self._detected = self.DeclareVectorOutputPort(
            "detected", 5, self._calc, prerequisites_of_calc={
                self.all_input_ports_ticket(), self.xd_ticket(), self.time_ticket()})
        DeclareSampledUpdate(self, self._update)

    def _update(self, context, state):
        state.set_value(self._detected.Eval(context))

    def _calc(self, context, output: BasicVector):
        held = context.get_discrete_state(self._held).value()
        if not is_sample_time(context.get_time()):
            output.SetFromVector(held)
            return
        c = self._config
        f = self._force.Eval(context)[0]
        mode, first, *switch = held.tolist()
        if mode == 0.0 and f > c.contact_threshold_n:
            mode = 1.0
            if first < 0:
                first = context.get_time()
            switch = self._pose.Eval(context).tolist()
        elif mode == 1.0 and f < c.contact_loss_threshold_n:
            mode = 0.0
        output.SetFromVector([mode, first, *switch])


class ContactDetector(Diagram):
    """The station's own contact switch, for controllers that have no
    ``contact_info`` output: the same 5 N rule as the hybrid controller's
    switch, on the same filtered force, sampled every 1 ms.

    Inputs: ``force`` (1, N, filtered), ``tip_pose`` (3). Outputs (this
    sample's values, held between samples): ``mode`` (1: 0 no contact, 1
    contact) and ``contact_info`` (4: [time of the first switch (s) or -1,
    x, y, phi at the latest switch]), as the hybrid controller's. A
    sub-diagram: the law (one Python evaluation per sample) and a
    Demultiplexer that names its outputs."""

    def __init__(self, config: ContactDetectorConfig = ContactDetectorConfig()):
        super().__init__()
        builder = DiagramBuilder()
        law = builder.AddNamedSystem("law", ContactDetectorLaw(config))
        split = builder.AddNamedSystem("outputs", Demultiplexer([1, 4]))
        builder.Connect(law.get_output_port(), split.get_input_port())
        for name in ("force", "tip_pose"):
            builder.ExportInput(law.GetInputPort(name), name)
        builder.ExportOutput(split.get_output_port(0), "mode")
        builder.ExportOutput(split.get_output_port(1), "contact_info")
        builder.BuildInto(self)
