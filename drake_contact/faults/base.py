"""Injected faults: a sensor, an encoder, the environment or a drive that
misbehaves for a while, scripted in the scenario's ``faults:`` list.

Each fault is its own small system on the signal it corrupts, inserted by
:func:`drake_contact.diagram.MakeContactDiagram` only when the scenario lists
faults (a scenario without faults has no fault systems). The signals
(:data:`SIGNALS`):

    force       the DSP's reading after ADC and tare, before the 120 Hz
                filter (N)
    encoders    the counted joint angles into the estimator (rad)
    surface     the tip state the wall sees (a shift of the surface along x)
    stiffness   the wall's stiffness_scale input (a factor on K_e)
    drive       the saturated torque into the motors (N m)

Every fault system is a Drake ``SymbolicVectorSystem`` (no Python runs per
step): its output is the corrupted signal and a 0/1 ``active`` flag, the
station logs the flags as ``fault_active`` (one column per fault). A fault
starts at ``start_s`` after t = 0, or after the first contact
(``start_from: contact``): the first 1 ms sample at which the true normal
force is above 5 N (the thesis's switch level), read by the
:class:`FaultClock` from the wall, so a
scripted fault hits every controller at the same physical moment whatever
its own contact detection does. The spike train draws from a
``RandomSource`` named for the fault, seeded with the rest of the
station's noise (:func:`drake_contact.diagram.SeedNoise`): same scenario and
seed, same spikes.

A kind of fault is one :class:`FaultKind` subclass registered with
:func:`register_fault_kind` (the built-in ones are in
:mod:`drake_contact.faults.builtin`): its signal, what ``magnitude`` means
and its allowed range, the check of that range, its expressions, and the
fault study's case of it. Scenario validation, the station's wiring, the
``fault_active`` log and the fault study follow from the registration.
"""

import dataclasses as dc
import math

import numpy as np
from pydrake.symbolic import Variable, if_then_else, logical_and
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import (
    Demultiplexer, Multiplexer, RandomSource, SymbolicVectorSystem)
from pydrake.common import RandomDistribution

from drake_contact.blocks import AddSubdiagram
from drake_contact.constants import CONTACT_THRESHOLD_N
from drake_contact.errors import ScenarioError
from drake_contact.plant.arm import CONTROL_PERIOD, TIME_TOLERANCE_S

#: The signals a fault can corrupt, where the station puts them: the DSP's
#: force reading, the counted joint angles, the tip state the wall sees,
#: the wall's K_e scale, the saturated torque into the motors.
SIGNALS = ("force", "encoders", "surface", "stiffness", "drive")

START_FROM = ("time", "contact")


@dc.dataclass(frozen=True)
class StudyCase:
    """The fault study's case of a kind: its name in the study's tables,
    what it does in words, and the fault's fields but its kind and start."""

    name: str
    description: str
    fields: dict


class FaultKind:
    """One kind of fault. A subclass sets the class attributes and
    :meth:`corrupt`, and :func:`register_fault_kind` makes it a kind that
    scenarios can name (``faults: [{kind: <name>, ...}]``).

    ``name``: the kind's name in scenarios. ``signal``: one of
    :data:`SIGNALS`. ``allowed``: what ``magnitude`` means and its allowed
    range, in the words of the error a bad one gets. ``spreads``: the kind
    spreads over its duration, which must then be finite. ``study_case``:
    the fault study's :class:`StudyCase`, or None. A law that needs
    randomness reads two uniform draws per sample from
    :meth:`FaultLaw.noise`.

    A kind in another package registers in every process that loads
    scenarios (the Dask workers of the fault study and the sweeps too) when
    its module is named under the entry-point group
    :data:`FAULT_KIND_GROUP`."""

    name: str = ""
    signal: str = ""
    allowed: str = ""
    spreads: bool = False
    study_case: StudyCase | None = None

    def magnitude_ok(self, m: float) -> bool:
        """Whether ``m`` is in the allowed range."""
        raise NotImplementedError

    def corrupt(self, law: "FaultLaw"):
        """Sets ``law.y`` (the corrupted signal, expressions of ``law.u``,
        ``law.on``, ``law.t``, ``law.t0``, ``law.fault``), and any state
        with its update in ``law.state`` and ``law.dynamics``."""
        raise NotImplementedError


#: The registered kinds by name, in registration order.
FAULT_KINDS: dict[str, FaultKind] = {}

#: The entry-point group whose modules are imported, registering their
#: kinds, when drake_contact.faults is.
FAULT_KIND_GROUP = "drake_contact.fault_kinds"

#: The fault study's null case, which no kind's case may be named.
NULL_CASE = "none"


def register_fault_kind(cls):
    """Registers the FaultKind subclass ``cls`` (a class decorator). The
    same class registered again (a module or notebook cell run twice)
    replaces itself; another class may not take a registered name or study
    case name."""
    kind = cls()
    if not kind.name or kind.signal not in SIGNALS:
        raise ValueError(f"fault kind {cls.__name__}: set name and a signal of {SIGNALS}")
    key = (cls.__module__, cls.__qualname__)
    old = FAULT_KINDS.get(kind.name)
    if old is not None and (type(old).__module__, type(old).__qualname__) != key:
        raise ValueError(f"fault kind '{kind.name}' is already registered by "
                         f"{type(old).__module__}.{type(old).__qualname__}")
    if kind.study_case is not None:
        taken = {k.study_case.name for n, k in FAULT_KINDS.items()
                 if k.study_case is not None and n != kind.name}
        if kind.study_case.name == NULL_CASE or kind.study_case.name in taken:
            raise ValueError(f"fault kind '{kind.name}': study case name "
                             f"'{kind.study_case.name}' is taken")
    FAULT_KINDS[kind.name] = kind
    return cls


def unregister_fault_kind(name):
    """Removes a registered kind (for tests that register a toy one)."""
    del FAULT_KINDS[name]


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
    # Its size; units and meaning depend on the kind (its class docstring).
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
        kind = FAULT_KINDS[self.kind]
        if not kind.magnitude_ok(self.magnitude):
            bad("magnitude", self.magnitude, f"{self.kind} takes {kind.allowed}")
        if kind.spreads and not math.isfinite(self.duration_s):
            bad("duration_s", self.duration_s, f"{self.kind} spreads over its duration: "
                "must be finite")

    @property
    def signal(self) -> str:
        """The signal it corrupts: one of :data:`SIGNALS`."""
        return FAULT_KINDS[self.kind].signal


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


class FaultLaw:
    """A fault's expressions while its kind writes them: the time ``t``, the
    signal ``u`` (a list of Variables), ``on`` (the fault is active), its
    start ``t0``, the ``fault`` (its FaultConfig), and the kind's results:
    ``y`` (starts as ``u``), ``state`` and ``dynamics`` (start empty).
    ``lsb``: an encoder fault's joint's angle per count (rad)."""

    def __init__(self, fault: FaultConfig, size: int, counts_per_revolution=None):
        self.fault = fault
        self.t = Variable("t")
        self.u = [Variable(f"u_{i}") for i in range(size)]
        self.contact_time = Variable("contact_time")
        self.inputs = self.u + [self.contact_time]
        self.on, self.t0 = _window(fault, self.t, self.contact_time)
        self.y = list(self.u)
        self.state, self.dynamics = [], []
        self.lsb = (None if counts_per_revolution is None
                    else 2 * np.pi / counts_per_revolution[fault.joint])
        self.noisy = False

    def noise(self):
        """The two uniform draws of this sample, as inputs: the fault's
        system then gets a RandomSource of its own."""
        draw, sign = Variable("draw"), Variable("sign")
        self.inputs += [draw, sign]
        self.noisy = True
        return draw, sign


def _fault_law(fault: FaultConfig, size: int, counts_per_revolution=None):
    """The fault as expressions: returns (kwargs for SymbolicVectorSystem,
    needs_noise). Input: [signal (size), contact_time, (noise 2)]; output:
    [corrupted signal (size), active]."""
    kind = FAULT_KINDS[fault.kind]
    law = FaultLaw(fault, size, counts_per_revolution)
    kind.corrupt(law)
    active = if_then_else(law.on, 1.0, 0.0)
    kwargs = dict(time=law.t, input=law.inputs, output=law.y + [active])
    if law.state:
        kwargs.update(state=law.state, dynamics=law.dynamics, time_period=CONTROL_PERIOD)
    return kwargs, law.noisy


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


def AddFaultChain(builder, faults, signal: str, size, *, prefix="fault",
                  counts_per_revolution=None) -> dict:
    """Adds the ``faults`` on ``signal`` in series (in the scenario's order;
    fault i named ``{prefix}_{i}_{kind}``); returns the chain's ports by
    name: ``signal`` (the first fault's input), ``contact_time`` (every
    fault's clock input, a list fed together from the FaultClock),
    ``signal_faulty`` (the last fault's output) and ``fault_active_<i>``
    (fault i's ``active``). {} when no fault is on ``signal``."""
    ports = {}
    for i, fault in enumerate(faults):
        if fault.signal != signal:
            continue
        system = AddFault(builder, fault, size, f"{prefix}_{i}_{fault.kind}",
                          counts_per_revolution=counts_per_revolution)
        if ports:
            builder.Connect(ports["signal_faulty"], system.GetInputPort("signal"))
        else:
            ports = {"signal": system.GetInputPort("signal"), "contact_time": []}
        ports["contact_time"].append(system.GetInputPort("contact_time"))
        ports["signal_faulty"] = system.GetOutputPort("signal_faulty")
        ports[f"fault_active_{i}"] = system.GetOutputPort("active")
    return ports


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
