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

One code path builds every N (:func:`MakeEnsembleDiagram`): each role is one
system whose ports are environment-major (environment i's k values at
``[k i, k (i + 1))``), wired with plain ``builder.Connect``. N = 1 is a
batch of one: each role's system alone, the thesis's diagram. A role that
is not batched is N single systems behind one adapter
(:func:`~drake_contact.blocks.AddEnvironments`), which at N = 1 is the
system itself.
"""

import dataclasses as dc
import functools
import zlib

import numpy as np
from pydrake.common import RandomGenerator
from pydrake.systems.framework import Diagram, DiagramBuilder, InputPort
from pydrake.systems.primitives import (
    Adder, ConstantVectorSource, MatrixGain, Multiplexer, RandomSource)
from pydrake.symbolic import Variable, floor, if_then_else

from drake_contact.arm_axis import LinearSystemBank, StackedSymbolicSystem
from drake_contact.blocks import AddEnvironments, EnvironmentCopies, connect, system_ports
from drake_contact.control.force_reference import ForceReference
from drake_contact.control.safety_supervisor import (
    SAFETY_STATES, STOP_REASONS, SafetySupervisor)
from drake_contact.errors import ScenarioError
from drake_contact.faults import AddFaultChain, FaultClock
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
    """Collects the station's exports: one call documents and logs a
    signal (:meth:`export_all` exports them)."""

    def __init__(self):
        self.exported = {}

    def export(self, name, port, meaning, *, log_as=None, log=True):
        """Exports ``port`` as ``name``; logs it under ``name`` (a size-1
        signal as a 1-D log), or under the keys of ``log_as``."""
        self.exported[name] = (port, meaning, log_as, log)

    def export_all(self, builder, count) -> dict:
        """Exports every collected port (environment-major, ``count``
        environments); returns the station's ``signals``."""
        signals = {}
        for name, (port, meaning, log_as, log) in self.exported.items():
            size = port.size() // count
            if log_as is None:
                log_as = {name: 0 if size == 1 else slice(0, size)} if log else {}
            builder.ExportOutput(port, name)
            signals[name] = Signal(size, meaning, dict(log_as))
        return signals


class ContactStation(Diagram):
    """The contact diagram of one scenario, or of an ensemble of N
    environments (built by :func:`MakeContactDiagram` or
    :func:`MakeEnsembleDiagram`).

    ``scenarios`` are the environments' scenarios, in the arm axis's order
    (``scenario`` is the first, the only one of a one-environment station);
    ``signals`` maps each exported output port's name to its
    :class:`Signal`, whose size is one environment's: the port carries
    ``num_envs`` of them, environment i's at ``[size * i, size * (i + 1))``;
    ``noise_sources`` lists each RandomSource with its environment and the
    name that keys its seed (:func:`SeedNoise`). Everything that evolves
    lives in the Context, as in any Diagram."""

    def __init__(self, scenarios, signals: dict, noise_sources: list):
        super().__init__()
        self.scenarios = list(scenarios)
        self.scenario = self.scenarios[0]
        self.num_envs = len(self.scenarios)
        self.signals = signals
        self.noise_sources = noise_sources


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


def _bank(systems):
    """The one system of a batch of one, else a LinearSystemBank of them."""
    return systems[0] if len(systems) == 1 else LinearSystemBank(systems)


def _faults_on(scenarios, signal) -> bool:
    """Whether the environments' faults corrupt ``signal`` (all of them or
    none: the structure key holds each fault's signal)."""
    return any(f.signal == signal for f in scenarios[0].faults)


def _add_fault_chains(builder, scenarios, signal, source, size, clock, active, *,
                      counts_per_revolution=None):
    """The faults on ``signal`` of every environment, after the output port
    ``source`` (environment-major, ``size`` per environment): one adapter
    (:func:`~drake_contact.blocks.AddEnvironments`) of each environment's
    chain, fed by ``clock``. Adds each fault's ``active`` port to
    ``active`` by its index; returns the corrupted port (``source`` itself
    without such faults). ``counts_per_revolution``: each environment's
    encoder counts, for faults on the encoders."""
    if not _faults_on(scenarios, signal):
        return source
    counts = counts_per_revolution
    chain = AddEnvironments(builder, f"faults_{signal}", len(scenarios), lambda b, i: (
        AddFaultChain(b, scenarios[i].faults, signal, size,
                      counts_per_revolution=None if counts is None else counts[i])))
    connect(builder, source, chain["signal"])
    connect(builder, clock, chain["contact_time"])
    active |= {int(name.rpartition("_")[2]): port for name, port in chain.items()
               if name.startswith("fault_active_")}
    return chain["signal_faulty"]


def _add_controller(builder, scenarios, state, measured, fault=None):
    """Adds the scenarios' controller (:func:`drake_contact.plugins.MakeController`)
    as ``controller`` (one system serving all environments when its plug-in
    declares ``ensemble``, else one per environment behind the adapter), the
    force reference if it reads ``force_desired``, and the station's contact
    detector if it has no ``contact_info`` but something needs one; connects
    every input by name. ``state``: the plant state port; ``measured``: the
    MeasuredSignals; ``fault``: the safety supervisor's ``force_fault``
    (None without one: a controller's ``force_fault`` input is left
    unconnected here, which one system alone reads as no fault; the caller
    feeds an ensemble's zeros). Returns ({input name: port}, {signal name: output
    port} of what the station exports from it, whether the station's
    detector says the mode). Every port is environment-major."""
    scenario = scenarios[0]
    config = scenario.controller
    declared = controller_declaration(config.name)
    options = [s.controller.factory_options() for s in scenarios]
    count = len(scenarios)
    if count > 1 and declared.ensemble:
        ports = system_ports(builder.AddNamedSystem(
            "controller", MakeController(config.name, options, count=count)))
    else:
        systems = [MakeController(config.name, o) for o in options]
        ports = AddEnvironments(builder, "controller", count, lambda b, i: system_ports(
            b.AddNamedSystem("controller", systems[i])))
    inputs = {n: p for n, p in ports.items() if _is_input(p)}
    outputs = {n: p for n, p in ports.items() if not _is_input(p)}
    sources = dict(measured.items()) | {"plant_state": state}
    if fault is not None:
        sources["force_fault"] = fault
    contact = outputs.get("contact_info")
    detected = contact is None
    if contact is None and ("force_desired" in inputs or scenario.identifiers):
        detector = AddEnvironments(builder, "contact_detector", count, lambda b, i: system_ports(
            b.AddNamedSystem("contact_detector", ContactDetector())))
        connect(builder, measured.force_filtered, detector["force"])
        connect(builder, measured.tip_pose_measured, detector["tip_pose"])
        outputs["mode"] = detector["mode"]
        contact = detector["contact_info"]
    if "force_desired" in inputs:
        configs = [s.force_reference for s in scenarios]
        reference = builder.AddNamedSystem("force_reference",
                                           ForceReference(configs if count > 1 else configs[0]))
        builder.Connect(contact, reference.GetInputPort("contact_info"))
        sources["force_desired"] = outputs["force_desired"] = reference.GetOutputPort(
            "force_desired")
    for name, port in inputs.items():
        if name in sources:
            connect(builder, sources[name], port)
        elif name in STATION_ACTION_INPUTS:
            # Environment-major, as every port: environment i's action at
            # [k i, k (i + 1)).
            builder.ExportInput(port, name)
    # impedance_estimate is connected once the identifiers exist.
    if contact is not None:
        outputs["contact_info"] = contact
    return inputs, outputs, detected


def _no_force_fault(builder, count):
    """The flag of an ensemble without a safety supervisor: zeros (no
    fault), one source for the controller and the identifiers. One system
    alone reads its unconnected ``force_fault`` input as no fault; in an
    ensemble a plug-in's per-environment copies sit behind the adapter's
    Demultiplexer (:class:`drake_contact.blocks.EnvironmentCopies`), whose
    own input must then be connected."""
    if builder.HasSubsystemNamed("no_force_fault"):
        return builder.GetSubsystemByName("no_force_fault").get_output_port()
    return builder.AddNamedSystem("no_force_fault",
                                  ConstantVectorSource(np.zeros(count))).get_output_port()


def _is_input(port):
    return isinstance(port, (list, tuple, InputPort))


#: Controller inputs the station exports as its own input ports, under the
#: same name: a policy's action, set from outside the station (the
#: Gymnasium environments fix it at each of their steps; an ensemble's port
#: holds every environment's action, environment-major).
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


def _add_arms(builder, scenarios):
    """The plant with one arm per environment (:func:`AddArmPlant`); returns
    (plant, scene_graph, the arms' state [q; v] (6 per environment), their
    joints' inertias (M's diagonal at q0, 3 per environment)). Each arm's
    actuators follow the previous arm's (AddArmPlant adds them in turn), so
    the plant's actuation and applied-force inputs are environment-major;
    its state port is too for one arm, and a Multiplexer
    ``plant_state_envs`` of the arms' state ports for more."""
    plant, scene_graph = AddArmPlant(builder, [s.arm for s in scenarios])
    inertias = np.diag(plant.CalcMassMatrix(plant.CreateDefaultContext()))
    if len(scenarios) == 1:
        return plant, scene_graph, plant.get_state_output_port(), inertias
    states = builder.AddNamedSystem("plant_state_envs", Multiplexer([6] * len(scenarios)))
    for i, arm in enumerate(arm_instances(plant)):
        builder.Connect(plant.get_state_output_port(arm), states.get_input_port(i))
    return plant, scene_graph, states.get_output_port(), inertias


@dc.dataclass
class _Physics:
    """The true physics around the arms: the tip kinematics, the wall
    (behind any environment faults), the joint friction, the faults'
    contact clock (None without faults) and each fault's ``active`` port
    by its index, and the torque the wall and the friction put on the
    joints. Ports environment-major."""

    tip: object
    wall: object
    friction: object
    clock: object
    active: dict
    external: object


def _add_physics(builder, scenarios, state, inertias) -> _Physics:
    """The tip kinematics, the wall (behind the scenarios' environment
    faults) and the joint friction of every arm, wired to its state: one
    system per role for all arms."""
    count = len(scenarios)
    for scenario, m in zip(scenarios, np.reshape(inertias, (count, 3))):
        check_friction_stability(scenario.joint_friction, m, scenario.arm.time_step)
    h = scenarios[0].arm.time_step
    tip = builder.AddNamedSystem("tip_kinematics", TipKinematics(_kinematics_model(), count))
    wall = builder.AddNamedSystem("wall", CompliantWall(
        [s.environment for s in scenarios], h,
        stiffness_scale_input=_faults_on(scenarios, "stiffness")))
    friction = AddJointFriction(builder, [s.joint_friction for s in scenarios],
                                mass_matrix_diagonal=inertias, time_step=h)
    external = builder.AddNamedSystem("external_torque", Adder(2, 3 * count))
    builder.Connect(state, tip.GetInputPort("plant_state"))
    builder.Connect(wall.GetOutputPort("force_on_tip"), tip.GetInputPort("force_on_tip"))
    clock, active = None, {}
    if scenarios[0].faults:
        # The faults' clock reads the true contact force; the wall's own
        # inputs may be corrupted (environment faults).
        clocks = AddEnvironments(builder, "fault_clock", count, lambda b, i: system_ports(
            b.AddNamedSystem("fault_clock", FaultClock())))
        builder.Connect(wall.GetOutputPort("contact_force"), clocks["u0"])
        clock = clocks["y0"]
    surface = _add_fault_chains(builder, scenarios, "surface", tip.GetOutputPort("tip_state"),
                                6, clock, active)
    builder.Connect(surface, wall.GetInputPort("tip_state"))
    if wall.HasInputPort("stiffness_scale"):
        one = builder.AddNamedSystem("stiffness_nominal", ConstantVectorSource([1.0] * count))
        scale = _add_fault_chains(builder, scenarios, "stiffness", one.get_output_port(), 1,
                                  clock, active)
        builder.Connect(scale, wall.GetInputPort("stiffness_scale"))
    builder.Connect(state, friction.GetInputPort("plant_state"))
    builder.Connect(tip.GetOutputPort("generalized_force"), external.GetInputPort("u0"))
    builder.Connect(friction.GetOutputPort("torque"), external.GetInputPort("u1"))
    return _Physics(tip, wall, friction, clock, active, external.GetOutputPort("sum"))


@functools.cache
def _kinematics_model():
    """The arm's standalone model, against which the tip kinematics' closed
    forms are checked (made once)."""
    return MakeArmModel()


def _apply_to_arms(builder, plant, torque, count):
    """Feeds the joint torques (3 per environment, in the arms' order) into
    the plant's applied generalized force; in an ensemble through
    :func:`FiniteGuard`."""
    if count > 1:
        guard = builder.AddNamedSystem("external_torque_guard", FiniteGuard(3, count))
        builder.Connect(torque, guard.get_input_port())
        torque = guard.get_output_port()
    builder.Connect(torque, plant.get_applied_generalized_force_input_port())


def MakeFloorDiagram(scenario: Scenario, joint_torque=(4.0, 0.0, 0.0)):
    """The speed floor: the plant, the wall and the joint physics only, with a
    constant motor torque (N m) and no sensors or controller. Exports
    ``contact_force_true``."""
    scenario.validate()
    builder = DiagramBuilder()
    plant, _, state, inertias = _add_arms(builder, [scenario])
    physics = _add_physics(builder, [scenario], state, inertias)
    _apply_to_arms(builder, plant, physics.external, 1)
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
    role of :func:`MakeContactDiagram` one system serving all N, every port
    environment-major (environment i's values at ``[k i, k (i + 1))``, k
    its size in ``signals``). One scenario gives the one-environment
    station: a batch of one, each role its system alone.

    Each environment has its own scenario (wall, noise seed, gains, faults,
    ...); they must share a structure
    (:func:`drake_contact.structure.ensemble_structure`: the plant step, the
    controller and what its plug-in switches on, the identifiers, the safety
    supervisor, the signal of each fault, ...), checked before anything is
    built: a ScenarioError names the first environment and field that
    differ. A role whose system serves N environments at once (the arm
    axis's roles, the force sensor, the force reference, and a controller or
    identifier whose plug-in declares ``ensemble``) is that system; any
    other (the safety supervisor, the contact detector, the faults, the DSP
    with its anti-aliasing filter or force faults in, a plug-in without
    ``ensemble``) is one system per environment behind one adapter
    (:class:`~drake_contact.blocks.EnvironmentCopies`). Environment i gives,
    bit for bit, the logs of :func:`MakeContactDiagram` of its scenario,
    seeded alike (:func:`SeedNoise`)."""
    scenarios = list(scenarios)
    if not scenarios:
        raise ScenarioError("an ensemble needs at least one scenario")
    for scenario in scenarios:
        scenario.validate()
    check_ensemble_structure(scenarios)
    count = len(scenarios)
    builder = DiagramBuilder()
    plant, scene_graph, state, inertias = _add_arms(builder, scenarios)
    physics = _add_physics(builder, scenarios, state, inertias)
    _apply_to_arms(builder, plant, physics.external, count)
    sensing = _add_sensing(builder, scenarios, state, physics)
    control = _add_control(builder, scenarios, state, sensing, physics, plant)
    signals = _Signals()
    _export_physics(signals.export, state, physics.tip, physics.wall)
    _export_sensing_and_control(signals.export, scenarios[0], sensing, control,
                                physics.friction)
    _export_faults(signals.export, builder, scenarios, physics)
    exported = signals.export_all(builder, count)
    builder.ExportOutput(scene_graph.get_query_output_port(), "query_object")
    exported["query_object"] = Signal(0, "the SceneGraph's query object (for visualizers)", {})
    station = ContactStation(scenarios, exported, [])
    builder.BuildInto(station)
    station.set_name("station")
    station.noise_sources[:] = _noise_sources(station, sensing.gauge_noise)
    _check_unique_noise_names(station)
    return station


@dc.dataclass
class _Sensing:
    """The sensors' ports: the encoders' counts after any encoder fault, the
    DSP's ports by name, what the sampled systems read, and the force
    sensor's noise sources in the environments' order."""

    counted: object
    dsp: dict
    measured: MeasuredSignals
    gauge_noise: list


def _add_sensing(builder, scenarios, state, physics) -> _Sensing:
    """The encoders and the kinematic estimator, the force sensor and the
    DSP, with the faults on their signals: one system per role for all
    environments (the DSPs one per environment behind the adapter when an
    anti-aliasing filter or a force fault is in)."""
    count = len(scenarios)
    zeros = [s.arm.initial_positions for s in scenarios]
    readings = [encoder_reading(s.encoders, q0) for s, q0 in zip(scenarios, zeros)]
    encoder = AddEncoders(builder, [s.encoders for s in scenarios], zeros)
    estimator = AddKinematicEstimator(builder, _kinematics_model(),
                                      [s.estimator for s in scenarios], readings)
    builder.Connect(state, encoder.GetInputPort("plant_state"))
    counted = _add_fault_chains(
        builder, scenarios, "encoders", encoder.GetOutputPort("joint_positions_measured"), 3,
        physics.clock, physics.active,
        counts_per_revolution=[s.encoders.counts_per_revolution for s in scenarios])
    builder.Connect(counted, estimator.GetInputPort("joint_positions_measured"))

    sensor = AddForceSensor(builder, [s.force_sensor for s in scenarios])
    gauge_noise = [s for s in sensor.GetSystems() if isinstance(s, RandomSource)]
    ticks = sensor.GetOutputPort("voltage_frame").size() // count
    fine_period = scenarios[0].force_sensor.fine_period
    if count == 1 or (scenarios[0].dsp.anti_aliasing.mode == "off"
                      and not _faults_on(scenarios, "force")):
        dsp = system_ports(AddDspForceInput(builder, [s.dsp for s in scenarios], fine_period,
                                            ticks, faults=scenarios[0].faults))
    else:
        dsp = AddEnvironments(builder, "dsp", count, lambda b, i: system_ports(AddDspForceInput(
            b, scenarios[i].dsp, fine_period, ticks, faults=scenarios[i].faults)))
    builder.Connect(physics.wall.GetOutputPort("force_on_tip"), sensor.GetInputPort("wrench"))
    builder.Connect(physics.tip.GetOutputPort("tip_state"), sensor.GetInputPort("tip_state"))
    if "contact_time" in dsp:
        builder.Connect(physics.clock, dsp["contact_time"])
        physics.active |= {int(name.rpartition("_")[2]): port for name, port in dsp.items()
                           if name.startswith("fault_active_")}
    builder.Connect(sensor.GetOutputPort("voltage"), dsp["voltage"])
    if "voltage_frame" in dsp:
        builder.Connect(sensor.GetOutputPort("voltage_frame"), dsp["voltage_frame"])
    blocks = {"estimator": system_ports(estimator), "dsp": dsp}
    measured = MeasuredSignals(**{name: blocks[m.source][m.port]
                                  for name, m in MEASUREMENTS.items()})
    return _Sensing(counted, dsp, measured, gauge_noise)


@dc.dataclass
class _Control:
    """The control side: the controller's output ports by name, its
    identifiers and the supervisor's ports (None when absent), the torque
    the controller commands and the one the plant gets, and whether the
    station's contact detector (not the controller) says the mode."""

    outputs: dict
    identifiers: object
    supervisor: dict
    torque: object
    applied: object
    detected: bool


def _add_control(builder, scenarios, state, sensing, physics, plant) -> _Control:
    """The controller, the identifiers, the safety supervisor, the torque
    limits, any drive faults, the motors and (for a plant step under 1 ms)
    the DAC's hold, wired from the measured signals to the arms'
    actuation; one torque limit, motor, DAC and guard system for all
    environments."""
    count = len(scenarios)
    scenario = scenarios[0]
    measured = sensing.measured
    supervisor = None
    if scenario.safety.enabled:
        # Before the controller: its monitor's flag holds the controller's
        # and the identifiers' state (force_fault).
        supervisor = AddEnvironments(builder, "safety_supervisor", count, lambda b, i: (
            system_ports(b.AddNamedSystem("safety_supervisor",
                                          SafetySupervisor(scenarios[i].safety)))))
        for name, port in measured.items():
            if MEASUREMENTS[name].role in supervisor:
                connect(builder, port, supervisor[MEASUREMENTS[name].role])
    fault = supervisor["force_fault"] if supervisor is not None else None
    inputs, controller, detected = _add_controller(builder, scenarios, state, measured, fault)
    if fault is None and "force_fault" in inputs and count > 1:
        connect(builder, _no_force_fault(builder, count), inputs["force_fault"])
    h = scenario.arm.time_step
    saturation = AddTorqueSaturation(builder, np.concatenate([s.torque_limits for s in scenarios]))
    motor = builder.AddNamedSystem("motors", _bank(
        [MatrixGain(np.diag(s.arm.motor_torque_scale)) for s in scenarios]))
    dac = (builder.AddNamedSystem("dac", SampleHold(CONTROL_PERIOD, 3, h, count))
           if h < CONTROL_PERIOD else None)
    guard = (builder.AddNamedSystem("actuation_guard", FiniteGuard(3, count)) if count > 1
             else None)
    identifiers = (AddIdentifiers(builder, scenarios if count > 1 else scenario)
                   if scenario.identifiers else None)
    torque = controller["joint_torque_commanded"]
    if identifiers is not None:
        for name, port in measured.items():
            if identifiers.HasInputPort(MEASUREMENTS[name].role):
                builder.Connect(port, identifiers.GetInputPort(MEASUREMENTS[name].role))
        if identifiers.HasInputPort("force_fault") and (fault is not None or count > 1):
            connect(builder, fault if fault is not None else _no_force_fault(builder, count),
                    identifiers.GetInputPort("force_fault"))
        if identifiers.HasInputPort("contact_info"):
            builder.Connect(controller["contact_info"], identifiers.GetInputPort("contact_info"))
    if "impedance_estimate" in inputs:
        source = scenario.controller.impedance_source_name()
        if not source:
            raise ScenarioError(
                f"controller '{scenario.controller.name}' reads impedance_estimate: name "
                "its identifier in controller.impedance_source")
        connect(builder, identifiers.GetOutputPort(f"impedance_{source}"),
                inputs["impedance_estimate"])
    if supervisor is not None:
        connect(builder, torque, supervisor["joint_torque_commanded"])
        builder.Connect(supervisor["joint_torque"], saturation.get_input_port())
    else:
        builder.Connect(torque, saturation.get_input_port())
    drive = _add_fault_chains(builder, scenarios, "drive", saturation.get_output_port(), 3,
                              physics.clock, physics.active)
    builder.Connect(drive, motor.get_input_port())
    applied = motor.get_output_port()
    if dac is not None:
        # Between samples the plant steps with the torque of the last sample.
        builder.Connect(applied, dac.get_input_port())
        applied = dac.get_output_port()
    if guard is None:
        builder.Connect(applied, plant.get_actuation_input_port())
    else:
        builder.Connect(applied, guard.get_input_port())
        builder.Connect(guard.get_output_port(), plant.get_actuation_input_port())
    return _Control(controller, identifiers, supervisor, torque, applied, detected)


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
        export("joint_torque_supervised", supervisor["joint_torque"],
               "the safety supervisor's torque, before saturation (N m)")
        export("safety_state", supervisor["safety_state"],
               "the safety supervisor's decision: " + ", ".join(
                   f"{k} {v}" for k, v in SAFETY_STATES.items()))
        export("safety_stop_reason", supervisor["safety_stop_reason"],
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
    if "force_measured_antialiased" in dsp:
        export("force_measured_antialiased", dsp["force_measured_antialiased"],
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


def _export_faults(export, builder, scenarios, physics):
    """Which fault is on, and the faults' contact clock."""
    faults = scenarios[0].faults
    if not faults:
        return

    def flags(b, i):
        mux = b.AddNamedSystem("fault_flags", Multiplexer(len(faults)))
        return {f"fault_active_{k}": mux.get_input_port(k) for k in range(len(faults))} | {
            "fault_active": mux.get_output_port()}
    flagged = AddEnvironments(builder, "fault_flags", len(scenarios), flags)
    for k in range(len(faults)):
        builder.Connect(physics.active[k], flagged[f"fault_active_{k}"])
    export("fault_active", flagged["fault_active"],
           "1 while the scenario's fault i is on, one column per fault in its order",
           log_as={"fault_active": slice(0, len(faults))})
    export("fault_contact_time", physics.clock,
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


def _noise_sources(station, gauge_noise) -> list:
    """(environment index, seed key name, source) of every RandomSource of
    ``station``, from an explicit map: the force sensor's gauge noise i
    (``gauge_noise``, one per environment in order) is environment i's,
    every source in block i of an :class:`~drake_contact.blocks.EnvironmentCopies`
    is environment i's, and in a one-environment station every source is
    environment 0's. The key is the source's name, without the ``@<i>``
    the gauge noise of environment i carries in an ensemble."""
    count = station.num_envs
    environment_of = {source: i for i, source in enumerate(gauge_noise)} if count > 1 else {}
    found = []

    def walk(system, env):
        for child in system.GetSystems():
            if isinstance(child, EnvironmentCopies):
                for i, block in enumerate(child.environments):
                    walk(block, i)
            elif isinstance(child, Diagram):
                walk(child, env)
            elif isinstance(child, RandomSource):
                own = environment_of.get(child, env)
                if own is None:
                    raise ValueError(f"noise source '{child.GetSystemPathname()}' belongs to no "
                                     "one environment: an ensemble seeds each one's noise apart")
                found.append((own, child.get_name().removesuffix(f"@{own}"), child))
    walk(station, 0 if count == 1 else None)
    return found


def _check_unique_noise_names(station):
    keys = [(env, key) for env, key, _ in station.noise_sources]
    if len(keys) != len(set(keys)):
        raise ValueError("the station's noise sources need unique names in each environment "
                         f"(seeded by name): {keys}")


def SeedNoise(diagram, context, seed=None):
    """Seeds the random state of every :class:`ContactStation` in
    ``diagram`` (the root diagram of ``context``, or a station itself).

    Each station's systems get their random state from ``seed`` (default:
    its scenario's ``simulation.seed``; in an ensemble, each environment's;
    a sequence: one seed per environment, for a station of that many),
    and each RandomSource then its own generator, seeded from its
    environment's seed and the source's name (``station.noise_sources``:
    the environment from the station's explicit map, the name without an
    ensemble's ``@<i>``), so the noise is
    the same whatever else the diagram holds, however the outer diagram and
    the station are named, whatever controller or identifier is wired in,
    and whether the environment runs alone or in an ensemble. Systems
    outside the stations are not touched."""
    stations = [diagram] if isinstance(diagram, ContactStation) else list(_stations(diagram))
    if not stations:
        raise ValueError(f"'{diagram.get_name()}' holds no ContactStation to seed")
    for station in stations:
        if seed is None:
            seeds = [s.simulation.seed for s in station.scenarios]
        elif np.ndim(seed) == 0:
            seeds = [int(seed)] * station.num_envs
        else:
            seeds = [int(s) for s in seed]
            if len(seeds) != station.num_envs:
                raise ValueError(f"SeedNoise: {len(seeds)} seeds for a station of "
                                 f"{station.num_envs} environments")
        station_context = station.GetMyMutableContextFromRoot(context)
        station.SetRandomContext(station_context, RandomGenerator(seeds[0]))
        for env, name, system in station.noise_sources:
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
