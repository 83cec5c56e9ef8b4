"""The safety layer's flag on the force reading (force_fault): the monitor's
rules sample by sample, and the laws that hold their state while it is up
(the hybrid law, the neural compensator, the RLS), one environment of an
ensemble held while the others run on bit for bit. (Closed-loop runs with
faults are in test_faults.py.)"""

import numpy as np
import pytest

from drake_contact.control.force_monitor import ForceReadingMonitor
from drake_contact.control.hybrid_controller import HybridControlLaw, HybridControllerConfig
from drake_contact.control.safety_supervisor import SafetyConfig
from drake_contact.identification.rls_identifier import RlsConfig, RlsIdentifier
from drake_contact.plant.arm import CONTROL_PERIOD, THESIS_Q0, ApplySampledUpdates
from drake_contact.plant.planar_arm import tip_pose


class Monitor:
    """The monitor stepped one 1 ms sample at a time."""

    def __init__(self, **config):
        self.system = ForceReadingMonitor(SafetyConfig(enabled=True, **config))
        self.context = self.system.CreateDefaultContext()
        self.k = 1000

    def step(self, raw, force=20.0):
        self.context.SetTime(self.k * CONTROL_PERIOD)
        self.system.get_input_port().FixValue(self.context, [raw, force])
        flag = self.system.get_output_port().Eval(self.context)[0]
        ApplySampledUpdates(self.system, self.context)
        self.k += 1
        return int(flag)


def _noise(n, seed=0, level=20.0):
    """A live reading: the DAC ripple and gauge noise around ``level``, on
    the ADC's 0.061 N counts."""
    rng = np.random.default_rng(seed)
    k = np.arange(n)
    value = level + 2.25 * np.sin(2 * np.pi * 0.48 * k + 0.3) + 0.19 * rng.standard_normal(n)
    return np.round(value / 0.061) * 0.061


def test_a_live_reading_is_never_flagged_a_stuck_one_is_at_the_fifth_repeat():
    monitor = Monitor(sensor_frozen_samples=5, sensor_settle_samples=3)
    assert [monitor.step(r) for r in _noise(2000)] == [0] * 2000
    # frozen at its last value (a dropout that holds): flagged at the 5th repeat
    flags = [monitor.step(20.13) for _ in range(8)]
    assert flags == [0] * 5 + [1] * 3
    # it moves again: held 3 samples more while the filter settles, then clear
    assert [monitor.step(r) for r in _noise(6, seed=1)] == [1, 1, 1, 0, 0, 0]


def test_a_jump_to_a_value_that_repeats_is_flagged_at_the_repeat():
    monitor = Monitor(sensor_jump_n=8.0, sensor_settle_samples=0)
    for r in _noise(50):
        monitor.step(r)
    # 20 N to exactly 0 N: the jump passes, its first repeat is flagged
    assert [monitor.step(0.0) for _ in range(4)] == [0, 1, 1, 1]
    assert monitor.step(_noise(1)[0]) == 0


@pytest.mark.parametrize("after", ["noise", "small_repeat"])
def test_a_real_jump_followed_by_noise_is_not_flagged(after):
    """A surface that gives way (20 N to 0 N in one sample) reads noise
    afterwards: never flagged. A repeat after a small change is noise too."""
    monitor = Monitor(sensor_jump_n=8.0)
    for r in _noise(50):
        monitor.step(r)
    if after == "noise":
        assert [monitor.step(r) for r in _noise(200, seed=2, level=0.0)] == [0] * 200
    else:
        monitor.step(20.5)
        assert [monitor.step(20.5) for _ in range(2)] == [0, 0]


def test_nothing_is_flagged_before_the_first_contact_or_with_the_check_off():
    before = Monitor()
    assert [before.step(0.0, force=0.0) for _ in range(20)] == [0] * 20
    off = Monitor(sensor_frozen_samples=0)
    assert [off.step(5.0) for _ in range(20)] == [0] * 20


def _law_bench(count):
    configs = [HybridControllerConfig(law="decoupled", decoupled_force_integral_gain=0.01,
                                      stiffness_estimate=7000.0 * (1 + i))
               for i in range(count)]
    law = HybridControlLaw(configs if count > 1 else configs[0])
    return law, law.CreateDefaultContext()


def _drive_law(law, context, k, f, fault=None, count=1):
    """One sample of the law with the arm at q0 and force ``f`` (per environment)."""
    q = np.tile(THESIS_Q0, count)
    pose = np.tile(tip_pose(list(THESIS_Q0)), count)
    context.SetTime(k * CONTROL_PERIOD)
    for name, value in (("tip_pose", pose), ("tip_velocity", np.zeros(3 * count)),
                        ("joint_positions", q), ("joint_velocities", np.zeros(3 * count)),
                        ("force", f), ("force_desired", np.full(count, 20.0)),
                        ("stiffness_estimate", np.full(count, 7000.0))):
        law.GetInputPort(name).FixValue(context, np.asarray(value, float))
    if fault is not None:
        law.GetInputPort("force_fault").FixValue(context, np.asarray(fault, float))
    out = law.get_output_port().Eval(context).copy()
    ApplySampledUpdates(law, context)
    return out


def test_the_hybrid_law_holds_its_output_and_state_while_flagged():
    law, context = _law_bench(1)
    for k in range(1, 20):
        _drive_law(law, context, k, [18.0])   # in contact, integrating
    held = context.get_discrete_state_vector().CopyToVector()
    for k in range(20, 30):  # flagged: output and state are those of before
        out = _drive_law(law, context, k, [0.0], fault=[1.0])
        np.testing.assert_array_equal(out, held)
        np.testing.assert_array_equal(context.get_discrete_state_vector().CopyToVector(), held)
    # unconnected or 0: the law runs (a reading of 0 N leaves contact)
    out = _drive_law(law, context, 30, [0.0], fault=[0.0])
    assert not np.array_equal(out, held)


def test_one_environment_held_the_other_runs_as_alone():
    law2, context2 = _law_bench(2)
    alone, context1 = _law_bench(1)
    rng = np.random.default_rng(3)
    for k in range(1, 60):
        f = 18.0 + rng.standard_normal(2)
        flagged = 20 <= k < 40
        out2 = _drive_law(law2, context2, k, f, fault=[0.0, float(flagged)], count=2)
        out1 = _drive_law(alone, context1, k, f[:1])
        rows = out2[law2._index]  # (the law's values, environments)
        np.testing.assert_array_equal(rows[:, 0], out1)  # environment 0 as alone
        if flagged:  # environment 1 held: its output is its state of before
            np.testing.assert_array_equal(rows[:, 1], before[:, 1])
        else:
            before = rows


def test_the_rls_holds_its_estimate_while_flagged():
    system = RlsIdentifier(RlsConfig())
    context = system.CreateDefaultContext()
    for name, value in (("tip_pose", [0.4581, 0.0, 0.0]), ("tip_velocity", [0.001, 0, 0]),
                        ("tip_acceleration", [0.01, 0, 0]), ("contact_info", [1.0, 0.457, 0, 0])):
        system.GetInputPort(name).FixValue(context, value)
    system.GetInputPort("force").FixValue(context, [7.7])
    for k in range(1, 10):
        context.SetTime(1.0 + k * CONTROL_PERIOD)
        ApplySampledUpdates(system, context)
    before = _state(context)
    system.GetInputPort("force").FixValue(context, [0.0])
    system.GetInputPort("force_fault").FixValue(context, [1.0])
    for k in range(10, 20):
        context.SetTime(1.0 + k * CONTROL_PERIOD)
        ApplySampledUpdates(system, context)
    np.testing.assert_array_equal(_state(context), before)
    system.GetInputPort("force_fault").FixValue(context, [0.0])
    ApplySampledUpdates(system, context)
    assert not np.array_equal(_state(context), before)


def _state(context):
    state = context.get_discrete_state()
    return np.concatenate([state.get_vector(i).CopyToVector() for i in range(state.num_groups())])


def test_the_neural_compensator_holds_its_output_and_weights_while_flagged():
    from drake_contact.control.nn_compensator import NnCompensationLaw, NnCompensatorConfig
    law = NnCompensationLaw([NnCompensatorConfig(), NnCompensatorConfig()])
    context = law.CreateDefaultContext()
    rng = np.random.default_rng(4)
    J = np.eye(3).ravel()
    for name, value in (("tip_jacobian", np.tile(J, 2)), ("force_desired", [20.0, 20.0]),
                        ("mode", [1.0, 1.0])):
        law.GetInputPort(name).FixValue(context, value)

    def step(k, fault):
        context.SetTime(k * CONTROL_PERIOD)
        law.GetInputPort("tip_pose").FixValue(context, 0.45 + 1e-4 * rng.standard_normal(6))
        law.GetInputPort("hybrid_torque").FixValue(context, rng.standard_normal(6))
        law.GetInputPort("force").FixValue(context, 18.0 + rng.standard_normal(2))
        law.GetInputPort("force_fault").FixValue(context, fault)
        out = law.get_output_port().Eval(context).copy()
        ApplySampledUpdates(law, context)
        return out
    for k in range(1, 10):
        before = step(k, [0.0, 0.0])
    for k in range(10, 20):  # environment 1 flagged: its part of the output stays
        out = step(k, [0.0, 1.0])
        n_and_torque = out[:12].reshape(2, 2, 3)  # [J^T n; n] per environment
        weights = out[12:].reshape(2, -1)
        np.testing.assert_array_equal(n_and_torque[:, 1], before[:12].reshape(2, 2, 3)[:, 1])
        np.testing.assert_array_equal(weights[1], before[12:].reshape(2, -1)[1])
        assert not np.array_equal(weights[0], before[12:].reshape(2, -1)[0])
        before = out
