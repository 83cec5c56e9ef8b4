"""Builds the simulation diagram of one scenario: the contact station::

    controller --joint_torque_commanded--> [safety_supervisor] --> torque_saturation
      --> [drive faults] --> motors --> [dac] --> plant.actuation
    plant.state --> tip_kinematics --tip_state--> wall --force_on_tip--+
    plant.state --> joint_friction ------------------------------------+--> adder
    adder (J^T F_wall + tau_friction) --> plant.applied_generalized_force
    plant.state --> encoders (quantized q) --> estimator --> tip pose/velocity/acceleration
    wall.force_on_tip --> force_sensor (FS6-120A, analog on a 12 kHz grid) --> dsp --> force
    estimator, dsp (MeasuredSignals) --> controller, identifiers

[bracketed]: only when the scenario has ``safety.enabled`` or ``faults``
(drake_contact.faults: sensor faults sit in the DSP, encoder faults before
the estimator, environment faults before the wall), and the dac (the torque
held between samples) when the plant steps finer than 1 ms.

Timing (plant/arm.py): at each 1 ms sample t_n the plant's step and every
discrete update are computed from the one Context at t_n, so every sampled
system reads what the sensing computes from the plant's state at t_n, and the
torque it computes from that acts from t_n.

:func:`MakeContactDiagram` returns a :class:`ContactStation`: a Drake Diagram
whose exported output ports are its signals, each documented in
``station.signals`` (name -> :class:`Signal`: size, meaning, and the log keys
it is logged under). A new signal is one ``signals.export(...)`` line here.
"""

import dataclasses as dc
import functools
import re
import zlib

import numpy as np
from pydrake.common import RandomGenerator
from pydrake.systems.framework import Diagram, DiagramBuilder, PortDataType
from pydrake.systems.primitives import (
    Adder, ConstantVectorSource, Demultiplexer, MatrixGain, Multiplexer, RandomSource,
    SymbolicVectorSystem)
from pydrake.symbolic import Variable, floor, if_then_else

from drake_contact.arm_axis import LinearSystemBank, StackedSymbolicSystem
from drake_contact.control.force_reference import ForceReference
from drake_contact.control.safety_supervisor import (
    SAFETY_STATES, STOP_REASONS, SafetySupervisor)
from drake_contact.errors import ScenarioError
from drake_contact.faults import ChainFaults, FaultClock
from drake_contact.identification.identifiers import AddIdentifiers
from drake_contact.measured import MEASUREMENTS, MeasuredSignals
from drake_contact.plant.arm import (
    CONTROL_PERIOD, TIME_TOLERANCE_S, AddArmPlant, MakeArmModel, arm_instances)
from drake_contact.plant.compliant_wall import CompliantWall
from drake_contact.plant.joint_physics import (
    AddEncoders, AddJointFriction, AddTorqueSaturation, check_friction_stability,
    encoder_reading)
from drake_contact.plant.tip_kinematics import TipKinematics
from drake_contact.plugins import ContactDetector, MakeController, controller_declaration
from drake_contact.scenario import Scenario
from drake_contact.sensing.dsp import AddDspForceInput
from drake_contact.sensing.estimator import AddKinematicEstimator
from drake_contact.sensing.force_sensor import AddForceSensor
from drake_contact.structure import check_ensemble_structure


@dc.dataclass(frozen=True)
class Signal:
    """One exported output of the station."""

    # Vector size.
    size: int
    # What it is, with units and frame.
    meaning: str
    # Log keys it is logged under: {key: column slice or index}. Empty: not
    # logged (e.g. the SceneGraph's query object).
    log_as: dict


class _Signals:
    """Collects one environment's exports: one call documents and logs a
    signal (:func:`_export_envs` exports them)."""

    def __init__(self):
        self.exported = {}

    def export(self, name, port, meaning, *, log_as=None, log=True):
        """Exports ``port`` as ``name``; logs it under ``name`` (a size-1
        port as a 1-D log), or under the keys of ``log_as``."""
        if log_as is None:
            log_as = {name: 0 if port.size() == 1 else slice(0, port.size())} if log else {}
        self.exported[name] = (port, meaning, dict(log_as))


class ContactStation(Diagram):
    """The contact diagram of one scenario, or of an ensemble of N
    environments (built by :func:`MakeContactDiagram` or
    :func:`MakeEnsembleDiagram`).

    ``scenarios`` are the environments' scenarios, in the arm axis's order
    (``scenario`` is the first, the only one of a one-environment station);
    ``signals`` maps each exported output port's name to its
    :class:`Signal`, whose size is one environment's: the port carries
    ``num_envs`` of them, environment i's at ``[size * i, size * (i + 1))``.
    Everything that evolves lives in the Context, as in any Diagram."""

    def __init__(self, scenarios, signals: dict):
        super().__init__()
        self.scenarios = list(scenarios)
        self.scenario = self.scenarios[0]
        self.num_envs = len(self.scenarios)
        self.signals = signals


class _Env:
    """Environment ``index``'s view of the station's builder: adds its
    systems as ``<name>@<index>`` (as ``<name>`` in a one-environment
    station) and connects like the DiagramBuilder it wraps."""

    def __init__(self, builder, index: int, count: int):
        self.builder, self.index, self.count = builder, index, count

    def name(self, name: str) -> str:
        return name if self.count == 1 else f"{name}@{self.index}"

    def AddNamedSystem(self, name, system):
        return self.builder.AddNamedSystem(self.name(name), system)

    def AddSystem(self, system):
        system.set_name(self.name(system.get_name()))
        return self.builder.AddSystem(system)

    def Connect(self, source, destination):
        self.builder.Connect(source, destination)


class _Wiring:
    """The station's DiagramBuilder, for systems that serve all N
    environments at once: environment i wires to a shared system through
    its views (:meth:`roles`), and the wiring connects shared systems to
    one another directly when every environment's connection runs between
    the same two ports in the arm axis's order; otherwise a Demultiplexer
    splits a shared output (made when an environment first needs its
    part) and a Multiplexer gathers a shared input (at :meth:`finish`).
    Every other call goes to the builder."""

    def __init__(self, builder, count):
        self.builder, self.count = builder, count
        self._axes, self._gathers = {}, []

    def __getattr__(self, name):
        return getattr(self.builder, name)

    def roles(self, name, system):
        """``system`` added as ``name`` (``None``: already added) to serve
        all environments; returns each environment's view of it (the
        system itself in a one-environment station)."""
        if name is not None:
            system = self.builder.AddNamedSystem(name, system)
        if self.count == 1:
            return [system]
        return [_Role(self, system, i) for i in range(self.count)]

    def axis(self, port):
        """The arm-axis output ``port`` (each environment's views come from it)."""
        key = (id(port.get_system()), int(port.get_index()))
        if key not in self._axes:
            self._axes[key] = _Axis(self, port)
        return self._axes[key]

    def gather(self, port):
        """The arm-axis input ``port``, fed environment by environment."""
        key = (id(port.get_system()), int(port.get_index()))
        found = [g for g in self._gathers if g.key == key]
        if found:
            return found[0]
        gather = _Gather(self, port, key)
        self._gathers.append(gather)
        return gather

    def resolve(self, source):
        return source.whole.split(source.index) if _is_output_part(source) else source

    def Connect(self, source, destination):
        if isinstance(destination, _Part):
            destination.whole.sources[destination.index] = source
        else:
            self.builder.Connect(self.resolve(source), destination)

    def ExportOutput(self, source, name):
        return self.builder.ExportOutput(self.resolve(source), name)

    def combined(self, sources, name):
        """One output port carrying ``sources`` (one per environment, in
        order): their shared system's own port when they are its views in
        order, else a Multiplexer ``name`` of them."""
        first = sources[0]
        if (_is_output_part(first) and len(sources) == first.whole.count
                and all(_is_output_part(s) and s.whole is first.whole and s.index == i
                        for i, s in enumerate(sources))):
            return first.whole.port
        mux = self.builder.AddNamedSystem(name, Multiplexer([first.size()] * len(sources)))
        for i, source in enumerate(sources):
            self.builder.Connect(self.resolve(source), mux.get_input_port(i))
        return mux.get_output_port()

    def finish(self):
        """Connects every shared input its environments fed."""
        for gather in self._gathers:
            fed = [s for s in gather.sources if s is not None]
            if not fed:
                continue
            if len(fed) != len(gather.sources):
                raise ScenarioError(f"input '{gather.port.get_name()}' of a shared system is "
                                    "fed in some environments only: they must share a structure")
            self.builder.Connect(self.combined(gather.sources, gather.name), gather.port)


class _Axis:
    """An output port carrying N environments' values (environment i's
    ``size`` values at ``[size i, size (i + 1))``)."""

    def __init__(self, wiring, port):
        self.wiring, self.port, self.count = wiring, port, wiring.count
        self.size = port.size() // self.count
        self._split = None

    def split(self, index):
        if self._split is None:
            name = f"{self.port.get_system().get_name()}_{self.port.get_name()}_envs"
            self._split = self.wiring.builder.AddNamedSystem(
                name, Demultiplexer([self.size] * self.count))
            self.wiring.builder.Connect(self.port, self._split.get_input_port())
        return self._split.get_output_port(index)


class _Part:
    """Environment ``index``'s part of an arm-axis port (an :class:`_Axis`
    or a :class:`_Gather`)."""

    def __init__(self, whole, index):
        self.whole, self.index = whole, index

    def size(self):
        return self.whole.size


def _is_output_part(port):
    return isinstance(port, _Part) and isinstance(port.whole, _Axis)


class _Gather:
    """An input port carrying N environments' values, fed one by one."""

    def __init__(self, wiring, port, key):
        self.port, self.key = port, key
        self.sources = [None] * wiring.count
        self.size = port.size() // wiring.count
        self.name = f"{port.get_system().get_name()}_{port.get_name()}_envs"


class _Role:
    """Environment ``index``'s view of a system serving all environments:
    its ports by name, as the system's own for one environment."""

    def __init__(self, wiring, system, index):
        self._wiring, self._system, self._index = wiring, system, index

    def GetOutputPort(self, name):
        return _Part(self._wiring.axis(self._system.GetOutputPort(name)), self._index)

    def GetInputPort(self, name):
        return _Part(self._wiring.gather(self._system.GetInputPort(name)), self._index)

    def get_output_port(self):
        return _Part(self._wiring.axis(self._system.get_output_port()), self._index)

    def get_input_port(self):
        return _Part(self._wiring.gather(self._system.get_input_port()), self._index)

    def HasOutputPort(self, name):
        return self._system.HasOutputPort(name)

    def HasInputPort(self, name):
        return self._system.HasInputPort(name)

    def input_ports(self):
        return {name: self.GetInputPort(name) for name in _input_ports(self._system)}

    def vector_outputs(self):
        return {name: self.GetOutputPort(name) for name in _vector_outputs(self._system)}


def _inputs_of(role):
    return role.input_ports() if isinstance(role, _Role) else _input_ports(role)


def _outputs_of(role):
    return role.vector_outputs() if isinstance(role, _Role) else _vector_outputs(role)


def _input_ports(system):
    return {system.get_input_port(i).get_name(): system.get_input_port(i)
            for i in range(system.num_input_ports())}


def _vector_outputs(system):
    return {system.get_output_port(i).get_name(): system.get_output_port(i)
            for i in range(system.num_output_ports())
            if system.get_output_port(i).get_data_type() == PortDataType.kVectorValued}


def SampleHold(period_s, size, time_step, count=1):
    """The DAC: a vector input (``size`` elements for each of ``count``
    environments) passed through at each 1 kHz sample instant and held from
    there until the next, for a plant that steps ``time_step`` <
    ``period_s``. Updated at the plant's step (so its events fall with the
    plant's); a ``SymbolicVectorSystem`` for one environment."""
    pieces = []
    for _ in range(count):
        t = Variable("t")
        u = [Variable(f"u{i}") for i in range(size)]
        held = [Variable(f"held{i}") for i in range(size)]
        at_sample = abs(t - floor(t / period_s + 0.5) * period_s) <= TIME_TOLERANCE_S
        passed = [if_then_else(at_sample, a, b) for a, b in zip(u, held)]
        pieces.append({"time": t, "state": held, "input": u, "dynamics": passed,
                       "output": passed})
    return StackedSymbolicSystem(pieces, time_period=time_step)


def _add_controller(builder, scenarios, states, measured):
    """Adds the scenarios' controller (:func:`drake_contact.plugins.MakeController`)
    as ``controller`` (one system for all environments when its plug-in
    declares ``ensemble``, else one per environment), the force reference
    if it reads ``force_desired``, and the station's contact detector if it
    has no ``contact_info`` but something needs one; connects every input by
    name. ``states``: each environment's plant state port; ``measured``:
    each one's MeasuredSignals. Returns (the controller's systems, per
    environment {input name: port}, {signal name: output port} of what the
    station exports from it)."""
    scenario = scenarios[0]
    config = scenario.controller
    declared = controller_declaration(config.name)
    options = [s.controller.factory_options() for s in scenarios]
    count = len(scenarios)
    if count > 1 and declared.ensemble:
        systems = [MakeController(config.name, options, count=count)]
        roles = builder.roles("controller", systems[0])
    else:
        systems = roles = [builder.AddNamedSystem("controller" if count == 1 else f"controller@{i}",
                                                  MakeController(config.name, o))
                           for i, o in enumerate(options)]
    inputs = [_inputs_of(r) for r in roles]
    ports = [_outputs_of(r) for r in roles]
    sources = [dict(m.items()) | {"plant_state": state} for m, state in zip(measured, states)]
    contact = [p.get("contact_info") for p in ports]
    if "contact_info" not in ports[0] and ("force_desired" in inputs[0] or scenario.identifiers):
        detectors = [builder.AddNamedSystem(
            "contact_detector" if count == 1 else f"contact_detector@{i}", ContactDetector())
            for i in range(count)]
        for detector, m, p in zip(detectors, measured, ports):
            builder.Connect(m.force_filtered, detector.GetInputPort("force"))
            builder.Connect(m.tip_pose_measured, detector.GetInputPort("tip_pose"))
            p["mode"] = detector.GetOutputPort("mode")
        contact = [d.GetOutputPort("contact_info") for d in detectors]
    if "force_desired" in inputs[0]:
        configs = [s.force_reference for s in scenarios]
        references = builder.roles("force_reference",
                                   ForceReference(configs if count > 1 else configs[0]))
        for reference, c, source, p in zip(references, contact, sources, ports):
            builder.Connect(c, reference.GetInputPort("contact_info"))
            source["force_desired"] = p["force_desired"] = reference.GetOutputPort(
                "force_desired")
    for own, source in zip(inputs, sources):
        for name, port in own.items():
            if name in source:
                builder.Connect(source[name], port)
            elif name in STATION_ACTION_INPUTS:
                if count > 1:
                    raise ScenarioError(f"controller '{config.name}' reads {name} from outside "
                                        "the station: an ensemble cannot export it")
                builder.ExportInput(port, name)
    # impedance_estimate is connected once the identifiers exist.
    for p, c in zip(ports, contact):
        if c is not None:
            p["contact_info"] = c
    return systems, inputs, ports


#: Controller inputs the station exports as its own input ports, under the
#: same name: a policy's action, set from outside the station (the
#: Gymnasium environment fixes it at each of its steps).
STATION_ACTION_INPUTS = ("policy_action",)


#: Controller outputs the station exports under their own names when a
#: controller has them (a controller declares more in its ``signals``).
CONTROLLER_SIGNALS = {
    "mode": "controller mode: 0 approach, 1 contact",
    "force_desired": "desired normal force f_d (N)",
    "contact_info": "[first switch time (s) or -1, x, y, phi at the switch] (s, m, rad)",
}


#: The same signals when the station's ContactDetector makes them.
DETECTOR_SIGNALS = {
    "mode": "the station's contact detector: 1 from filtered force > 5 N, 0 below 0 N",
    "contact_info": "the detector's [first switch time (s) or -1, x, y, phi at the switch] "
                    "(s, m, rad)",
}


def _add_arms(builder, scenarios, shared):
    """The plant with one arm per environment (:func:`AddArmPlant`); returns
    (plant, scene_graph, each environment's plant state port [q; v] (6),
    its actuation port (3), its joints' inertias (M's diagonal at q0)).
    With ``shared`` (an ensemble whose roles serve all environments), the
    state ports are views of one port of every arm's [q; v] in turn, and
    the actuation ports are parts of the plant's whole actuation input."""
    plant, scene_graph = AddArmPlant(builder.builder, [s.arm for s in scenarios])
    inertias = np.diag(plant.CalcMassMatrix(plant.CreateDefaultContext()))
    if len(scenarios) == 1:
        return (plant, scene_graph, [plant.get_state_output_port()],
                [plant.get_actuation_input_port()], [inertias])
    arms = arm_instances(plant)
    states = [plant.get_state_output_port(arm) for arm in arms]
    inertias = [inertias[3 * i:3 * i + 3] for i in range(len(arms))]
    if not shared:
        return (plant, scene_graph, states,
                [plant.get_actuation_input_port(arm) for arm in arms], inertias)
    # Each arm's actuators follow the previous arm's (AddArmPlant adds them
    # in turn): the whole input is environment-major.
    axis = builder.axis(builder.combined(states, "plant_state_envs"))
    actuation = builder.gather(plant.get_actuation_input_port())
    return (plant, scene_graph, [_Part(axis, i) for i in range(len(arms))],
            [_Part(actuation, i) for i in range(len(arms))], inertias)


@dc.dataclass
class _Physics:
    """One environment's true physics around its arm: the tip kinematics,
    the wall (behind its environment faults), the joint friction, its faults'
    ports, and the torque the wall and the friction put on the joints."""

    tip: object
    wall: object
    friction: object
    faults: object
    external: object


def _one_or_all(items):
    """The one item of a one-environment station, else the list (the
    constructors of the systems that serve all environments take both)."""
    return items[0] if len(items) == 1 else items


def _add_physics(builder, envs, scenarios, states, inertias, shared) -> list:
    """The tip kinematics, the wall (behind the scenario's environment
    faults) and the joint friction of every arm, wired to its state port:
    with ``shared``, one system per role for all arms."""
    count = len(scenarios)
    for scenario, m in zip(scenarios, inertias):
        check_friction_stability(scenario.joint_friction, m, scenario.arm.time_step)
    h = scenarios[0].arm.time_step
    scale_input = [any(f.signal == "stiffness" for f in s.faults) for s in scenarios]
    if shared:
        tips = builder.roles("tip_kinematics", TipKinematics(_kinematics_model(), count))
        walls = builder.roles("wall", CompliantWall(
            _one_or_all([s.environment for s in scenarios]), h,
            stiffness_scale_input=scale_input[0]))
        frictions = builder.roles(None, AddJointFriction(
            builder, _one_or_all([s.joint_friction for s in scenarios]),
            mass_matrix_diagonal=np.concatenate(inertias), time_step=h))
        externals = builder.roles("external_torque", Adder(2, 3 * count))
    else:
        tips = [env.AddNamedSystem("tip_kinematics", TipKinematics(_kinematics_model()))
                for env in envs]
        walls = [env.AddNamedSystem("wall", CompliantWall(
            s.environment, h, stiffness_scale_input=scale))
            for env, s, scale in zip(envs, scenarios, scale_input)]
        frictions = [AddJointFriction(env, s.joint_friction, mass_matrix_diagonal=m,
                                      time_step=h)
                     for env, s, m in zip(envs, scenarios, inertias)]
        externals = [env.AddNamedSystem("external_torque", Adder(2, 3)) for env in envs]
    out = []
    for env, scenario, state, tip, wall, friction, external in zip(
            envs, scenarios, states, tips, walls, frictions, externals):
        env.Connect(state, tip.GetInputPort("plant_state"))
        env.Connect(wall.GetOutputPort("force_on_tip"), tip.GetInputPort("force_on_tip"))
        faults = scenario.faults
        if faults:
            # The faults' clock reads the true contact force; the wall's own
            # inputs may be corrupted (environment faults).
            clock = env.AddNamedSystem("fault_clock", FaultClock())
            env.Connect(wall.GetOutputPort("contact_force"), clock.get_input_port())
            clock = clock.get_output_port()
            surface, active = ChainFaults(env, faults, "surface",
                                          tip.GetOutputPort("tip_state"), 6, clock)
            env.Connect(surface, wall.GetInputPort("tip_state"))
            if wall.HasInputPort("stiffness_scale"):
                one = env.AddNamedSystem("stiffness_nominal", ConstantVectorSource([1.0]))
                scale, more = ChainFaults(env, faults, "stiffness", one.get_output_port(), 1,
                                          clock)
                env.Connect(scale, wall.GetInputPort("stiffness_scale"))
                active |= more
        else:
            clock, active = None, {}
            env.Connect(tip.GetOutputPort("tip_state"), wall.GetInputPort("tip_state"))
        env.Connect(state, friction.GetInputPort("plant_state"))
        env.Connect(tip.GetOutputPort("generalized_force"), external.GetInputPort("u0"))
        env.Connect(friction.GetOutputPort("torque"), external.GetInputPort("u1"))
        out.append(_Physics(tip, wall, friction, _FaultPorts(clock, active),
                            external.GetOutputPort("sum")))
    return out


@functools.cache
def _kinematics_model():
    """The arm's standalone model, against which the tip kinematics' closed
    forms are checked (made once)."""
    return MakeArmModel()


def _apply_to_arms(builder, plant, ports, shared):
    """Feeds each environment's joint torque port (3) into the plant's
    applied generalized force, in the arms' order (in an ensemble, through
    :func:`FiniteGuard`)."""
    count = len(ports)
    if count == 1:
        builder.Connect(ports[0], plant.get_applied_generalized_force_input_port())
        return
    if shared:
        guard = FiniteGuard(3, count)
        for port, role in zip(ports, builder.roles("external_torque_guard", guard)):
            builder.Connect(port, role.get_input_port())
        builder.Connect(guard.get_output_port(), plant.get_applied_generalized_force_input_port())
        return
    mux = builder.AddNamedSystem("external_torque_arms", Multiplexer([3] * count))
    for i, port in enumerate(ports):
        guard = builder.AddNamedSystem(f"external_torque_guard@{i}", FiniteGuard(3))
        builder.Connect(port, guard.get_input_port())
        builder.Connect(guard.get_output_port(), mux.get_input_port(i))
    builder.Connect(mux.get_output_port(), plant.get_applied_generalized_force_input_port())


def FiniteGuard(size, count=1):
    """u where it is finite, else 0, element by element (``size`` elements
    for each of ``count`` environments): in an ensemble, between each
    environment and the plant, whose every input must be finite (the plant
    stops the whole simulation on a NaN), so that one diverging environment
    does not stop the others. The runner reports that environment as
    diverged from its logs. Stateless."""
    pieces = []
    for _ in range(count):
        u = [Variable(f"u{i}") for i in range(size)]
        pieces.append({"input": u,
                       "output": [if_then_else(abs(x) < np.inf, x, 0.0) for x in u]})
    return StackedSymbolicSystem(pieces)


@dc.dataclass
class _FaultPorts:
    """The FaultClock's output (None without faults) and each fault's
    ``active`` output port by its index in the scenario."""

    clock: object
    active: dict


def MakeFloorDiagram(scenario: Scenario, joint_torque=(4.0, 0.0, 0.0)):
    """The speed floor: the plant, the wall and the joint physics only, with a
    constant motor torque (N m) and no sensors or controller. Exports
    ``contact_force_true``."""
    scenario.validate()
    builder = _Wiring(DiagramBuilder(), 1)
    plant, _, states, _, inertias = _add_arms(builder, [scenario], True)
    (physics,) = _add_physics(builder, [_Env(builder, 0, 1)], [scenario], states, inertias, True)
    _apply_to_arms(builder, plant, [physics.external], True)
    torque = builder.AddNamedSystem("joint_torque", ConstantVectorSource(list(joint_torque)))
    builder.Connect(torque.get_output_port(), plant.get_actuation_input_port())
    builder.ExportOutput(physics.wall.GetOutputPort("contact_force"), "contact_force_true")
    diagram = builder.Build()
    diagram.set_name("floor_diagram")
    return diagram


def MakeContactDiagram(scenario: Scenario) -> ContactStation:
    """The arm, its joint physics, the wall, the sensors, the scenario's
    controller and identifiers.

    Returns a :class:`ContactStation` named ``station`` whose output ports
    are listed, with sizes and meanings, in its ``signals``; ``query_object``
    (the SceneGraph's, for a visualizer) is exported too. Raises
    ScenarioError for settings that cannot run (e.g. friction regularization
    unstable at the plant step). Its noise is seeded by :func:`SeedNoise`.
    """
    return MakeEnsembleDiagram([scenario])


def MakeEnsembleDiagram(scenarios) -> ContactStation:
    """N environments in one station: one plant holding N arms, and each
    role of :func:`MakeContactDiagram` serving all N, every output port
    carrying an arm axis (environment i's values at ``[k i, k (i + 1))``,
    k its size in ``signals``).

    Each environment has its own scenario (wall, noise seed, gains, faults,
    ...); they must share a structure
    (:func:`drake_contact.structure.ensemble_structure`: the plant step, the
    controller and what its plug-in switches on, the identifiers, the safety
    supervisor, the number of faults, ...), checked before anything is
    built: a ScenarioError names the first environment and field that
    differ. A role whose system serves N
    environments at once (the force sensor, the force reference, and a
    controller whose plug-in declares ``ensemble``) is one system; any other
    is one system per environment (named ``<name>@<i>``), Drake's C++
    systems included. Environment i gives, bit for bit, the logs of
    :func:`MakeContactDiagram` of its scenario, seeded alike
    (:func:`SeedNoise`). One scenario gives the one-environment station."""
    scenarios = list(scenarios)
    if not scenarios:
        raise ScenarioError("an ensemble needs at least one scenario")
    for scenario in scenarios:
        scenario.validate()
    check_ensemble_structure(scenarios)
    count = len(scenarios)
    # Every role serves all environments at once, except around faults,
    # which chain per environment between the roles.
    shared = count == 1 or not any(s.faults for s in scenarios)
    builder = _Wiring(DiagramBuilder(), count)
    envs = [_Env(builder, i, count) for i in range(count)]
    plant, scene_graph, states, actuation, inertias = _add_arms(builder, scenarios, shared)
    physics = _add_physics(builder, envs, scenarios, states, inertias, shared)
    _apply_to_arms(builder, plant, [p.external for p in physics], shared)
    sensing = _add_sensing(builder, envs, scenarios, states, physics, shared)
    control = _add_control(builder, envs, scenarios, states, sensing, physics, actuation, shared)
    exports = []
    for env, scenario, state, p, sensed, controlled in zip(
            envs, scenarios, states, physics, sensing, control):
        signals = _Signals()
        _export_physics(signals.export, state, p.tip, p.wall)
        _export_sensing_and_control(signals.export, scenario, sensed, controlled, p.friction)
        _export_faults(signals.export, env, scenario, p.faults)
        exports.append(signals.exported)
    signals = _export_envs(builder, exports)
    builder.ExportOutput(scene_graph.get_query_output_port(), "query_object")
    signals["query_object"] = Signal(0, "the SceneGraph's query object (for visualizers)", {})
    builder.finish()
    station = ContactStation(scenarios, signals)
    builder.BuildInto(station)
    station.set_name("station")
    _check_unique_noise_names(station)
    return station


def _export_envs(builder, exports):
    """Exports each signal of the environments' ``exports`` (per
    environment {name: (port, meaning, log_as)}) as one port carrying all of
    them; returns the station's ``signals``."""
    signals = {}
    for i, exported in enumerate(exports[1:], start=1):
        # The structure key should make this impossible; a plug-in whose
        # options change its ports without declaring its structure cannot
        # lose an environment's signal silently either.
        if set(exported) != set(exports[0]):
            name = sorted(set(exported) ^ set(exports[0]))[0]
            raise ScenarioError(f"the ensemble's environments differ in the signal '{name}' "
                                f"(environment {i} and environment 0): they must share a "
                                "structure")
    for name, (port, meaning, log_as) in exports[0].items():
        ports = [exported[name][0] for exported in exports]
        if len(ports) > 1:
            port = builder.combined(ports, f"{name}_envs")
        builder.ExportOutput(port, name)
        signals[name] = Signal(ports[0].size(), meaning, dict(log_as))
    return signals


@dc.dataclass
class _Sensing:
    """The sensors' ports: the encoders' counts after any encoder fault, the
    DSP sub-diagram, and what the sampled systems read."""

    counted: object
    dsp: object
    measured: MeasuredSignals


def _add_sensing(builder, envs, scenarios, states, physics, shared) -> list:
    """The encoders and the kinematic estimator, the force sensor and the
    DSP of every environment, with the faults on their signals; with
    ``shared``, one system per role for all environments (the DSP too when
    no environment's anti-aliasing filter is in)."""
    count = len(scenarios)
    zeros = [s.arm.initial_positions for s in scenarios]
    readings = [encoder_reading(s.encoders, q0) for s, q0 in zip(scenarios, zeros)]
    if shared:
        encoders = builder.roles(None, AddEncoders(
            builder, _one_or_all([s.encoders for s in scenarios]), zeros))
        estimators = builder.roles(None, AddKinematicEstimator(
            builder, _kinematics_model(), _one_or_all([s.estimator for s in scenarios]),
            readings))
    else:
        encoders = [AddEncoders(env, s.encoders, q0) for env, s, q0 in zip(envs, scenarios, zeros)]
        estimators = [AddKinematicEstimator(env, _kinematics_model(), s.estimator, reading)
                      for env, s, reading in zip(envs, scenarios, readings)]
    counted = []
    for env, scenario, state, p, encoder, estimator in zip(
            envs, scenarios, states, physics, encoders, estimators):
        env.Connect(state, encoder.GetInputPort("plant_state"))
        port = encoder.GetOutputPort("joint_positions_measured")
        if p.faults.clock is not None:
            port, active = ChainFaults(
                env, scenario.faults, "encoders", port, 3, p.faults.clock,
                counts_per_revolution=scenario.encoders.counts_per_revolution)
            p.faults.active |= active
        env.Connect(port, estimator.GetInputPort("joint_positions_measured"))
        counted.append(port)

    configs = [s.force_sensor for s in scenarios]
    sensors = builder.roles(None, AddForceSensor(builder, _one_or_all(configs)))
    ticks = sensors[0].GetOutputPort("voltage_frame").size()
    fine_period = scenarios[0].force_sensor.fine_period
    if shared and (count == 1 or all(s.dsp.anti_aliasing.mode == "off" for s in scenarios)):
        dsps = builder.roles(None, AddDspForceInput(
            builder, _one_or_all([s.dsp for s in scenarios]), fine_period, ticks,
            faults=scenarios[0].faults))
    else:
        dsps = [AddDspForceInput(env, s.dsp, fine_period, ticks, faults=s.faults)
                for env, s in zip(envs, scenarios)]
    out = []
    for env, scenario, p, sensor, dsp, port, estimator in zip(
            envs, scenarios, physics, sensors, dsps, counted, estimators):
        env.Connect(p.wall.GetOutputPort("force_on_tip"), sensor.GetInputPort("wrench"))
        env.Connect(p.tip.GetOutputPort("tip_state"), sensor.GetInputPort("tip_state"))
        faults = p.faults
        if dsp.HasInputPort("contact_time"):
            env.Connect(faults.clock, dsp.GetInputPort("contact_time"))
            faults.active |= {i: dsp.GetOutputPort(f"fault_active_{i}")
                              for i, f in enumerate(scenario.faults) if f.signal == "force"}
        env.Connect(sensor.GetOutputPort("voltage"), dsp.GetInputPort("voltage"))
        if dsp.HasInputPort("voltage_frame"):
            env.Connect(sensor.GetOutputPort("voltage_frame"), dsp.GetInputPort("voltage_frame"))
        blocks = {"estimator": estimator, "dsp": dsp}
        measured = MeasuredSignals(**{name: blocks[m.source].GetOutputPort(m.port)
                                      for name, m in MEASUREMENTS.items()})
        out.append(_Sensing(port, dsp, measured))
    return out


@dc.dataclass
class _Control:
    """One environment's control side: the controller's output ports by
    name, its identifiers and supervisor (None when absent), the torque the
    controller commands and the one the plant gets, and whether the
    station's contact detector (not the controller) says the mode."""

    outputs: dict
    identifiers: object
    supervisor: object
    torque: object
    applied: object
    detected: bool


def _add_control(builder, envs, scenarios, states, sensing, physics, actuation, shared) -> list:
    """The controller, the identifiers, the safety supervisor, the torque
    limits, any drive faults, the motors and (for a plant step under 1 ms)
    the DAC's hold of every environment, wired from its measured signals to
    its arm's actuation; with ``shared``, one torque limit, motor, DAC and
    guard system for all environments."""
    count = len(scenarios)
    measured = [s.measured for s in sensing]
    systems, inputs, outputs = _add_controller(builder, scenarios, states, measured)
    detected = not systems[0].HasOutputPort("contact_info")
    h = scenarios[0].arm.time_step
    if shared:
        saturations = builder.roles(None, AddTorqueSaturation(
            builder, np.concatenate([s.torque_limits for s in scenarios])))
        gains = [MatrixGain(np.diag(s.arm.motor_torque_scale)) for s in scenarios]
        motors = builder.roles("motors", _one_or_all(gains) if count == 1
                               else LinearSystemBank(gains))
        dacs = (builder.roles("dac", SampleHold(CONTROL_PERIOD, 3, h, count))
                if h < CONTROL_PERIOD else [None] * count)
        guards = (builder.roles("actuation_guard", FiniteGuard(3, count)) if count > 1
                  else [None])
    else:
        saturations = [AddTorqueSaturation(env, s.torque_limits) for env, s in zip(envs, scenarios)]
        motors = [env.AddNamedSystem("motors", MatrixGain(np.diag(s.arm.motor_torque_scale)))
                  for env, s in zip(envs, scenarios)]
        dacs = [env.AddNamedSystem("dac", SampleHold(CONTROL_PERIOD, 3, h))
                if h < CONTROL_PERIOD else None for env in envs]
        guards = [env.AddNamedSystem("actuation_guard", FiniteGuard(3)) for env in envs]
    if shared and scenarios[0].identifiers:
        identifier_roles = builder.roles(None, AddIdentifiers(builder, _one_or_all(scenarios)))
    else:
        identifier_roles = [AddIdentifiers(env, s) if s.identifiers else None
                            for env, s in zip(envs, scenarios)]
    out = []
    for (env, scenario, own, controller, m, p, arm, saturation, motor, dac, guard,
         identifiers) in zip(envs, scenarios, inputs, outputs, measured, physics, actuation,
                             saturations, motors, dacs, guards, identifier_roles):
        torque = controller["joint_torque_commanded"]
        if identifiers is not None:
            for name, port in m.items():
                if identifiers.HasInputPort(MEASUREMENTS[name].role):
                    env.Connect(port, identifiers.GetInputPort(MEASUREMENTS[name].role))
            if identifiers.HasInputPort("contact_info"):
                env.Connect(controller["contact_info"], identifiers.GetInputPort("contact_info"))
        if "impedance_estimate" in own:
            source = scenario.controller.impedance_source_name()
            if not source:
                raise ScenarioError(
                    f"controller '{scenario.controller.name}' reads impedance_estimate: name "
                    "its identifier in controller.impedance_source")
            env.Connect(identifiers.GetOutputPort(f"impedance_{source}"),
                        own["impedance_estimate"])
        supervisor = None
        if scenario.safety.enabled:
            supervisor = env.AddNamedSystem("safety_supervisor",
                                            SafetySupervisor(scenario.safety))
            env.Connect(torque, supervisor.GetInputPort("joint_torque_commanded"))
            for name, port in m.items():
                if supervisor.HasInputPort(MEASUREMENTS[name].role):
                    env.Connect(port, supervisor.GetInputPort(MEASUREMENTS[name].role))
            env.Connect(supervisor.GetOutputPort("joint_torque"), saturation.get_input_port())
        else:
            env.Connect(torque, saturation.get_input_port())
        drive = saturation.get_output_port()
        if p.faults.clock is not None:
            drive, active = ChainFaults(env, scenario.faults, "drive", drive, 3, p.faults.clock)
            p.faults.active |= active
        env.Connect(drive, motor.get_input_port())
        applied = motor.get_output_port()
        if dac is not None:
            # Between samples the plant steps with the torque of the last sample.
            env.Connect(applied, dac.get_input_port())
            applied = dac.get_output_port()
        if guard is None:
            env.Connect(applied, arm)
        else:
            env.Connect(applied, guard.get_input_port())
            env.Connect(guard.get_output_port(), arm)
        out.append(_Control(controller, identifiers, supervisor, torque, applied, detected))
    return out


def _export_physics(export, state, tip, wall):
    """The true signals: the arm's state, the tip's, the wall's."""
    export("joint_state_true", state, "arm [q; v] (rad, rad/s)",
           log_as={"joint_positions_true": slice(0, 3), "joint_velocities_true": slice(3, 6)})
    export("tip_state_true", tip.GetOutputPort("tip_state"),
           "tip [x, y, phi, xdot, ydot, phidot], world (m, rad, /s)",
           log_as={"tip_pose_true": slice(0, 3), "tip_velocity_true": slice(3, 6)})
    export("contact_force_true", wall.GetOutputPort("contact_force"),
           "true normal force on the tip (N)")
    export("penetration_true", wall.GetOutputPort("penetration"),
           "true surface displacement xe (m)")
    export("true_impedance", wall.GetOutputPort("true_impedance"),
           "true [M_e, B_e, K_e] (kg, N s/m, N/m)")


def _export_sensing_and_control(export, scenario, sensing, control, friction):
    """What the sensors read, what the controller, supervisor and
    identifiers output, and the torques on the joints."""
    supervisor = control.supervisor
    export("joint_positions_measured", sensing.counted,
           "encoder-quantized q, zeroed at q0, after any encoder fault (rad)")
    export("joint_torque_commanded", control.torque, "controller's torque before saturation (N m)")
    if supervisor is not None:
        export("joint_torque_supervised", supervisor.GetOutputPort("joint_torque"),
               "the safety supervisor's torque, before saturation (N m)")
        export("safety_state", supervisor.GetOutputPort("safety_state"),
               "the safety supervisor's decision: " + ", ".join(
                   f"{k} {v}" for k, v in SAFETY_STATES.items()))
        export("safety_stop_reason", supervisor.GetOutputPort("safety_stop_reason"),
               "why the supervisor stopped the arm: " + ", ".join(
                   f"{k} {v}" for k, v in STOP_REASONS.items()))
    export("joint_torque_applied", control.applied,
           "motor torque into the plant: saturated, times the motor scale (N m)")
    export("joint_friction_torque", friction.GetOutputPort("torque"),
           "friction torque on the joints (N m)")
    _export_measured(export, sensing)
    _export_controller(export, scenario, control)


def _export_measured(export, sensing):
    measured, dsp = sensing.measured, sensing.dsp
    for name, port in measured.items():
        if MEASUREMENTS[name].station:
            export(name, port, MEASUREMENTS[name].meaning)
    if dsp.HasOutputPort("force_measured_antialiased"):
        export("force_measured_antialiased", dsp.GetOutputPort("force_measured_antialiased"),
               "second DSP channel through the 190 Hz RC filter (N)")


def _export_controller(export, scenario, control):
    controller, identifiers = control.outputs, control.identifiers
    detected = control.detected
    declared = controller_declaration(scenario.controller.name)
    signals = CONTROLLER_SIGNALS | declared.signals
    for name, meaning in signals.items():
        if name in controller:
            if detected and name in DETECTOR_SIGNALS:
                meaning = DETECTOR_SIGNALS[name]
            export(name, controller[name], meaning)
    for name, port in controller.items():
        if name not in signals and name not in ("joint_torque_commanded", *declared.unlogged):
            export(f"controller_{name}", port,
                   f"controller '{scenario.controller.name}' output {name}")
    if identifiers is not None:
        for config in scenario.identifiers:
            export(f"impedance_{config.name}",
                   identifiers.GetOutputPort(f"impedance_{config.name}"),
                   f"identifier {config.name}'s [M_e, B_e, K_e] (kg, N s/m, N/m)")
            if identifiers.HasOutputPort(f"force_estimate_{config.name}"):
                export(f"force_estimate_{config.name}",
                       identifiers.GetOutputPort(f"force_estimate_{config.name}"),
                       f"identifier {config.name}'s network force f(x) (N)")


def _export_faults(export, builder, scenario, faults):
    """Which fault is on, and the faults' contact clock."""
    if not scenario.faults:
        return
    flags = builder.AddNamedSystem("fault_flags", Multiplexer(len(scenario.faults)))
    for i in range(len(scenario.faults)):
        builder.Connect(faults.active[i], flags.get_input_port(i))
    export("fault_active", flags.get_output_port(),
           "1 while the scenario's fault i is on, one column per fault in its order",
           log_as={"fault_active": slice(0, len(scenario.faults))})
    export("fault_contact_time", faults.clock,
           "first sample with a true contact force > 5 N, the faults' clock (s; -1 before)")

def control_steps_per_plant_step(scenario: Scenario) -> int:
    """How many plant steps make one 1 ms control period."""
    return int(round(CONTROL_PERIOD / scenario.arm.time_step))


def leaf_systems(diagram):
    """Every leaf system of ``diagram``, depth first, in diagram order."""
    for system in diagram.GetSystems():
        if isinstance(system, Diagram):
            yield from leaf_systems(system)
        else:
            yield system


#: Each noise source's seed hashes this prefix and its name. The prefix is
#: part of the seed: changing it changes every scenario's noise realization,
#: and with it every published result and golden log.
_NOISE_KEY_PREFIX = "::run::station::"


def _noise_sources(station):
    """(environment index, seed key name, source) of every RandomSource of
    ``station``: the environment is the ``@<i>`` in its path (0 without
    one), the key its name without it."""
    for system in leaf_systems(station):
        if isinstance(system, RandomSource):
            path = system.GetSystemPathname()
            found = _ENV_TAG.findall(path)
            yield (int(found[-1]) if found else 0, _ENV_TAG.sub("", system.get_name()), system)


_ENV_TAG = re.compile(r"@(\d+)")


def _check_unique_noise_names(station):
    keys = [(env, key) for env, key, _ in _noise_sources(station)]
    if len(keys) != len(set(keys)):
        raise ValueError("the station's noise sources need unique names in each environment "
                         f"(seeded by name): {keys}")


def SeedNoise(diagram, context, seed=None):
    """Seeds the random state of every :class:`ContactStation` in
    ``diagram`` (the root diagram of ``context``, or a station itself).

    Each station's systems get their random state from ``seed`` (default:
    its scenario's ``simulation.seed``; in an ensemble, each environment's),
    and each RandomSource then its own generator, seeded from that seed and
    the source's name (without its environment's ``@<i>``), so the noise is
    the same whatever else the diagram holds, however the outer diagram and
    the station are named, whatever controller or identifier is wired in,
    and whether the environment runs alone or in an ensemble. Systems
    outside the stations are not touched."""
    stations = [diagram] if isinstance(diagram, ContactStation) else list(_stations(diagram))
    if not stations:
        raise ValueError(f"'{diagram.get_name()}' holds no ContactStation to seed")
    for station in stations:
        seeds = [s.simulation.seed if seed is None else int(seed) for s in station.scenarios]
        station_context = station.GetMyMutableContextFromRoot(context)
        station.SetRandomContext(station_context, RandomGenerator(seeds[0]))
        for env, name, system in _noise_sources(station):
            key = zlib.crc32((_NOISE_KEY_PREFIX + name).encode())
            system.SetRandomContext(
                system.GetMyMutableContextFromRoot(context),
                RandomGenerator((seeds[env] * 1_000_003 + key) % 2**31))


def _stations(diagram):
    for system in diagram.GetSystems():
        if isinstance(system, ContactStation):
            yield system
        elif isinstance(system, Diagram):
            yield from _stations(system)
