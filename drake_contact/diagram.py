"""Builds the simulation diagram of one scenario.

    controller --joint_torque_commanded--> torque_saturation --> motors --> plant.actuation
    plant.state --> tip_kinematics --tip_state--> wall --force_on_tip--+
    plant.state --> joint_friction ------------------------------------+--> adder
    adder (J^T F_wall + tau_friction) --> plant.applied_generalized_force
    plant.state --> encoders (quantized q) --> estimator --> tip pose/velocity/acceleration
    wall.force_on_tip --> force_sensor (FS6-120A, analog on a 12 kHz grid) --> dsp --> force

Every signal a run logs is an exported output port of the diagram, named
``<what>`` with units in :data:`EXPORTED_OUTPUTS`.
"""

import numpy as np
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import Adder, ConstantVectorSource, MatrixGain

from drake_contact.arm import CONTROL_PERIOD, AddArmPlant, MakeArmModel
from drake_contact.compliant_wall import CompliantWall
from drake_contact.dsp import AddDspForceInput
from drake_contact.errors import ScenarioError
from drake_contact.estimator import AddKinematicEstimator
from drake_contact.force_reference import ForceReference
from drake_contact.force_sensor import AddForceSensor
from drake_contact.hybrid_controller import HybridController
from drake_contact.identification import AddIdentifiers
from drake_contact.nn_compensator import NnCompensator
from drake_contact.joint_physics import (
    AddEncoders, AddJointFriction, AddTorqueSaturation, check_friction_stability)
from drake_contact.push_controller import ConstantForcePushController
from drake_contact.scenario import Scenario
from drake_contact.tip_kinematics import TipKinematics

#: Exported outputs of :func:`MakeContactDiagram`: name -> (size, meaning).
EXPORTED_OUTPUTS = {
    "joint_state_true": (6, "arm [q; v] (rad, rad/s)"),
    "tip_state_true": (6, "tip [x, y, phi, xdot, ydot, phidot], world (m, rad, /s)"),
    "contact_force_true": (1, "true normal force on the tip (N)"),
    "penetration_true": (1, "true surface displacement xe (m)"),
    "true_impedance": (3, "true [M_e, B_e, K_e] (kg, N s/m, N/m)"),
    "joint_positions_measured": (3, "encoder-quantized q, zeroed at q0 (rad)"),
    "joint_torque_commanded": (3, "controller's torque before saturation (N m)"),
    "joint_torque_applied": (3, "motor torque into the plant: saturated, times the motor scale (N m)"),
    "joint_friction_torque": (3, "Coulomb friction torque on the joints (N m)"),
    "force_measured": (1, "DSP force after ADC, scale, sign and tare (N)"),
    "force_filtered": (1, "force_measured through the 120 Hz Butterworth (N)"),
    "tip_pose_measured": (3, "estimated tip [x, y, phi] from encoders (m, rad)"),
    "tip_velocity_measured": (3, "estimated tip velocity (m/s, rad/s)"),
    "tip_acceleration_measured": (3, "estimated tip acceleration (m/s^2, rad/s^2)"),
    "joint_positions_estimated": (3, "q1, q2 as read, q3 filtered (rad)"),
    "joint_velocities_estimated": (3, "joint velocities by backward differences (rad/s)"),
}

#: Exported only when the scenario has them: name -> (size, meaning).
OPTIONAL_OUTPUTS = {
    "force_measured_antialiased": (1, "second DSP channel through the 190 Hz RC filter (N)"),
    "mode": (1, "controller mode: 0 approach, 1 contact"),
    "force_desired": (1, "desired normal force f_d (N)"),
    "contact_info": (4, "[first switch time (s) or -1, x, y, phi at the switch]"),
    "nn_output": (3, "compensator output n = [n_x (N), n_y (N), n_phi (N m)]"),
    "hybrid_torque": (3, "the hybrid part's command tau_h, before J^T n (N m)"),
}


def _add_push_controller(builder, scenario, plant, measured):
    controller = builder.AddNamedSystem(
        "controller", ConstantForcePushController(plant, scenario.controller.push))
    builder.Connect(plant.get_state_output_port(), controller.GetInputPort("plant_state"))
    return {"joint_torque_commanded": controller.GetOutputPort("joint_torque_commanded")}


def _add_hybrid_controller(builder, scenario, plant, measured):
    config = scenario.controller.hybrid
    controller = builder.AddNamedSystem("controller", HybridController(config))
    reference = builder.AddNamedSystem("force_reference", ForceReference(scenario.force_reference))
    for name in ("tip_pose", "tip_velocity", "joint_positions", "joint_velocities"):
        builder.Connect(measured[name], controller.GetInputPort(name))
    builder.Connect(measured["force_filtered"], controller.GetInputPort("force"))
    builder.Connect(reference.GetOutputPort("force_desired"),
                    controller.GetInputPort("force_desired"))
    builder.Connect(controller.GetOutputPort("contact_info"),
                    reference.GetInputPort("contact_info"))
    # The decoupled law's k_e: the scenario's constant, or an identifier's
    # K_e (connected once the identifiers exist).
    if not config.stiffness_source:
        stiffness = builder.AddNamedSystem(
            "stiffness_estimate", ConstantVectorSource([config.stiffness_estimate]))
        builder.Connect(stiffness.get_output_port(), controller.GetInputPort("stiffness_estimate"))
    return {
        "stiffness_estimate_input": controller.GetInputPort("stiffness_estimate"),
        "joint_torque_commanded": controller.GetOutputPort("joint_torque_commanded"),
        "mode": controller.GetOutputPort("mode"),
        "contact_info": controller.GetOutputPort("contact_info"),
        "tip_jacobian": controller.GetOutputPort("tip_jacobian"),
        "force_desired": reference.GetOutputPort("force_desired"),
    }


def _add_nn_controller(builder, scenario, plant, measured):
    """The hybrid part plus the 9-12-3 compensator: tau = tau_h + J^T n."""
    ports = _add_hybrid_controller(builder, scenario, plant, measured)
    hybrid = scenario.controller.hybrid
    compensator = builder.AddNamedSystem(
        "nn_compensator",
        NnCompensator(scenario.controller.nn, hybrid.y_desired, hybrid.phi_desired))
    builder.Connect(measured["tip_pose"], compensator.GetInputPort("tip_pose"))
    builder.Connect(ports["tip_jacobian"], compensator.GetInputPort("tip_jacobian"))
    builder.Connect(measured["force_filtered"], compensator.GetInputPort("force"))
    builder.Connect(ports["force_desired"], compensator.GetInputPort("force_desired"))
    builder.Connect(ports["mode"], compensator.GetInputPort("mode"))
    builder.Connect(ports["joint_torque_commanded"], compensator.GetInputPort("hybrid_torque"))
    total = builder.AddNamedSystem("nn_torque_sum", Adder(2, 3))
    builder.Connect(ports["joint_torque_commanded"], total.get_input_port(0))
    builder.Connect(compensator.GetOutputPort("joint_torque"), total.get_input_port(1))
    ports["hybrid_torque"] = ports["joint_torque_commanded"]
    ports["joint_torque_commanded"] = total.get_output_port()
    ports["nn_output"] = compensator.GetOutputPort("nn_output")
    return ports


#: controller.name -> adder(builder, scenario, plant, measured ports) returning
#: a dict of its output ports, at least joint_torque_commanded.
CONTROLLER_ADDERS = {
    "push": _add_push_controller,
    "hybrid": _add_hybrid_controller,
    "nn": _add_nn_controller,
}


def _add_arm_and_wall(builder, scenario):
    """The plant, its tip kinematics, the wall and the joint friction, wired;
    returns (plant, scene_graph, tip, wall, friction torque port)."""
    plant, scene_graph = AddArmPlant(builder, scenario.arm)
    state_port = plant.get_state_output_port()
    joint_inertias = np.diag(plant.CalcMassMatrix(plant.CreateDefaultContext()))
    check_friction_stability(scenario.joint_friction, joint_inertias, scenario.arm.time_step)

    tip = builder.AddNamedSystem("tip_kinematics", TipKinematics(plant))
    builder.Connect(state_port, tip.GetInputPort("plant_state"))
    wall = builder.AddNamedSystem(
        "wall", CompliantWall(scenario.environment, scenario.arm.time_step))
    builder.Connect(tip.GetOutputPort("tip_state"), wall.GetInputPort("tip_state"))
    builder.Connect(wall.GetOutputPort("force_on_tip"), tip.GetInputPort("force_on_tip"))

    friction_in, friction_out = AddJointFriction(
        builder, scenario.joint_friction, mass_matrix_diagonal=joint_inertias,
        time_step=scenario.arm.time_step)
    builder.Connect(state_port, friction_in)
    external = builder.AddNamedSystem("external_torque", Adder(2, 3))
    builder.Connect(tip.GetOutputPort("generalized_force"), external.get_input_port(0))
    builder.Connect(friction_out, external.get_input_port(1))
    builder.Connect(external.get_output_port(), plant.get_applied_generalized_force_input_port())
    return plant, scene_graph, tip, wall, friction_out


def MakeFloorDiagram(scenario: Scenario, joint_torque=(4.0, 0.0, 0.0)):
    """The speed floor: the plant, the wall and the joint physics only, with a
    constant motor torque (N m) and no sensors or controller. Exports
    ``contact_force_true``."""
    scenario.validate()
    builder = DiagramBuilder()
    plant, _, _, wall, _ = _add_arm_and_wall(builder, scenario)
    torque = builder.AddNamedSystem("joint_torque", ConstantVectorSource(list(joint_torque)))
    builder.Connect(torque.get_output_port(), plant.get_actuation_input_port())
    builder.ExportOutput(wall.GetOutputPort("contact_force"), "contact_force_true")
    diagram = builder.Build()
    diagram.set_name("floor_diagram")
    return diagram


def MakeContactDiagram(scenario: Scenario, *, meshcat=None):
    """The arm, its joint physics, the wall and the scenario's controller.

    Returns a Diagram named ``contact_diagram`` exporting the outputs listed in
    :data:`EXPORTED_OUTPUTS`. Raises ScenarioError for settings that cannot
    run (e.g. friction regularization unstable at the plant step).

    Given a ``meshcat``, also draws the arm, the wall and the contact force
    there (:mod:`drake_contact.visualization`); without one, nothing is
    added and a run pays nothing for visualization.
    """
    scenario.validate()
    builder = DiagramBuilder()
    plant, scene_graph, tip, wall, friction_out = _add_arm_and_wall(builder, scenario)
    state_port = plant.get_state_output_port()

    encoders_in, encoders_out = AddEncoders(
        builder, scenario.encoders, scenario.arm.initial_positions)
    builder.Connect(state_port, encoders_in)
    estimator = AddKinematicEstimator(builder, MakeArmModel(), scenario.estimator)
    builder.Connect(encoders_out, estimator["joint_positions_measured"])

    sensor = AddForceSensor(builder, scenario.force_sensor)
    builder.Connect(wall.GetOutputPort("force_on_tip"), sensor["wrench"])
    builder.Connect(tip.GetOutputPort("tip_state"), sensor["tip_state"])
    dsp = AddDspForceInput(builder, scenario.dsp, scenario.force_sensor.fine_period,
                           sensor["voltage_frame"].size())
    builder.Connect(sensor["voltage"], dsp["voltage"])
    if "voltage_frame" in dsp:
        builder.Connect(sensor["voltage_frame"], dsp["voltage_frame"])

    if scenario.controller.name not in CONTROLLER_ADDERS:
        raise ScenarioError(f"controller.name = '{scenario.controller.name}' is unknown: "
                            f"choose one of {', '.join(CONTROLLER_ADDERS)}")
    measured = {
        "tip_pose": estimator["tip_pose"], "tip_velocity": estimator["tip_velocity"],
        "joint_positions": estimator["joint_positions"],
        "joint_velocities": estimator["joint_velocities"],
        "force_filtered": dsp["force_filtered"],
        "force_measured": dsp["force_measured"],
        "tip_acceleration": estimator["tip_acceleration"],
        "tip_velocity_raw": estimator["tip_velocity_raw"],
        "tip_acceleration_raw": estimator["tip_acceleration_raw"],
    }
    controller_ports = CONTROLLER_ADDERS[scenario.controller.name](
        builder, scenario, plant, measured)
    torque = controller_ports["joint_torque_commanded"]
    identifier_ports = {}
    if scenario.identifiers:
        identifier_ports = AddIdentifiers(builder, scenario, measured,
                                          controller_ports["contact_info"])
        source = scenario.controller.hybrid.stiffness_source
        if source:
            pick = builder.AddNamedSystem("stiffness_from_identifier",
                                          MatrixGain(np.array([[0.0, 0.0, 1.0]])))
            builder.Connect(identifier_ports[source]["impedance"], pick.get_input_port())
            builder.Connect(pick.get_output_port(), controller_ports["stiffness_estimate_input"])
    saturation = AddTorqueSaturation(builder, scenario.torque_limits)
    motors = builder.AddNamedSystem(
        "motors", MatrixGain(np.diag(scenario.arm.motor_torque_scale)))
    builder.Connect(torque, saturation.get_input_port())
    builder.Connect(saturation.get_output_port(), motors.get_input_port())
    builder.Connect(motors.get_output_port(), plant.get_actuation_input_port())

    exports = {
        "joint_state_true": state_port,
        "tip_state_true": tip.GetOutputPort("tip_state"),
        "contact_force_true": wall.GetOutputPort("contact_force"),
        "penetration_true": wall.GetOutputPort("penetration"),
        "true_impedance": wall.GetOutputPort("true_impedance"),
        "joint_positions_measured": encoders_out,
        "joint_torque_commanded": torque,
        "joint_torque_applied": motors.get_output_port(),
        "joint_friction_torque": friction_out,
        "force_measured": dsp["force_measured"],
        "force_filtered": dsp["force_filtered"],
        "tip_pose_measured": estimator["tip_pose"],
        "tip_velocity_measured": estimator["tip_velocity"],
        "tip_acceleration_measured": estimator["tip_acceleration"],
        "joint_positions_estimated": estimator["joint_positions"],
        "joint_velocities_estimated": estimator["joint_velocities"],
    }
    assert exports.keys() == EXPORTED_OUTPUTS.keys()
    if "force_measured_antialiased" in dsp:
        exports["force_measured_antialiased"] = dsp["force_measured_antialiased"]
    for name, port in controller_ports.items():
        if name in OPTIONAL_OUTPUTS:
            exports[name] = port
    for name, ports in identifier_ports.items():
        exports[f"impedance_{name}"] = ports["impedance"]
        if "force_estimate" in ports:
            exports[f"force_estimate_{name}"] = ports["force_estimate"]
    for name, port in exports.items():
        builder.ExportOutput(port, name)

    if meshcat is not None:
        from drake_contact.visualization import AddContactVisualization
        AddContactVisualization(
            builder, scene_graph, meshcat, tip_state=tip.GetOutputPort("tip_state"),
            penetration=wall.GetOutputPort("penetration"),
            contact_force=wall.GetOutputPort("contact_force"),
            surface_x=scenario.environment.surface_x)

    diagram = builder.Build()
    diagram.set_name("contact_diagram")
    return diagram


def control_steps_per_plant_step(scenario: Scenario) -> int:
    """How many plant steps make one 1 ms control period."""
    return int(round(CONTROL_PERIOD / scenario.arm.time_step))
