"""Online identification of the environment's impedance by a neural network
(thesis chapter 5): a 3-4-1 network in parallel with the environment.

Inputs u = (s_x xe, s_v xe', s_a xe'') (scaled so their magnitudes match;
styrofoam s_x = 1000, rubber 10000, s_v = 100), four bipolar-sigmoid hidden
neurons f(h) = 2/(1 + e^-h) - 1 with biases, and an output neuron scaled to
newtons: the text's, a bipolar sigmoid as in its controller (section 5.2,
``output_layer: sigmoid``, f_hat = S f(v . [1, f(h)])), which the thesis
scenarios' networks use with S = 40 N (the thesis gives no range; 20 N,
its controller's, could not reach the 20-28 N the wall returns), or a
linear one (ours, the default: f_hat = S (v . [1, f(h)])). Every 1 ms after
the contact switch one gradient step on E = 1/2 (f - f_hat)^2 with learning
rate eta (1e-4).

Explicit coefficients by probing with "dummy" inputs at (x*, v*, a*):

    K_e = f_hat(x*, 0, 0) / x*
    B_e = (f_hat(x*, v*, 0) - f_hat(x*, 0, 0)) / v*
    M_e = (f_hat(x*, v*, a*) - f_hat(x*, v*, 0)) / a*

The thesis's K_e formula is a secant through the origin: it takes the
network's output at x* as K_e x*. But xe is measured from the switch point,
where the force is already about 5 N, so the network learns f = 5 N + K_e xe
and the secant over-estimates K_e by about 5 N / x* (+35-80 % here). The
option ``force_offset`` (ours, like the RLS's) trains the network on
f - f_s, with f_s the force it reads at its first sample after the switch,
so that the secant is K_e again; its ``force_estimate`` adds f_s back. The
network sees only one resting operating point after the ~100 ms switch
transient, so K_e comes out right only near that point: probe x* at the
displacement it rests at (2 mm styrofoam, 0.3 mm rubber here), as the thesis
says ("dummy values close to learned values"). B_e and M_e rest on the
transient alone and depend on the initial weights, which are seeded by the
run's seed and the identifier's ``seed_key`` (its name by default).

Self-scaling (ours; ``normalization: running``): no per-material
constant. Each input is divided by the largest magnitude it has taken since
the switch, s_i = max(floor_i, max |x_i|), and the output by the largest
|f - f_s| so far, s_f, so u = x / s lies in [-1, 1] and

    f_hat = s_f (v . [1, f(W [1, x / s])])

with one gradient step of rate eta on the normalized loss
1/2 ((f - f_s - f_hat) / s_f)^2 (normalized LMS, Widrow & Lehr 1990; running
input scales as in online normalization, e.g. Chiley et al. 2019):

    e = (f - f_s - f_hat) / s_f
    v += eta e [1, f(h)]
    W += eta outer(e v_1: (1 - f(h)^2) / 2, [1, u])

The scales are updated with the sample before the step. ``readout`` then
reads (M_e, B_e, K_e) at the current operating point x = (xe, xe', xe''):

- ``jacobian``: the partial derivatives of f_hat,
  d f_hat / d x_i = (s_f / s_i) sum_k v_k (1 - f(h_k)^2) / 2 W_k,i.
- ``operating_point``: the thesis's secants with the probe replaced by the
  current displacement and the running scales, x* = xe (at least its floor),
  v* = s_v, a* = s_a:
  K_e = f_hat(xe, 0, 0) / xe, B_e = (f_hat(xe, s_v, 0) - f_hat(xe, 0, 0)) / s_v,
  M_e = (f_hat(xe, s_v, s_a) - f_hat(xe, s_v, 0)) / s_a.

Which readout, measured on identify_any (walls 5-120 kN/m off the sweep's
grid): the Jacobian reads K_e near zero (-100 %). After the 50-100 ms switch
transient the arm rests at one point, so the data pin f_hat there and not its
slope; and in the transient, with running-max scales, input and target
normalized are both about 1 all through the monotone rise, so no slope is
learned there either (replaying stored transient samples offline did not
rescue it: -27 to -97 %). The secant at the current displacement needs only
the level the network holds at rest, f_hat(xe) = f - f_s, so it is K_e up to
the anchor's error: the force at the switch less the static force there,
over f - f_s (the identifier's ``signals`` decide f_s; docs/reproduction.md, "nn_auto").

With ``readout_time_constant_s`` tau, ``operating_point`` reports each
coefficient as the exponentially weighted least-squares fit of its
secants since the switch: for K_e, the slope through the origin of the
network's rest force f_hat(x*_i, 0, 0) over the displacements x*_i visited,

    K_e = sum_i d^(k-i) x*_i f_hat(x*_i, 0, 0) / sum_i d^(k-i) x*_i^2,   d = e^(-T/tau),

and B_e, M_e likewise with the steps v*, a*. Each sample's secant
rise / step weighs by step^2, the inverse of its variance when the rise
carries a fixed error, so the first samples after the switch, whose
displacement is microns and whose secants are wild, count for almost
nothing; and the average takes out the readout's swing with a probing
signal (the secant at the current displacement moves some 5 % with
identify_any's 1.7 Hz probe). tau = 0 reads each sample's secants alone.

The floors (1 um, 0.1 mm/s, 0.01 m/s^2, 0.1 N) only keep the first samples
finite: each is below what any wall's 20 N transient reaches (xe is 0.1 mm at
150 kN/m), so no scale rests on one.
"""

import dataclasses as dc
from collections.abc import Sequence

import numpy as np
from pydrake.systems.framework import LeafSystem

from drake_contact.blocks import environment_configs
from drake_contact.plant.arm import CONTROL_PERIOD, DeclareSampledUpdate, held_while_flagged
from drake_contact.errors import ScenarioError
from drake_contact.arm_axis import check_switches
from drake_contact.identification.stacked import (
    at, constants, every, products, stepped, together)

HIDDEN = 4
OUTPUT_LAYERS = ("linear", "sigmoid", "appendix_e")
NORMALIZATIONS = ("fixed", "running")
READOUTS = ("probe", "operating_point", "jacobian")


@dc.dataclass
class NnIdentifierConfig:
    """The 3-4-1 identifier network."""

    # Learning rate eta (thesis: 1e-4; Fig 6.6 uses a smaller one).
    learning_rate: float = 1e-4
    # Input scales for (xe, xe', xe''); styrofoam 1000, rubber 10000 on xe.
    input_scale: list[float] = dc.field(default_factory=lambda: [1000.0, 100.0, 1.0])
    # Output scale S (N).
    output_scale_n: float = 20.0
    # Probe point (m, m/s, m/s^2); styrofoam (2e-3, 1e-2, 1), rubber (2e-4, 1e-2, 0.5).
    probe: list[float] = dc.field(default_factory=lambda: [2e-3, 1e-2, 1.0])
    # Train on f - f_s, f_s the force at the switch (removes the switch-point bias).
    force_offset: bool = False
    # Standard deviation of the seeded initial weights.
    initial_weight_std: float = 0.3
    # Output layer: linear, f_hat = S (v . [1, f(h)]) (ours, the default);
    # sigmoid, f_hat = S f(v . [1, f(h)]), the text's network (sections 4.5
    # and 5.2; see SigmoidImpedanceNetwork); or appendix_e,
    # f_hat = S f(v . [1, h]) with the update of the text's network, as
    # Appendix E codes its controller's network (see AppendixEImpedanceNetwork).
    output_layer: str = "linear"
    # Input and output scales: fixed (input_scale, output_scale_n: the thesis)
    # or running (ours: the largest |x_i| and |f - f_s| since the switch, at
    # least scale_floor; learning_rate is then the rate on the normalized loss).
    normalization: str = "fixed"
    # Floors of the running scales (m, m/s, m/s^2, N): below any wall's transient.
    scale_floor: list[float] = dc.field(default_factory=lambda: [1e-6, 1e-4, 1e-2, 0.1])
    # Readout of (M_e, B_e, K_e): probe (secants at the fixed probe point: the
    # thesis), operating_point (secants at the current xe, steps = running
    # scales) or jacobian (partial derivatives at the current sample); the
    # last two need normalization: running.
    readout: str = "probe"
    # Time constant (s) of the readout's averaging, operating_point only (0 =
    # each sample's secants as they are): the exponentially weighted least
    # squares over the samples since the switch, each secant weighted by its
    # step squared (see the module doc).
    readout_time_constant_s: float = 0.0

    def validate(self, prefix):
        if not (0 < self.learning_rate < 1):
            raise ScenarioError(f"{prefix}.learning_rate = {self.learning_rate} is out of range: "
                                "must be in (0, 1)")
        if len(self.input_scale) != 3 or not all(np.isfinite(x) and x > 0
                                                 for x in self.input_scale):
            raise ScenarioError(f"{prefix}.input_scale = {self.input_scale} is out of range: "
                                "must be 3 finite values > 0")
        # The estimates divide by the probe point: a subnormal one overflows.
        if len(self.probe) != 3 or not all(np.isfinite(x) and x >= 1e-9 for x in self.probe):
            raise ScenarioError(f"{prefix}.probe = {self.probe} is out of range: "
                                "must be 3 finite values >= 1e-09 (m, m/s, m/s^2)")
        if self.normalization not in NORMALIZATIONS:
            raise ScenarioError(f"{prefix}.normalization = '{self.normalization}' is unknown: "
                                f"choose one of {', '.join(NORMALIZATIONS)}")
        if self.readout not in READOUTS:
            raise ScenarioError(f"{prefix}.readout = '{self.readout}' is unknown: "
                                f"choose one of {', '.join(READOUTS)}")
        if self.readout != "probe" and self.normalization != "running":
            raise ScenarioError(f"{prefix}.readout = '{self.readout}' needs "
                                f"{prefix}.normalization = 'running' (the running scales "
                                "are its steps)")
        tau = self.readout_time_constant_s
        if not (np.isfinite(tau) and 0 <= tau <= 100):
            raise ScenarioError(f"{prefix}.readout_time_constant_s = {tau} is out of range: "
                                "must be in [0, 100] s")
        if tau > 0 and self.readout != "operating_point":
            raise ScenarioError(f"{prefix}.readout_time_constant_s = {tau} needs "
                                f"{prefix}.readout = 'operating_point' (it averages its "
                                "secants)")
        if len(self.scale_floor) != 4 or not all(np.isfinite(x) and x > 0
                                                 for x in self.scale_floor):
            raise ScenarioError(f"{prefix}.scale_floor = {self.scale_floor} is out of range: "
                                "must be 4 finite values > 0 (m, m/s, m/s^2, N)")
        for field in ("output_scale_n", "initial_weight_std"):
            value = getattr(self, field)
            if not (np.isfinite(value) and value > 0):
                raise ScenarioError(f"{prefix}.{field} = {value} is out of range: "
                                    "must be finite and > 0")
        if self.output_layer not in OUTPUT_LAYERS:
            raise ScenarioError(f"{prefix}.output_layer = '{self.output_layer}' is unknown: "
                                f"choose one of {', '.join(OUTPUT_LAYERS)}")
        if self.output_layer != "linear" and self.normalization != "fixed":
            raise ScenarioError(f"{prefix}.output_layer = '{self.output_layer}' is out of "
                                "range with normalization 'running': the running scales "
                                "are built for the linear output layer")


def structure(config):
    """The options a config switches on (its structure: which arithmetic
    runs and the state's shape), by field."""
    return {"output_layer": config.output_layer, "normalization": config.normalization,
            "readout": config.readout,
            "readout_time_constant_s": config.readout_time_constant_s > 0}


def check_structure(configs, prefix="identifiers.nn"):
    """Raises ScenarioError naming the field if the environments' configs
    differ in an option they switch (their numbers may differ, and so may
    force_offset: an anchor f_s of 0 is the arithmetic without it)."""
    check_switches(configs, structure, prefix)


def _configs(config):
    return environment_configs(config, NnIdentifierConfig, "identifiers.nn")


class ImpedanceNetwork:
    """The network's arithmetic on flat weight vectors (no Drake), for one
    environment or N (one config each), weights (size,) or stacked (N, size).

    Layout: W (HIDDEN x 4, inputs [1, u]) then v (1 + HIDDEN), row-major.

    One sample's arithmetic runs in work buffers the network owns (the
    system trains and probes it every 1 ms on 4-vectors, where numpy's
    per-call cost outweighs the arithmetic): the same IEEE operations, in
    the same order, as the array expressions in the docstrings, elementwise
    over the arm axis, written once for one environment (its scalars Python
    floats, its buffers without the environment axis) and N
    (:mod:`drake_contact.identification.stacked`), so that each
    environment's values are bit for bit its own alone.

    The public methods take one environment's arrays (1-D) or the stack
    (N, ...) and answer likewise.
    """

    size = HIDDEN * 4 + HIDDEN + 1
    _SPLIT = HIDDEN * 4

    def __init__(self, config: NnIdentifierConfig | Sequence[NnIdentifierConfig]):
        configs = _configs(config)
        check_structure(configs)
        self.configs = configs
        self.c = configs[0]
        self.count = count = len(configs)
        self._one = one = count == 1
        self._matvec, self._rowdot = products(one)
        lead = () if one else (count,)
        self._lead = lead
        # Per environment, as the operands of one environment's arithmetic.
        scales = np.array([c.input_scale for c in configs], dtype=float)   # (N, 3)
        self.scale = scales[0] if one else scales
        self._s = [constants(scales[:, k], one) for k in range(3)]
        self._S = constants([c.output_scale_n for c in configs], one)
        self._eta = constants([c.learning_rate for c in configs], one)
        self._eta_matrix = self._eta if one else self._eta[:, :, None]
        self._probe = np.array([c.probe for c in configs], dtype=float)     # (N, 3): x*, v*, a*
        self._xs, self._vs, self._acc = (constants(self._probe[:, k], one) for k in range(3))
        self._probe_point = self._probe[0] if one else self._probe
        self._floor = np.array([c.scale_floor for c in configs], dtype=float)
        # Where v_0, v_1: and W are in the weights.
        split = self._SPLIT
        self._v0 = at(split, one)
        self._v1 = slice(split + 1, None) if one else (slice(None), slice(split + 1, None))
        self._w_part = slice(None, split) if one else (slice(None), slice(None, split))
        self._v_part = slice(split, None) if one else (slice(None), slice(split, None))
        self._u1 = np.ones(lead + (4,))                # [1, scale * x]
        self._u_at = [at(k, one) for k in range(4)]
        self._u1_row = self._u1[..., None, :]
        self._h1 = np.ones(lead + (HIDDEN + 1,))       # [1, f(h)]
        self._hidden = self._h1[..., 1:]
        self._pre = np.empty(lead + (HIDDEN,))
        self._a = np.empty(lead + (HIDDEN,))
        self._a_column = self._a[..., :, None]
        self._slope = np.empty(lead + (HIDDEN,))
        self._step = np.empty(lead + (self.size,))     # eta [grad_W.ravel(), grad_v]
        self._step_W = self._step[..., :split].reshape(lead + (HIDDEN, 4))
        self._step_v = self._step[..., split:]
        # The probes' inputs [1, scale * x*] (3 probes x 4) and their hidden layers.
        xs, vs, acc = self._probe.T
        zeros = np.zeros(count)
        points = np.stack([np.stack([xs, zeros, zeros], 1), np.stack([xs, vs, zeros], 1),
                           np.stack([xs, vs, acc], 1)], 1)                  # (N, 3, 3)
        inputs = np.concatenate([np.ones((count, 3, 1)), scales[:, None, :] * points], axis=2)
        self._probe_inputs = inputs[0] if one else inputs
        self._probe_input_rows = [self._probe_inputs[..., p, :] for p in range(3)]
        self._probe_pre = np.empty(lead + (3, HIDDEN))
        self._probe_rows = [self._probe_pre[..., p, :] for p in range(3)]
        self._probe_hidden = np.empty(lead + (3, HIDDEN))
        self._probe_hidden_rows = [self._probe_hidden[..., p, :] for p in range(3)]
        # The running normalization's: per-environment scalars of a row
        # (v_0, s_f, ...) by self._at[k], a column of ones, zeros, x's floor.
        self._at = [at(k, one) for k in range(4)]
        self._ones = np.ones(lead + (1,))
        self._zero = 0.0 if one else np.zeros((count, 1))
        self._floor_x = constants(self._floor[:, 0], one)

    def unpack(self, weights):
        """W and v of one environment's weights (or the stack's (N, ...))."""
        split = self._SPLIT
        return (weights[..., :split].reshape(*np.shape(weights)[:-1], HIDDEN, 4),
                weights[..., split:])

    @staticmethod
    def _f(pre, out):
        """out = f(pre) = 2 / (1 + e^-pre) - 1 (pre is overwritten)."""
        np.negative(pre, out=pre)
        np.exp(pre, out=pre)
        np.add(1.0, pre, out=pre)
        np.divide(2.0, pre, out=pre)
        np.subtract(pre, 1.0, out=out)

    def _W(self, weights):
        return weights[self._w_part].reshape(self._lead + (HIDDEN, 4))

    def _pre_activations(self, weights, x0, x1, x2):
        """[1, scale x] into the buffer u1 and W [1, scale x] into pre; x0,
        x1, x2 each environment's (a float for one, else (N,))."""
        u1, at = self._u1, self._u_at
        s0, s1, s2 = self._s
        u1[at[1]] = s0 * x0
        u1[at[2]] = s1 * x1
        u1[at[3]] = s2 * x2
        self._matvec(self._W(weights), u1, self._pre)

    def _forward(self, weights, x0, x1, x2):
        """f_hat for raw x = (x0, x1, x2); [1, scale x] and [1, f(h)] into
        the buffers."""
        self._pre_activations(weights, x0, x1, x2)
        self._f(self._pre, self._hidden)
        return self._S * (weights[self._v0] + self._rowdot(weights[self._v1], self._hidden))

    def _train(self, weights, x0, x1, x2, f, out):
        """One gradient step (see :meth:`train`), the new weights into
        ``out``; returns f_hat before the step."""
        f_hat = self._forward(weights, x0, x1, x2)
        c = -(f - f_hat) * self._S                     # -e S
        a, slope, hidden = self._a, self._slope, self._hidden
        np.multiply(c, weights[self._v1], out=a)       # -e S v_1: f'(h)
        np.multiply(a, 0.5, out=a)
        np.multiply(hidden, hidden, out=slope)
        np.subtract(1.0, slope, out=slope)
        np.multiply(a, slope, out=a)
        np.multiply(self._a_column, self._u1_row, out=self._step_W)
        np.multiply(self._h1, c, out=self._step_v)
        np.multiply(self._step, self._eta, out=self._step)
        np.subtract(weights, self._step, out=out)
        return f_hat

    def _probe_layers(self, weights):
        """W [1, scale x*] of the three probes into the buffer probe_pre."""
        W = self._W(weights)
        for u, row in zip(self._probe_input_rows, self._probe_rows):
            self._matvec(W, u, row)

    def _impedance(self, weights):
        """(M_e, B_e, K_e), each a float for one environment, else (N,)
        (see :meth:`impedance`)."""
        self._probe_layers(weights)
        self._f(self._probe_pre, self._probe_hidden)
        v0, v1, S = weights[self._v0], weights[self._v1], self._S
        f_x, f_xv, f_xva = (S * (v0 + self._rowdot(v1, h)) for h in self._probe_hidden_rows)
        return (f_xva - f_xv) / self._acc, (f_xv - f_x) / self._vs, f_x / self._xs

    @staticmethod
    def _single(weights):
        return np.ndim(weights) == 1

    def _stack(self, weights, x):
        """Checks one environment's weights and x (1-D) or the stack's."""
        weights, x = np.asarray(weights, dtype=float), np.asarray(x, dtype=float)
        if (weights.ndim == 1) != self._one:
            raise ValueError(f"weights of shape {weights.shape} for {self.count} environments")
        return weights, x.reshape(self._lead + (3,))

    def _scalar(self, f):
        """Each environment's scalar: a float for one, a column (N, 1) for N."""
        f = np.asarray(f, dtype=float)
        return f if self._one else f.reshape(self.count, 1)

    def _columns(self, x):
        """x's three values per environment, each a float or a column (N, 1)."""
        return tuple(x[self._at[k]] for k in range(3))

    def forward(self, weights, x):
        """f_hat (N) and the inputs [1, scale x] and hidden activations for
        raw x = (xe, xe', xe''); stacked (N, ...) for stacked arguments."""
        weights, x = self._stack(weights, x)
        f_hat = self._forward(weights, *self._columns(x))
        return f_hat, self._u1.copy(), self._hidden.copy()

    def train(self, weights, x, f):
        """One gradient step on 1/2 (f - f_hat)^2; returns the new weights
        and f_hat before the step:

            e = f - f_hat
            v -= eta (-e S [1, f(h)])
            W -= eta outer(-e S v_1: (1 - f(h)^2) / 2, [1, u])
        """
        weights, x = self._stack(weights, x)
        new = np.empty_like(weights)
        f_hat = self._train(weights, *self._columns(x), self._scalar(f), new)
        return new, f_hat

    def impedance(self, weights):
        """(M_e, B_e, K_e) by probing at (x*, v*, a*); (N, 3) for stacked weights."""
        weights, _ = self._stack(weights, np.zeros(self._lead + (3,)))
        return together(self._impedance(weights), self._one)

    # Self-scaling (normalization: running): plain array expressions over
    # the last axis, one environment's vectors or N's rows (N, k), the
    # per-environment scalars indexed by self._at (a float for one); the
    # scales s = (s_x, s_v, s_a, s_f) are arguments (the system's state).

    def _shaped(self, array, size):
        """One environment's (size,) array, or N's (N, size)."""
        return np.asarray(array, dtype=float).reshape(self._lead + (size,))

    def _update_scales(self, scales, x, f):
        return np.maximum(scales, np.abs(np.concatenate([x, np.reshape(f, self._lead + (1,))],
                                                        axis=-1)))

    def _forward_scaled(self, weights, x, scales):
        W, v = self.unpack(weights)
        at = self._at
        u = np.concatenate([self._ones, x / scales[..., :3]], axis=-1)
        pre = np.empty(self._lead + (HIDDEN,))
        self._matvec(W, u, pre)
        hidden = 2.0 / (1.0 + np.exp(-pre)) - 1.0
        return scales[at[3]] * (v[at[0]] + self._rowdot(v[..., 1:], hidden)), u, hidden

    def _train_scaled(self, weights, x, f, scales):
        W, v = self.unpack(weights)
        f_hat, u, hidden = self._forward_scaled(weights, x, scales)
        minus_e = -((f - f_hat) / scales[self._at[3]])
        grad_v = minus_e * np.concatenate([self._ones, hidden], axis=-1)
        back = minus_e * v[..., 1:] * 0.5 * (1.0 - hidden**2)
        grad_W = back[..., :, None] * u[..., None, :]
        new = np.concatenate([(W - self._eta_matrix * grad_W).reshape(self._lead + (-1,)),
                              v - self._eta * grad_v], axis=-1)
        return new, f_hat

    def _jacobian(self, weights, x, scales):
        W, v = self.unpack(weights)
        _, _, hidden = self._forward_scaled(weights, x, scales)
        back = v[..., 1:] * 0.5 * (1.0 - hidden**2)
        d_u = np.swapaxes(W[..., :, 1:], -1, -2) @ back[..., None]
        return (scales[self._at[3]] * d_u[..., 0] / scales[..., :3])[..., ::-1]

    def _secants(self, weights, x, scales, probe=None):
        at = self._at
        if probe is None:
            floor, x0 = self._floor_x, x[at[0]]
            if self._one:
                xs = float(x0) if abs(x0) >= floor else (floor if x0 >= 0 else -floor)
            else:
                xs = np.where(np.abs(x0) >= floor, x0, np.where(x0 >= 0, floor, -floor))
            vs, acc = scales[at[1]], scales[at[2]]
        else:
            xs, vs, acc = probe[at[0]], probe[at[1]], probe[at[2]]
        zero = self._zero
        one = self._one
        f_x, f_xv, f_xva = (self._forward_scaled(weights, together(p, one), scales)[0]
                            for p in ((xs, zero, zero), (xs, vs, zero), (xs, vs, acc)))
        return together((f_xva - f_xv, f_xv - f_x, f_x), one), together((acc, vs, xs), one)

    @staticmethod
    def _average_secants(sums, rises, steps, decay):
        new = np.concatenate([decay * sums[..., :3] + steps * rises,
                              decay * sums[..., 3:] + steps * steps], axis=-1)
        return new, new[..., :3] / new[..., 3:]

    def update_scales(self, scales, x, f):
        """The running scales after the sample x = (xe, xe', xe''), f (N,
        less f_s): elementwise max(scales, |x|, |f|)."""
        return self._update_scales(self._shaped(scales, 4), self._shaped(x, 3),
                                   self._scalar(f))

    def forward_scaled(self, weights, x, scales):
        """f_hat = s_f (v . [1, f(W [1, x / s])]) and the inputs [1, x / s]
        and hidden activations."""
        return self._forward_scaled(self._shaped(weights, self.size), self._shaped(x, 3),
                                    self._shaped(scales, 4))

    def train_scaled(self, weights, x, f, scales):
        """One step on 1/2 ((f - f_hat) / s_f)^2; returns the new weights and
        f_hat before the step (see the module doc)."""
        return self._train_scaled(self._shaped(weights, self.size), self._shaped(x, 3),
                                  self._scalar(f), self._shaped(scales, 4))

    def jacobian(self, weights, x, scales):
        """(M_e, B_e, K_e) = d f_hat / d (xe'', xe', xe) at x."""
        return self._jacobian(self._shaped(weights, self.size), self._shaped(x, 3),
                              self._shaped(scales, 4))

    def operating_point(self, weights, x, scales, probe=None):
        """(M_e, B_e, K_e) by the thesis's secants at x* = xe (at least its
        floor in magnitude), v* = s_v, a* = s_a; or at a given ``probe``."""
        rises, steps = self.secants(weights, x, scales, probe)
        return rises / steps

    def secants(self, weights, x, scales, probe=None):
        """The secants of :meth:`operating_point` as (rises, steps), each in
        the order (M_e, B_e, K_e): rises (f_xva - f_xv, f_xv - f_x, f_x)
        (N) over steps (a*, v*, x*)."""
        return self._secants(self._shaped(weights, self.size), self._shaped(x, 3),
                             self._shaped(scales, 4),
                             None if probe is None else self._shaped(probe, 3))

    @staticmethod
    def average_secants(sums, rises, steps, decay):
        """The exponentially weighted least-squares readout: ``sums`` = [sum
        of step * rise (3), sum of step^2 (3)] decayed by ``decay`` and
        updated with this sample's secants; returns (new sums, (M_e, B_e,
        K_e) = sum step * rise / sum step^2)."""
        return ImpedanceNetwork._average_secants(
            *(np.asarray(a, dtype=float) for a in (sums, rises, steps)), decay)

    def initial_weights(self, seed):
        """One environment's initial weights (its config's spread) from its seed."""
        rng = np.random.default_rng(seed)
        return rng.normal(0.0, self.c.initial_weight_std, self.size)

    def initial_stack(self, seeds):
        """The N environments' initial weights (N, size), environment i's
        from ``seeds[i]`` and its own config, as each alone."""
        return np.stack([np.random.default_rng(seed).normal(0.0, c.initial_weight_std, self.size)
                         for seed, c in zip(seeds, self.configs)])


class SigmoidImpedanceNetwork(ImpedanceNetwork):
    """The text's network (section 5.2: "the process ... is same as that of
    the neural network controller explained in Chapter 4.5"): the output
    neuron is a bipolar sigmoid of the hidden *activations*, scaled to S,
    and one back-propagation step of eqs. 4.26-4.29 on E = 1/2 (f - f_hat)^2:

        t = v . [1, f(h)],   f_hat = S f(t)
        d = e S f'(t),       f'(t) = (1 - f(t)^2) / 2
        W += eta outer(d v_1: f'(h), [1, u])     (v before its step)
        v += eta d [1, f(h)]

    The thesis gives no output range; the output cannot leave (-S, S), so S
    must hold the wall's force with room: see ``output_scale_n`` of the
    scenarios that use it.
    """

    def _summed(self):
        """What the output neuron sums: the hidden activations f(h)."""
        return self._hidden

    def _probes_summed(self):
        """The same for the three probes (their f(h), one row each)."""
        self._f(self._probe_pre, self._probe_hidden)
        return self._probe_hidden_rows

    def _output(self, weights, summed):
        """S f(v . [1, summed]) for one environment's or N's layer."""
        t = weights[self._v0] + self._rowdot(weights[self._v1], summed)
        return self._S * (2.0 / (1.0 + np.exp(-t)) - 1.0)

    def _forward(self, weights, x0, x1, x2):
        self._pre_activations(weights, x0, x1, x2)
        self._f(self._pre.copy(), self._hidden)
        return self._output(weights, self._summed())

    def _train(self, weights, x0, x1, x2, f, out):
        f_hat = self._forward(weights, x0, x1, x2)
        q = f_hat / self._S
        d = (f - f_hat) * self._S * 0.5 * (1.0 - q * q)
        hidden = self._hidden
        back = d * weights[self._v1] * 0.5 * (1.0 - hidden * hidden)
        outer = back[..., :, None] * self._u1_row
        out[self._w_part] = weights[self._w_part] + (self._eta_matrix * outer).reshape(
            self._lead + (self._SPLIT,))
        out[self._v_part] = weights[self._v_part] + self._eta * d * self._h1
        return f_hat

    def _impedance(self, weights):
        self._probe_layers(weights)
        f_x, f_xv, f_xva = (self._output(weights, layer) for layer in self._probes_summed())
        return (f_xva - f_xv) / self._acc, (f_xv - f_x) / self._vs, f_x / self._xs


class AppendixEImpedanceNetwork(SigmoidImpedanceNetwork):
    """The network with the output layer of Appendix E's code (its
    controller's network; section 5.2 says the identifier's works the same
    way): the output neuron sums the hidden *pre-activations* h and is a
    bipolar sigmoid scaled to S (the code's ``st1 = 40/(1+exp(-t1)) - 20``,
    S = 20 N), while the update uses the activations f(h) as the text's
    network would (:class:`SigmoidImpedanceNetwork`'s step):

        t = v . [1, h],   f_hat = S f(t)
        d = e S f'(t),    f'(t) = (1 - f(t)^2) / 2
        W += eta outer(d v_1: f'(h), [1, u])     (v before its step)
        v += eta d [1, f(h)]

    The output cannot leave (-S, S): a wall force beyond S is learnt only
    as saturation.
    """

    def _summed(self):
        return self._pre

    def _probes_summed(self):
        return self._probe_rows


def make_network(config: NnIdentifierConfig | Sequence[NnIdentifierConfig]) -> ImpedanceNetwork:
    """The network for the configs' ``output_layer`` (one config, or one per
    environment sharing it)."""
    layer = _configs(config)[0].output_layer
    if layer == "appendix_e":
        return AppendixEImpedanceNetwork(config)
    if layer == "sigmoid":
        return SigmoidImpedanceNetwork(config)
    return ImpedanceNetwork(config)


class NnIdentifier(LeafSystem):
    """The neural identifier, trained every 1 ms after the first switch, for
    N environments (one config and one seed each; a single config and seed:
    N = 1). The configs may differ in their numbers and in force_offset, not
    in the options they switch (:func:`check_structure`); environment i's
    initial weights come from its own seed, as alone.

    Input ports (env-major): as RlsIdentifier (force (N), tip_pose (3 N),
      tip_velocity (3 N), tip_acceleration (3 N), contact_info (4 N)).
    Output ports (state outputs, env-major): impedance (3 N): [M_e, B_e, K_e]
      (kg, N s/m, N/m) by ``readout``;
      force_estimate (N): the network's force before each step (N; plus
      f_s with ``force_offset``).
    State (env-major): the weights (discrete), seeded; [started, f_s]; with
      ``normalization: running`` also the scales (s_x, s_v, s_a, s_f);
      with ``readout_time_constant_s`` also the readout's weighted sums
      [sum step * rise (3), sum step^2 (3)].
    """

    def __init__(self, config: NnIdentifierConfig | Sequence[NnIdentifierConfig],
                 seed: int | Sequence[int]):
        super().__init__()
        configs = _configs(config)
        self._count = count = len(configs)
        seeds = [seed] if np.ndim(seed) == 0 else list(seed)
        if len(seeds) != count:
            raise ScenarioError(f"identifiers.nn: {len(seeds)} seeds for {count} environments")
        self._net = net = make_network(configs)
        weights = net.initial_stack(seeds)
        self._force = self.DeclareVectorInputPort("force", count)
        self._pose = self.DeclareVectorInputPort("tip_pose", 3 * count)
        self._velocity = self.DeclareVectorInputPort("tip_velocity", 3 * count)
        self._acceleration = self.DeclareVectorInputPort("tip_acceleration", 3 * count)
        self._contact = self.DeclareVectorInputPort("contact_info", 4 * count)
        # The safety supervisor's flag: while it is up, the network and its
        # estimate are held (unconnected: never).
        self._fault = self.DeclareVectorInputPort("force_fault", count)
        self._weights = self.DeclareDiscreteState(weights.reshape(-1))
        self._impedance = self.DeclareDiscreteState(
            net.impedance(weights[0] if count == 1 else weights).reshape(-1))
        self._estimate = self.DeclareDiscreteState(count)
        self._switch = self.DeclareDiscreteState(2 * count)
        first = configs[0]
        self._offset = np.array([c.force_offset for c in configs], dtype=bool)
        self._running = first.normalization == "running"
        if self._running:
            # The running scales (s_x, s_v, s_a, s_f), from their floors.
            self._scales = self.DeclareDiscreteState(net._floor.reshape(-1))
            self._i_scales = int(self._scales)
        self._readout = first.readout
        self._averaged = first.readout_time_constant_s > 0
        if self._averaged:
            self._readout_decay = constants(
                [np.exp(-CONTROL_PERIOD / c.readout_time_constant_s) for c in configs],
                count == 1)
            # The readout's weighted sums: [sum step * rise, sum step^2] (3 + 3).
            self._i_sums = int(self.DeclareDiscreteState(6 * count))
        # Plain ints index the groups (cheaper to pass to pydrake).
        self._i_weights, self._i_impedance, self._i_estimate, self._i_switch = (
            int(i) for i in (self._weights, self._impedance, self._estimate, self._switch))
        DeclareSampledUpdate(self, self._update)
        self.DeclareStateOutputPort("impedance", self._impedance)
        self.DeclareStateOutputPort("force_estimate", self._estimate)
        # Where each environment's values are in the inputs and the state
        # (drake_contact.identification.stacked: one environment's are
        # scalars, as alone; N's (N,) arrays).
        self._one = one = count == 1
        self._x = every(0, 3, one)
        self._time = 0 if one else slice(0, None, 4)
        self._x_switch = every(1, 4, one)
        self._each = every(0, 1, one)
        self._impedance_at = [at(k, one) for k in range(3)]
        self._new = np.empty((count, net.size))

    def _started(self, contact):
        """Which environments are past their switch (N,), or None when all
        are (N > 1; one environment is not stepped before its switch)."""
        started = np.logical_not(np.less(contact[self._time], 0.0))
        return None if np.count_nonzero(started) == self._count else started

    def _update(self, context, state):
        contact = self._contact.Eval(context)
        if contact[0] < 0 and (self._one or max(contact[4::4].tolist()) < 0):
            return
        count, net = self._count, self._net
        started = None if self._one else self._started(contact)
        # A flagged force reading holds the estimate, as before the switch.
        step, started = stepped(started, held_while_flagged(self._fault, context), self._one)
        if not step:
            return
        x0 = self._pose.Eval(context)[self._x] - contact[self._x_switch]
        x1 = self._velocity.Eval(context)[self._x]
        x2 = self._acceleration.Eval(context)[self._x]
        force = self._force.Eval(context)[self._each]
        switch = context.get_discrete_state(self._i_switch).value()
        if self._one:
            switched, f_s = switch.tolist()
            if not switched:
                f_s = force if self._offset[0] else 0.0
                state.get_mutable_value(self._i_switch)[:] = (1.0, f_s)
        else:
            switch = switch.reshape(count, 2)
            first, f_s = np.equal(switch[:, 0], 0.0), switch[:, 1:]
            if started is not None:  # environments before their switch: zeros in, state kept
                first &= started
                x0, x1, x2, force = (np.where(started[:, None], v, 0.0)
                                     for v in (x0, x1, x2, force))
            if np.count_nonzero(first):
                f_s = np.where(first[:, None], np.where(self._offset[:, None], force, 0.0), f_s)
                switched = (np.ones(count) if started is None
                            else np.where(started, 1.0, switch[:, 0]))
                new_switch = np.concatenate([switched[:, None], f_s], axis=1)
                state.get_mutable_value(self._i_switch)[:] = new_switch.reshape(-1)
        f = force - f_s
        if self._running:
            x = together((x0, x1, x2), self._one)
            self._update_running(context, state, x, f, f_s, started)
            return
        weights = context.get_discrete_state(self._i_weights).value()
        if started is None:  # into the state
            new = state.get_mutable_value(self._i_weights)
            new = new if self._one else new.reshape(count, net.size)
        else:
            new = self._new
        if not self._one:
            weights = weights.reshape(count, net.size)
        f_hat = net._train(weights, x0, x1, x2, f, new)
        M_e, B_e, K_e = net._impedance(new)
        if started is None:
            impedance = state.get_mutable_value(self._i_impedance)
            if not self._one:
                impedance = impedance.reshape(count, 3)
            for index, value in zip(self._impedance_at, (M_e, B_e, K_e)):
                impedance[index] = value
            state.get_mutable_value(self._i_estimate)[self._each] = f_hat + f_s
            return
        self._store(context, state, started, ((self._i_weights, new),
                                              (self._i_impedance, together((M_e, B_e, K_e),
                                                                           False)),
                                              (self._i_estimate, f_hat + f_s)))

    def _store(self, context, state, started, groups):
        """Writes each (group, new values (N, k)) of the started environments
        (all when ``started`` is None)."""
        for group, value in groups:
            if started is not None:
                old = context.get_discrete_state(group).value().reshape(self._count, -1)
                value = np.where(started[:, None], np.reshape(value, (self._count, -1)), old)
            state.get_mutable_value(group)[:] = value if self._one else np.reshape(value, -1)

    def _update_running(self, context, state, x, f, f_s, started):
        net = self._net
        lead = net._lead

        def read(group, size):
            return context.get_discrete_state(group).value().reshape(lead + (size,))
        scales = net._update_scales(read(self._i_scales, 4), x, f)
        weights, f_hat = net._train_scaled(read(self._i_weights, net.size), x, f, scales)
        groups = []
        if self._readout == "jacobian":
            impedance = net._jacobian(weights, x, scales)
        elif self._averaged:
            sums, impedance = net._average_secants(
                read(self._i_sums, 6), *net._secants(weights, x, scales), self._readout_decay)
            groups.append((self._i_sums, sums))
        else:
            probe = net._probe_point if self._readout == "probe" else None
            rises, steps = net._secants(weights, x, scales, probe)
            impedance = rises / steps
        groups += [(self._i_scales, scales), (self._i_weights, weights),
                   (self._i_impedance, impedance), (self._i_estimate, f_hat + f_s)]
        self._store(context, state, started, groups)
