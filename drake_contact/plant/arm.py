"""The 3-DOF planar direct-drive arm (thesis Appendix A-D), loaded from URDF.

Link data (thesis Appendix A-D): lengths a_i, masses m_i, COM at a_i + S_ix from joint i,
Izz about the COM. The plant is a discrete ``MultibodyPlant`` whose step
is 1 ms / 2**k; it starts at the thesis's q0.
"""

import dataclasses as dc

import numpy as np
from pydrake.multibody.parsing import Parser
from pydrake.multibody.plant import AddMultibodyPlant, MultibodyPlantConfig
from pydrake.multibody.tree import ModelInstanceIndex
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import SymbolicVectorSystem

from drake_contact.errors import ScenarioError
from drake_contact.constants import RATIO_TOLERANCE, TIME_TOLERANCE_S
from drake_contact.resources import arm_urdf_path

#: Controller sample period (s): every controller runs at 1 kHz.
CONTROL_PERIOD = 1e-3

#: Sampling, as the thesis's DSP did it (Appendix E, the 1 ms interrupt):
#: at each whole millisecond t_n every sampled system (controllers,
#: identifiers, supervisor, detector, force reference, plug-ins) and every
#: discrete filter reads values computed from the plant's state at t_n, and
#: the torque computed from them acts on the plant from t_n on (the DSP's
#: computation time is neglected). In Drake terms: the plant steps as a
#: periodic discrete update (``use_sampled_output_ports=False``) and every
#: sampled system declares its update as a periodic discrete update at the
#: same instants, so the Simulator computes all of them from one Context,
#: the one at t_n, before it stores any. A law is an output computed from
#: its inputs and its stored state, y_n = g(x_n, s_n), held between samples
#: when the plant steps finer than 1 ms; its update stores s_(n+1) =
#: f(x_n, s_n). The first sample is at 1 ms: the estimator's differences
#: and filters take the pose at t = 0 as their first sample.
FIRST_SAMPLE_S = CONTROL_PERIOD


def DeclareSampledUpdate(system, update):
    """Declares ``update(context, discrete_values)`` on ``system`` at every
    1 kHz sample instant, as a periodic discrete update.

    The Simulator computes every discrete update due at t_n (the plant's
    step, the filters', every sampled system's) from the same Context, the
    state at t_n, and then stores them all: the update sees exactly what the
    system's output showed, and what the plant's step read through it."""
    system.DeclarePeriodicDiscreteUpdateEvent(CONTROL_PERIOD, 0.0, update)
    system._sampled_update = update


def CalcSampledUpdate(system, context):
    """The discrete state a leaf ``system`` declared with
    :func:`DeclareSampledUpdate` takes at the sample at ``context``'s time
    (a new DiscreteValues; the context is not changed). For tests and
    step-by-step use outside a Simulator."""
    values = context.get_discrete_state().Clone()
    system._sampled_update(context, values)
    return values


def ApplySampledUpdates(system, context):
    """Computes the sample at ``context``'s time for every leaf of
    ``system`` (a leaf or a Diagram, ``context`` its own) declared with
    :func:`DeclareSampledUpdate`, and every discrete SymbolicVectorSystem
    (sampled every 1 ms: the faults, the force reading's monitor), all from
    the same context, then stores them in it, as a Simulator does at a
    sample instant."""
    leaves = [system] if not hasattr(system, "GetSystems") else list(_leaves(system))
    updates = []
    for leaf in leaves:
        leaf_context = leaf.GetMyMutableContextFromRoot(context) if leaf is not system \
            else context
        if hasattr(leaf, "_sampled_update"):
            updates.append((leaf_context, CalcSampledUpdate(leaf, leaf_context)))
        elif isinstance(leaf, SymbolicVectorSystem) and leaf.num_discrete_state_groups():
            values = leaf.AllocateDiscreteVariables()
            leaf.CalcForcedDiscreteVariableUpdate(leaf_context, values)
            updates.append((leaf_context, values))
    for leaf_context, values in updates:
        leaf_context.SetDiscreteState(values)


def _leaves(diagram):
    for system in diagram.GetSystems():
        if hasattr(system, "GetSystems"):
            yield from _leaves(system)
        else:
            yield system


def is_sample_time(t: float) -> bool:
    """True at the 1 kHz sample instants from FIRST_SAMPLE_S on (whole
    multiples of the period, as Drake's periodic events compute them), False
    before and between them (a plant step finer than 1 ms)."""
    return (t > FIRST_SAMPLE_S - TIME_TOLERANCE_S
            and abs(t - round(t / CONTROL_PERIOD) * CONTROL_PERIOD) <= TIME_TOLERANCE_S)


def held_while_flagged(port, context):
    """Which environments a sampled law holds at this sample: those whose
    ``force_fault`` input (``port``, one value per environment: the safety
    supervisor's flag on the force reading) is up. None when none is, or the
    port is unconnected (no supervisor); else a boolean mask (N,)."""
    if not port.HasValue(context):
        return None
    flags = port.Eval(context)
    return flags > 0.0 if flags.any() else None


#: Link lengths a_i (m), masses m_i (kg), COM offsets S_ix (m), Izz (kg m^2).
LINK_LENGTHS = (0.2207, 0.1603, 0.1508)
LINK_MASSES = (12.88, 5.95, 0.44)
LINK_COM_OFFSETS = (-0.0476, -0.0619, -0.0918)
LINK_IZZ = (0.138841, 0.039523, 1.339e-3)

#: Initial configuration (rad): tip at about (0.454 m, 0, 0).
THESIS_Q0 = (-0.5377671, 1.3205011, -0.7827340)

#: Name of the end-effector contact frame in the URDF.
TIP_FRAME = "tip"
MODEL_NAME = "kiguchi_arm"


@dc.dataclass
class ArmConfig:
    """The simulated arm."""

    # Plant time step (s): 1 ms / 2**k (1, 0.5, 0.25, ... ms).
    time_step: float = 1e-3
    # Initial joint angles q0 (rad).
    initial_positions: list[float] = dc.field(default_factory=lambda: list(THESIS_Q0))
    # Torque each motor delivers per N m commanded (the drives' true torque
    # constants against the DAC scaling the controller assumes), joints 1-3.
    motor_torque_scale: list[float] = dc.field(default_factory=lambda: [1.0, 1.0, 1.0])

    def validate(self, prefix="arm"):
        h = self.time_step
        if not (np.isfinite(h) and 0 < h <= CONTROL_PERIOD):
            raise ScenarioError(
                f"{prefix}.time_step = {h} is out of range: must be in (0, 0.001] s "
                "and divide the 1 ms control period")
        if h < 1e-6:
            raise ScenarioError(f"{prefix}.time_step = {h} is out of range: must be >= 1e-06 s "
                                "(at most 1000 plant steps per control period)")
        ratio = CONTROL_PERIOD / h
        n = int(round(ratio))
        if abs(ratio - n) > RATIO_TOLERANCE * ratio or n & (n - 1) or h != CONTROL_PERIOD / n:
            # Drake times a periodic event k * period: k h equals n * 1 ms to
            # the bit for every k only when 1 ms / h is a power of two (for
            # h = 0.1 ms, 18 % of the samples fall an ulp off the plant's
            # step, and the sampled systems would read another state).
            raise ScenarioError(
                f"{prefix}.time_step = {h} is out of range: must be 0.001 / 2**k s "
                "(0.001, 0.0005, 0.00025, 0.000125, ...), so that the plant's steps fall "
                "exactly on the 1 ms samples")
        scale = self.motor_torque_scale
        if len(scale) != 3 or not all(np.isfinite(x) and 0.5 <= x <= 2.0 for x in scale):
            raise ScenarioError(
                f"{prefix}.motor_torque_scale = {scale} is out of range: must be 3 values in "
                "[0.5, 2]")
        q0 = self.initial_positions
        if len(q0) != 3 or not np.all(np.isfinite(q0)):
            raise ScenarioError(
                f"{prefix}.initial_positions = {q0} is out of range: must be 3 finite angles in rad")


def AddArmPlant(builder: DiagramBuilder, config):
    """Adds the arm (and a SceneGraph) to ``builder``; with a list of N
    configs, one plant holding N arms (the model instances ``env<i>::``
    of :func:`arm_instances`, in order), which must share their time step.

    Returns (plant, scene_graph). The plant is finalized and its default
    state is q = ``initial_positions``, v = 0 (each arm's own). Gravity
    points along -z, normal to the plane of motion, so it produces no joint
    torque. The arms do not touch one another: each one's state evolves as
    it would in a plant of its own, bit for bit.
    """
    configs = config if isinstance(config, (list, tuple)) else [config]
    steps = {c.time_step for c in configs}
    if len(steps) != 1:
        raise ScenarioError(f"arm.time_step = {sorted(steps)}: the arms of one plant share "
                            "their time step")
    plant, scene_graph = AddMultibodyPlant(
        MultibodyPlantConfig(time_step=configs[0].time_step, use_sampled_output_ports=False),
        builder)
    plant.set_name("plant")
    instances = ([LoadArm(plant)] if len(configs) == 1 else
                 [LoadArm(plant, prefix=f"env{i}") for i in range(len(configs))])
    plant.Finalize()
    for instance, c in zip(instances, configs):
        plant.SetDefaultPositions(instance, np.asarray(c.initial_positions, dtype=float))
    return plant, scene_graph


def arm_instances(plant):
    """The arms' model instances of a plant :func:`AddArmPlant` made, in
    the order of their environments."""
    # AddArmPlant adds them in that order.
    return [ModelInstanceIndex(i) for i in range(plant.num_model_instances())
            if plant.GetModelInstanceName(ModelInstanceIndex(i)).split("::")[-1] == MODEL_NAME]


def LoadArm(plant, prefix=""):
    """Parses the arm's URDF into an unfinalized plant (its model instance
    named ``<prefix>::kiguchi_arm`` with a prefix); returns its instance."""
    parser = Parser(plant, prefix) if prefix else Parser(plant)
    (instance,) = parser.AddModels(str(arm_urdf_path()))
    return instance


def MakeArmModel(time_step: float = 0.0):
    """A standalone finalized plant of the arm (no SceneGraph), e.g. for a
    controller's own model or for computing kinematics off-line."""
    from pydrake.multibody.plant import MultibodyPlant
    plant = MultibodyPlant(time_step)
    LoadArm(plant)
    plant.Finalize()
    return plant
