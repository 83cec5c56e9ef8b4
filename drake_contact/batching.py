"""The check every batched system passes: N environments in one system give,
bit for bit, what N systems alone give.

A system that serves an ensemble (a plug-in that declares ``ensemble``, a
role over the arm axis) has environment-major ports: environment i's k
values at ``[k i, k (i + 1))`` of a port whose one-environment size is k.
:func:`batched_mismatches` drives the batched system and N one-environment
systems on the same inputs, sample by sample, each in a Simulator of its
own, and compares every vector output of every environment after every
sample by its bits (so +0 and -0 differ, and NaN equals only the same
NaN). :func:`assert_batched_equals_alone` raises on the first mismatch,
naming the port, the environment, the element and the time; a plug-in's
author runs it on their own law in a test (docs/extending.md).
"""

import dataclasses as dc

import numpy as np
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import PortDataType


@dc.dataclass(frozen=True)
class Mismatch:
    """One output element that differs between a batched system and the
    same environment's system alone."""

    # Output port name, environment index, element within the environment's
    # part, simulated time (s), and the two values.
    port: str
    environment: int
    element: int
    time_s: float
    batched: float
    alone: float


def _bits(values):
    return np.ascontiguousarray(values, dtype=float).view(np.uint64)


def _simulator(system):
    simulator = Simulator(system)
    return simulator, simulator.get_mutable_context()


def batched_mismatches(batched, alone, inputs, period_s, *, limit=10) -> list:
    """The first ``limit`` output elements in which ``batched`` (a system
    serving N environments) differs from ``alone`` (N one-environment
    systems, in order), driven alike: ``inputs[k][i]`` is environment i's
    {input port name: value} over sample k, held from ``k period_s``, and
    the outputs are compared at ``(k + 1) period_s``, after the sample's
    updates. Every vector output of the batched system is compared, each
    environment's part against its own system's port of that name."""
    count = len(alone)
    many, many_context = _simulator(batched)
    ones = [_simulator(system) for system in alone]
    outputs = [batched.get_output_port(p).get_name() for p in range(batched.num_output_ports())
               if batched.get_output_port(p).get_data_type() == PortDataType.kVectorValued]
    found = []
    for k, sample in enumerate(inputs):
        if len(sample) != count:
            raise ValueError(f"inputs[{k}] has {len(sample)} environments, not {count}")
        for name in sample[0]:
            batched.GetInputPort(name).FixValue(
                many_context, np.concatenate([np.atleast_1d(np.asarray(env[name], dtype=float))
                                              for env in sample]))
        for (simulator, context), system, env in zip(ones, alone, sample):
            for name, value in env.items():
                system.GetInputPort(name).FixValue(context, np.atleast_1d(value))
        t = (k + 1) * period_s
        many.AdvanceTo(t)
        for simulator, _ in ones:
            simulator.AdvanceTo(t)
        for name in outputs:
            whole = batched.GetOutputPort(name).Eval(many_context)
            for i, (system, (_, context)) in enumerate(zip(alone, ones)):
                mine = system.GetOutputPort(name).Eval(context)
                size = len(mine)
                part = whole[size * i:size * (i + 1)]
                for e in np.flatnonzero(_bits(part) != _bits(mine)):
                    found.append(Mismatch(name, i, int(e), t, float(part[e]), float(mine[e])))
                    if len(found) >= limit:
                        return found
    return found


def assert_batched_equals_alone(batched, alone, inputs, period_s):
    """Raises AssertionError, naming the first mismatch, unless ``batched``
    gives each environment's outputs bit for bit as its system alone
    (:func:`batched_mismatches`)."""
    found = batched_mismatches(batched, alone, inputs, period_s, limit=1)
    if found:
        m = found[0]
        raise AssertionError(
            f"output '{m.port}' of environment {m.environment}, element {m.element}, at "
            f"t = {m.time_s:.6g} s: {m.batched!r} batched, {m.alone!r} alone")
