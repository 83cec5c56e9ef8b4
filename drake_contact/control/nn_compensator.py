"""The neural-network compensator added to the hybrid controller (thesis
section 4.5, equations 4.18-4.22; Figs 6.11-6.17).

A 9-12-3 network reads the measured tip pose, its previous sample and the
hybrid part's motor commands tau_h, and outputs Cartesian forces n =
(n_x, n_y, n_phi); the arm receives tau_h + J^T n. Every 1 ms in contact, one
back-propagation step on E = 1/2 sum e_k^2 with

    e = (f_d - f, y_d - y, phi_d - phi)

taken as the error at the network's outputs (direct neuro-control: the
plant's Jacobian is assumed +1).

Forward pass, with u the 9 inputs (the code adds 0.01 m / 0.01 rad to the y
and phi inputs so they are not zero) and sigma(s) = 2 / (1 + e^-s) - 1:

    h = W^T [1, u]                  (12 hidden pre-activations)
    o = V^T [1, sigma(h)]           (text; the Appendix E code sums V^T [1, h])
    n_k = R_k sigma(o_k),  R = (20 N, 10 N, 1 N m)

Update, with eta the learning rate and sigma'(s) = (1 - sigma(s)^2) / 2:

    delta_k = e_k R_k sigma'(o_k)
    V += eta [1, sigma(h)] delta^T
    W += eta [1, u] (sigma'(h) * (V_1: delta))^T

(the Appendix E code multiplies V by [1, sigma(h)] in the update whichever
forward pass it uses; so does the option ``output_layer: appendix_e``). The
weights are discrete state: a copied context carries what the network has
learned. The initial weights are Appendix E's, read from
``models/nn/compensator_initial_weights.yaml``.
"""

import dataclasses as dc
from pathlib import Path

import numpy as np
import yaml
from pydrake.systems.framework import Diagram, DiagramBuilder, LeafSystem
from pydrake.systems.primitives import Demultiplexer

from drake_contact.plant.arm import CONTROL_PERIOD, DeclareSampledUpdate, is_sample_time
from drake_contact.errors import ScenarioError
from drake_contact.resources import models_dir

INPUTS, HIDDEN, OUTPUTS = 9, 12, 3
OUTPUT_LAYERS = ("text", "appendix_e")


@dc.dataclass
class NnCompensatorConfig:
    """The 9-12-3 compensator."""

    # Learning rate eta (thesis: 5e-5 for Figs 6.11-6.17, 1e-5 for 6.13-6.14).
    learning_rate: float = 5e-5
    # Train every sample in contact (false: a fixed network).
    learning: bool = True
    # Initial weights: a YAML file, relative to models/ unless absolute.
    initial_weights: str = "nn/compensator_initial_weights.yaml"
    # Output layer: text (V . sigma(h), eq. 4.18) or appendix_e (V . h, the code).
    output_layer: str = "text"
    # Output half-ranges R (N, N, N m): n_k = R_k sigma(o_k).
    output_half_ranges: list[float] = dc.field(default_factory=lambda: [20.0, 10.0, 1.0])
    # Added to the 9 inputs (m, m, rad, m, m, rad, N m x 3); the code's 0.01s.
    input_offsets: list[float] = dc.field(
        default_factory=lambda: [0.0, 0.01, 0.01, 0.0, 0.01, 0.01, 0.0, 0.0, 0.0])

    def validate(self, prefix="controller.nn"):
        if not (0 <= self.learning_rate < 1):
            raise ScenarioError(f"{prefix}.learning_rate = {self.learning_rate} is out of range: "
                                "must be in [0, 1)")
        if self.output_layer not in OUTPUT_LAYERS:
            raise ScenarioError(f"{prefix}.output_layer = '{self.output_layer}' is unknown: "
                                f"choose one of {', '.join(OUTPUT_LAYERS)}")
        if len(self.output_half_ranges) != OUTPUTS or not all(
                r > 0 for r in self.output_half_ranges):
            raise ScenarioError(f"{prefix}.output_half_ranges = {self.output_half_ranges} is out "
                                f"of range: must be {OUTPUTS} values > 0")
        if len(self.input_offsets) != INPUTS or not all(np.isfinite(self.input_offsets)):
            raise ScenarioError(f"{prefix}.input_offsets = {self.input_offsets} is out of range: "
                                f"must be {INPUTS} finite values")
        load_initial_weights(self.initial_weights, f"{prefix}.initial_weights")


def load_initial_weights(path, field="initial_weights"):
    """(W (10 x 12), V (13 x 3)) from a weights file; bias rows first."""
    file = Path(path) if Path(path).is_absolute() else models_dir() / path
    try:
        data = yaml.safe_load(file.read_text())
        W = np.array(data["input_to_hidden"], dtype=float)
        V = np.array(data["hidden_to_output"], dtype=float)
    except (OSError, yaml.YAMLError, KeyError, TypeError, ValueError) as e:
        raise ScenarioError(f"{field} = '{path}' cannot be read as network weights: {e}") from None
    if W.shape != (INPUTS + 1, HIDDEN) or V.shape != (HIDDEN + 1, OUTPUTS):
        raise ScenarioError(
            f"{field} = '{path}' has input_to_hidden {W.shape} and hidden_to_output {V.shape}: "
            f"must be ({INPUTS + 1}, {HIDDEN}) and ({HIDDEN + 1}, {OUTPUTS})")
    return W, V


def _sigma(s):
    return 2.0 / (1.0 + np.exp(-s)) - 1.0


class CompensatorNetwork:
    """The network's arithmetic on a flat weight vector [W.ravel(), V.ravel()]
    (no Drake), for the system and the tests."""

    size = (INPUTS + 1) * HIDDEN + (HIDDEN + 1) * OUTPUTS

    def __init__(self, config: NnCompensatorConfig):
        self.eta = config.learning_rate
        self.R = np.asarray(config.output_half_ranges, dtype=float)
        self.offsets = np.asarray(config.input_offsets, dtype=float)
        self.text_output = config.output_layer == "text"

    @staticmethod
    def pack(W, V):
        return np.concatenate([W.ravel(), V.ravel()])

    @staticmethod
    def unpack(weights):
        split = (INPUTS + 1) * HIDDEN
        return (weights[:split].reshape(INPUTS + 1, HIDDEN),
                weights[split:].reshape(HIDDEN + 1, OUTPUTS))

    def forward(self, weights, inputs):
        """n (3) and the intermediates (u1 = [1, u], h, sigma(h), o)."""
        W, V = self.unpack(weights)
        u1 = np.concatenate([[1.0], inputs + self.offsets])
        h = u1 @ W
        s_h = _sigma(h)
        o = np.concatenate([[1.0], s_h if self.text_output else h]) @ V
        return self.R * _sigma(o), (u1, h, s_h, o)

    def train(self, weights, inputs, error):
        """One step on 1/2 |error|^2, error = target - n at this sample's
        forward pass; returns (new weights, n before the step)."""
        W, V = self.unpack(weights)
        n, (u1, h, s_h, o) = self.forward(weights, inputs)
        delta = error * self.R * 0.5 * (1.0 - (n / self.R) ** 2)  # R sigma'(o)
        back = (V[1:] @ delta) * 0.5 * (1.0 - s_h ** 2)
        V_new = V + self.eta * np.outer(np.concatenate([[1.0], s_h]), delta)
        W_new = W + self.eta * np.outer(u1, back)
        return self.pack(W_new, V_new), n


class NnCompensationLaw(LeafSystem):
    """The compensator's law as one leaf system (see :class:`NnCompensator`
    for the ports): its single output ``compensation`` = [J^T n (3), n (3),
    the weights after this sample's training (159)] is evaluated on the
    inputs at a sample instant and held between them; the discrete update
    at each sample stores the weights, the pose (next sample's previous
    pose) and the held outputs.

    State groups: 0 the weights (159), 1 the previous tip pose (3), 2 the
    held [J^T n, n] (6).
    """

    def __init__(self, config: NnCompensatorConfig, y_desired=0.0, phi_desired=0.0):
        super().__init__()
        config.validate()
        self._net = CompensatorNetwork(config)
        self._learning = config.learning and config.learning_rate > 0
        self._targets = np.array([y_desired, phi_desired])
        self._pose = self.DeclareVectorInputPort("tip_pose", 3)
        self._jacobian = self.DeclareVectorInputPort("tip_jacobian", 9)
        self._tau_h = self.DeclareVectorInputPort("hybrid_torque", 3)
        self._force = self.DeclareVectorInputPort("force", 1)
        self._force_desired = self.DeclareVectorInputPort("force_desired", 1)
        self._mode = self.DeclareVectorInputPort("mode", 1)
        W, V = load_initial_weights(config.initial_weights)
        self._weights = self.DeclareDiscreteState(CompensatorNetwork.pack(W, V))
        self._previous_pose = self.DeclareDiscreteState(3)
        self._held = self.DeclareDiscreteState(6)
        self._size = 6 + len(CompensatorNetwork.pack(W, V))
        self._compensation = self.DeclareVectorOutputPort(
            "compensation", self._size, self._calc_compensation,
            prerequisites_of_calc={self.all_input_ports_ticket(), self.xd_ticket(),
                                   self.time_ticket()})
        DeclareSampledUpdate(self, self._update)

    def _calc_compensation(self, context, output):
        weights = context.get_discrete_state(self._weights).value()
        value = output.get_mutable_value()
        value[6:] = weights
        if not is_sample_time(context.get_time()):
            value[:6] = context.get_discrete_state(self._held).value()
            return
        if self._mode.Eval(context)[0] < 0.5:
            value[:6] = 0.0
            return
        pose = self._pose.Eval(context)
        previous = context.get_discrete_state(self._previous_pose).value()
        inputs = np.concatenate([pose, previous, self._tau_h.Eval(context)])
        if self._learning:
            error = np.concatenate([
                [self._force_desired.Eval(context)[0] - self._force.Eval(context)[0]],
                self._targets - pose[1:]])
            new_weights, n = self._net.train(weights, inputs, error)
            value[6:] = new_weights
        else:
            n = self._net.forward(weights, inputs)[0]
        J = self._jacobian.Eval(context).reshape(3, 3)
        value[:3] = J.T @ n
        value[3:6] = n

    def _update(self, context, state):
        if not is_sample_time(context.get_time()):
            return  # t = 0: the first sample is at 1 ms
        compensation = self._compensation.Eval(context)
        state.get_mutable_vector(self._weights).SetFromVector(compensation[6:])
        state.get_mutable_vector(self._previous_pose).SetFromVector(self._pose.Eval(context))
        state.get_mutable_vector(self._held).SetFromVector(compensation[:6])


class NnCompensator(Diagram):
    """The compensator, sampled every 1 ms in the same event as the hybrid
    controller, whose outputs of this sample it reads.

    Input ports:
      tip_pose (3): measured [x, y, phi] (m, rad);
      tip_jacobian (9): J of [x, y, phi] w.r.t. q, row-major (the hybrid
        controller's, this sample);
      hybrid_torque (3): the hybrid part's motor commands tau_h (N m);
      force (1): the DSP's filtered force (N); force_desired (1) (N);
      mode (1): the controller's mode (1 = contact).
    Output ports (this sample's values, held between samples):
      joint_torque (3): J^T n (N m), zero outside contact;
      nn_output (3): n = [n_x (N), n_y (N), n_phi (N m)].
    State: the weights (159), the previous tip pose, the held outputs.
    Targets y_d = phi_d = 0 (the hybrid controller's). A sub-diagram: the
    law (:class:`NnCompensationLaw`) and a Demultiplexer naming its outputs.
    """

    def __init__(self, config: NnCompensatorConfig, y_desired=0.0, phi_desired=0.0):
        super().__init__()
        builder = DiagramBuilder()
        law = builder.AddNamedSystem("law", NnCompensationLaw(config, y_desired, phi_desired))
        size = law.get_output_port().size()
        split = builder.AddNamedSystem("outputs", Demultiplexer([3, 3, size - 6]))
        builder.Connect(law.get_output_port(), split.get_input_port())
        for port in range(law.num_input_ports()):
            builder.ExportInput(law.get_input_port(port), law.get_input_port(port).get_name())
        builder.ExportOutput(split.get_output_port(0), "joint_torque")
        builder.ExportOutput(split.get_output_port(1), "nn_output")
        builder.BuildInto(self)
