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
"""

import dataclasses as dc

import numpy as np
from pydrake.systems.framework import LeafSystem

from drake_contact.plant.arm import CONTROL_PERIOD, DeclareSampledUpdate
from drake_contact.errors import ScenarioError


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

    def validate(self, prefix):
        if len(self.theta0) != 3 or not all(np.isfinite(self.theta0)):
            raise ScenarioError(f"{prefix}.theta0 = {self.theta0} is out of range: "
                                "must be 3 finite values (kg, N s/m, N/m)")
        if len(self.p0) != 4 or not all(x > 0 for x in self.p0):
            raise ScenarioError(f"{prefix}.p0 = {self.p0} is out of range: must be 4 values > 0")
        if not (0 < self.forgetting_factor <= 1):
            raise ScenarioError(f"{prefix}.forgetting_factor = {self.forgetting_factor} is out "
                                "of range: must be in (0, 1]")


class RlsEstimator:
    """The RLS recursion itself (no Drake), for tests and the system."""

    def __init__(self, config: RlsConfig):
        self.n = 4 if config.force_offset else 3
        self.lam = config.forgetting_factor
        self.theta = np.array(list(config.theta0) + [0.0] * (self.n - 3), dtype=float)
        self.P = np.diag(np.asarray(config.p0[:self.n], dtype=float))

    @staticmethod
    def step(theta, P, phi, f, lam):
        """One update; returns (theta, P)."""
        P_phi = P @ phi
        gain = P_phi / (lam + phi @ P_phi)
        theta = theta + gain * (f - phi @ theta)
        P = (P - np.outer(gain, P_phi)) / lam
        return theta, 0.5 * (P + P.T)

    def update(self, xe, xe_dot, xe_ddot, f):
        phi = np.array([xe_ddot, xe_dot, xe, 1.0][:self.n])
        self.theta, self.P = self.step(self.theta, self.P, phi, f, self.lam)
        return self.theta


class RlsIdentifier(LeafSystem):
    """RLS identification, sampled every 1 ms, active after the first switch.

    Input ports:
      force (1): filtered force (N); tip_pose (3), tip_velocity (3),
      tip_acceleration (3): the estimator's (m, m/s, m/s^2; only x is used);
      contact_info (4): [first switch time or -1, x, y, phi at the switch].
    Output port: impedance (3): [M_e, B_e, K_e] (kg, N s/m, N/m), theta0
      until the switch (state output).
    State: theta (n), P (n x n), with n = 3, or 4 with the force offset.
    """

    def __init__(self, config: RlsConfig):
        super().__init__()
        self._config = config
        init = RlsEstimator(config)
        self._n = init.n
        self._force = self.DeclareVectorInputPort("force", 1)
        self._pose = self.DeclareVectorInputPort("tip_pose", 3)
        self._velocity = self.DeclareVectorInputPort("tip_velocity", 3)
        self._acceleration = self.DeclareVectorInputPort("tip_acceleration", 3)
        self._contact = self.DeclareVectorInputPort("contact_info", 4)
        self._impedance = self.DeclareDiscreteState(init.theta[:3])
        self._state = self.DeclareDiscreteState(np.concatenate([init.theta, init.P.ravel()]))
        DeclareSampledUpdate(self, self._update)
        self.DeclareStateOutputPort("impedance", self._impedance)

    def _update(self, context, state):
        t_contact, x_switch = self._contact.Eval(context)[:2]
        if t_contact < 0:
            return
        n = self._n
        values = context.get_discrete_state(self._state).value()
        theta, P = values[:n], values[n:].reshape(n, n)
        xe = self._pose.Eval(context)[0] - x_switch
        phi = np.array([self._acceleration.Eval(context)[0], self._velocity.Eval(context)[0],
                        xe, 1.0][:n])
        theta, P = RlsEstimator.step(theta, P, phi, self._force.Eval(context)[0],
                                     self._config.forgetting_factor)
        state.get_mutable_vector(self._state).SetFromVector(np.concatenate([theta, P.ravel()]))
        state.get_mutable_vector(self._impedance).SetFromVector(theta[:3])
