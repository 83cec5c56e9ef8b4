"""Injected faults: a sensor, an encoder, the environment or a drive that
misbehaves for a while, scripted in the scenario's ``faults:`` list.

Each fault is its own small system on the signal it corrupts, inserted by
:func:`drake_contact.diagram.MakeContactDiagram` only when the scenario lists
faults (a scenario without them builds the same diagram as before):

    force sensor   the DSP's reading after ADC and tare, before the 120 Hz
                   filter (N): force_dropout_zero, force_dropout_hold,
                   force_spikes, force_bias, force_gain, force_saturation
    encoders       the counted joint angles into the estimator (rad):
                   encoder_missed_counts, encoder_frozen
    environment    the wall: surface_retreat and surface_motion shift the
                   surface along x (the tip state the wall sees), and
                   stiffness_step and stiffness_ramp scale K_e (the wall's
                   stiffness_scale input)
    drive          the saturated torque into the motors (N m):
                   torque_limit, motor_scale

Every fault system is a Drake ``SymbolicVectorSystem`` (no Python runs per
step): its output is the corrupted signal and a 0/1 ``active`` flag, the
station logs the flags as ``fault_active`` (one column per fault). A fault
starts at ``start_s`` after t = 0, or after the first contact
(``start_from: contact``): the first 1 ms sample at which the true normal
force is above 5 N (the thesis's switch level), read by the :class:`FaultClock` from the wall, so a
scripted fault hits every controller at the same physical moment whatever
its own contact detection does. The spike train draws from a
``RandomSource`` named for the fault, seeded with the rest of the
station's noise (:func:`drake_contact.diagram.SeedNoise`): same scenario and
seed, same spikes.

What ``magnitude`` means, per kind (:data:`FAULT_KINDS`):

    force_dropout_zero     (unused, 0) the reading is 0 N
    force_dropout_hold     (unused, 0) the reading stays at its last value
    force_spikes           spike height (N), sign random, at ``rate_hz`` on average
    force_bias             offset added to the reading (N)
    force_gain             factor on the reading (a gain change)
    force_saturation       the ADC clips the reading to +-magnitude (N)
    encoder_missed_counts  counts the joint's encoder misses, evenly over the
                           fault (the reading stays off by them afterwards)
    encoder_frozen         (unused, 0) the joint's reading stays at its last value
    surface_retreat        the surface moves away from the arm by this (m), back at the end
    surface_motion         the surface moves along +x at this speed (m/s) during the fault
    stiffness_step         factor on K_e during the fault
    stiffness_ramp         K_e ramps to this factor over the fault and stays
    torque_limit           the joint's torque limit drops to this (N m)
    motor_scale            factor on the joint's motor torque
"""

import dataclasses as dc
import math

import numpy as np
from pydrake.symbolic import Variable, floor, if_then_else, logical_and
from pydrake.symbolic import max as sym_max, min as sym_min
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import (
    Demultiplexer, Multiplexer, RandomSource, SymbolicVectorSystem)
from pydrake.common import RandomDistribution

from drake_contact.blocks import AddSubdiagram
from drake_contact.control.hybrid_controller import CONTACT_THRESHOLD_N
from drake_contact.errors import ScenarioError
from drake_contact.plant.arm import CONTROL_PERIOD, TIME_TOLERANCE_S

#: Each kind: (signal it corrupts, what magnitude means and its allowed range).
FAULT_KINDS = {
    "force_dropout_zero": ("force", "unused: 0"),
    "force_dropout_hold": ("force", "unused: 0"),
    "force_spikes": ("force", "spike height in N, finite and != 0"),
    "force_bias": ("force", "offset in N, finite"),
    "force_gain": ("force", "factor in [0, 100]"),
    "force_saturation": ("force", "clip level in N, > 0"),
    "encoder_missed_counts": ("encoders", "counts missed, finite, |.| <= 1e6"),
    "encoder_frozen": ("encoders", "unused: 0"),
    "surface_retreat": ("surface", "displacement away from the arm in m, |.| <= 0.1"),
    "surface_motion": ("surface", "speed along +x in m/s, |.| <= 1"),
    "stiffness_step": ("stiffness", "factor on K_e in (0, 100]"),
    "stiffness_ramp": ("stiffness", "final factor on K_e in (0, 100]"),
    "torque_limit": ("drive", "torque limit in N m, >= 0"),
    "motor_scale": ("drive", "factor on the motor torque in [-10, 10]"),
}

START_FROM = ("time", "contact")


@dc.dataclass
class FaultConfig:
    """One scripted fault."""

    # Which fault (see FAULT_KINDS).
    kind: str = "force_dropout_zero"
    # When it starts (s): after t = 0 (start_from: time) or after the first
    # 1 ms sample with a true contact force > 5 N (start_from: contact).
    start_s: float = 0.0
    start_from: str = "time"
    # How long it lasts (s); .inf for the rest of the run.
    duration_s: float = 0.05
    # Its size; units and meaning depend on the kind (module docstring).
    magnitude: float = 0.0
    # The joint (0, 1, 2) of an encoder or drive fault.
    joint: int = 0
    # force_spikes: mean number of spikes per second while active (Hz).
    rate_hz: float = 50.0

    def validate(self, prefix="faults[0]"):
        def bad(field, value, allowed):
            raise ScenarioError(f"{prefix}.{field} = {value} is out of range: {allowed}")
        if self.kind not in FAULT_KINDS:
            raise ScenarioError(f"{prefix}.kind = '{self.kind}' is unknown: choose one of "
                                f"{', '.join(FAULT_KINDS)}")
        if not (math.isfinite(self.start_s) and self.start_s >= 0):
            bad("start_s", self.start_s, "must be >= 0 s")
        if self.start_from not in START_FROM:
            raise ScenarioError(f"{prefix}.start_from = '{self.start_from}' is unknown: "
                                f"choose one of {', '.join(START_FROM)}")
        if not (self.duration_s >= CONTROL_PERIOD):  # NaN fails too; .inf passes
            bad("duration_s", self.duration_s, "must be >= 0.001 s (.inf: to the end)")
        if self.joint not in (0, 1, 2):
            bad("joint", self.joint, "must be 0, 1 or 2")
        if not (math.isfinite(self.rate_hz) and 0 < self.rate_hz <= 1000):
            bad("rate_hz", self.rate_hz, "must be in (0, 1000] Hz")
        m = self.magnitude
        allowed = FAULT_KINDS[self.kind][1]
        ok = {
            "force_dropout_zero": m == 0, "force_dropout_hold": m == 0, "encoder_frozen": m == 0,
            "force_spikes": math.isfinite(m) and m != 0,
            "force_bias": math.isfinite(m),
            "force_gain": 0 <= m <= 100,
            "force_saturation": math.isfinite(m) and m > 0,
            "encoder_missed_counts": math.isfinite(m) and abs(m) <= 1e6,
            "surface_retreat": abs(m) <= 0.1,
            "surface_motion": abs(m) <= 1,
            "stiffness_step": 0 < m <= 100, "stiffness_ramp": 0 < m <= 100,
            "torque_limit": math.isfinite(m) and m >= 0,
            "motor_scale": -10 <= m <= 10,
        }[self.kind]
        if not ok:
            bad("magnitude", m, f"{self.kind} takes {allowed}")
        if self.kind in ("encoder_missed_counts", "stiffness_ramp") \
                and not math.isfinite(self.duration_s):
            bad("duration_s", self.duration_s, f"{self.kind} spreads over its duration: "
                "must be finite")

    @property
    def signal(self) -> str:
        """The signal it corrupts: force, encoders, surface, stiffness or drive."""
        return FAULT_KINDS[self.kind][0]


def validate_faults(faults):
    """Validates each fault, named by its index in the list."""
    for i, fault in enumerate(faults):
        fault.validate(f"faults[{i}]")


def _window(fault: FaultConfig, t, contact_time):
    """(active, t0): the 0/1 expression 'the fault is on at t' and its start."""
    if fault.start_from == "time":
        t0 = fault.start_s
    else:
        t0 = if_then_else(contact_time >= 0.0, contact_time + fault.start_s, np.inf)
    on = t >= t0 - TIME_TOLERANCE_S
    if math.isfinite(fault.duration_s):
        on = logical_and(on, t < t0 + fault.duration_s - TIME_TOLERANCE_S)
    return on, t0


def _fault_law(fault: FaultConfig, size: int, counts_per_revolution=None):
    """The fault as expressions: returns (kwargs for SymbolicVectorSystem,
    needs_noise). Input: [signal (size), contact_time, (noise 2)]; output:
    [corrupted signal (size), active]."""
    t = Variable("t")
    u = [Variable(f"u_{i}") for i in range(size)]
    tc = Variable("contact_time")
    inputs = u + [tc]
    on, t0 = _window(fault, t, tc)
    active = if_then_else(on, 1.0, 0.0)
    m = fault.magnitude
    kind = fault.kind
    state, dynamics = [], []
    y = list(u)
    j = fault.joint
    if kind == "force_dropout_zero":
        y = [if_then_else(on, 0.0, v) for v in u]
    elif kind in ("force_dropout_hold", "encoder_frozen"):
        # held: the last value before the fault, kept while it is on.
        idx = range(size) if kind == "force_dropout_hold" else [j]
        held = {i: Variable(f"held_{i}") for i in idx}
        state = list(held.values())
        dynamics = [if_then_else(on, held[i], u[i]) for i in idx]
        for i in idx:
            y[i] = if_then_else(on, held[i], u[i])
    elif kind == "force_spikes":
        draw, sign = Variable("draw"), Variable("sign")
        inputs += [draw, sign]
        p = fault.rate_hz * CONTROL_PERIOD
        spike = if_then_else(logical_and(on, draw < p),
                             if_then_else(sign < 0.5, -m, m), 0.0)
        y = [v + spike for v in u]
    elif kind == "force_bias":
        y = [v + if_then_else(on, m, 0.0) for v in u]
    elif kind == "force_gain":
        y = [if_then_else(on, m * v, v) for v in u]
    elif kind == "force_saturation":
        y = [if_then_else(on, sym_min(sym_max(v, -m), m), v) for v in u]
    elif kind == "encoder_missed_counts":
        lsb = 2 * np.pi / counts_per_revolution[j]
        done = sym_min(sym_max((t - t0) / fault.duration_s, 0.0), 1.0)
        # Counts missed so far; 0 before the start (t0 may be inf).
        missed = if_then_else(t >= t0 - TIME_TOLERANCE_S, floor(m * done + 0.5), 0.0)
        y[j] = u[j] - missed * lsb
    elif kind == "surface_retreat":
        # The wall sees the tip moved back by the retreat: x - shift.
        y[0] = u[0] - if_then_else(on, m, 0.0)
    elif kind == "surface_motion":
        travelled = if_then_else(t >= t0 - TIME_TOLERANCE_S, sym_min(t - t0, fault.duration_s), 0.0)
        y[0] = u[0] - m * sym_max(travelled, 0.0)
    elif kind == "stiffness_step":
        y = [if_then_else(on, m * u[0], u[0])]
    elif kind == "stiffness_ramp":
        done = if_then_else(t >= t0 - TIME_TOLERANCE_S,
                            sym_min(sym_max((t - t0) / fault.duration_s, 0.0), 1.0), 0.0)
        y = [u[0] * (1.0 + (m - 1.0) * done)]
    elif kind == "torque_limit":
        y[j] = if_then_else(on, sym_min(sym_max(u[j], -m), m), u[j])
    elif kind == "motor_scale":
        y[j] = if_then_else(on, m * u[j], u[j])
    kwargs = dict(time=t, input=inputs, output=y + [active])
    if state:
        kwargs.update(state=state, dynamics=dynamics, time_period=CONTROL_PERIOD)
    return kwargs, kind == "force_spikes"


def AddFault(builder: DiagramBuilder, fault: FaultConfig, size: int, name: str, *,
             counts_per_revolution=None):
    """Adds one fault on a ``size``-vector signal as the sub-diagram ``name``.

    Ports: ``signal`` (input, size), ``contact_time`` (input, 1, from the
    :class:`FaultClock`), ``signal_faulty`` (output, size) and ``active``
    (output, 1: 1 while the fault is on). A spike train adds the
    RandomSource ``{name}_draws`` (uniform, two per 1 ms sample)."""
    fault.validate(name)
    kwargs, needs_noise = _fault_law(fault, size, counts_per_revolution)

    def build(inner):
        law = inner.AddNamedSystem(f"{name}_law", SymbolicVectorSystem(**kwargs))
        split = inner.AddNamedSystem(f"{name}_outputs", Demultiplexer([size, 1]))
        inner.Connect(law.get_output_port(), split.get_input_port())
        sizes = [size, 1] + ([2] if needs_noise else [])
        mux = inner.AddNamedSystem(f"{name}_inputs", Multiplexer(sizes))
        inner.Connect(mux.get_output_port(), law.get_input_port())
        if needs_noise:
            draws = inner.AddNamedSystem(f"{name}_draws", RandomSource(
                RandomDistribution.kUniform, 2, CONTROL_PERIOD))
            inner.Connect(draws.get_output_port(), mux.get_input_port(2))
        return {"signal": mux.get_input_port(0), "contact_time": mux.get_input_port(1),
                "signal_faulty": split.get_output_port(0), "active": split.get_output_port(1)}
    return AddSubdiagram(builder, name, build)


#: The true force (N) that starts a fault's contact clock: the thesis's
#: contact switch level, read from the truth.
CONTACT_CLOCK_FORCE_N = CONTACT_THRESHOLD_N


def FaultClock(threshold_n=CONTACT_CLOCK_FORCE_N):
    """The time of the first contact, for faults that start from it.

    A ``SymbolicVectorSystem`` sampled every 1 ms. Input ``contact_force``
    (1, the wall's true normal force, N); output ``contact_time`` (1): the
    first sample time t_n with a force > ``threshold_n`` (s), from the next
    sample on (a state, as the wall's force feeds back through the faults
    it starts), -1 before it.
    The thesis's controllers switch to contact at 5 N of *measured* force,
    so this is within a few ms of their switch, but the same for every
    controller. Its state holds
    that time + 1 (0 = not yet), so the default zero state means 'no
    contact'."""
    t, f, c = Variable("t"), Variable("f"), Variable("c")
    system = SymbolicVectorSystem(
        time=t, state=[c], input=[f],
        dynamics=[if_then_else(logical_and(c == 0.0, f > threshold_n), t + 1.0, c)],
        output=[if_then_else(c > 0.0, c - 1.0, -1.0)], time_period=CONTROL_PERIOD)
    return system


def ChainFaults(builder, faults, signal: str, source, size, clock, *, prefix="fault",
                counts_per_revolution=None):
    """Puts the ``faults`` on ``signal`` in series after the output port
    ``source`` (in the scenario's order); returns (the last output port,
    {fault index: its ``active`` port}). ``clock`` is the FaultClock's
    output; fault i is named ``{prefix}_{i}_{kind}``."""
    active = {}
    port = source
    for i, fault in enumerate(faults):
        if fault.signal != signal:
            continue
        system = AddFault(builder, fault, size, f"{prefix}_{i}_{fault.kind}",
                          counts_per_revolution=counts_per_revolution)
        builder.Connect(port, system.GetInputPort("signal"))
        builder.Connect(clock, system.GetInputPort("contact_time"))
        port = system.GetOutputPort("signal_faulty")
        active[i] = system.GetOutputPort("active")
    return port, active
