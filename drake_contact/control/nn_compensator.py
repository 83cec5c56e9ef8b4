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
    # Robust modifications of the update (none in the thesis; all off by
    # default, so the reproduction runs the thesis's update). w0 are the
    # initial weights, g the thesis's step eta [1, u] back^T, eta [1, s] delta^T.
    # sigma-modification (leakage; Ioannou & Kokotovic 1983, Ioannou & Sun
    # 1996 sec. 8.5.2): w += g - eta sigma (w - w0). Dimensionless per sample.
    leakage: float = 0.0
    # e-modification (Narendra & Annaswamy 1987): w += g - eta nu |e| (w - w0),
    # |e| the error vector's norm (N, m, rad as they are). Per N per sample.
    e_modification: float = 0.0
    # Dead zone (Peterson & Narendra 1982): no update while |f_d - f| <= this (N).
    dead_zone_n: float = 0.0
    # Normalized gradient (Ioannou & Sun 1996 sec. 4.3): eta / (1 + |[1, u]|^2 +
    # |[1, sigma(h)]|^2) instead of eta.
    normalized: bool = False
    # Projection (Ioannou & Sun 1996 sec. 8.5.4): after each step, |w - w0| <=
    # this bound (0 = unbounded).
    weight_bound: float = 0.0
    # Reference model (s; 0 = none, the thesis): the force error the network
    # learns from is f_m - f, with f_m the desired force through a first-order
    # lag of this time constant, started at the measured force on the switch
    # to contact; a step of f_d asks the network for a response the contact
    # can give, not for the step itself (model-reference adaptive control,
    # Ioannou & Sun 1996 ch. 6; Landau 1979).
    reference_time_constant_s: float = 0.0

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
        for field in ("leakage", "e_modification", "dead_zone_n", "weight_bound",
                      "reference_time_constant_s"):
            value = getattr(self, field)
            if not (np.isfinite(value) and value >= 0):
                raise ScenarioError(f"{prefix}.{field} = {value} is out of range: must be >= 0")
        if self.leakage * self.learning_rate >= 1:
            raise ScenarioError(f"{prefix}.leakage = {self.leakage} is out of range: "
                                "learning_rate * leakage must be < 1")
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
    (no Drake), for the system and the tests.

    One sample's arithmetic runs in work buffers the network owns (the
    system calls it once per 1 ms sample on 9-12-3 arrays, where numpy's
    per-call cost outweighs the arithmetic): the same IEEE operations, in
    the same order, as the array expressions in the docstrings, with the
    3-vectors in Python floats and every matrix product in numpy's BLAS."""

    size = (INPUTS + 1) * HIDDEN + (HIDDEN + 1) * OUTPUTS
    _SPLIT = (INPUTS + 1) * HIDDEN

    def __init__(self, config: NnCompensatorConfig):
        self.eta = config.learning_rate
        self.R = np.asarray(config.output_half_ranges, dtype=float)
        self.offsets = np.asarray(config.input_offsets, dtype=float)
        self.text_output = config.output_layer == "text"
        self._R = [float(r) for r in self.R]
        # [1, u]; u's three parts (pose, previous pose, tau_h) and their offsets.
        self._u1 = np.ones(INPUTS + 1)
        self._u = self._u1[1:]
        self._u_parts = [self._u1[1:4], self._u1[4:7], self._u1[7:10]]
        self._offset_parts = [self.offsets[0:3], self.offsets[3:6], self.offsets[6:9]]
        # [1, h] and [1, sigma(h)]; a scratch 12-vector; the back-propagated
        # hidden errors; o's scratch; delta; n.
        self._h1 = np.ones(HIDDEN + 1)
        self._h = self._h1[1:]
        self._s1 = np.ones(HIDDEN + 1)
        self._s_h = self._s1[1:]
        self._t = np.empty(HIDDEN)
        self._back = np.empty(HIDDEN)
        self._o = np.empty(OUTPUTS)
        self._to = np.empty(OUTPUTS)
        self._delta = np.empty(OUTPUTS)
        self._n = np.empty(OUTPUTS)
        # The step, flat like the weights (eta [1, u] back^T, eta [1, s] delta^T),
        # and the new weights.
        self._step = np.empty(self.size)
        self._step_W = self._step[:self._SPLIT].reshape(INPUTS + 1, HIDDEN)
        self._step_V = self._step[self._SPLIT:].reshape(HIDDEN + 1, OUTPUTS)
        self._u1_column = self._u1[:, None]
        self._s1_column = self._s1[:, None]
        self._new = np.empty(self.size)
        # Robust modifications (see NnCompensatorConfig); w0 the initial weights.
        self.leakage = float(config.leakage)
        self.e_modification = float(config.e_modification)
        self.dead_zone_n = float(config.dead_zone_n)
        self.normalized = bool(config.normalized)
        self.weight_bound = float(config.weight_bound)
        self.robust = bool(self.leakage or self.e_modification or self.dead_zone_n
                           or self.normalized or self.weight_bound)
        self.w0 = self.pack(*load_initial_weights(config.initial_weights))

    @staticmethod
    def pack(W, V):
        return np.concatenate([W.ravel(), V.ravel()])

    @staticmethod
    def unpack(weights):
        split = (INPUTS + 1) * HIDDEN
        return (weights[:split].reshape(INPUTS + 1, HIDDEN),
                weights[split:].reshape(HIDDEN + 1, OUTPUTS))

    def _set_inputs(self, pose, previous, tau_h):
        """u = [pose, previous, tau_h] + offsets, into the [1, u] buffer."""
        for part, value, offset in zip(self._u_parts, (pose, previous, tau_h),
                                       self._offset_parts):
            np.add(value, offset, out=part)

    def _forward(self, weights):
        """The forward pass on the buffered inputs: h, sigma(h), o and n into
        the buffers; returns (V, n as three floats)."""
        split = self._SPLIT
        W = weights[:split].reshape(INPUTS + 1, HIDDEN)
        V = weights[split:].reshape(HIDDEN + 1, OUTPUTS)
        h, t, o, to = self._h, self._t, self._o, self._to
        np.dot(self._u1, W, out=h)                     # h = W^T [1, u]
        np.negative(h, out=t)                          # sigma(h) = 2 / (1 + e^-h) - 1
        np.exp(t, out=t)
        np.add(1.0, t, out=t)
        np.divide(2.0, t, out=t)
        np.subtract(t, 1.0, out=self._s_h)
        np.dot(self._s1 if self.text_output else self._h1, V, out=o)
        np.negative(o, out=to)
        np.exp(to, out=to)
        e0, e1, e2 = to.tolist()
        R0, R1, R2 = self._R
        return V, (R0 * (2.0 / (1.0 + e0) - 1.0), R1 * (2.0 / (1.0 + e1) - 1.0),
                   R2 * (2.0 / (1.0 + e2) - 1.0))

    def _train(self, weights, error):
        """One step on the buffered inputs with error = (e0, e1, e2); the new
        weights into the buffer ``_new``; returns n (three floats)."""
        V, (n0, n1, n2) = self._forward(weights)
        R0, R1, R2 = self._R
        e0, e1, e2 = error
        q0, q1, q2 = n0 / R0, n1 / R1, n2 / R2
        delta = self._delta                            # e R sigma'(o)
        delta[0] = e0 * R0 * 0.5 * (1.0 - q0 * q0)
        delta[1] = e1 * R1 * 0.5 * (1.0 - q1 * q1)
        delta[2] = e2 * R2 * 0.5 * (1.0 - q2 * q2)
        back, t, s_h = self._back, self._t, self._s_h  # (V_1: delta) sigma'(h)
        np.dot(V[1:], delta, out=back)
        np.multiply(back, 0.5, out=back)
        np.multiply(s_h, s_h, out=t)
        np.subtract(1.0, t, out=t)
        np.multiply(back, t, out=back)
        step = self._step                              # eta [1, u] back^T, eta [1, s] delta^T
        np.multiply(self._u1_column, back, out=self._step_W)
        np.multiply(self._s1_column, delta, out=self._step_V)
        if self.robust:
            self._robust_step(weights, (e0, e1, e2))
            return n0, n1, n2
        np.multiply(step, self.eta, out=step)
        np.add(weights, step, out=self._new)
        return n0, n1, n2

    def _robust_step(self, weights, error):
        """The new weights into ``_new`` from the unscaled gradient step in
        ``_step``, with the configured modifications (NnCompensatorConfig)."""
        if abs(error[0]) <= self.dead_zone_n:
            self._new[:] = weights                     # dead zone: no update
            return
        eta = self.eta
        if self.normalized:
            eta = eta / (1.0 + float(self._u1 @ self._u1) + float(self._s1 @ self._s1))
        drift = weights - self.w0
        leak = self.leakage + self.e_modification * float(np.sqrt(sum(e * e for e in error)))
        self._new[:] = weights + eta * self._step - eta * leak * drift
        if self.weight_bound > 0:
            offset = self._new - self.w0
            norm = float(np.sqrt(offset @ offset))
            if norm > self.weight_bound:
                self._new[:] = self.w0 + offset * (self.weight_bound / norm)

    def forward(self, weights, inputs):
        """n (3) and the intermediates (u1 = [1, u], h, sigma(h), o)."""
        np.add(inputs, self.offsets, out=self._u)
        _, n = self._forward(weights)
        return np.array(n), (self._u1.copy(), self._h.copy(), self._s_h.copy(),
                             self._o.copy())

    def train(self, weights, inputs, error):
        """One step on 1/2 |error|^2, error = target - n at this sample's
        forward pass; returns (new weights, n before the step)."""
        np.add(inputs, self.offsets, out=self._u)
        n = self._train(weights, np.asarray(error, dtype=float).tolist())
        return self._new.copy(), np.array(n)


class NnCompensationLaw(LeafSystem):
    """The compensator's law as one leaf system (see :class:`NnCompensator`
    for the ports): its single output ``compensation`` = [J^T n (3), n (3),
    the weights after this sample's training (159)] is evaluated on the
    inputs at a sample instant and held between them; the discrete update
    at each sample stores the weights, the pose (next sample's previous
    pose) and the held outputs.

    State groups: 0 the weights (159), 1 the previous tip pose (3), 2 the
    held [J^T n, n] (6), 3 the reference model's force f_m (1; NaN outside
    contact).
    """

    def __init__(self, config: NnCompensatorConfig, y_desired=0.0, phi_desired=0.0):
        super().__init__()
        config.validate()
        self._net = CompensatorNetwork(config)
        self._learning = config.learning and config.learning_rate > 0
        self._targets = np.array([y_desired, phi_desired])
        self._y_desired, self._phi_desired = (float(x) for x in self._targets)
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
        # The reference model: f_m[k] = a f_m[k-1] + (1 - a) f_d[k], a = e^(-T/tau).
        tau = config.reference_time_constant_s
        self._reference_pole = float(np.exp(-CONTROL_PERIOD / tau)) if tau > 0 else None
        self._reference = self.DeclareDiscreteState([np.nan])
        # Plain ints index the groups (cheaper to pass to pydrake).
        self._i_weights, self._i_previous, self._i_held, self._i_reference = (
            int(i) for i in (self._weights, self._previous_pose, self._held, self._reference))
        self._size = 6 + len(CompensatorNetwork.pack(W, V))
        self._compensation = self.DeclareVectorOutputPort(
            "compensation", self._size, self._calc_compensation,
            prerequisites_of_calc={self.all_input_ports_ticket(), self.xd_ticket(),
                                   self.time_ticket()})
        DeclareSampledUpdate(self, self._update)

    def _calc_compensation(self, context, output):
        weights = context.get_discrete_state(self._i_weights).value()
        value = output.get_mutable_value()
        if not is_sample_time(context.get_time()):
            value[6:] = weights
            value[:6] = context.get_discrete_state(self._i_held).value()
            return
        if self._mode.Eval(context)[0] < 0.5:
            value[6:] = weights
            value[:6] = 0.0
            return
        net = self._net
        pose = self._pose.Eval(context)
        net._set_inputs(pose, context.get_discrete_state(self._i_previous).value(),
                        self._tau_h.Eval(context))
        if self._learning:
            _, y, phi = pose.tolist()
            f = self._force.Eval(context)[0]
            n = net._train(weights, (self._force_target(context, f) - f,
                                     self._y_desired - y, self._phi_desired - phi))
            value[6:] = net._new
        else:
            value[6:] = weights
            n = net._forward(weights)[1]
        n_out = value[3:6]
        n_out[0], n_out[1], n_out[2] = n
        J = self._jacobian.Eval(context).reshape(3, 3)
        np.dot(J.T, n_out, out=value[:3])

    def _force_target(self, context, f):
        """The force the network is asked for at this contact sample: f_d,
        or with a reference model f_m (see NnCompensatorConfig)."""
        f_d = self._force_desired.Eval(context)[0]
        a = self._reference_pole
        if a is None:
            return f_d
        previous = context.get_discrete_state(self._i_reference).value()[0]
        if previous != previous:  # NaN: the first sample in contact
            previous = f
        return a * previous + (1.0 - a) * f_d

    def _update(self, context, state):
        if not is_sample_time(context.get_time()):
            return  # t = 0: the first sample is at 1 ms
        compensation = self._compensation.Eval(context)
        state.get_mutable_value(self._i_weights)[:] = compensation[6:]
        state.get_mutable_value(self._i_previous)[:] = self._pose.Eval(context)
        state.get_mutable_value(self._i_held)[:] = compensation[:6]
        if self._reference_pole is not None:
            reference = state.get_mutable_value(self._i_reference)
            if self._mode.Eval(context)[0] < 0.5:
                reference[0] = np.nan
            else:
                reference[0] = self._force_target(context, self._force.Eval(context)[0])


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
