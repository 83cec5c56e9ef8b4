"""The compliant environment: a wall at x = surface_x facing the arm (-x).

Model (thesis chapter 5): M_e xe'' + B_e xe' + K_e xe = f, with xe the
surface displacement, i.e. how far the tip has pushed the surface in.

In contact the surface moves with the tip (xe = x_tip - surface_x), so the
normal force on the tip is

    f = K_e xe + B_e xe' + M_e xe''      (``law: linear``)
    f = (K_e xe + B_e xe') (xe / x_ref)^(n-1) + M_e xe''   (``law: hunt_crossley``)

clipped at zero: the wall pushes and never pulls. The plant is discrete and
applies this force over its next step, so xe'' is the tip's last known
acceleration (the only causal estimate), smoothed by one pole
``acceleration_smoothing`` = alpha. The wall and the plant update together,
so the force over step n uses the acceleration over step n - 2, and the
explicit inertial term is stable while (1 - alpha) M_e / m_tip < 1 (m_tip the
arm's effective mass along x, 1 / (J M^-1 J^T)_xx = 6.8 kg at q0), i.e. M_e up
to about 13 kg at alpha = 0.5 (11 kg with a 7-50 kN/m spring, measured on a
6.8 kg point mass).

Out of contact the surface has its own state (xe, xe') and relaxes back by
the free M_e, B_e, K_e dynamics, integrated by implicit Euler at the plant
step (unconditionally stable, so any M_e >= 0, B_e >= 0, K_e > 0 is safe). The
tip is in contact while it is at or beyond the free surface; a tip that
retreats faster than the surface can follow leaves it, and the force is zero.

Options: tangential Coulomb friction along the surface (the thesis notes the
tip sticks to soft material), regularized inside |v_y| < stiction_velocity;
and a linear drift of K_e in time (material properties change with
temperature and humidity), K_e(t) = K_e (1 + stiffness_drift_per_s t).
"""

import dataclasses as dc

import numpy as np
from pydrake.common.value import Value
from pydrake.systems.framework import BasicVector, LeafSystem, ValueProducer

from drake_contact.errors import ScenarioError

CONTACT_LAWS = ("linear", "hunt_crossley")


@dc.dataclass
class EnvironmentConfig:
    """True parameters of the wall (controllers never read these)."""

    # Stiffness K_e (N/m). Styrofoam about 7e3, rubber 4.4e4-6.2e4 (thesis).
    stiffness: float = 7000.0
    # Damping B_e (N s/m). The thesis calls it realistic but gives no value.
    damping: float = 20.0
    # Mass M_e (kg) moving with the surface. The thesis: "very small".
    mass: float = 0.01
    # Rest position of the surface along world x (m); thesis about 0.456.
    surface_x: float = 0.456
    # Normal law: "linear" (the thesis's model) or "hunt_crossley".
    law: str = "linear"
    # Hunt-Crossley exponent n (dimensionless), used by law hunt_crossley.
    hunt_crossley_exponent: float = 1.5
    # Penetration (m) at which the Hunt-Crossley law equals the linear one.
    hunt_crossley_reference_penetration: float = 1e-3
    # Tangential Coulomb friction coefficient along the surface (0 = off).
    friction_coefficient: float = 0.0
    # Tangential speed (m/s) below which friction is linear (sticking).
    stiction_velocity: float = 0.01
    # Relative drift of K_e per second: K_e(t) = K_e (1 + drift t).
    stiffness_drift_per_s: float = 0.0
    # Pole of the one-pole smoother on the tip acceleration used by M_e.
    acceleration_smoothing: float = 0.5

    def validate(self, prefix="environment", duration=None):
        def bad(field, value, allowed):
            raise ScenarioError(f"{prefix}.{field} = {value} is out of range: {allowed}")
        if not (np.isfinite(self.stiffness) and self.stiffness > 0):
            bad("stiffness", self.stiffness, "must be > 0 N/m")
        if not (np.isfinite(self.damping) and self.damping >= 0):
            bad("damping", self.damping, "must be >= 0 N s/m")
        if not (np.isfinite(self.mass) and self.mass >= 0):
            bad("mass", self.mass, "must be >= 0 kg")
        if not np.isfinite(self.surface_x):
            bad("surface_x", self.surface_x, "must be a finite position in m")
        if self.law not in CONTACT_LAWS:
            raise ScenarioError(
                f"{prefix}.law = '{self.law}' is unknown: choose one of {', '.join(CONTACT_LAWS)}")
        if not (self.hunt_crossley_exponent >= 1):
            bad("hunt_crossley_exponent", self.hunt_crossley_exponent, "must be >= 1")
        if not (self.hunt_crossley_reference_penetration > 0):
            bad("hunt_crossley_reference_penetration",
                self.hunt_crossley_reference_penetration, "must be > 0 m")
        if not (self.friction_coefficient >= 0):
            bad("friction_coefficient", self.friction_coefficient, "must be >= 0")
        if not (self.stiction_velocity > 0):
            bad("stiction_velocity", self.stiction_velocity, "must be > 0 m/s")
        if not (0 <= self.acceleration_smoothing < 1):
            bad("acceleration_smoothing", self.acceleration_smoothing, "must be in [0, 1)")
        if duration is not None and 1 + self.stiffness_drift_per_s * duration <= 0:
            bad("stiffness_drift_per_s", self.stiffness_drift_per_s,
                f"must keep K_e > 0 over the run: > {-1 / duration:.4g} 1/s")


# Indices into the wall's discrete state. K_e(t) is state (updated every
# step) so that nothing the wall outputs depends on time: the sensor's fine
# 12 kHz clock then reuses the cached force instead of calling Python.
_S, _SD, _ACC, _VPREV, _K = range(5)


class CompliantWall(LeafSystem):
    """A unilateral mass-spring-damper wall, stepped at the plant's step.

    Input ports:
      tip_state (6): tip [x, y, phi, xdot, ydot, phidot] in world (m, rad, /s).
    Output ports:
      force_on_tip (3): [f_x, f_y, tau_z] the wall applies to the tip, world
        frame (N, N, N m); f_x = -f_normal.
      contact_force (1): true normal force f >= 0 (N).
      penetration (1): true surface displacement xe (m), 0 out of contact.
      true_impedance (3): [M_e, B_e, K_e(t)] (kg, N s/m, N/m), for scoring.
    State (discrete, 5): free-surface displacement and velocity, smoothed tip
      acceleration, previous tip x-velocity, K_e at this step.
    """

    def __init__(self, config: EnvironmentConfig, time_step: float):
        super().__init__()
        config.validate()
        self._config = config
        self._h = float(time_step)
        self._tip = self.DeclareVectorInputPort("tip_state", 6)
        self.DeclareDiscreteState([0.0, 0.0, 0.0, 0.0, config.stiffness])
        self.DeclarePeriodicDiscreteUpdateEvent(self._h, 0.0, self._update)
        # All outputs share one evaluation of the contact law, which reads the
        # input and the state only (not time).
        self._law_cache = self.DeclareCacheEntry(
            description="contact law",
            value_producer=_value_producer(self._calc_law, 9),
            prerequisites_of_calc={self._tip.ticket(), self.xd_ticket()})
        law = {self._law_cache.ticket()}
        self.DeclareVectorOutputPort("force_on_tip", 3, self._calc_force_on_tip, law)
        self.DeclareVectorOutputPort("contact_force", 1, self._calc_contact_force, law)
        self.DeclareVectorOutputPort("penetration", 1, self._calc_penetration, law)
        self.DeclareVectorOutputPort("true_impedance", 3, self._calc_true_impedance, law)

    @property
    def config(self) -> EnvironmentConfig:
        return self._config

    def stiffness_at(self, t):
        """True K_e (N/m) at time t, including the drift."""
        return self._config.stiffness * (1.0 + self._config.stiffness_drift_per_s * t)

    # The law: [fx, fy, tau_z, f_normal, xe, M, B, K, touching].
    def _calc_law(self, context, out: BasicVector):
        c = self._config
        x, _, _, vx, vy, _ = self._tip.Eval(context)
        state = context.get_discrete_state_vector().value()
        K = state[_K]
        xe = x - c.surface_x
        touching = xe > 0.0 and xe >= state[_S]
        fn = 0.0
        if touching:
            elastic = K * xe + c.damping * vx
            if c.law == "hunt_crossley":
                elastic *= (xe / c.hunt_crossley_reference_penetration) ** (
                    c.hunt_crossley_exponent - 1.0)
            fn = max(elastic + c.mass * state[_ACC], 0.0)
        ft = 0.0
        if fn > 0.0 and c.friction_coefficient > 0.0:
            ft = -c.friction_coefficient * fn * np.clip(vy / c.stiction_velocity, -1.0, 1.0)
        out.set_value([-fn, ft, 0.0, fn, xe if touching else 0.0,
                       c.mass, c.damping, K, 1.0 if fn > 0.0 else 0.0])

    def _law(self, context):
        return self._law_cache.Eval(context).value()

    def _calc_force_on_tip(self, context, output):
        output.SetFromVector(self._law(context)[0:3])

    def _calc_contact_force(self, context, output):
        output.SetAtIndex(0, self._law(context)[3])

    def _calc_penetration(self, context, output):
        output.SetAtIndex(0, self._law(context)[4])

    def _calc_true_impedance(self, context, output):
        output.SetFromVector(self._law(context)[5:8])

    def _free_step(self, s, sd, K):
        """One implicit-Euler step of M s'' + B s' + K s = 0."""
        c, h = self._config, self._h
        if c.mass > 0.0:
            det = 1.0 + h * c.damping / c.mass + h * h * K / c.mass
            s_next = ((1.0 + h * c.damping / c.mass) * s + h * sd) / det
            sd_next = (sd - h * K / c.mass * s) / det
            return s_next, sd_next
        s_next = s / (1.0 + h * K / c.damping) if c.damping > 0.0 else 0.0
        return s_next, (s_next - s) / h

    def _update(self, context, discrete_state):
        c, h = self._config, self._h
        x, _, _, vx, _, _ = self._tip.Eval(context)
        old = context.get_discrete_state_vector().value()
        law = self._law(context)
        K = law[7]
        if law[8] > 0.0:
            # In contact the surface is at the tip; it relaxes from there.
            s, sd = self._free_step(x - c.surface_x, vx, K)
        else:
            s, sd = self._free_step(old[_S], old[_SD], K)
        alpha = c.acceleration_smoothing
        acc = alpha * old[_ACC] + (1.0 - alpha) * (vx - old[_VPREV]) / h
        K_next = self.stiffness_at(context.get_time() + h)
        discrete_state.set_value([s, sd, acc, vx, K_next])


def _value_producer(calc, size):
    return ValueProducer(
        allocate=Value[BasicVector](BasicVector(size)).Clone,
        calc=lambda context, abstract: calc(context, abstract.get_mutable_value()))
