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

import numpy as np
from pydrake.systems.framework import LeafSystem

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


class ImpedanceNetwork:
    """The network's arithmetic on a flat weight vector (no Drake).

    Layout: W (HIDDEN x 4, inputs [1, u]) then v (1 + HIDDEN), row-major.

    One sample's arithmetic runs in work buffers the network owns (the
    system trains and probes it every 1 ms on 4-vectors, where numpy's
    per-call cost outweighs the arithmetic): the same IEEE operations, in
    the same order, as the array expressions in the docstrings, with the
    scalars in Python floats and every matrix product in numpy's BLAS.
    """

    size = HIDDEN * 4 + HIDDEN + 1
    _SPLIT = HIDDEN * 4

    def __init__(self, config: NnIdentifierConfig):
        self.c = config
        self.scale = np.asarray(config.input_scale, dtype=float)
        self._scale = self.scale.tolist()
        self._S = float(config.output_scale_n)
        self._eta = float(config.learning_rate)
        self._u1 = np.ones(4)                          # [1, scale * x]
        self._h1 = np.ones(HIDDEN + 1)                 # [1, f(h)]
        self._hidden = self._h1[1:]
        self._pre = np.empty(HIDDEN)
        self._a = np.empty(HIDDEN)
        self._a_column = self._a[:, None]
        self._step = np.empty(self.size)               # eta [grad_W.ravel(), grad_v]
        self._step_W = self._step[:self._SPLIT].reshape(HIDDEN, 4)
        self._step_v = self._step[self._SPLIT:]
        # The probes' inputs [1, scale * x*] and their hidden layers.
        xs, vs, acc = config.probe
        self._probe_inputs = [np.concatenate([[1.0], self.scale * np.array(x)])
                              for x in ([xs, 0.0, 0.0], [xs, vs, 0.0], [xs, vs, acc])]
        self._probe_pre = np.empty((3, HIDDEN))
        self._probe_rows = list(self._probe_pre)
        self._probe_hidden = np.empty((3, HIDDEN))
        self._probe_hidden_rows = list(self._probe_hidden)

    def unpack(self, weights):
        return weights[:HIDDEN * 4].reshape(HIDDEN, 4), weights[HIDDEN * 4:]

    @staticmethod
    def _f(pre, out):
        """out = f(pre) = 2 / (1 + e^-pre) - 1 (pre is overwritten)."""
        np.negative(pre, out=pre)
        np.exp(pre, out=pre)
        np.add(1.0, pre, out=pre)
        np.divide(2.0, pre, out=pre)
        np.subtract(pre, 1.0, out=out)

    def _pre_activations(self, weights, x0, x1, x2):
        """[1, scale x] into the buffer u1 and W [1, scale x] into pre."""
        u1 = self._u1
        s0, s1, s2 = self._scale
        u1[1] = s0 * x0
        u1[2] = s1 * x1
        u1[3] = s2 * x2
        W = weights[:self._SPLIT].reshape(HIDDEN, 4)
        np.dot(W, u1, out=self._pre)

    def _forward(self, weights, x0, x1, x2):
        """f_hat for raw x = (x0, x1, x2); [1, scale x] and [1, f(h)] into
        the buffers."""
        self._pre_activations(weights, x0, x1, x2)
        self._f(self._pre, self._hidden)
        return self._S * (weights[self._SPLIT] + np.dot(weights[self._SPLIT + 1:], self._hidden))

    def _train(self, weights, x0, x1, x2, f, out):
        """One gradient step (see :meth:`train`), the new weights into
        ``out``; returns f_hat before the step."""
        f_hat = self._forward(weights, x0, x1, x2)
        c = -(f - f_hat) * self._S                     # -e S
        a = self._a                                    # -e S v_1: f'(h)
        for j, (v_j, h_j) in enumerate(zip(weights[self._SPLIT + 1:].tolist(),
                                            self._hidden.tolist())):
            a[j] = c * v_j * 0.5 * (1.0 - h_j * h_j)
        np.multiply(self._a_column, self._u1, out=self._step_W)
        np.multiply(self._h1, c, out=self._step_v)
        np.multiply(self._step, self._eta, out=self._step)
        np.subtract(weights, self._step, out=out)
        return f_hat

    def _impedance(self, weights):
        """(M_e, B_e, K_e) as floats (see :meth:`impedance`)."""
        W = weights[:self._SPLIT].reshape(HIDDEN, 4)
        for u, row in zip(self._probe_inputs, self._probe_rows):
            np.dot(W, u, out=row)
        self._f(self._probe_pre, self._probe_hidden)
        v0, v1, S = weights[self._SPLIT], weights[self._SPLIT + 1:], self._S
        f_x, f_xv, f_xva = (S * (v0 + np.dot(v1, h)) for h in self._probe_hidden_rows)
        xs, vs, acc = self.c.probe
        return (f_xva - f_xv) / acc, (f_xv - f_x) / vs, f_x / xs

    def forward(self, weights, x):
        """f_hat (N) and the hidden activations for raw x = (xe, xe', xe'')."""
        f_hat = self._forward(weights, *np.asarray(x, dtype=float).tolist())
        return f_hat, self._u1.copy(), self._hidden.copy()

    def train(self, weights, x, f):
        """One gradient step on 1/2 (f - f_hat)^2; returns the new weights
        and f_hat before the step:

            e = f - f_hat
            v -= eta (-e S [1, f(h)])
            W -= eta outer(-e S v_1: (1 - f(h)^2) / 2, [1, u])
        """
        new = np.empty(self.size)
        f_hat = self._train(weights, *np.asarray(x, dtype=float).tolist(), f, new)
        return new, f_hat

    def impedance(self, weights):
        """(M_e, B_e, K_e) by probing at (x*, v*, a*)."""
        return np.array(self._impedance(weights))

    # Self-scaling (normalization: running): plain array expressions; the
    # scales s = (s_x, s_v, s_a, s_f) are arguments (the system's state).

    def update_scales(self, scales, x, f):
        """The running scales after the sample x = (xe, xe', xe''), f (N,
        less f_s): elementwise max(scales, |x|, |f|)."""
        return np.maximum(scales, np.abs(np.append(np.asarray(x, dtype=float), f)))

    def forward_scaled(self, weights, x, scales):
        """f_hat = s_f (v . [1, f(W [1, x / s])]) and the hidden activations."""
        W, v = self.unpack(weights)
        u = np.concatenate([[1.0], np.asarray(x, dtype=float) / scales[:3]])
        hidden = 2.0 / (1.0 + np.exp(-(W @ u))) - 1.0
        return scales[3] * (v[0] + v[1:] @ hidden), u, hidden

    def train_scaled(self, weights, x, f, scales):
        """One step on 1/2 ((f - f_hat) / s_f)^2; returns the new weights and
        f_hat before the step (see the module doc)."""
        W, v = self.unpack(weights)
        f_hat, u, hidden = self.forward_scaled(weights, x, scales)
        e = (f - f_hat) / scales[3]
        grad_v = -e * np.concatenate([[1.0], hidden])
        grad_W = np.outer(-e * v[1:] * 0.5 * (1.0 - hidden**2), u)
        eta = self.c.learning_rate
        return np.concatenate([(W - eta * grad_W).ravel(), v - eta * grad_v]), f_hat

    def jacobian(self, weights, x, scales):
        """(M_e, B_e, K_e) = d f_hat / d (xe'', xe', xe) at x."""
        W, v = self.unpack(weights)
        _, _, hidden = self.forward_scaled(weights, x, scales)
        d_u = W[:, 1:].T @ (v[1:] * 0.5 * (1.0 - hidden**2))
        return (scales[3] * d_u / scales[:3])[::-1]

    def operating_point(self, weights, x, scales, probe=None):
        """(M_e, B_e, K_e) by the thesis's secants at x* = xe (at least its
        floor in magnitude), v* = s_v, a* = s_a; or at a given ``probe``."""
        rises, steps = self.secants(weights, x, scales, probe)
        return rises / steps

    def secants(self, weights, x, scales, probe=None):
        """The secants of :meth:`operating_point` as (rises, steps), each in
        the order (M_e, B_e, K_e): rises (f_xva - f_xv, f_xv - f_x, f_x)
        (N) over steps (a*, v*, x*)."""
        if probe is None:
            floor = self.c.scale_floor[0]
            xs = float(x[0]) if abs(x[0]) >= floor else (floor if x[0] >= 0 else -floor)
            vs, acc = scales[1], scales[2]
        else:
            xs, vs, acc = probe
        f_x, f_xv, f_xva = (self.forward_scaled(weights, p, scales)[0]
                            for p in ([xs, 0.0, 0.0], [xs, vs, 0.0], [xs, vs, acc]))
        return np.array([f_xva - f_xv, f_xv - f_x, f_x]), np.array([acc, vs, xs])

    @staticmethod
    def average_secants(sums, rises, steps, decay):
        """The exponentially weighted least-squares readout: ``sums`` = [sum
        of step * rise (3), sum of step^2 (3)] decayed by ``decay`` and
        updated with this sample's secants; returns (new sums, (M_e, B_e,
        K_e) = sum step * rise / sum step^2)."""
        new = np.concatenate([decay * sums[:3] + steps * rises,
                              decay * sums[3:] + steps * steps])
        return new, new[:3] / new[3:]

    def initial_weights(self, seed):
        rng = np.random.default_rng(seed)
        return rng.normal(0.0, self.c.initial_weight_std, self.size)


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
        t = weights[self._SPLIT] + float(np.dot(weights[self._SPLIT + 1:], self._pre))
        self._f(self._pre.copy(), self._hidden)
        return self._S * (2.0 / (1.0 + np.exp(-t)) - 1.0)

    def _train(self, weights, x0, x1, x2, f, out):
        f_hat = self._forward(weights, x0, x1, x2)
        q = f_hat / self._S
        d = (f - f_hat) * self._S * 0.5 * (1.0 - q * q)
        v1 = weights[self._SPLIT + 1:]
        hidden = self._hidden
        back = d * v1 * 0.5 * (1.0 - hidden * hidden)
        out[:self._SPLIT] = weights[:self._SPLIT] + self._eta * np.outer(back, self._u1).ravel()
        out[self._SPLIT:] = weights[self._SPLIT:] + self._eta * d * self._h1
        return f_hat

    def _impedance(self, weights):
        W = weights[:self._SPLIT].reshape(HIDDEN, 4)
        v0, v1, S = weights[self._SPLIT], weights[self._SPLIT + 1:], self._S
        f_x, f_xv, f_xva = (S * (2.0 / (1.0 + np.exp(-(v0 + np.dot(v1, W @ u)))) - 1.0)
                            for u in self._probe_inputs)
        xs, vs, acc = self.c.probe
        return (f_xva - f_xv) / acc, (f_xv - f_x) / vs, f_x / xs


def make_network(config: NnIdentifierConfig) -> ImpedanceNetwork:
    """The network for ``config.output_layer``."""
    if config.output_layer == "appendix_e":
        return AppendixEImpedanceNetwork(config)
    return ImpedanceNetwork(config)


class NnIdentifier(LeafSystem):
    """The neural identifier, trained every 1 ms after the first switch.

    Input ports: as RlsIdentifier (force, tip_pose, tip_velocity,
      tip_acceleration, contact_info).
    Output ports (state outputs): impedance (3): [M_e, B_e, K_e] (kg, N s/m,
      N/m) by ``readout``;
      force_estimate (1): the network's force before each step (N; plus
      f_s with ``force_offset``).
    State: the weights (discrete), seeded; [started, f_s]; with
      ``normalization: running`` also the scales (s_x, s_v, s_a, s_f);
      with ``readout_time_constant_s`` also the readout's weighted sums
      [sum step * rise (3), sum step^2 (3)].
    """

    def __init__(self, config: NnIdentifierConfig, seed: int):
        super().__init__()
        self._net = make_network(config)
        weights = self._net.initial_weights(seed)
        self._force = self.DeclareVectorInputPort("force", 1)
        self._pose = self.DeclareVectorInputPort("tip_pose", 3)
        self._velocity = self.DeclareVectorInputPort("tip_velocity", 3)
        self._acceleration = self.DeclareVectorInputPort("tip_acceleration", 3)
        self._contact = self.DeclareVectorInputPort("contact_info", 4)
        self._weights = self.DeclareDiscreteState(weights)
        self._impedance = self.DeclareDiscreteState(self._net.impedance(weights))
        self._estimate = self.DeclareDiscreteState(1)
        self._switch = self.DeclareDiscreteState(2)
        self._running = config.normalization == "running"
        if self._running:
            # The running scales (s_x, s_v, s_a, s_f), from their floors.
            self._scales = self.DeclareDiscreteState(np.asarray(config.scale_floor, dtype=float))
            self._i_scales = int(self._scales)
        tau = config.readout_time_constant_s
        self._readout_decay = float(np.exp(-CONTROL_PERIOD / tau)) if tau > 0 else None
        if self._readout_decay is not None:
            # The readout's weighted sums: [sum step * rise, sum step^2] (3 + 3).
            self._i_sums = int(self.DeclareDiscreteState(6))
        # Plain ints index the groups (cheaper to pass to pydrake).
        self._i_weights, self._i_impedance, self._i_estimate, self._i_switch = (
            int(i) for i in (self._weights, self._impedance, self._estimate, self._switch))
        DeclareSampledUpdate(self, self._update)
        self.DeclareStateOutputPort("impedance", self._impedance)
        self.DeclareStateOutputPort("force_estimate", self._estimate)

    def _update(self, context, state):
        contact = self._contact.Eval(context)
        if contact[0] < 0:
            return
        x0 = self._pose.Eval(context)[0] - contact[1]
        x1 = self._velocity.Eval(context)[0]
        x2 = self._acceleration.Eval(context)[0]
        force = self._force.Eval(context)[0]
        started, f_s = context.get_discrete_state(self._i_switch).value().tolist()
        if not started:
            f_s = force if self._net.c.force_offset else 0.0
            state.get_mutable_value(self._i_switch)[:] = (1.0, f_s)
        net = self._net
        if self._running:
            self._update_running(context, state, (x0, x1, x2), force - f_s, f_s)
            return
        weights = state.get_mutable_value(self._i_weights)
        f_hat = net._train(context.get_discrete_state(self._i_weights).value(),
                           float(x0), float(x1), float(x2), float(force - f_s), weights)
        state.get_mutable_value(self._i_impedance)[:] = net._impedance(weights)
        state.get_mutable_value(self._i_estimate)[0] = f_hat + f_s

    def _update_running(self, context, state, x, f, f_s):
        net = self._net
        scales = net.update_scales(context.get_discrete_state(self._i_scales).value(), x, f)
        weights, f_hat = net.train_scaled(context.get_discrete_state(self._i_weights).value(),
                                          x, f, scales)
        if net.c.readout == "jacobian":
            impedance = net.jacobian(weights, x, scales)
        elif self._readout_decay is not None:
            sums, impedance = net.average_secants(
                context.get_discrete_state(self._i_sums).value(),
                *net.secants(weights, x, scales), self._readout_decay)
            state.get_mutable_value(self._i_sums)[:] = sums
        else:
            probe = net.c.probe if net.c.readout == "probe" else None
            impedance = net.operating_point(weights, x, scales, probe)
        state.get_mutable_value(self._i_scales)[:] = scales
        state.get_mutable_value(self._i_weights)[:] = weights
        state.get_mutable_value(self._i_impedance)[:] = impedance
        state.get_mutable_value(self._i_estimate)[0] = f_hat + f_s
