"""The safety supervisor, sample by sample against its definition, and its
validation. (Closed-loop runs with faults are in test_faults.py.)"""

import numpy as np
import pytest

from drake_contact import ScenarioError, load_scenario
from drake_contact.control.safety_supervisor import (
    CLAMPED, LOSS_HOLD, PASS, REFLEX, SENSOR_HOLD, STOPPED, SafetyConfig, SafetySupervisor)
from drake_contact.plant.arm import THESIS_Q0, ApplySampledUpdates
from drake_contact.plant.planar_arm import tip_jacobian

Q = np.array(THESIS_Q0)
J = np.array(tip_jacobian(list(Q)))


class Bench:
    """A supervisor stepped one 1 ms sample at a time with fixed inputs."""

    def __init__(self, **config):
        self.system = SafetySupervisor(SafetyConfig(enabled=True, **config))
        self.context = self.system.CreateDefaultContext()
        self.k = 1000  # t = 1 s: past the speed check's start
        self.raw = 0.0

    def step(self, *, tau, force, raw=None, q=Q, qdot=(0, 0, 0), v=(0, 0, 0)):
        """One sample: returns (torque out, safety_state). The raw reading
        moves by 0.1 N each sample unless given (a live sensor)."""
        self.raw += 0.1
        self.context.SetTime(self.k * 1e-3)
        inputs = {"joint_torque_commanded": tau, "force": [force],
                  "force_raw": [self.raw if raw is None else raw], "joint_positions": q,
                  "joint_velocities": qdot, "tip_velocity": v}
        for name, value in inputs.items():
            self.system.GetInputPort(name).FixValue(self.context, np.asarray(value, float))
        tau_out = self.system.GetOutputPort("joint_torque").Eval(self.context).copy()
        state = int(self.system.GetOutputPort("safety_state").Eval(self.context)[0])
        ApplySampledUpdates(self.system, self.context)
        self.k += 1
        return tau_out, state


def test_it_passes_the_controller_through_below_every_limit():
    bench = Bench()
    tau = J.T @ [20.0, 1.0, 0.01]
    out, state = bench.step(tau=tau, force=20.0)
    np.testing.assert_array_equal(out, tau)
    assert state == PASS


def test_the_commanded_push_is_clamped_whatever_the_sensor_reads():
    bench = Bench(force_limit_n=60.0, push_clamp_fraction=0.8)
    out, state = bench.step(tau=J.T @ [100.0, 2.0, 0.05], force=3.0)
    assert state == CLAMPED
    np.testing.assert_allclose(out, J.T @ [48.0, 2.0, 0.05], rtol=1e-9, atol=1e-12)


def test_the_reflex_lowers_the_clamp_and_damps_for_its_hold_time():
    bench = Bench(force_limit_n=60.0, reflex_fraction=0.7, reflex_push_fraction=0.4,
                  reflex_damping_x=300.0, reflex_hold_s=0.003)
    v = (0.01, 0.0, 0.0)
    out, state = bench.step(tau=J.T @ [30.0, 0.0, 0.0], force=43.0, v=v)
    assert state == REFLEX
    np.testing.assert_allclose(out, J.T @ [24.0, 0.0, 0.0], rtol=1e-9, atol=1e-12)  # min(30 - 3, 24)
    for _ in range(3):  # within the hold time the reflex stays, unclamped here
        out, state = bench.step(tau=J.T @ [10.0, 0.0, 0.0], force=20.0, v=v)
        assert state == REFLEX
        np.testing.assert_allclose(out, J.T @ [7.0, 0.0, 0.0], rtol=1e-9, atol=1e-12)
    assert bench.step(tau=J.T @ [10.0, 0.0, 0.0], force=20.0, v=v)[1] == PASS


def test_a_frozen_reading_in_contact_holds_the_arm_then_hands_back():
    bench = Bench(sensor_frozen_samples=5)
    tau = J.T @ [20.0, 0.0, 0.0]
    bench.step(tau=tau, force=20.0)            # armed by the contact
    good, _ = bench.step(tau=tau, force=20.0)  # the last sample the reading moved
    q_moved = Q + [0.002, 0.0, 0.0]
    states = [bench.step(tau=tau * 3, force=0.0, raw=0.0, q=q_moved)[1] for _ in range(6)]
    # 0.0 first (the reading moved), then unchanged: a hold at the 5th repeat;
    # until then the blind controller's 60 N push is clamped to 48 N
    assert states == [CLAMPED] * 5 + [SENSOR_HOLD]
    out, state = bench.step(tau=tau * 3, force=0.0, raw=0.0, q=Q + [0.003, 0.0, 0.0])
    assert state == SENSOR_HOLD
    config = SafetyConfig()
    # the torque of when the reading last moved plus the PD about the angles of then
    expected = good + np.asarray(config.stop_stiffness) * (q_moved - (Q + [0.003, 0.0, 0.0]))
    np.testing.assert_allclose(out, expected, rtol=1e-9, atol=1e-12)
    # it moves again: held sensor_settle_samples more (the filter settles), then handed back
    settle = [bench.step(tau=tau, force=20.0)[1] for _ in range(config.sensor_settle_samples + 1)]
    assert settle == [SENSOR_HOLD] * config.sensor_settle_samples + [PASS]


def test_a_sensor_fault_that_lasts_ends_in_a_safe_stop():
    bench = Bench(sensor_frozen_samples=2, sensor_fault_stop_s=0.005)
    bench.step(tau=[1.0, 0.0, 0.0], force=20.0)
    states = [bench.step(tau=[1.0, 0.0, 0.0], force=20.0, raw=5.0)[1] for _ in range(10)]
    assert SENSOR_HOLD in states and states[-1] == STOPPED
    assert bench.system.GetOutputPort("safety_stop_reason").Eval(bench.context)[0] == 4


def test_the_stop_counts_the_stuck_reading_not_the_settle_after_it():
    """Stuck 8 samples, then 20 samples of settle: flagged for longer than
    the 10 ms stop time, but stuck for less: held, never stopped."""
    bench = Bench(sensor_frozen_samples=2, sensor_fault_stop_s=0.010, sensor_settle_samples=20)
    bench.step(tau=[1.0, 0.0, 0.0], force=20.0)
    states = [bench.step(tau=[1.0, 0.0, 0.0], force=20.0, raw=5.0)[1] for _ in range(10)]
    states += [bench.step(tau=[1.0, 0.0, 0.0], force=20.0)[1] for _ in range(25)]
    assert states.count(SENSOR_HOLD) == 8 + 20 and STOPPED not in states


@pytest.mark.parametrize("inputs, reason", [
    ({"tau": [np.nan, 0.0, 0.0], "force": 10.0}, 1),
    ({"tau": [0.0, 0.0, 0.0], "force": 70.0}, 2),
    ({"tau": [0.0, 0.0, 0.0], "force": 10.0, "v": (0.4, 0.4, 0.0)}, 3),
])
def test_the_safe_stop_holds_the_arm_backed_off_and_latches(inputs, reason):
    bench = Bench(force_limit_n=60.0, tip_speed_limit_m_s=0.5, force_stop_samples=2)
    for _ in range(2):
        out, state = bench.step(**inputs)
    assert state == STOPPED
    assert bench.system.GetOutputPort("safety_stop_reason").Eval(bench.context)[0] == reason
    config = SafetyConfig()
    kp, kd = np.asarray(config.stop_stiffness), np.asarray(config.stop_damping)
    # it holds the angles that put the tip 2 mm back along -x
    q_hold = Q + np.linalg.solve(J, [-config.stop_backoff_m, 0.0, 0.0])
    np.testing.assert_allclose(out, kp * (q_hold - Q), rtol=1e-9, atol=1e-12)
    q = Q + [0.01, -0.01, 0.0]
    qdot = np.array([0.1, 0.0, 0.2])
    out, state = bench.step(tau=[5.0, 0.0, 0.0], force=10.0, q=q, qdot=qdot)
    assert state == STOPPED  # latched: the controller is ignored from then on
    np.testing.assert_allclose(out, kp * (q_hold - q) - kd * qdot, rtol=1e-9, atol=1e-12)


def test_one_sample_over_the_limit_is_a_reflex_not_a_stop():
    bench = Bench(force_limit_n=60.0, force_stop_samples=3)
    assert bench.step(tau=[0.0, 0.0, 0.0], force=70.0)[1] == REFLEX
    assert bench.step(tau=[0.0, 0.0, 0.0], force=30.0)[1] == REFLEX


def test_a_contact_loss_holds_the_arm_until_the_force_is_back():
    bench = Bench(contact_loss="hold", contact_loss_time_s=0.002)
    bench.step(tau=[1.0, 0.0, 0.0], force=20.0)
    states = [bench.step(tau=[1.0, 0.0, 0.0], force=0.1)[1] for _ in range(4)]
    assert states[0] == PASS and states[-1] == LOSS_HOLD
    assert bench.step(tau=[1.0, 0.0, 0.0], force=3.0)[1] == LOSS_HOLD
    assert bench.step(tau=[1.0, 0.0, 0.0], force=8.0)[1] == PASS


def test_the_torque_rate_limit_bounds_each_joints_change_per_sample():
    bench = Bench(torque_rate_limit=[1000.0, 0.0, 10.0])
    bench.step(tau=[0.0, 0.0, 0.0], force=1.0)
    out, _ = bench.step(tau=[5.0, 5.0, 5.0], force=1.0)
    np.testing.assert_allclose(out, [1.0, 5.0, 0.01], rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("override, field", [
    ("safety.force_limit_n=0", "safety.force_limit_n"),
    ("safety.reflex_fraction=1.5", "safety.reflex_fraction"),
    ("safety.contact_loss=retreat", "safety.contact_loss"),
    ("safety.torque_rate_limit=[1, 2]", "safety.torque_rate_limit"),
    ("safety.contact_loss_force_n=6", "safety.contact_loss_force_n"),
    ("safety.force_stop_samples=0", "safety.force_stop_samples"),
])
def test_bad_safety_settings_are_refused_naming_the_field(override, field):
    with pytest.raises(ScenarioError, match=field.replace(".", r"\.")):
        load_scenario("push_constant", [override])
