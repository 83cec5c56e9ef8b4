"""Online identification of the environment's impedance by a neural network
(thesis chapter 5): a 3-4-1 network in parallel with the environment.

Inputs u = (s_x xe, s_v xe', s_a xe'') (scaled so their magnitudes match;
styrofoam s_x = 1000, rubber 10000, s_v = 100), four bipolar-sigmoid hidden
neurons f(h) = 2/(1 + e^-h) - 1 with biases, and a linear output scaled to
newtons, f_hat = S (v . [1, f(h)]) (the thesis's output neuron is a sigmoid,
as in its controller, section 5.2; one scaled to S = 20 N could not reach
the 20-28 N the wall returns). Every 1 ms after the contact switch one
gradient step on E = 1/2 (f - f_hat)^2 with learning rate eta (1e-4).

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
transient alone and depend on the initial weights. The thesis's form is the
default.

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

Which readout, measured on identify_any (walls 5-120 kN/m off the issue's
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
from drake_contact.plant.arm import CONTROL_PERIOD, DeclareSampledUpdate
from drake_contact.errors import ScenarioError

HIDDEN = 4
OUTPUT_LAYERS = ("linear", "appendix_e")
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
    # Output layer: linear, f_hat = S (v . [1, f(h)]) (ours, the default), or
    # appendix_e, f_hat = S f(v . [1, h]) with the update of the text's
    # network, as Appendix E codes its controller's network (see
    # AppendixEImpedanceNetwork).
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


def _switches(config):
    """The options a config switches on (its structure: which arithmetic
    runs and the state's shape), by field."""
    return {"output_layer": config.output_layer, "normalization": config.normalization,
            "readout": config.readout,
            "readout_time_constant_s": config.readout_time_constant_s > 0}


def check_structure(configs, prefix="identifiers.nn"):
    """Raises ScenarioError naming the field if the environments' configs
    differ in an option they switch (their numbers may differ, and so may
    force_offset: an anchor f_s of 0 is the arithmetic without it)."""
    first = _switches(configs[0])
    for i, config in enumerate(configs[1:], start=1):
        for field, value in _switches(config).items():
            if value != first[field]:
                raise ScenarioError(
                    f"{prefix}.{field}: environment {i} has {value} and environment 0 "
                    f"{first[field]}: the environments must share a structure (which options "
                    "are on), not only their numbers")


def _configs(config):
    return environment_configs(config, NnIdentifierConfig, "identifiers.nn")


class ImpedanceNetwork:
    """The network's arithmetic on flat weight vectors (no Drake), for N
    environments (one config each; a single config: N = 1), weights stacked
    (N, size).

    Layout: W (HIDDEN x 4, inputs [1, u]) then v (1 + HIDDEN), row-major.

    One sample's arithmetic runs in work buffers the network owns (the
    system trains and probes it every 1 ms on 4-vectors, where numpy's
    per-call cost outweighs the arithmetic): the same IEEE operations, in
    the same order, as the array expressions in the docstrings, elementwise
    over the arm axis, every matrix product numpy's ``matmul`` over the
    stack, which calls BLAS once per environment as ``np.dot`` does for
    one, so that each environment's values are bit for bit its own.

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
        # Per environment, as the operands of one environment's arithmetic.
        scales = np.array([c.input_scale for c in configs], dtype=float)   # (N, 3)
        self.scale = scales[0] if count == 1 else scales
        self._scales = scales
        self._S = np.array([c.output_scale_n for c in configs], dtype=float)
        self._eta = np.array([c.learning_rate for c in configs], dtype=float)
        self._eta_column = self._eta[:, None]
        self._eta_matrix = self._eta[:, None, None]
        self._probe = np.array([c.probe for c in configs], dtype=float)     # (N, 3): x*, v*, a*
        self._floor = np.array([c.scale_floor for c in configs], dtype=float)
        split = self._SPLIT
        self._u1 = np.ones((count, 4))                 # [1, scale * x]
        self._u1_column, self._u1_row = self._u1[:, :, None], self._u1[:, None, :]
        self._h1 = np.ones((count, HIDDEN + 1))        # [1, f(h)]
        self._hidden = self._h1[:, 1:]
        self._hidden_column = self._hidden[:, :, None]
        self._pre = np.empty((count, HIDDEN))
        self._pre_column = self._pre[:, :, None]
        self._dots = np.empty((count, 1, 1))
        self._dot = self._dots[:, 0, 0]
        self._a = np.empty((count, HIDDEN))
        self._a_column = self._a[:, :, None]
        self._step = np.empty((count, self.size))     # eta [grad_W.ravel(), grad_v]
        self._step_W = self._step[:, :split].reshape(count, HIDDEN, 4)
        self._step_v = self._step[:, split:]
        # The probes' inputs [1, scale * x*] (N, 3 probes, 4) and their hidden layers.
        xs, vs, acc = self._probe.T
        zeros = np.zeros(count)
        points = np.stack([np.stack([xs, zeros, zeros], 1), np.stack([xs, vs, zeros], 1),
                           np.stack([xs, vs, acc], 1)], 1)                  # (N, 3, 3)
        self._probe_inputs = np.concatenate([np.ones((count, 3, 1)), scales[:, None, :] * points],
                                            axis=2)
        self._probe_columns = self._probe_inputs[:, :, :, None]
        self._probe_pre = np.empty((count, 3, HIDDEN))
        self._probe_hidden = np.empty((count, 3, HIDDEN))
        self._probe_dots = np.empty((count, 3, 1, 1))
        self._probe_reversed = self._probe[:, ::-1].copy()           # (a*, v*, x*)
        self._impedance_buffer = np.empty((count, 3))
        self._S_column = self._S[:, None]
        self._c = np.empty((count, 1))
        self._slope = np.empty((count, HIDDEN))

    def _rows(self, array, size=None):
        """``array`` as (N, k) rows: one environment's 1-D array, or the stack."""
        array = np.asarray(array, dtype=float)
        return array.reshape(self.count, -1 if size is None else size)

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
        return weights[:, :self._SPLIT].reshape(self.count, HIDDEN, 4)

    def _pre_activations(self, weights, x0, x1, x2):
        """[1, scale x] into the buffer u1 and W [1, scale x] into pre; x0,
        x1, x2 (N,)."""
        u1, scales = self._u1, self._scales
        np.multiply(scales[:, 0], x0, out=u1[:, 1])
        np.multiply(scales[:, 1], x1, out=u1[:, 2])
        np.multiply(scales[:, 2], x2, out=u1[:, 3])
        np.matmul(self._W(weights), self._u1_column, out=self._pre_column)

    def _forward(self, weights, x0, x1, x2):
        """f_hat (N,) for raw x = (x0, x1, x2); [1, scale x] and [1, f(h)]
        into the buffers."""
        self._pre_activations(weights, x0, x1, x2)
        self._f(self._pre, self._hidden)
        np.matmul(weights[:, None, self._SPLIT + 1:], self._hidden_column, out=self._dots)
        return self._S * (weights[:, self._SPLIT] + self._dot)

    def _train(self, weights, x0, x1, x2, f, out):
        """One gradient step (see :meth:`train`), the new weights into
        ``out`` (N, size); returns f_hat (N,) before the step."""
        f_hat = self._forward(weights, x0, x1, x2)
        c, slope = self._c, self._slope
        np.subtract(f, f_hat, out=c[:, 0])             # -e S
        np.negative(c, out=c)
        np.multiply(c, self._S_column, out=c)
        a = self._a                                    # -e S v_1: f'(h)
        np.multiply(c, weights[:, self._SPLIT + 1:], out=a)
        np.multiply(a, 0.5, out=a)
        hidden = self._hidden
        np.multiply(hidden, hidden, out=slope)
        np.subtract(1.0, slope, out=slope)
        np.multiply(a, slope, out=a)
        np.multiply(self._a_column, self._u1_row, out=self._step_W)
        np.multiply(self._h1, c, out=self._step_v)
        np.multiply(self._step, self._eta_column, out=self._step)
        np.subtract(weights, self._step, out=out)
        return f_hat

    def _probe_outputs(self, weights):
        """f_hat at the three probe points, (N, 3)."""
        np.matmul(self._W(weights)[:, None], self._probe_columns,
                  out=self._probe_pre[:, :, :, None])
        self._f(self._probe_pre, self._probe_hidden)
        np.matmul(weights[:, None, None, self._SPLIT + 1:], self._probe_hidden[:, :, :, None],
                  out=self._probe_dots)
        return self._S[:, None] * (weights[:, self._SPLIT, None] + self._probe_dots[:, :, 0, 0])

    def _impedance(self, weights):
        """(M_e, B_e, K_e) as a buffer (N, 3) (see :meth:`impedance`)."""
        f = self._probe_outputs(weights)
        impedance = self._impedance_buffer
        np.subtract(f[:, 2:], f[:, 1:2], out=impedance[:, 0:1])   # (f_xva - f_xv) / a*
        np.subtract(f[:, 1:2], f[:, 0:1], out=impedance[:, 1:2])  # (f_xv - f_x) / v*
        impedance[:, 2] = f[:, 0]                                 # f_x / x*
        np.divide(impedance, self._probe_reversed, out=impedance)
        return impedance

    def _single(self, weights):
        return np.ndim(weights) == 1

    def forward(self, weights, x):
        """f_hat (N) and the inputs [1, scale x] and hidden activations for
        raw x = (xe, xe', xe''); stacked (N, ...) for stacked arguments."""
        single = self._single(weights)
        x = self._rows(x, 3)
        f_hat = self._forward(self._rows(weights), x[:, 0], x[:, 1], x[:, 2])
        if single:
            return f_hat[0], self._u1[0].copy(), self._hidden[0].copy()
        return f_hat, self._u1.copy(), self._hidden.copy()

    def train(self, weights, x, f):
        """One gradient step on 1/2 (f - f_hat)^2; returns the new weights
        and f_hat before the step:

            e = f - f_hat
            v -= eta (-e S [1, f(h)])
            W -= eta outer(-e S v_1: (1 - f(h)^2) / 2, [1, u])
        """
        single = self._single(weights)
        x = self._rows(x, 3)
        new = np.empty((self.count, self.size))
        f_hat = self._train(self._rows(weights), x[:, 0], x[:, 1], x[:, 2],
                            self._rows(f, 1)[:, 0], new)
        return (new[0], f_hat[0]) if single else (new, f_hat)

    def impedance(self, weights):
        """(M_e, B_e, K_e) by probing at (x*, v*, a*); (N, 3) for stacked weights."""
        impedance = self._impedance(self._rows(weights)).copy()
        return impedance[0] if self._single(weights) else impedance

    # Self-scaling (normalization: running): plain array expressions over
    # the stack's rows (N, k); the scales s = (s_x, s_v, s_a, s_f) are
    # arguments (the system's state). The public methods take one
    # environment's 1-D arrays or the stack.

    def _update_scales(self, scales, x, f):
        return np.maximum(scales, np.abs(np.concatenate([x, f[:, None]], axis=1)))

    def _forward_scaled(self, weights, x, scales):
        W, v = self.unpack(weights)
        u = np.concatenate([np.ones((len(x), 1)), x / scales[:, :3]], axis=1)
        hidden = 2.0 / (1.0 + np.exp(-(W @ u[:, :, None])[:, :, 0])) - 1.0
        dot = (v[:, None, 1:] @ hidden[:, :, None])[:, 0, 0]
        return scales[:, 3] * (v[:, 0] + dot), u, hidden

    def _train_scaled(self, weights, x, f, scales):
        W, v = self.unpack(weights)
        f_hat, u, hidden = self._forward_scaled(weights, x, scales)
        e = (f - f_hat) / scales[:, 3]
        minus_e = -e
        grad_v = minus_e[:, None] * np.concatenate([np.ones((len(x), 1)), hidden], axis=1)
        back = minus_e[:, None] * v[:, 1:] * 0.5 * (1.0 - hidden**2)
        grad_W = back[:, :, None] * u[:, None, :]
        new = np.concatenate([(W - self._eta_matrix * grad_W).reshape(len(x), -1),
                              v - self._eta_column * grad_v], axis=1)
        return new, f_hat

    def _jacobian(self, weights, x, scales):
        W, v = self.unpack(weights)
        _, _, hidden = self._forward_scaled(weights, x, scales)
        back = v[:, 1:] * 0.5 * (1.0 - hidden**2)
        d_u = (W[:, :, 1:].transpose(0, 2, 1) @ back[:, :, None])[:, :, 0]
        return (scales[:, 3, None] * d_u / scales[:, :3])[:, ::-1]

    def _secants(self, weights, x, scales, probe=None):
        count = len(x)
        if probe is None:
            floor, x0 = self._floor[:, 0], x[:, 0]
            xs = np.where(np.abs(x0) >= floor, x0, np.where(x0 >= 0, floor, -floor))
            vs, acc = scales[:, 1], scales[:, 2]
        else:
            xs, vs, acc = probe.T
        zeros = np.zeros(count)
        f_x, f_xv, f_xva = (self._forward_scaled(weights, np.stack(p, axis=1), scales)[0]
                            for p in ((xs, zeros, zeros), (xs, vs, zeros), (xs, vs, acc)))
        return (np.stack([f_xva - f_xv, f_xv - f_x, f_x], axis=1),
                np.stack([acc, vs, xs], axis=1))

    @staticmethod
    def _average_secants(sums, rises, steps, decay):
        new = np.concatenate([decay * sums[:, :3] + steps * rises,
                              decay * sums[:, 3:] + steps * steps], axis=1)
        return new, new[:, :3] / new[:, 3:]

    def _answer(self, single, *arrays):
        answers = tuple(a[0] if single else a for a in arrays)
        return answers if len(answers) > 1 else answers[0]

    def update_scales(self, scales, x, f):
        """The running scales after the sample x = (xe, xe', xe''), f (N,
        less f_s): elementwise max(scales, |x|, |f|)."""
        single = np.ndim(scales) == 1
        return self._answer(single, self._update_scales(
            self._rows(scales, 4), self._rows(x, 3), self._rows(f, 1)[:, 0]))

    def forward_scaled(self, weights, x, scales):
        """f_hat = s_f (v . [1, f(W [1, x / s])]) and the inputs [1, x / s]
        and hidden activations."""
        return self._answer(self._single(weights), *self._forward_scaled(
            self._rows(weights), self._rows(x, 3), self._rows(scales, 4)))

    def train_scaled(self, weights, x, f, scales):
        """One step on 1/2 ((f - f_hat) / s_f)^2; returns the new weights and
        f_hat before the step (see the module doc)."""
        return self._answer(self._single(weights), *self._train_scaled(
            self._rows(weights), self._rows(x, 3), self._rows(f, 1)[:, 0],
            self._rows(scales, 4)))

    def jacobian(self, weights, x, scales):
        """(M_e, B_e, K_e) = d f_hat / d (xe'', xe', xe) at x."""
        return self._answer(self._single(weights), self._jacobian(
            self._rows(weights), self._rows(x, 3), self._rows(scales, 4)))

    def operating_point(self, weights, x, scales, probe=None):
        """(M_e, B_e, K_e) by the thesis's secants at x* = xe (at least its
        floor in magnitude), v* = s_v, a* = s_a; or at a given ``probe``."""
        rises, steps = self.secants(weights, x, scales, probe)
        return rises / steps

    def secants(self, weights, x, scales, probe=None):
        """The secants of :meth:`operating_point` as (rises, steps), each in
        the order (M_e, B_e, K_e): rises (f_xva - f_xv, f_xv - f_x, f_x)
        (N) over steps (a*, v*, x*)."""
        return self._answer(self._single(weights), *self._secants(
            self._rows(weights), self._rows(x, 3), self._rows(scales, 4),
            None if probe is None else self._rows(probe, 3)))

    @staticmethod
    def average_secants(sums, rises, steps, decay):
        """The exponentially weighted least-squares readout: ``sums`` = [sum
        of step * rise (3), sum of step^2 (3)] decayed by ``decay`` and
        updated with this sample's secants; returns (new sums, (M_e, B_e,
        K_e) = sum step * rise / sum step^2)."""
        single = np.ndim(sums) == 1
        new, impedance = ImpedanceNetwork._average_secants(
            *(np.asarray(a, dtype=float).reshape(-1, n)
              for a, n in ((sums, 6), (rises, 3), (steps, 3))),
            np.asarray(decay, dtype=float).reshape(-1, 1))
        return (new[0], impedance[0]) if single else (new, impedance)

    def initial_weights(self, seed):
        """One environment's initial weights (its config's spread) from its seed."""
        rng = np.random.default_rng(seed)
        return rng.normal(0.0, self.c.initial_weight_std, self.size)

    def initial_stack(self, seeds):
        """The N environments' initial weights (N, size), environment i's
        from ``seeds[i]`` and its own config, as each alone."""
        return np.stack([np.random.default_rng(seed).normal(0.0, c.initial_weight_std, self.size)
                         for seed, c in zip(seeds, self.configs)])


class AppendixEImpedanceNetwork(ImpedanceNetwork):
    """The network with the output layer of Appendix E's code (its
    controller's network; section 5.2 says the identifier's works the same
    way): the output neuron sums the hidden *pre-activations* h and is a
    bipolar sigmoid scaled to S (the code's ``st1 = 40/(1+exp(-t1)) - 20``,
    S = 20 N), while the update uses the activations f(h) as the text's
    network would:

        t = v . [1, h],   f_hat = S f(t)
        d = e S f'(t),    f'(t) = (1 - f(t)^2) / 2
        W += eta outer(d v_1: f'(h), [1, u])     (v before its step)
        v += eta d [1, f(h)]

    The output cannot leave (-S, S): a wall force beyond S is learnt only
    as saturation.
    """

    def _forward(self, weights, x0, x1, x2):
        self._pre_activations(weights, x0, x1, x2)
        np.matmul(weights[:, None, self._SPLIT + 1:], self._pre_column, out=self._dots)
        t = weights[:, self._SPLIT] + self._dot
        self._f(self._pre.copy(), self._hidden)
        return self._S * (2.0 / (1.0 + np.exp(-t)) - 1.0)

    def _train(self, weights, x0, x1, x2, f, out):
        f_hat = self._forward(weights, x0, x1, x2)
        S = self._S
        q = f_hat / S
        d = (f - f_hat) * S * 0.5 * (1.0 - q * q)
        v1 = weights[:, self._SPLIT + 1:]
        hidden = self._hidden
        back = d[:, None] * v1 * 0.5 * (1.0 - hidden * hidden)
        split = self._SPLIT
        out[:, :split] = weights[:, :split] + (
            self._eta_matrix * (back[:, :, None] * self._u1_row)).reshape(self.count, split)
        out[:, split:] = weights[:, split:] + (self._eta * d)[:, None] * self._h1
        return f_hat

    def _probe_outputs(self, weights):
        np.matmul(self._W(weights)[:, None], self._probe_columns,
                  out=self._probe_pre[:, :, :, None])
        np.matmul(weights[:, None, None, self._SPLIT + 1:], self._probe_pre[:, :, :, None],
                  out=self._probe_dots)
        t = weights[:, self._SPLIT, None] + self._probe_dots[:, :, 0, 0]
        return self._S[:, None] * (2.0 / (1.0 + np.exp(-t)) - 1.0)


def make_network(config: NnIdentifierConfig | Sequence[NnIdentifierConfig]) -> ImpedanceNetwork:
    """The network for the configs' ``output_layer`` (one config, or one per
    environment sharing it)."""
    if _configs(config)[0].output_layer == "appendix_e":
        return AppendixEImpedanceNetwork(config)
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
        self._weights = self.DeclareDiscreteState(weights.reshape(-1))
        self._impedance = self.DeclareDiscreteState(net.impedance(weights).reshape(-1))
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
            self._readout_decay = np.array([float(np.exp(-CONTROL_PERIOD
                                                         / c.readout_time_constant_s))
                                            for c in configs])
            # The readout's weighted sums: [sum step * rise, sum step^2] (3 + 3).
            self._i_sums = int(self.DeclareDiscreteState(6 * count))
        # Plain ints index the groups (cheaper to pass to pydrake).
        self._i_weights, self._i_impedance, self._i_estimate, self._i_switch = (
            int(i) for i in (self._weights, self._impedance, self._estimate, self._switch))
        DeclareSampledUpdate(self, self._update)
        self.DeclareStateOutputPort("impedance", self._impedance)
        self.DeclareStateOutputPort("force_estimate", self._estimate)
        self._started = np.empty(count, dtype=bool)
        self._x = np.empty((3, count))                 # (xe, xe', xe'') per environment
        self._new = np.empty((count, net.size))

    def _update(self, context, state):
        contact = self._contact.Eval(context)
        count = self._count
        if contact[0] < 0 and (count == 1 or max(contact[4::4].tolist()) < 0):
            return
        started = np.logical_not(np.less(contact[0::4], 0.0), out=self._started)
        some = np.count_nonzero(started) < count
        x = self._x
        np.subtract(self._pose.Eval(context)[0::3], contact[1::4], out=x[0])
        x[1] = self._velocity.Eval(context)[0::3]
        x[2] = self._acceleration.Eval(context)[0::3]
        force = self._force.Eval(context)
        switch = context.get_discrete_state(self._i_switch).value().reshape(count, 2)
        first = np.equal(switch[:, 0], 0.0)
        f_s = switch[:, 1]
        if some:  # environments before their switch: zeros in, their state kept
            first &= started
            x[:, ~started] = 0.0
            force = np.where(started, force, 0.0)
        if np.count_nonzero(first):
            f_s = np.where(first, np.where(self._offset, force, 0.0), f_s)
            new_switch = np.stack([np.where(started, 1.0, switch[:, 0]), f_s], axis=1)
            state.get_mutable_value(self._i_switch)[:] = new_switch.reshape(-1)
        f = force - f_s
        if self._running:
            self._update_running(context, state, x.T, f, f_s, started, some)
            return
        net, new = self._net, self._new
        weights = context.get_discrete_state(self._i_weights).value().reshape(count, net.size)
        f_hat = net._train(weights, x[0], x[1], x[2], f, new)
        impedance = net._impedance(new)
        self._store(context, state, started, some, ((self._i_weights, new),
                                                    (self._i_impedance, impedance),
                                                    (self._i_estimate, f_hat + f_s)))

    def _store(self, context, state, started, some, groups):
        """Writes each (group, new values (N, k)) of the started environments."""
        for group, value in groups:
            if some:
                old = context.get_discrete_state(group).value().reshape(self._count, -1)
                value = np.where(started[:, None], value.reshape(self._count, -1), old)
            state.get_mutable_value(group)[:] = value.reshape(-1)

    def _update_running(self, context, state, x, f, f_s, started, some):
        net, count = self._net, self._count
        scales = net._update_scales(
            context.get_discrete_state(self._i_scales).value().reshape(count, 4), x, f)
        weights, f_hat = net._train_scaled(
            context.get_discrete_state(self._i_weights).value().reshape(count, net.size),
            x, f, scales)
        groups = []
        if self._readout == "jacobian":
            impedance = net._jacobian(weights, x, scales)
        elif self._averaged:
            sums, impedance = net._average_secants(
                context.get_discrete_state(self._i_sums).value().reshape(count, 6),
                *net._secants(weights, x, scales), self._readout_decay[:, None])
            groups.append((self._i_sums, sums))
        else:
            probe = net._probe if self._readout == "probe" else None
            rises, steps = net._secants(weights, x, scales, probe)
            impedance = rises / steps
        groups += [(self._i_scales, scales), (self._i_weights, weights),
                   (self._i_impedance, impedance), (self._i_estimate, f_hat + f_s)]
        self._store(context, state, started, some, groups)
