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
``acceleration_smoothing`` = alpha: the force over the step from t_n uses
(xe'(t_n) - xe'(t_(n-1))) / h. On a 6.8 kg point mass (the arm's effective
mass along x at q0) pushed with 20 N against 50 N s/m, the contact settles
for M_e up to 0.1 kg at 1 kN/m, 0.2 kg at 7 kN/m, 0.3 kg at 50 kN/m and
1-2 kg at 1 MN/m (alpha = 0.5, measured); with more, the surface's own
inertia carries it off the decelerating tip and the contact chatters. The
thesis calls M_e "very small" (0.01 kg here).

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
import pydrake.symbolic as sym
from pydrake.systems.framework import Diagram, DiagramBuilder
from pydrake.systems.primitives import Demultiplexer, Multiplexer

from drake_contact.arm_axis import StackedSymbolicSystem
from drake_contact.blocks import environment_configs
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
        if not (abs(self.surface_x) <= 1):
            bad("surface_x", self.surface_x, "must be in [-1, 1] m")
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
        if not np.isfinite(self.stiffness_drift_per_s):
            bad("stiffness_drift_per_s", self.stiffness_drift_per_s, "must be finite (1/s)")
        if duration is not None and 1 + self.stiffness_drift_per_s * duration <= 0:
            bad("stiffness_drift_per_s", self.stiffness_drift_per_s,
                f"must keep K_e > 0 over the run: > {-1 / duration:.4g} 1/s")


# The wall's discrete state, as it was one plant step ago (see
# contact_law_expressions): free-surface displacement and velocity, smoothed
# tip acceleration, previous tip x-velocity, and the time at which K_e(t)
# held (the step's start; 0 in the all-zero default state, so that it starts
# at K_e(0) = K_e).
STATE_NAMES = ("surface_displacement", "surface_velocity", "tip_acceleration_smoothed",
               "tip_velocity_previous", "stiffness_time")
#: The contact law's outputs, in the order of its output vector.
OUTPUT_SIZES = {"force_on_tip": 3, "contact_force": 1, "penetration": 1, "true_impedance": 3}


class CompliantWall(Diagram):
    """A unilateral mass-spring-damper wall, stepped at the plant's step.

    Input ports:
      tip_state (6): tip [x, y, phi, xdot, ydot, phidot] in world (m, rad, /s).
      stiffness_scale (1, only with ``stiffness_scale_input``): factor on
        K_e(t), for injected faults (drake_contact.faults).
    Output ports:
      force_on_tip (3): [f_x, f_y, tau_z] the wall applies to the tip, world
        frame (N, N, N m); f_x = -f_normal.
      contact_force (1): true normal force f >= 0 (N).
      penetration (1): true surface displacement xe (m), 0 out of contact.
      true_impedance (3): [M_e, B_e, K_e(t)] (kg, N s/m, N/m), for scoring.
    State (discrete, 5, see :data:`STATE_NAMES`): free-surface displacement
      and velocity, smoothed tip acceleration, previous tip x-velocity, and
      the time K_e(t) is taken at over this step.

    No Python runs while it simulates: the law and the state update are
    symbolic expressions that a ``SymbolicVectorSystem`` (``contact_law``,
    holding the state) evaluates in C++, and a ``Demultiplexer``
    (``outputs``) splits its output vector into the four ports. With a
    list of N configs, the walls of N environments on the arm axis: every
    port N times its size, environment i's values at ``[k i, k (i + 1))``,
    each wall's expressions evaluated as alone (``config`` is the first's). The
    expressions perform the floating-point operations of the former Python
    implementation in its order, so results are bit-identical to it (see
    :func:`contact_law_expressions`).
    """

    def __init__(self, config, time_step: float, *, stiffness_scale_input=False):
        super().__init__()
        configs = environment_configs(config, EnvironmentConfig, "environment")
        for c in configs:
            c.validate()
        count = len(configs)
        self._config = configs[0]
        self.configs = configs
        self._h = float(time_step)
        pieces = []
        for c in configs:
            t, state, tip, dynamics, outputs = contact_law_expressions(
                c, self._h, stiffness_scale_input=stiffness_scale_input)
            pieces.append({"time": t, "state": state, "input": tip, "dynamics": dynamics,
                           "output": outputs})
        inputs = [6, 1] if stiffness_scale_input else [6]
        builder = DiagramBuilder()
        law = builder.AddNamedSystem("contact_law", StackedSymbolicSystem(
            pieces, input_sizes=inputs, output_sizes=list(OUTPUT_SIZES.values()),
            time_period=self._h))
        split = builder.AddNamedSystem("outputs", Demultiplexer(
            [size * count for size in OUTPUT_SIZES.values()]))
        builder.Connect(law.get_output_port(), split.get_input_port())
        if stiffness_scale_input:
            mux = builder.AddNamedSystem("inputs", Multiplexer([6 * count, count]))
            builder.Connect(mux.get_output_port(), law.get_input_port())
            builder.ExportInput(mux.get_input_port(0), "tip_state")
            builder.ExportInput(mux.get_input_port(1), "stiffness_scale")
        else:
            builder.ExportInput(law.get_input_port(), "tip_state")
        for i, name in enumerate(OUTPUT_SIZES):
            builder.ExportOutput(split.get_output_port(i), name)
        builder.BuildInto(self)

    @property
    def config(self) -> EnvironmentConfig:
        return self._config

    def stiffness_at(self, t):
        """True K_e (N/m) at time t, including the drift."""
        return self._config.stiffness * (1.0 + self._config.stiffness_drift_per_s * t)


def _held(e):
    """``e``, evaluated to the same double, as an operand that Drake's
    simplifier will not merge into an enclosing sum or product.

    Drake flattens sums and products (``(a + b) + c`` becomes one sum
    whose terms it adds in its own order, ``c1 * (c2 * x)`` becomes
    ``(c1 * c2) * x``), which would round differently from the Python
    law; ``max(e, -inf)`` is ``e`` exactly (NaN included) and is a leaf to
    the flattening."""
    return sym.max(e, -np.inf)


def contact_law_expressions(config: EnvironmentConfig, h: float, *,
                            stiffness_scale_input=False):
    """The wall as symbolic expressions: returns (t, state, tip, dynamics,
    outputs), the time, state (5) and input (6, tip_state; 7 with
    ``stiffness_scale_input``: then K_e(t) is multiplied by the 7th, for
    injected faults) variables, the state's update and the output vector
    [force_on_tip (3), contact_force, penetration, true_impedance (3)].

    Timing: like every discrete system of the station, the wall reads the
    plant's state at t_n in the same event as the plant's step from t_n. Its
    state S_(n-1) is the wall one step ago; the update stores S_n =
    dynamics(t_n, S_(n-1), tip(t_n)) and the output is the contact law at
    (S_n, tip(t_n)), S_n computed there by the same expressions. So the
    force over the step from t_n is the law of the surface advanced to t_n
    with the tip at t_n: a wall stepped right after the plant.

    Each expression does the IEEE operations of the former Python law in
    its order: constants are grouped into Python floats as the Python code
    grouped them, two-operand sums and products only (commutative, hence
    exact in any order), and :func:`_held` around every rounded
    intermediate that Drake would otherwise flatten."""
    c = config
    t = sym.Variable("t")
    state = np.array([sym.Variable(name) for name in STATE_NAMES])
    tip = np.array([sym.Variable(name) for name in (
        "x", "y", "phi", "xdot", "ydot", "phidot")])
    s, sd, acc, v_prev, t_k = state
    x, _, _, vx, vy, _ = tip

    # K_e(t) = K_e (1 + drift t), t the time stored by the last update.
    if c.stiffness_drift_per_s == 0.0:
        K = float(c.stiffness)
    else:
        K = _held(c.stiffness * (1.0 + c.stiffness_drift_per_s * t_k))
    if stiffness_scale_input:
        scale = sym.Variable("stiffness_scale")
        tip = np.append(tip, scale)
        K = _held(K * scale)
    xe = x - c.surface_x
    touching = sym.logical_and(xe > 0.0, xe >= s)
    elastic = _held(_held(K * xe) + c.damping * vx)
    if c.law == "hunt_crossley":
        elastic = _held(elastic * sym.pow(xe / c.hunt_crossley_reference_penetration,
                                          c.hunt_crossley_exponent - 1.0))
    # Python's max(a, 0.0) and std::max(a, 0.0) agree (a when not a < 0).
    fn = sym.if_then_else(touching, sym.max(elastic + c.mass * acc, 0.0), 0.0)
    ft = 0.0
    if c.friction_coefficient > 0.0:
        # np.clip(v, -1, 1) = min(max(v, -1), 1).
        slip = sym.min(sym.max(vy / c.stiction_velocity, -1.0), 1.0)
        ft = sym.if_then_else(fn > 0.0, _held(-c.friction_coefficient * fn) * slip, 0.0)
    outputs = [-fn, ft, 0.0, fn, sym.if_then_else(touching, xe, 0.0),
               c.mass, c.damping, K]

    # In contact (f > 0) the surface is at the tip and relaxes from there;
    # otherwise it relaxes from its own state: one implicit-Euler step of
    # M s'' + B s' + K s = 0. (Each branch whole, so that evaluating the
    # update evaluates the contact law once per state element.)
    def free_step(s, sd):
        if c.mass > 0.0:
            a1 = 1.0 + h * c.damping / c.mass
            det = a1 + _mul(h * h, K) / c.mass
            return (a1 * s + h * sd) / det, (sd - _mul(h, K) / c.mass * s) / det
        s_next = s / (1.0 + _mul(h, K) / c.damping) if c.damping > 0.0 else 0.0
        return s_next, (s_next - s) / h

    contact = fn > 0.0
    pushed, free = free_step(xe, vx), free_step(s, sd)
    s_next, sd_next = (sym.if_then_else(contact, a, b) for a, b in zip(pushed, free))
    alpha = c.acceleration_smoothing
    acc_next = alpha * acc + (1.0 - alpha) * (vx - v_prev) / h
    dynamics = _expressions([s_next, sd_next, acc_next, vx, t])
    # The state holds the wall as it was one step ago; the output advances it
    # to t_n from the tip state at t_n (the same expressions as the update).
    advanced = {variable: value for variable, value in zip(state, dynamics)}
    outputs = np.array([value.Substitute(advanced) for value in _expressions(outputs)])
    return t, state, tip, dynamics, outputs


def _expressions(values):
    return np.array([e if isinstance(e, sym.Expression) else sym.Expression(e)
                     for e in values], dtype=object)


def _mul(constant: float, K):
    """constant * K, folded in Python when K is a constant."""
    return constant * K if isinstance(K, float) else _held(constant * K)
