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
import zlib

import numpy as np
from pydrake.common import RandomGenerator
from pydrake.systems.framework import Diagram, DiagramBuilder, PortDataType
from pydrake.systems.primitives import (
    Adder, ConstantVectorSource, MatrixGain, Multiplexer, RandomSource, SymbolicVectorSystem)
from pydrake.symbolic import Variable, floor, if_then_else

from drake_contact.control.force_reference import ForceReference
from drake_contact.control.safety_supervisor import (
    SAFETY_STATES, STOP_REASONS, SafetySupervisor)
from drake_contact.errors import ScenarioError
from drake_contact.faults import ChainFaults, FaultClock
from drake_contact.identification.identifiers import AddIdentifiers
from drake_contact.measured import MEASUREMENTS, MeasuredSignals
from drake_contact.plant.arm import CONTROL_PERIOD, TIME_TOLERANCE_S, AddArmPlant, MakeArmModel
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
    """Collects the station's exports: one call documents, exports and logs
    a signal."""

    def __init__(self, builder):
        self._builder = builder
        self.signals = {}

    def export(self, name, port, meaning, *, log_as=None, log=True):
        """Exports ``port`` as ``name``; logs it under ``name`` (a size-1
        port as a 1-D log), or under the keys of ``log_as``."""
        if log_as is None:
            log_as = {name: 0 if port.size() == 1 else slice(0, port.size())} if log else {}
        self._builder.ExportOutput(port, name)
        self.signals[name] = Signal(port.size(), meaning, dict(log_as))


class ContactStation(Diagram):
    """The contact diagram of one scenario (built by :func:`MakeContactDiagram`).

    ``scenario`` is the scenario it was built from; ``signals`` maps each
    exported output port's name to its :class:`Signal`. Everything that
    evolves lives in the Context, as in any Diagram."""

    def __init__(self, scenario: Scenario, signals: dict):
        super().__init__()
        self.scenario = scenario
        self.signals = signals


def SampleHold(period_s, size, time_step):
    """The DAC: a vector input passed through at each 1 kHz sample instant
    and held from there until the next, for a plant that steps ``time_step``
    < ``period_s``. A ``SymbolicVectorSystem`` updated at the plant's step
    (so its events fall with the plant's), in C++."""
    t = Variable("t")
    u = [Variable(f"u{i}") for i in range(size)]
    held = [Variable(f"held{i}") for i in range(size)]
    at_sample = abs(t - floor(t / period_s + 0.5) * period_s) <= TIME_TOLERANCE_S
    passed = [if_then_else(at_sample, a, b) for a, b in zip(u, held)]
    return SymbolicVectorSystem(time=t, state=held, input=u, dynamics=passed, output=passed,
                                time_period=time_step)


def _add_controller(builder, scenario, plant, measured: MeasuredSignals):
    """Adds the scenario's controller (:func:`drake_contact.plugins.MakeController`)
    as ``controller``, the force reference if it reads ``force_desired``,
    and the station's contact detector if it has no ``contact_info`` but
    something needs one; connects every input by name. Returns (controller,
    {signal name: output port} of what the station exports from it)."""
    config = scenario.controller
    system = MakeController(config.name, config.factory_options())
    controller = builder.AddNamedSystem("controller", system)
    sources = dict(measured.items()) | {"plant_state": plant.get_state_output_port()}
    ports = {}
    contact = None
    if controller.HasOutputPort("contact_info"):
        contact = controller.GetOutputPort("contact_info")
    elif controller.HasInputPort("force_desired") or scenario.identifiers:
        detector = builder.AddNamedSystem("contact_detector", ContactDetector())
        builder.Connect(measured.force_filtered, detector.GetInputPort("force"))
        builder.Connect(measured.tip_pose_measured, detector.GetInputPort("tip_pose"))
        contact = detector.GetOutputPort("contact_info")
        ports["mode"] = detector.GetOutputPort("mode")
    if controller.HasInputPort("force_desired"):
        reference = builder.AddNamedSystem(
            "force_reference", ForceReference(scenario.force_reference))
        builder.Connect(contact, reference.GetInputPort("contact_info"))
        sources["force_desired"] = reference.GetOutputPort("force_desired")
        ports["force_desired"] = sources["force_desired"]
    for i in range(controller.num_input_ports()):
        name = controller.get_input_port(i).get_name()
        if name in sources:
            builder.Connect(sources[name], controller.get_input_port(i))
        elif name in STATION_ACTION_INPUTS:
            builder.ExportInput(controller.get_input_port(i), name)
    # impedance_estimate is connected once the identifiers exist.
    for i in range(controller.num_output_ports()):
        port = controller.get_output_port(i)
        if port.get_data_type() == PortDataType.kVectorValued:
            ports[port.get_name()] = port
    if contact is not None:
        ports["contact_info"] = contact
    return controller, ports


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


def _add_arm_and_wall(builder, scenario):
    """The plant, its tip kinematics, the wall (behind the scenario's
    environment faults) and the joint friction, wired; returns (plant,
    scene_graph, tip, wall, friction, faults): ``faults`` is a
    :class:`_FaultPorts` (no clock when the scenario has no faults)."""
    plant, scene_graph = AddArmPlant(builder, scenario.arm)
    state_port = plant.get_state_output_port()
    joint_inertias = np.diag(plant.CalcMassMatrix(plant.CreateDefaultContext()))
    check_friction_stability(scenario.joint_friction, joint_inertias, scenario.arm.time_step)

    tip = builder.AddNamedSystem("tip_kinematics", TipKinematics(plant))
    builder.Connect(state_port, tip.GetInputPort("plant_state"))
    faults = scenario.faults
    wall = builder.AddNamedSystem("wall", CompliantWall(
        scenario.environment, scenario.arm.time_step,
        stiffness_scale_input=any(f.signal == "stiffness" for f in faults)))
    builder.Connect(wall.GetOutputPort("force_on_tip"), tip.GetInputPort("force_on_tip"))
    if faults:
        # The faults' clock reads the true contact force; the wall's own
        # inputs may be corrupted (environment faults).
        clock = builder.AddNamedSystem("fault_clock", FaultClock())
        builder.Connect(wall.GetOutputPort("contact_force"), clock.get_input_port())
        clock = clock.get_output_port()
        surface, active = ChainFaults(builder, faults, "surface",
                                      tip.GetOutputPort("tip_state"), 6, clock)
        builder.Connect(surface, wall.GetInputPort("tip_state"))
        if wall.HasInputPort("stiffness_scale"):
            one = builder.AddNamedSystem("stiffness_nominal", ConstantVectorSource([1.0]))
            scale, more = ChainFaults(builder, faults, "stiffness", one.get_output_port(), 1, clock)
            builder.Connect(scale, wall.GetInputPort("stiffness_scale"))
            active |= more
    else:
        clock, active = None, {}
        builder.Connect(tip.GetOutputPort("tip_state"), wall.GetInputPort("tip_state"))

    friction = AddJointFriction(
        builder, scenario.joint_friction, mass_matrix_diagonal=joint_inertias,
        time_step=scenario.arm.time_step)
    builder.Connect(state_port, friction.GetInputPort("plant_state"))
    external = builder.AddNamedSystem("external_torque", Adder(2, 3))
    builder.Connect(tip.GetOutputPort("generalized_force"), external.get_input_port(0))
    builder.Connect(friction.GetOutputPort("torque"), external.get_input_port(1))
    builder.Connect(external.get_output_port(), plant.get_applied_generalized_force_input_port())
    return plant, scene_graph, tip, wall, friction, _FaultPorts(clock, active)


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
    builder = DiagramBuilder()
    plant, _, _, wall, _, _ = _add_arm_and_wall(builder, scenario)
    torque = builder.AddNamedSystem("joint_torque", ConstantVectorSource(list(joint_torque)))
    builder.Connect(torque.get_output_port(), plant.get_actuation_input_port())
    builder.ExportOutput(wall.GetOutputPort("contact_force"), "contact_force_true")
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
    scenario.validate()
    builder = DiagramBuilder()
    plant, scene_graph, tip, wall, friction, faults = _add_arm_and_wall(builder, scenario)
    sensing = _add_sensing(builder, scenario, plant, tip, wall, faults)
    control = _add_control(builder, scenario, plant, sensing.measured, faults)
    signals = _Signals(builder)
    _export_physics(signals.export, plant, tip, wall)
    _export_sensing_and_control(signals.export, scenario, sensing, control, friction)
    _export_faults(signals.export, builder, scenario, faults)
    signals.export("query_object", scene_graph.get_query_output_port(),
                   "the SceneGraph's query object (for visualizers)", log=False)
    station = ContactStation(scenario, signals.signals)
    builder.BuildInto(station)
    station.set_name("station")
    _check_unique_noise_names(station)
    return station


@dc.dataclass
class _Sensing:
    """The sensors' ports: the encoders' counts after any encoder fault, the
    DSP sub-diagram, and what the sampled systems read."""

    counted: object
    dsp: object
    measured: MeasuredSignals


def _add_sensing(builder, scenario, plant, tip, wall, faults) -> _Sensing:
    """The encoders and the kinematic estimator, the force sensor and the
    DSP, with the faults on their signals."""
    state_port = plant.get_state_output_port()
    encoders = AddEncoders(builder, scenario.encoders, scenario.arm.initial_positions)
    builder.Connect(state_port, encoders.GetInputPort("plant_state"))
    estimator = AddKinematicEstimator(
        builder, MakeArmModel(), scenario.estimator,
        encoder_reading(scenario.encoders, scenario.arm.initial_positions))
    counted = encoders.GetOutputPort("joint_positions_measured")
    if faults.clock is not None:
        counted, active = ChainFaults(
            builder, scenario.faults, "encoders", counted, 3, faults.clock,
            counts_per_revolution=scenario.encoders.counts_per_revolution)
        faults.active |= active
    builder.Connect(counted, estimator.GetInputPort("joint_positions_measured"))

    sensor = AddForceSensor(builder, scenario.force_sensor)
    builder.Connect(wall.GetOutputPort("force_on_tip"), sensor.GetInputPort("wrench"))
    builder.Connect(tip.GetOutputPort("tip_state"), sensor.GetInputPort("tip_state"))
    dsp = AddDspForceInput(builder, scenario.dsp, scenario.force_sensor.fine_period,
                           sensor.GetOutputPort("voltage_frame").size(), faults=scenario.faults)
    if dsp.HasInputPort("contact_time"):
        builder.Connect(faults.clock, dsp.GetInputPort("contact_time"))
        faults.active |= {i: dsp.GetOutputPort(f"fault_active_{i}")
                          for i, f in enumerate(scenario.faults) if f.signal == "force"}
    builder.Connect(sensor.GetOutputPort("voltage"), dsp.GetInputPort("voltage"))
    if dsp.HasInputPort("voltage_frame"):
        builder.Connect(sensor.GetOutputPort("voltage_frame"), dsp.GetInputPort("voltage_frame"))

    blocks = {"estimator": estimator, "dsp": dsp}
    measured = MeasuredSignals(**{name: blocks[m.source].GetOutputPort(m.port)
                                  for name, m in MEASUREMENTS.items()})
    return _Sensing(counted, dsp, measured)


@dc.dataclass
class _Control:
    """The control side's systems and ports: the controller (its system and
    its output ports by name), the identifiers and the supervisor (None when
    absent), the torque the controller commands and the one the plant gets."""

    system: object
    outputs: dict
    identifiers: object
    supervisor: object
    torque: object
    applied: object


def _add_control(builder, scenario, plant, measured, faults) -> _Control:
    """The controller, the identifiers, the safety supervisor, the torque
    limits, any drive faults, the motors and (for a plant step under 1 ms)
    the DAC's hold, wired from ``measured`` to the plant's actuation."""
    controller_system, controller = _add_controller(builder, scenario, plant, measured)
    torque = controller["joint_torque_commanded"]
    identifiers = None
    if scenario.identifiers:
        identifiers = AddIdentifiers(builder, scenario)
        for name, port in measured.items():
            if identifiers.HasInputPort(MEASUREMENTS[name].role):
                builder.Connect(port, identifiers.GetInputPort(MEASUREMENTS[name].role))
        if identifiers.HasInputPort("contact_info"):
            builder.Connect(controller["contact_info"],
                            identifiers.GetInputPort("contact_info"))
    if controller_system.HasInputPort("impedance_estimate"):
        source = scenario.controller.impedance_source_name()
        if not source:
            raise ScenarioError(
                f"controller '{scenario.controller.name}' reads impedance_estimate: name its "
                "identifier in controller.impedance_source")
        builder.Connect(identifiers.GetOutputPort(f"impedance_{source}"),
                        controller_system.GetInputPort("impedance_estimate"))
    saturation = AddTorqueSaturation(builder, scenario.torque_limits)
    motors = builder.AddNamedSystem(
        "motors", MatrixGain(np.diag(scenario.arm.motor_torque_scale)))
    supervisor = None
    if scenario.safety.enabled:
        supervisor = builder.AddNamedSystem("safety_supervisor", SafetySupervisor(scenario.safety))
        builder.Connect(torque, supervisor.GetInputPort("joint_torque_commanded"))
        for name, port in measured.items():
            if supervisor.HasInputPort(MEASUREMENTS[name].role):
                builder.Connect(port, supervisor.GetInputPort(MEASUREMENTS[name].role))
        builder.Connect(supervisor.GetOutputPort("joint_torque"), saturation.get_input_port())
    else:
        builder.Connect(torque, saturation.get_input_port())
    drive = saturation.get_output_port()
    if faults.clock is not None:
        drive, active = ChainFaults(builder, scenario.faults, "drive", drive, 3, faults.clock)
        faults.active |= active
    builder.Connect(drive, motors.get_input_port())
    applied = motors.get_output_port()
    if scenario.arm.time_step < CONTROL_PERIOD:
        # Between samples the plant steps with the torque of the last sample.
        dac = builder.AddNamedSystem("dac", SampleHold(CONTROL_PERIOD, 3, scenario.arm.time_step))
        builder.Connect(applied, dac.get_input_port())
        applied = dac.get_output_port()
    builder.Connect(applied, plant.get_actuation_input_port())
    return _Control(controller_system, controller, identifiers, supervisor, torque, applied)


def _export_physics(export, plant, tip, wall):
    """The true signals: the arm's state, the tip's, the wall's."""
    export("joint_state_true", plant.get_state_output_port(), "arm [q; v] (rad, rad/s)",
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
    detected = not control.system.HasOutputPort("contact_info")
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


def _check_unique_noise_names(station):
    names = [s.get_name() for s in leaf_systems(station) if isinstance(s, RandomSource)]
    if len(names) != len(set(names)):
        raise ValueError(f"the station's noise sources need unique names (seeded by name): {names}")


def SeedNoise(diagram, context, seed=None):
    """Seeds the random state of every :class:`ContactStation` in
    ``diagram`` (the root diagram of ``context``, or a station itself).

    Each station's systems get their random state from ``seed`` (default:
    its scenario's ``simulation.seed``), and each RandomSource then its own
    generator, seeded from that seed and the source's name, so the noise is
    the same whatever else the diagram holds, however the outer diagram and
    the station are named, and whatever controller or identifier is wired
    in. Systems outside the stations are not touched."""
    stations = [diagram] if isinstance(diagram, ContactStation) else list(_stations(diagram))
    if not stations:
        raise ValueError(f"'{diagram.get_name()}' holds no ContactStation to seed")
    for station in stations:
        station_seed = station.scenario.simulation.seed if seed is None else int(seed)
        station_context = station.GetMyMutableContextFromRoot(context)
        station.SetRandomContext(station_context, RandomGenerator(station_seed))
        for system in leaf_systems(station):
            if isinstance(system, RandomSource):
                key = zlib.crc32((_NOISE_KEY_PREFIX + system.get_name()).encode())
                system.SetRandomContext(
                    system.GetMyMutableContextFromRoot(context),
                    RandomGenerator((station_seed * 1_000_003 + key) % 2**31))


def _stations(diagram):
    for system in diagram.GetSystems():
        if isinstance(system, ContactStation):
            yield system
        elif isinstance(system, Diagram):
            yield from _stations(system)
