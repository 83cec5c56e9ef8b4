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

One :class:`NnCompensator` serves N environments (an ensemble; one config
each, a single config for one): the network's arithmetic runs once for all
of them on arrays over the arm axis (weights (N, 159)), each environment
bit for bit what it computes alone. The configs may differ in every number
(rates, ranges, offsets, initial weights, robust gains, the reference
model's time constant), not in the options they switch on.
"""

import dataclasses as dc
import functools
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import yaml
from pydrake.systems.framework import Diagram, DiagramBuilder, LeafSystem
from pydrake.systems.primitives import Demultiplexer

from drake_contact.blocks import environment_configs
from drake_contact.plant.arm import (
    CONTROL_PERIOD, DeclareSampledUpdate, held_while_flagged, is_sample_time)
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
        W, V = (x.copy() for x in _parse_weights(file.read_text()))
    except (OSError, yaml.YAMLError, KeyError, TypeError, ValueError) as e:
        raise ScenarioError(f"{field} = '{path}' cannot be read as network weights: {e}") from None
    if W.shape != (INPUTS + 1, HIDDEN) or V.shape != (HIDDEN + 1, OUTPUTS):
        raise ScenarioError(
            f"{field} = '{path}' has input_to_hidden {W.shape} and hidden_to_output {V.shape}: "
            f"must be ({INPUTS + 1}, {HIDDEN}) and ({HIDDEN + 1}, {OUTPUTS})")
    return W, V


@functools.lru_cache(maxsize=16)
def _parse_weights(text):
    """(W, V) from a weights file's text (parsed once per text: an ensemble
    validates and loads the same file once per environment)."""
    data = yaml.safe_load(text)
    return (np.array(data["input_to_hidden"], dtype=float),
            np.array(data["hidden_to_output"], dtype=float))


def _sigma(s):
    return 2.0 / (1.0 + np.exp(-s)) - 1.0


def _configs(config):
    return environment_configs(config, NnCompensatorConfig, "controller.nn")


_ROBUST_FIELDS = ("leakage", "e_modification", "dead_zone_n", "normalized", "weight_bound")


def structure(config):
    """The options a config switches on or off (its structure), by the field
    that switches each."""
    return {"output_layer": config.output_layer,
            "learning": bool(config.learning and config.learning_rate > 0),
            "robust": any(bool(getattr(config, f)) for f in _ROBUST_FIELDS),
            "normalized": bool(config.normalized),
            "weight_bound": config.weight_bound > 0,
            "reference_time_constant_s": config.reference_time_constant_s > 0}


def _check_structure(configs, prefix="controller.nn"):
    """Raises ScenarioError naming the field if the configs differ in the
    options they switch on (their numbers may differ)."""
    first = structure(configs[0])
    for i, config in enumerate(configs[1:], start=1):
        for switch, value in structure(config).items():
            if value == first[switch]:
                continue
            field = switch
            if switch == "robust":  # named by a robust option on in one, off in the other
                field = next(f for f in _ROBUST_FIELDS
                             if bool(getattr(config, f)) != bool(getattr(configs[0], f)))
            elif switch == "learning":
                field = "learning" if config.learning != configs[0].learning else "learning_rate"
            raise ScenarioError(
                f"{prefix}.{field}: environment {i} switches {switch} to {value} and "
                f"environment 0 to {first[switch]}: the environments' configs must share "
                "their structure (which options are on), not only their numbers")


class CompensatorNetwork:
    """The network's arithmetic for N environments (one config each; a
    single config: N = 1), on flat weight vectors [W.ravel(), V.ravel()]
    stacked as (N, 159) (no Drake), for the system and the tests.

    One sample's arithmetic runs in work buffers the network owns (the
    system calls it once per 1 ms sample on small arrays, where numpy's
    per-call cost outweighs the arithmetic): the same IEEE operations, in
    the same order, as the array expressions in the docstrings, elementwise
    over the arm axis. Each matrix product is numpy's ``matmul`` over the
    stack, which calls BLAS's gemv (or dot) once per environment with the
    arguments ``np.dot`` passes for one: environment i's sums are those of
    the single-environment product, bit for bit (BLAS's kernels fuse and
    reorder the terms, so a product written out elementwise would not be).

    The configs may differ in their numbers (rates, ranges, offsets, initial
    weights, robust gains), not in the options they switch on (see
    :func:`_check_structure`)."""

    size = (INPUTS + 1) * HIDDEN + (HIDDEN + 1) * OUTPUTS
    _SPLIT = (INPUTS + 1) * HIDDEN

    def __init__(self, config: NnCompensatorConfig | Sequence[NnCompensatorConfig]):
        configs = _configs(config)
        _check_structure(configs)
        self.count = count = len(configs)
        first = configs[0]
        # Per environment: (N, 1) to scale (N, 159) rows, (N, k) per output/input.
        self._eta = np.array([[c.learning_rate] for c in configs], dtype=float)
        self._R = np.array([c.output_half_ranges for c in configs], dtype=float)
        self._offsets = np.array([c.input_offsets for c in configs], dtype=float)
        self.text_output = first.output_layer == "text"
        split = self._SPLIT
        # The weights (copied in), W, V and V's rows 1: as views.
        self._w = np.empty((count, self.size))
        self._w_flat = self._w.reshape(-1)
        self._W = self._w[:, :split].reshape(count, INPUTS + 1, HIDDEN)
        self._V = self._w[:, split:].reshape(count, HIDDEN + 1, OUTPUTS)
        self._V1 = self._V[:, 1:]
        # [1, u] (u: pose, previous pose, tau_h) and u's three parts; [1, h].
        self._u1 = np.ones((count, INPUTS + 1))
        self._u = self._u1[:, 1:]
        self._u_parts = [self._u1[:, 1:4], self._u1[:, 4:7], self._u1[:, 7:10]]
        self._offset_parts = [self._offsets[:, 0:3], self._offsets[:, 3:6],
                              self._offsets[:, 6:9]]
        self._h1 = np.ones((count, HIDDEN + 1))
        self._h = self._h1[:, 1:]
        # [1, sigma(h), q = n / R] in one row, and [1 - sigma(h)^2, 1 - q^2]:
        # the two slopes take one pair of calls. The first 12 of the latter
        # are also sigma(h)'s scratch.
        self._s1q = np.ones((count, 1 + HIDDEN + OUTPUTS))
        self._s1 = self._s1q[:, :HIDDEN + 1]
        self._s_h = self._s1q[:, 1:HIDDEN + 1]
        self._q = self._s1q[:, HIDDEN + 1:]
        self._sq = self._s1q[:, 1:]
        self._slopes = np.empty((count, HIDDEN + OUTPUTS))
        self._t = self._slopes[:, :HIDDEN]
        self._slope_q = self._slopes[:, HIDDEN:]
        # The back-propagated hidden errors (and a scratch); o and two
        # scratches; delta and two scratches; n.
        self._back = np.empty((count, HIDDEN))
        self._back_scaled = np.empty((count, HIDDEN))
        self._o = np.empty((count, OUTPUTS))
        self._to = np.empty((count, OUTPUTS))
        self._to2 = np.empty((count, OUTPUTS))
        self._delta = np.empty((count, OUTPUTS))
        self._d1 = np.empty((count, OUTPUTS))
        self._d2 = np.empty((count, OUTPUTS))
        self._squares = np.empty((count, HIDDEN + OUTPUTS))
        self._t2 = np.empty((count, HIDDEN))
        self.n = np.empty((count, OUTPUTS))
        # Constants as arrays of their operands' shapes (numpy's per-call
        # cost on these small arrays is lower than with a Python float).
        self._ones_h, self._twos_h = np.ones((count, HIDDEN)), np.full((count, HIDDEN), 2.0)
        self._halves_h = np.full((count, HIDDEN), 0.5)
        self._ones_o, self._twos_o = np.ones((count, OUTPUTS)), np.full((count, OUTPUTS), 2.0)
        self._halves_o = np.full((count, OUTPUTS), 0.5)
        self._ones_hq = np.ones((count, HIDDEN + OUTPUTS))
        self._eta_full = np.repeat(self._eta, self.size, axis=1)
        # The stacked rows and columns matmul reads and writes.
        self._u1_row, self._u1_column = self._u1[:, None, :], self._u1[:, :, None]
        self._s1_row, self._s1_column = self._s1[:, None, :], self._s1[:, :, None]
        self._o_input_row = (self._s1 if self.text_output else self._h1)[:, None, :]
        self._h_row, self._o_row = self._h[:, None, :], self._o[:, None, :]
        self._back_column = self._back[:, :, None]
        self._back_scaled_row = self._back_scaled[:, None, :]
        self._delta_row, self._delta_column = self._delta[:, None, :], self._delta[:, :, None]
        # The step, flat like the weights ([1, u] back^T, [1, s] delta^T),
        # the step times eta, and the new weights.
        self._step = np.empty((count, self.size))
        self._step_W = self._step[:, :split].reshape(count, INPUTS + 1, HIDDEN)
        self._step_V = self._step[:, split:].reshape(count, HIDDEN + 1, OUTPUTS)
        self._eta_step = np.empty((count, self.size))
        self._new = np.empty((count, self.size))
        self._drift = np.empty((count, self.size))
        self._stepped = np.empty((count, self.size))
        self._squares_e = np.empty((OUTPUTS, count))
        self._sums = np.empty((2, count))
        self._leak = np.empty((count, 1))
        self._still = np.empty(count, dtype=bool)
        # Robust modifications (see NnCompensatorConfig); w0 the initial weights.
        self._leakage = np.array([c.leakage for c in configs], dtype=float)
        self._e_modification = np.array([c.e_modification for c in configs], dtype=float)
        self._dead_zone_n = np.array([c.dead_zone_n for c in configs], dtype=float)
        self._weight_bound = np.array([[c.weight_bound] for c in configs], dtype=float)
        self.normalized = bool(first.normalized)
        self.bounded = first.weight_bound > 0
        self.robust = structure(first)["robust"]
        loaded = {}
        for c in configs:
            if c.initial_weights not in loaded:
                loaded[c.initial_weights] = self.pack(*load_initial_weights(c.initial_weights))
        self._w0 = np.array([loaded[c.initial_weights] for c in configs])
        # A single config's view: the attributes as for one network.
        self._single = isinstance(config, NnCompensatorConfig)
        if self._single:
            self.eta, self.R, self.offsets = first.learning_rate, self._R[0], self._offsets[0]
            self.leakage, self.e_modification = float(first.leakage), float(first.e_modification)
            self.dead_zone_n = float(first.dead_zone_n)
            self.weight_bound = float(first.weight_bound)
            self.w0 = self._w0[0]
        else:
            self.eta, self.R, self.offsets = self._eta[:, 0], self._R, self._offsets
            self.leakage, self.e_modification = self._leakage, self._e_modification
            self.dead_zone_n, self.weight_bound = self._dead_zone_n, self._weight_bound[:, 0]
            self.w0 = self._w0

    @staticmethod
    def pack(W, V):
        return np.concatenate([W.ravel(), V.ravel()])

    @staticmethod
    def unpack(weights):
        split = (INPUTS + 1) * HIDDEN
        return (weights[:split].reshape(INPUTS + 1, HIDDEN),
                weights[split:].reshape(HIDDEN + 1, OUTPUTS))

    def set_inputs(self, pose, previous, tau_h):
        """u = [pose, previous, tau_h] + offsets, into the [1, u] buffer;
        each argument (N, 3)."""
        parts, offsets = self._u_parts, self._offset_parts
        np.add(pose, offsets[0], parts[0])
        np.add(previous, offsets[1], parts[1])
        np.add(tau_h, offsets[2], parts[2])

    def load(self, weights):
        """Copies ``weights`` (159 N, env-major) in."""
        np.copyto(self._w_flat, weights)

    def _forward(self, n):
        """The forward pass on the buffered inputs and weights: h, sigma(h)
        and o into the buffers, n into ``n`` (N, 3)."""
        t, t2, to, to2 = self._t, self._t2, self._to, self._to2
        np.matmul(self._u1_row, self._W, self._h_row)      # h = W^T [1, u]
        np.negative(self._h, t)                            # sigma(h) = 2 / (1 + e^-h) - 1
        np.exp(t, t2)
        np.add(self._ones_h, t2, t)
        np.divide(self._twos_h, t, t2)
        np.subtract(t2, self._ones_h, self._s_h)
        np.matmul(self._o_input_row, self._V, self._o_row)
        np.negative(self._o, to)                           # n = R sigma(o)
        np.exp(to, to2)
        np.add(self._ones_o, to2, to)
        np.divide(self._twos_o, to, to2)
        np.subtract(to2, self._ones_o, to)
        np.multiply(self._R, to, n)

    def _train(self, error, n, new):
        """One step on the buffered inputs and weights with ``error`` (N, 3)
        = (f, y, phi) errors: n into ``n`` (N, 3), the new weights into
        ``new`` (N, 159)."""
        self._forward(n)
        R, delta, d1, d2 = self._R, self._delta, self._d1, self._d2
        np.divide(n, R, self._q)                           # sigma(o) = n / R
        np.multiply(self._sq, self._sq, self._squares)     # 1 - sigma^2, of h and of o
        np.subtract(self._ones_hq, self._squares, self._slopes)
        np.multiply(error, R, d1)                          # delta = e R 0.5 (1 - sigma(o)^2)
        np.multiply(d1, self._halves_o, d2)
        np.multiply(d2, self._slope_q, delta)
        back, scaled = self._back, self._back_scaled       # (V_1: delta) 0.5 (1 - sigma(h)^2)
        np.matmul(self._V1, self._delta_column, self._back_column)
        np.multiply(back, self._halves_h, self._t2)
        np.multiply(self._t2, self._t, scaled)
        np.multiply(self._u1_column, self._back_scaled_row, self._step_W)
        np.multiply(self._s1_column, self._delta_row, self._step_V)
        if self.robust:
            self._robust_step(error, new)
            return
        np.multiply(self._step, self._eta_full, self._eta_step)  # w + eta step
        np.add(self._w, self._eta_step, new)

    def _robust_step(self, error, new):
        """The new weights into ``new`` from the unscaled gradient step in
        ``_step``, with the configured modifications (NnCompensatorConfig):
        w + eta g - eta (sigma + nu |e|) (w - w0), then the projection; w
        where |e_f| <= the dead zone."""
        weights, w0, step, drift = self._w, self._w0, self._step, self._drift
        count = self.count
        if self.normalized:
            norms = np.matmul(self._u1_row, self._u1_column).reshape(count, 1)
            norms += 1.0                                   # (1 + |u1|^2) + |s1|^2
            norms += np.matmul(self._s1_row, self._s1_column).reshape(count, 1)
            eta = self._eta / norms
            np.multiply(eta, step, self._eta_step)
        else:
            eta = self._eta
            np.multiply(self._eta_full, step, self._eta_step)
        np.subtract(weights, w0, drift)
        squares, sums, leak = self._squares_e, self._sums, self._leak
        np.multiply(error.T, error.T, squares)             # |e|, as Python's sum: ((0 + a) + b) + c
        np.add(squares[0], squares[1], sums[0])
        np.add(sums[0], squares[2], sums[1])
        np.sqrt(sums[1], sums[0])
        np.multiply(self._e_modification, sums[0], sums[1])  # sigma + nu |e|
        np.add(self._leakage, sums[1], leak[:, 0])
        np.multiply(eta, leak, leak)                       # eta (sigma + nu |e|) (w - w0)
        np.multiply(leak, drift, drift)
        np.add(weights, self._eta_step, self._stepped)
        np.subtract(self._stepped, drift, new)
        if self.bounded:
            offset = new - w0
            norm = np.matmul(offset[:, None, :], offset[:, :, None]).reshape(count, 1)
            np.sqrt(norm, out=norm)
            outside = norm > self._weight_bound
            if np.count_nonzero(outside):
                scale = np.divide(self._weight_bound, norm, out=np.ones_like(norm),
                                  where=outside)
                np.copyto(new, w0 + offset * scale, where=outside)
        # Dead zone: no update while |f_d - f| <= dead_zone_n.
        still = np.less_equal(np.abs(error[:, 0]), self._dead_zone_n, self._still)
        if np.count_nonzero(still):
            np.copyto(new, weights, where=still[:, None])

    def _stack(self, weights, inputs, *more):
        single = np.ndim(weights) == 1
        if single != (np.ndim(inputs) == 1):
            raise ValueError("weights and inputs: both one environment's or both stacked")
        arrays = [np.asarray(a, dtype=float).reshape(self.count, -1)
                  for a in (weights, inputs, *more)]
        np.copyto(self._w, arrays[0])
        np.add(arrays[1], self._offsets, out=self._u)
        return single, arrays

    def forward(self, weights, inputs):
        """n and the intermediates (u1 = [1, u], h, sigma(h), o) for
        ``weights`` (159, or (N, 159)) and ``inputs`` (9 or (N, 9)); the
        results 1-D for 1-D arguments, else stacked."""
        single, _ = self._stack(weights, inputs)
        self._forward(self.n)
        parts = (self.n, self._u1, self._h, self._s_h, self._o)
        if single:
            parts = tuple(part[0] for part in parts)
        n, *intermediates = (part.copy() for part in parts)
        return n, tuple(intermediates)

    def train(self, weights, inputs, error):
        """One step on 1/2 |error|^2, error = target - n at this sample's
        forward pass; returns (new weights, n before the step), 1-D for
        1-D arguments, else stacked (N, ...)."""
        single, (_, _, error) = self._stack(weights, inputs, error)
        self._train(error, self.n, self._new)
        if single:
            return self._new[0].copy(), self.n[0].copy()
        return self._new.copy(), self.n.copy()


class NnCompensationLaw(LeafSystem):
    """The compensator's law as one leaf system for N environments (one
    config each; see :class:`NnCompensator` for the ports): its single
    output ``compensation`` = [J^T n (3 N), n (3 N), the weights after this
    sample's training (159 N)], each field env-major, is evaluated on the
    inputs at a sample instant and held between them (a cached output: the
    law runs once per sample); the discrete update at each sample stores
    the weights, the pose (next sample's previous pose) and the held
    outputs.

    State groups (each env-major): 0 the weights (159 N), 1 the previous
    tip pose (3 N), 2 the held [J^T n (3 N), n (3 N)] (field-major, as in
    the output), 3 the reference model's force f_m (N; NaN outside contact).
    """

    def __init__(self, config: NnCompensatorConfig | Sequence[NnCompensatorConfig],
                 y_desired=0.0, phi_desired=0.0):
        super().__init__()
        configs = _configs(config)
        for i, c in enumerate(configs):
            c.validate("controller.nn" if len(configs) == 1 else f"controller.nn[{i}]")
        self._net = net = CompensatorNetwork(
            config if isinstance(config, NnCompensatorConfig) else configs)
        self._count = count = net.count
        self._learning = structure(configs[0])["learning"]
        # Targets (N, 2): [y_d, phi_d] per environment.
        self._targets = np.stack([np.broadcast_to(np.asarray(y_desired, dtype=float), count),
                                  np.broadcast_to(np.asarray(phi_desired, dtype=float), count)],
                                 axis=1)
        self._pose = self.DeclareVectorInputPort("tip_pose", 3 * count)
        self._jacobian = self.DeclareVectorInputPort("tip_jacobian", 9 * count)
        self._tau_h = self.DeclareVectorInputPort("hybrid_torque", 3 * count)
        self._force = self.DeclareVectorInputPort("force", count)
        self._force_desired = self.DeclareVectorInputPort("force_desired", count)
        self._mode = self.DeclareVectorInputPort("mode", count)
        # The safety supervisor's flag: while it is up, the compensator holds
        # its output and state (unconnected: never).
        self._fault = self.DeclareVectorInputPort("force_fault", count)
        self._weights = self.DeclareDiscreteState(net._w0.ravel())
        self._previous_pose = self.DeclareDiscreteState(3 * count)
        self._held = self.DeclareDiscreteState(6 * count)
        # The reference model: f_m[k] = a f_m[k-1] + (1 - a) f_d[k], a = e^(-T/tau).
        self._reference_model = configs[0].reference_time_constant_s > 0
        poles = [float(np.exp(-CONTROL_PERIOD / c.reference_time_constant_s))
                 if c.reference_time_constant_s > 0 else 0.0 for c in configs]
        self._reference_pole = np.array(poles)
        self._reference_gain = np.array([1.0 - a for a in poles])
        self._reference = self.DeclareDiscreteState(np.full(count, np.nan))
        # Plain ints index the groups (cheaper to pass to pydrake).
        self._i_weights, self._i_previous, self._i_held, self._i_reference = (
            int(i) for i in (self._weights, self._previous_pose, self._held, self._reference))
        self._size = (6 + CompensatorNetwork.size) * count
        # Work buffers: the error (N, 3) the network learns from; the mode
        # test; the reference model's target (numpy's per-call cost
        # dominates on (N,) arrays: constants are arrays too).
        self._error = np.empty((count, OUTPUTS))
        self._force_error, self._pose_error = self._error[:, 0], self._error[:, 1:]
        self._halves = np.full(count, 0.5)
        self._approach = np.empty(count, dtype=bool)
        self._first = np.empty(count, dtype=bool)
        self._target = np.empty(count)
        self._target_terms = np.empty((2, count))
        self._compensation = self.DeclareVectorOutputPort(
            "compensation", self._size, self._calc_compensation,
            prerequisites_of_calc={self.all_input_ports_ticket(), self.xd_ticket(),
                                   self.time_ticket()})
        DeclareSampledUpdate(self, self._update)

    def _calc_compensation(self, context, output):
        count = self._count
        held = 6 * count
        weights = context.get_discrete_state(self._i_weights).value()
        value = output.get_mutable_value()
        paused = None
        if is_sample_time(context.get_time()):
            paused = held_while_flagged(self._fault, context)
        if not is_sample_time(context.get_time()) or paused is not None and paused.all():
            value[held:] = weights
            value[:held] = context.get_discrete_state(self._i_held).value()
            return
        approach = np.less(self._mode.Eval(context), self._halves, self._approach)
        approaching = np.count_nonzero(approach)
        if approaching == count:
            value[held:] = weights
            value[:held] = 0.0
            return
        net = self._net
        pose = self._pose.Eval(context).reshape(count, 3)
        previous = context.get_discrete_state(self._i_previous).value().reshape(count, 3)
        net.set_inputs(pose, previous, self._tau_h.Eval(context).reshape(count, 3))
        net.load(weights)
        # The network writes n and the new weights into the output.
        n = value[3 * count:held].reshape(count, 3)
        new = value[held:].reshape(count, CompensatorNetwork.size)
        if self._learning:
            f = self._force.Eval(context)
            np.subtract(self._force_target(context, f), f, self._force_error)
            np.subtract(self._targets, pose[:, 1:], self._pose_error)
            net._train(self._error, n, new)
        else:
            net._forward(n)
            new[:] = net._w
        # J^T n = (n^T J)^T, J row-major (N, 3, 3).
        np.matmul(n[:, None, :], self._jacobian.Eval(context).reshape(count, 3, 3),
                  value[:3 * count].reshape(count, 1, 3))
        if approaching:  # outside contact: no learning, no compensation
            value[:held].reshape(2, count, 3)[:, approach] = 0.0
            new[approach] = net._w[approach]
        if paused is not None:  # held: the output and weights of before
            value[:held].reshape(2, count, 3)[:, paused] = context.get_discrete_state(
                self._i_held).value().reshape(2, count, 3)[:, paused]
            new[paused] = weights.reshape(count, CompensatorNetwork.size)[paused]

    def _force_target(self, context, f):
        """The force (N) the network is asked for at this contact sample:
        f_d, or with a reference model f_m (see NnCompensatorConfig)."""
        f_d = self._force_desired.Eval(context)
        if not self._reference_model:
            return f_d
        previous = context.get_discrete_state(self._i_reference).value()
        if np.count_nonzero(np.not_equal(previous, previous, self._first)):
            previous = np.where(self._first, f, previous)  # NaN: the first sample in contact
        lag, step, target = self._target_terms[0], self._target_terms[1], self._target
        np.multiply(self._reference_pole, previous, lag)
        np.multiply(self._reference_gain, f_d, step)
        np.add(lag, step, target)
        return target

    def _update(self, context, state):
        if not is_sample_time(context.get_time()):
            return  # t = 0: the first sample is at 1 ms
        held = 6 * self._count
        compensation = self._compensation.Eval(context)
        state.get_mutable_value(self._i_weights)[:] = compensation[held:]
        state.get_mutable_value(self._i_held)[:] = compensation[:held]
        paused = held_while_flagged(self._fault, context)
        if paused is not None:  # the pose and reference of before, too
            previous = state.get_mutable_value(self._i_previous).reshape(self._count, 3)
            previous[~paused] = self._pose.Eval(context).reshape(self._count, 3)[~paused]
            if self._reference_model:
                reference = state.get_mutable_value(self._i_reference)
                kept = reference.copy()
                self._update_reference(context, reference)
                reference[paused] = kept[paused]
            return
        state.get_mutable_value(self._i_previous)[:] = self._pose.Eval(context)
        if self._reference_model:
            self._update_reference(context, state.get_mutable_value(self._i_reference))

    def _update_reference(self, context, reference):
        """f_m at this sample into ``reference``, forgotten outside contact."""
        approach = np.less(self._mode.Eval(context), self._halves, self._approach)
        approaching = np.count_nonzero(approach)
        if approaching < self._count:
            reference[:] = self._force_target(context, self._force.Eval(context))
        if approaching:
            reference[approach] = np.nan


class NnCompensator(Diagram):
    """The compensator for N environments (one config each; a single config:
    N = 1), sampled every 1 ms in the same event as the hybrid controller,
    whose outputs of this sample it reads.

    Input ports (env-major: environment i's k values at [k i, k i + k)):
      tip_pose (3 N): measured [x, y, phi] (m, rad);
      tip_jacobian (9 N): J of [x, y, phi] w.r.t. q, row-major (the hybrid
        controller's, this sample);
      hybrid_torque (3 N): the hybrid part's motor commands tau_h (N m);
      force (N): the DSP's filtered force (N); force_desired (N) (N);
      mode (N): the controller's mode (1 = contact).
    Output ports (this sample's values, held between samples; env-major):
      joint_torque (3 N): J^T n (N m), zero outside contact;
      nn_output (3 N): n = [n_x (N), n_y (N), n_phi (N m)].
    State: the weights (159 N), the previous tip pose, the held outputs.
    Targets y_d, phi_d (one, or one per environment) are the hybrid
    controller's. A sub-diagram: the law (:class:`NnCompensationLaw`) and a
    Demultiplexer naming its outputs.
    """

    def __init__(self, config: NnCompensatorConfig | Sequence[NnCompensatorConfig],
                 y_desired=0.0, phi_desired=0.0):
        super().__init__()
        builder = DiagramBuilder()
        law = builder.AddNamedSystem("law", NnCompensationLaw(config, y_desired, phi_desired))
        count = law._count
        size = law.get_output_port().size()
        split = builder.AddNamedSystem("outputs",
                                       Demultiplexer([3 * count, 3 * count, size - 6 * count]))
        builder.Connect(law.get_output_port(), split.get_input_port())
        for port in range(law.num_input_ports()):
            builder.ExportInput(law.get_input_port(port), law.get_input_port(port).get_name())
        builder.ExportOutput(split.get_output_port(0), "joint_torque")
        builder.ExportOutput(split.get_output_port(1), "nn_output")
        builder.BuildInto(self)
