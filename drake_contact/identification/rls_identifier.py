"""Online identification of the environment's impedance by recursive least
squares (thesis chapter 5, equations 5.1-5.10).

    f = phi^T theta,  phi = (xe'', xe', xe),  theta = (M_e, B_e, K_e)

with f the DSP's filtered force and xe the tip's displacement from where it
was at the contact switch (the thesis's choice), its velocity and
acceleration from the kinematic estimator. Each 1 ms sample after the switch:

    k = P phi / (lambda + phi^T P phi)
    theta += k (f - phi^T theta)
    P = (P - k phi^T P) / lambda

lambda = 1 is the thesis's RLS; lambda < 1 forgets, for environments that
change in time.

Referencing xe to the switch point biases the fit: the force there is
already about 5 N, so f = K_e xe + f_switch and a line through the origin
over-estimates K_e (by about f_switch / (f - f_switch), +33 % at 20 N). The
option ``force_offset`` adds a constant to the regressor, phi = (xe'', xe',
xe, 1), theta = (M_e, B_e, K_e, f_0), which removes it. The thesis's form
stays the default.

The option ``stiffness_drift`` q (ours) lets K_e change in time
the way a Kalman filter does (L. Ljung and S. Gunnarsson, "Adaptation and
tracking in system identification - a survey", Automatica 26(1):7-21,
1990, section 3): K_e is modelled as a random walk whose step per sample
has variance q K_e^2 (relative, so the same q serves any wall; K_e is the
current estimate), and each update adds it to P:

    P[K, K] += q theta_K^2

Unlike lambda < 1, which discounts every parameter and multiplies P by
1/lambda per sample while the arm rests (windup), it lets only K_e move,
and at rest P_KK grows linearly, not exponentially.

A random walk follows a drift, not a jump (a material change). The option
``change_threshold_n`` (ours) resets the covariance when the fit
stops predicting the force, the covariance resetting of G. C. Goodwin and
K. S. Sin, Adaptive Filtering, Prediction and Control, 1984, section 3.3
(and K. J. Astrom and B. Wittenmark, Adaptive Control, 2nd ed., 1995,
section 11.4, on detecting parameter changes): the a priori prediction
error e = f - phi^T theta is averaged by a first-order filter of time
constant ``change_time_constant_s`` (on the 1 ms samples, alpha = T / tau),

    e_bar += alpha (e - e_bar),

and when |e_bar| exceeds the threshold, no sooner than
``change_holdoff_s`` after the switch or the last reset, P returns to its
initial diag(p0) (theta is kept) and e_bar to 0. The gauge noise alone moves
e_bar by about 0.1 N; a change of K_e at 20 N moves it by newtons.
"""

import dataclasses as dc
from collections.abc import Sequence

import numpy as np
from pydrake.systems.framework import LeafSystem

from drake_contact.blocks import environment_configs
from drake_contact.plant.arm import (
    CONTROL_PERIOD, TIME_TOLERANCE_S, DeclareSampledUpdate, held_while_flagged)
from drake_contact.errors import ScenarioError
from drake_contact.arm_axis import check_switches
from drake_contact.identification.stacked import at, constants, every, products, stepped


@dc.dataclass
class RlsConfig:
    """Recursive least squares on (M_e, B_e, K_e)."""

    # Initial estimate (kg, N s/m, N/m); the thesis's text: (0, 0, 2e5).
    theta0: list[float] = dc.field(default_factory=lambda: [0.0, 0.0, 2.0e5])
    # Initial covariance diagonal for (M_e, B_e, K_e) (and f_0 with the offset).
    p0: list[float] = dc.field(default_factory=lambda: [1.0e2, 1.0e6, 1.0e12, 1.0e4])
    # Forgetting factor in (0, 1]; 1 = no forgetting (the thesis).
    forgetting_factor: float = 1.0
    # Add a force offset f_0 to the regressor (removes the switch-point bias).
    force_offset: bool = False
    # Relative random-walk variance of K_e per sample (see the module doc);
    # 0 = a constant K_e (the thesis).
    stiffness_drift: float = 0.0
    # Covariance reset on a detected change (see the module doc): threshold
    # on the filtered prediction error (N; 0 = off), its time constant (s) and
    # the least time between resets, and after the switch (s).
    change_threshold_n: float = 0.0
    change_time_constant_s: float = 0.05
    change_holdoff_s: float = 0.5

    def validate(self, prefix):
        if len(self.theta0) != 3 or not all(np.isfinite(self.theta0)):
            raise ScenarioError(f"{prefix}.theta0 = {self.theta0} is out of range: "
                                "must be 3 finite values (kg, N s/m, N/m)")
        if len(self.p0) != 4 or not all(x > 0 for x in self.p0):
            raise ScenarioError(f"{prefix}.p0 = {self.p0} is out of range: must be 4 values > 0")
        if not (0 < self.forgetting_factor <= 1):
            raise ScenarioError(f"{prefix}.forgetting_factor = {self.forgetting_factor} is out "
                                "of range: must be in (0, 1]")
        if not (0 <= self.stiffness_drift <= 1e-3):
            raise ScenarioError(f"{prefix}.stiffness_drift = {self.stiffness_drift} is out of "
                                "range: must be in [0, 1e-3] (a relative variance per sample)")
        for name, low, high in (("change_threshold_n", 0.0, 1e3),
                                ("change_time_constant_s", 1e-3, 10.0),
                                ("change_holdoff_s", 0.0, 1e3)):
            value = getattr(self, name)
            if not (low <= value <= high):
                raise ScenarioError(f"{prefix}.{name} = {value} is out of range: must be in "
                                    f"[{low:g}, {high:g}]")


class RlsEstimator:
    """The RLS recursion itself (no Drake), for tests and the system."""

    def __init__(self, config: RlsConfig):
        self.n = 4 if config.force_offset else 3
        self.lam = config.forgetting_factor
        self.drift = config.stiffness_drift
        self.theta = np.array(list(config.theta0) + [0.0] * (self.n - 3), dtype=float)
        self.P0 = np.diag(np.asarray(config.p0[:self.n], dtype=float))
        self.P = self.P0.copy()
        # Change detection: the filtered prediction error and the time of the
        # switch or the last reset (samples counted by update()).
        self.config = config
        self.error = 0.0
        self.samples = 0
        self.last_reset = 0
        self.resets = []

    @staticmethod
    def change_step(error, samples, last, prediction_error, config):
        """One sample of the change detector: the filtered error after it and
        whether to reset (``samples``: this sample's count since the switch,
        ``last``: the count at the last reset or 0)."""
        error += CONTROL_PERIOD / config.change_time_constant_s * (prediction_error - error)
        armed = (samples - last) * CONTROL_PERIOD >= config.change_holdoff_s - TIME_TOLERANCE_S
        return error, armed and abs(error) > config.change_threshold_n

    def detect(self, phi, f):
        """Filters the a priori error of a sample and resets P on a change
        (before the sample's update); returns whether it reset."""
        if not self.config.change_threshold_n:
            return False
        self.error, reset = self.change_step(self.error, self.samples, self.last_reset,
                                             f - phi @ self.theta, self.config)
        if reset:
            self.P = self.P0.copy()
            self.error = 0.0
            self.last_reset = self.samples
            self.resets.append(self.samples)
        return reset

    @staticmethod
    def step(theta, P, phi, f, lam, drift=0.0):
        """One update; returns (theta, P)."""
        P_phi = P @ phi
        gain = P_phi / (lam + phi @ P_phi)
        theta = theta + gain * (f - phi @ theta)
        P = (P - np.outer(gain, P_phi)) / lam
        P = 0.5 * (P + P.T)
        if drift:
            P[2, 2] += drift * theta[2] * theta[2]
        return theta, P

    def update(self, xe, xe_dot, xe_ddot, f):
        phi = np.array([xe_ddot, xe_dot, xe, 1.0][:self.n])
        self.samples += 1
        self.detect(phi, f)
        self.theta, self.P = self.step(self.theta, self.P, phi, f, self.lam, self.drift)
        return self.theta


def _configs(config, prefix):
    return environment_configs(config, RlsConfig, prefix)


def structure(config):
    """The options a config switches on (its structure: the state's shape
    and which arithmetic runs), by field."""
    return {"force_offset": bool(config.force_offset),
            "stiffness_drift": config.stiffness_drift > 0,
            "change_threshold_n": config.change_threshold_n > 0}


def check_structure(configs, prefix="identifiers.rls"):
    """Raises ScenarioError naming the field if the environments' configs
    differ in an option they switch on (their numbers may differ)."""
    check_switches(configs, structure, prefix)


class RlsIdentifier(LeafSystem):
    """RLS identification, sampled every 1 ms, active after the first switch,
    for N environments (one config each; a single config: N = 1). The
    configs may differ in their numbers (theta0, p0, lambda, q, the change
    detector's threshold, time constant and hold-off), not in the options
    they switch on (:func:`check_structure`).

    Input ports (env-major: environment i's k values at [k i, k i + k)):
      force (N): filtered force (N); tip_pose (3 N), tip_velocity (3 N),
      tip_acceleration (3 N): the estimator's (m, m/s, m/s^2; only x is used);
      contact_info (4 N): [first switch time or -1, x, y, phi at the switch].
    Output port: impedance (3 N): [M_e, B_e, K_e] (kg, N s/m, N/m), theta0
      until the environment's switch (state output).
    State (env-major): theta (n), P (n x n) per environment, with n = 3, or 4
      with the force offset; with change detection also [filtered error,
      samples since the switch, sample of the last reset] (RlsEstimator.detect).

    Each environment's step is RlsEstimator.step's arithmetic, operation for
    operation, elementwise over the arm axis, its products per environment
    (:mod:`drake_contact.identification.stacked`): every environment's
    values are bit for bit those of its identifier alone.
    """

    def __init__(self, config: RlsConfig | Sequence[RlsConfig], *, prefix="identifiers.rls"):
        super().__init__()
        configs = _configs(config, prefix)
        check_structure(configs, prefix)
        self._count = count = len(configs)
        inits = [RlsEstimator(c) for c in configs]
        self._n = n = inits[0].n
        self._force = self.DeclareVectorInputPort("force", count)
        self._pose = self.DeclareVectorInputPort("tip_pose", 3 * count)
        self._velocity = self.DeclareVectorInputPort("tip_velocity", 3 * count)
        self._acceleration = self.DeclareVectorInputPort("tip_acceleration", 3 * count)
        self._contact = self.DeclareVectorInputPort("contact_info", 4 * count)
        # The safety supervisor's flag: while it is up, the estimate is held
        # (unconnected: never).
        self._fault = self.DeclareVectorInputPort("force_fault", count)
        self._impedance = self.DeclareDiscreteState(
            np.concatenate([init.theta[:3] for init in inits]))
        self._state = self.DeclareDiscreteState(
            np.concatenate([np.concatenate([init.theta, init.P.ravel()]) for init in inits]))
        # Plain ints index the groups (cheaper to pass to pydrake).
        self._i_impedance, self._i_state = int(self._impedance), int(self._state)
        DeclareSampledUpdate(self, self._update)
        self.DeclareStateOutputPort("impedance", self._impedance)
        # The arithmetic is written once (drake_contact.identification.stacked):
        # one environment's buffers without the environment axis and its
        # constants Python floats, as alone; N environments' (N, ...).
        self._one = one = count == 1
        self._matvec, self._rowdot = products(one)
        self._lam = constants([c.forgetting_factor for c in configs], one)
        self._lam_matrix = self._lam if one else self._lam[:, :, None]
        self._drift = constants([c.stiffness_drift for c in configs], one)
        self._drifting = configs[0].stiffness_drift > 0
        self._detect = configs[0].change_threshold_n > 0
        if self._detect:
            self._i_change = int(self.DeclareDiscreteState(np.zeros(3 * count)))
            self._P0 = inits[0].P0 if one else np.stack([init.P0 for init in inits])
            # change_step's operands: alpha = T / tau, the hold-off less the
            # tolerance, the threshold.
            self._alpha = constants([CONTROL_PERIOD / c.change_time_constant_s for c in configs],
                                    one)
            self._holdoff = constants([c.change_holdoff_s - TIME_TOLERANCE_S for c in configs],
                                      one)
            self._threshold = constants([c.change_threshold_n for c in configs], one)
        # Where each environment's values are in the inputs: x of a pose
        # (3 per environment), the switch time and x of contact_info (4).
        # (A float for one environment, a column (N, 1) for N: see
        # drake_contact.identification.stacked.)
        self._x = every(0, 3, one)
        self._time = 0 if one else slice(0, None, 4)
        self._x_switch = every(1, 4, one)
        self._f = every(0, 1, one)
        # An environment's k-th value of a buffer's last axis, and P's K_e, K_e.
        self._at = [at(k, one) for k in range(3)]
        self._K_K = (2, 2) if one else (slice(None), slice(2, 3), 2)
        # Work buffers of one sample's step (see _update).
        lead = () if one else (count,)
        self._values = np.empty(lead + (n + n * n,))   # the state [theta, P.ravel()] read
        self._theta = self._values[..., :n]
        self._P = self._values[..., n:].reshape(lead + (n, n))
        self._phi = np.ones(lead + (n,))               # [xe'', xe', xe(, 1)]
        self._P_phi = np.empty(lead + (n,))
        self._P_phi_row = self._P_phi[..., None, :]
        self._gain = np.empty(lead + (n,))
        self._gain_column = self._gain[..., :, None]
        self._theta_step = np.empty(lead + (n,))
        self._B = np.empty(lead + (n, n))
        self._B_transposed = np.swapaxes(self._B, -1, -2)
        self._new = np.empty(lead + (n + n * n,))     # the state written
        self._new_theta = self._new[..., :n]
        self._new_P = self._new[..., n:].reshape(lead + (n, n))
        self._new_impedance = self._new[..., :3]

    def _started(self, contact):
        """Which environments are past their switch (N,), or None when all
        are (N > 1; one environment is not stepped before its switch)."""
        started = np.logical_not(np.less(contact[self._time], 0.0))
        return None if np.count_nonzero(started) == self._count else started

    def _update(self, context, state):
        contact = self._contact.Eval(context)
        if contact[0] < 0 and (self._one or max(contact[4::4].tolist()) < 0):
            return
        count = self._count
        started = None if self._one else self._started(contact)
        # A flagged force reading holds the estimate, as before the switch.
        step, started = stepped(started, held_while_flagged(self._fault, context), self._one)
        if not step:
            return
        # RlsEstimator.step's arithmetic, operation for operation, in the
        # buffers: theta and P (a copy of the state), phi, the new state.
        self._values.reshape(-1)[:] = context.get_discrete_state(self._i_state).value()
        phi, P_phi, gain, B = self._phi, self._P_phi, self._gain, self._B
        at = self._at
        phi[at[0]] = self._acceleration.Eval(context)[self._x]
        phi[at[1]] = self._velocity.Eval(context)[self._x]
        phi[at[2]] = self._pose.Eval(context)[self._x] - contact[self._x_switch]
        f = self._force.Eval(context)[self._f]
        if started is not None:  # environments before their switch: zeros in, state kept
            phi[~started, :3] = 0.0
            f = np.where(started[:, None], f, 0.0)
        if self._detect:
            self._detect_change(context, state, f, started)
        self._matvec(self._P, phi, P_phi)
        np.divide(P_phi, self._lam + self._rowdot(phi, P_phi), out=gain)
        np.multiply(gain, f - self._rowdot(phi, self._theta), out=self._theta_step)
        np.add(self._theta, self._theta_step, out=self._new_theta)
        np.multiply(self._gain_column, self._P_phi_row, out=B)
        np.subtract(self._P, B, out=B)
        np.divide(B, self._lam_matrix, out=B)
        np.add(B, self._B_transposed, out=self._new_P)
        np.multiply(self._new_P, 0.5, out=self._new_P)
        if self._drifting:
            K = self._new_theta[self._at[2]]
            self._new_P[self._K_K] += self._drift * K * K
        new, impedance = self._new, self._new_impedance
        if started is not None:
            new = np.where(started[:, None], new, self._values)
            impedance = np.where(started[:, None], new[:, :3],
                                 context.get_discrete_state(self._i_impedance).value()
                                 .reshape(count, 3))
        state.get_mutable_value(self._i_state)[:] = new.reshape(-1)
        state.get_mutable_value(self._i_impedance)[:] = impedance.reshape(-1)

    def _detect_change(self, context, state, f, started):
        """RlsEstimator.detect on the state: may reset the P read."""
        change = context.get_discrete_state(self._i_change).value()
        if not self._one:
            change = change.reshape(self._count, 3)
        at = self._at
        error, samples, last = change[at[0]], change[at[1]] + 1.0, change[at[2]]
        error = error + self._alpha * (f - self._rowdot(self._phi, self._theta) - error)
        armed = (samples - last) * CONTROL_PERIOD >= self._holdoff
        reset = armed & (abs(error) > self._threshold)
        if self._one:
            if reset:
                self._P[:] = self._P0
                error, last = 0.0, samples
            state.get_mutable_value(self._i_change)[:] = [error, samples, last]
            return
        if started is not None:
            reset &= started[:, None]
        if np.count_nonzero(reset):
            self._P[reset[:, 0]] = self._P0[reset[:, 0]]
            error = np.where(reset, 0.0, error)
            last = np.where(reset, samples, last)
        new = np.concatenate([error, samples, last], axis=1)
        if started is not None:
            new = np.where(started[:, None], new, change)
        state.get_mutable_value(self._i_change)[:] = new.reshape(-1)
