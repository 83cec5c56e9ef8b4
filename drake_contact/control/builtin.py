"""The thesis's controllers as plug-in factories.

Registered under the entry-point group ``drake_contact.controllers`` in this
project's ``pyproject.toml``, exactly as a third-party controller registers
(:mod:`drake_contact.plugins`). Each factory takes the options mapping and
returns one Drake System whose ports follow the plug-in contract. For these
three the station passes the scenario's typed section as the options
(``controller.push``, ``controller.hybrid``, or both ``hybrid`` and ``nn``
for ``nn``), as each one's :func:`~drake_contact.plugins.declare` says, so
the thesis's scenarios keep their YAML. ``hybrid`` and ``nn`` declare
``ensemble``: given a list of N mappings (an ensemble's environments) they
return one system serving all N, every port env-major.
"""

import dataclasses as dc
from collections.abc import Sequence
from types import SimpleNamespace

from pydrake.systems.framework import Diagram, DiagramBuilder
from pydrake.systems.primitives import Adder, ConstantVectorSource, Demultiplexer, Multiplexer

from drake_contact.blocks import environment_configs
from drake_contact.control import hybrid_controller, nn_compensator
from drake_contact.control.hybrid_controller import HybridController, HybridControllerConfig
from drake_contact.control.nn_compensator import NnCompensator, NnCompensatorConfig
from drake_contact.control.push_controller import ConstantForcePushController, PushConfig
from drake_contact.errors import ScenarioError
from drake_contact.measured import by_role
from drake_contact.plant.arm import MakeArmModel
from drake_contact.options import config_from_options
from drake_contact.plugins import declare


@declare(sections=("push",), contender=False)
def push(options: dict):
    """The constant-force pushing harness (:class:`ConstantForcePushController`);
    options: the fields of :class:`PushConfig`. Reads the true plant state."""
    return ConstantForcePushController(
        MakeArmModel(), config_from_options(PushConfig, options, "controller.push"))


class ThesisHybridController(Diagram):
    """The thesis's approach and hybrid (or decoupled) contact controller as
    one plug-in system for N environments (one config each; a single config:
    N = 1): :class:`HybridController`, with the decoupled law's k_e from the
    ``impedance_estimate`` input (3 per environment, its K_e picked) when
    ``stiffness_source`` names an identifier, else from the constant
    ``stiffness_estimate``.

    Inputs: tip_pose_measured, tip_velocity_measured,
    joint_positions_estimated, joint_velocities_estimated, force_filtered,
    force_desired (and impedance_estimate). Outputs: joint_torque_commanded,
    mode, contact_info, tip_jacobian (see :class:`HybridController`). Every
    port is env-major (environment i's k values at [k i, k (i + 1)))."""

    def __init__(self, config: HybridControllerConfig | Sequence[HybridControllerConfig]):
        super().__init__()
        builder = DiagramBuilder()
        configs = _hybrid_configs(config)
        hybrid = builder.AddNamedSystem("hybrid", HybridController(config))
        _export_hybrid(builder, hybrid, configs)
        for name in ("joint_torque_commanded", "mode", "contact_info", "tip_jacobian"):
            builder.ExportOutput(hybrid.GetOutputPort(name), name)
        builder.BuildInto(self)


def _hybrid_configs(config):
    return environment_configs(config, HybridControllerConfig, "controller.hybrid")


def _export_hybrid(builder, hybrid, configs):
    """Exports the hybrid controller's measured inputs under the station's
    names for them, and f_d, and feeds its k_e (per environment: K_e, the
    third of its identifier's three, picked apart so that one
    environment's non-finite estimate stays its own)."""
    station = by_role()
    for role in ("tip_pose", "tip_velocity", "joint_positions", "joint_velocities", "force"):
        builder.ExportInput(hybrid.GetInputPort(role), station[role])
    for name in ("force_desired", "force_fault"):
        builder.ExportInput(hybrid.GetInputPort(name), name)
    count = len(configs)
    if configs[0].stiffness_source:
        split = builder.AddNamedSystem("impedance_split", Demultiplexer(3 * count, 1))
        pick = builder.AddNamedSystem("stiffness_from_identifier", Multiplexer(count))
        builder.ExportInput(split.get_input_port(), "impedance_estimate")
        for i in range(count):
            builder.Connect(split.get_output_port(3 * i + 2), pick.get_input_port(i))
        builder.Connect(pick.get_output_port(), hybrid.GetInputPort("stiffness_estimate"))
    else:
        stiffness = builder.AddNamedSystem(
            "stiffness_estimate", ConstantVectorSource([c.stiffness_estimate for c in configs]))
        builder.Connect(stiffness.get_output_port(), hybrid.GetInputPort("stiffness_estimate"))


def _hybrid_structure(options: dict) -> dict:
    """What the hybrid section ``options`` (checked when the scenario
    loaded) switches on, as ``hybrid.<field>``: the switches read its fields
    by name, without building a config (every environment's key is made
    when an ensemble is built)."""
    config = SimpleNamespace(**options)
    return {f"hybrid.{field}": value
            for field, value in hybrid_controller.structure(config).items()}


def _nn_structure(options: dict) -> dict:
    """The hybrid part's switches and the compensator's (``nn.<switch>``)."""
    config = SimpleNamespace(**options["nn"])
    return _hybrid_structure(options["hybrid"]) | {
        f"nn.{switch}": value for switch, value in nn_compensator.structure(config).items()}


@declare(sections=("hybrid",), impedance_source="hybrid.stiffness_source",
         unlogged=("tip_jacobian",), ensemble=True, structure=_hybrid_structure)
def hybrid(options: dict | list):
    """The thesis's hybrid controller; options: the fields of
    :class:`HybridControllerConfig` (a list of them: one system serving an
    ensemble's environments)."""
    if isinstance(options, list):
        return ThesisHybridController([config_from_options(
            HybridControllerConfig, o, "controller.hybrid") for o in options])
    return ThesisHybridController(
        config_from_options(HybridControllerConfig, options, "controller.hybrid"))


@dc.dataclass
class NnControllerOptions:
    """Options of the ``nn`` controller: its hybrid part and its compensator."""

    hybrid: HybridControllerConfig = dc.field(default_factory=HybridControllerConfig)
    nn: NnCompensatorConfig = dc.field(default_factory=NnCompensatorConfig)


class ThesisNnController(Diagram):
    """The hybrid part plus the 9-12-3 compensator (section 4.5):
    tau = tau_h + J^T n, one plug-in system for N environments (one config
    of each part per environment; single configs: N = 1).

    Inputs: as :class:`ThesisHybridController`. Outputs:
    joint_torque_commanded (tau_h + J^T n), hybrid_torque (tau_h), nn_output
    (n), mode, contact_info, tip_jacobian; every port env-major."""

    def __init__(self, hybrid_config: HybridControllerConfig | Sequence[HybridControllerConfig],
                 nn_config: NnCompensatorConfig | Sequence[NnCompensatorConfig]):
        super().__init__()
        builder = DiagramBuilder()
        configs = _hybrid_configs(hybrid_config)
        count = len(configs)
        hybrid = builder.AddNamedSystem("hybrid", HybridController(hybrid_config))
        _export_hybrid(builder, hybrid, configs)
        y_desired, phi_desired = (configs[0].y_desired, configs[0].phi_desired) if count == 1 \
            else ([c.y_desired for c in configs], [c.phi_desired for c in configs])
        compensator = builder.AddNamedSystem(
            "nn_compensator", NnCompensator(nn_config, y_desired, phi_desired))
        if compensator.GetOutputPort("joint_torque").size() != 3 * count:
            raise ScenarioError(f"controller: {count} hybrid configs and "
                                f"{compensator.GetOutputPort('joint_torque').size() // 3} nn "
                                "configs: give one of each per environment")
        # The compensator reads the same measured pose, force and f_d.
        station = by_role() | {"force_desired": "force_desired", "force_fault": "force_fault"}
        for role in ("tip_pose", "force", "force_desired", "force_fault"):
            builder.ConnectInput(station[role], compensator.GetInputPort(role))
        for name in ("tip_jacobian", "mode"):
            builder.Connect(hybrid.GetOutputPort(name), compensator.GetInputPort(name))
        tau_h = hybrid.GetOutputPort("joint_torque_commanded")
        builder.Connect(tau_h, compensator.GetInputPort("hybrid_torque"))
        total = builder.AddNamedSystem("nn_torque_sum", Adder(2, 3 * count))
        builder.Connect(tau_h, total.get_input_port(0))
        builder.Connect(compensator.GetOutputPort("joint_torque"), total.get_input_port(1))
        builder.ExportOutput(total.get_output_port(), "joint_torque_commanded")
        builder.ExportOutput(tau_h, "hybrid_torque")
        builder.ExportOutput(compensator.GetOutputPort("nn_output"), "nn_output")
        for name in ("mode", "contact_info", "tip_jacobian"):
            builder.ExportOutput(hybrid.GetOutputPort(name), name)
        builder.BuildInto(self)


@declare(sections=("hybrid", "nn"), impedance_source="hybrid.stiffness_source",
         unlogged=("tip_jacobian",), ensemble=True, structure=_nn_structure, signals={
             "nn_output": "compensator output n = [n_x (N), n_y (N), n_phi (N m)]",
             "hybrid_torque": "the hybrid part's command tau_h, before J^T n (N m)"})
def nn(options: dict | list):
    """The neural-network controller; options: ``hybrid`` (the fields of
    :class:`HybridControllerConfig`) and ``nn`` (of :class:`NnCompensatorConfig`);
    a list of them: one system serving an ensemble's environments."""
    configs = [config_from_options(NnControllerOptions, o, "controller")
               for o in (options if isinstance(options, list) else [options])]
    for config in configs:
        config.hybrid.validate("controller.hybrid")
        config.nn.validate("controller.nn")
    if not isinstance(options, list):
        return ThesisNnController(configs[0].hybrid, configs[0].nn)
    return ThesisNnController([c.hybrid for c in configs], [c.nn for c in configs])
