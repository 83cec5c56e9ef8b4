"""The library's batched-equals-alone check (drake_contact.batching): it
passes a batched law that is exact, and names the port, environment,
element and time of the first bit that differs, +0 against -0 included."""

import numpy as np
import pytest
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import Adder, ConstantVectorSource, PassThrough

from drake_contact.batching import assert_batched_equals_alone, batched_mismatches
from drake_contact.identification.rls_identifier import RlsConfig, RlsIdentifier
from drake_contact.plant.arm import CONTROL_PERIOD


# [docs: batched check]
def _wall_signals(count, samples=200, seed=0):
    """Per sample, per environment: an RLS identifier's inputs on a wall of
    its own stiffness, in contact from sample 20 on."""
    rng = np.random.default_rng(seed)
    signals = []
    for k in range(samples):
        t = k * CONTROL_PERIOD
        sample = []
        for i in range(count):
            x = 0.45 + 1e-3 * (1 - np.exp(-t / 0.03)) + rng.normal(0, 1e-6)
            force = 5.0 + (7000.0 + 3000.0 * i) * (x - 0.45) + rng.normal(0, 0.3)
            contact = [20 * CONTROL_PERIOD, 0.45, 0.0, 0.0] if k >= 20 else [-1.0, 0, 0, 0]
            sample.append({"force": [force], "tip_pose": [x, 0.1, 0.2],
                           "tip_velocity": [rng.normal(0, 1e-3), 0, 0],
                           "tip_acceleration": [rng.normal(0, 1e-2), 0, 0],
                           "contact_info": contact})
        signals.append(sample)
    return signals


def test_a_batched_identifier_gives_each_environment_its_own_run():
    configs = [RlsConfig(), RlsConfig(forgetting_factor=0.99), RlsConfig(theta0=[0, 0, 1e4])]
    assert_batched_equals_alone(RlsIdentifier(configs), [RlsIdentifier(c) for c in configs],
                                _wall_signals(len(configs)), CONTROL_PERIOD)
# [docs: end]


def _adds_zero(count):
    """u + 0 over N environments: -0 becomes +0 (alone: u passed through)."""
    builder = DiagramBuilder()
    adder = builder.AddNamedSystem("adder", Adder(2, count))
    zero = builder.AddNamedSystem("zero", ConstantVectorSource(np.zeros(count)))
    builder.Connect(zero.get_output_port(), adder.get_input_port(1))
    builder.ExportInput(adder.get_input_port(0), "u")
    builder.ExportOutput(adder.get_output_port(), "y")
    return builder.Build()


def _pass_through():
    builder = DiagramBuilder()
    passed = builder.AddNamedSystem("passed", PassThrough(1))
    builder.ExportInput(passed.get_input_port(), "u")
    builder.ExportOutput(passed.get_output_port(), "y")
    return builder.Build()


def test_a_sign_of_zero_is_a_mismatch_named_in_one_line():
    inputs = [[{"u": [1.0]}, {"u": [2.0]}], [{"u": [3.0]}, {"u": [-0.0]}]]
    found = batched_mismatches(_adds_zero(2), [_pass_through(), _pass_through()], inputs, 0.001)
    assert [(m.port, m.environment, m.element, m.time_s) for m in found] == [("y", 1, 0, 0.002)]
    with pytest.raises(AssertionError, match=r"output 'y' of environment 1, element 0, at "
                                             r"t = 0\.002 s: 0\.0 batched, -0\.0 alone"):
        assert_batched_equals_alone(_adds_zero(2), [_pass_through(), _pass_through()], inputs,
                                    0.001)
