"""Simultaneous sampling, as the thesis's DSP did it (Appendix E, ``c_int1``):
at each 1 ms sample t_n every sampled system reads values computed from the
plant's state at t_n, and the torque it computes acts on the plant from t_n.

A probe controller (a plain Drake LeafSystem, declared as any plug-in would
declare it, knowing nothing of the station's timing) records what it reads in
its update; its torque law is a direct function of what it reads. Checked at
the plant steps h = 1 ms and h = 0.25 ms.
"""

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder, LeafSystem
from pydrake.systems.primitives import LogVectorOutput
from scipy import signal

import drake_contact.diagram as station_module
from drake_contact import MakeContactDiagram, ScenarioError, load_scenario
from drake_contact.plant.arm import CONTROL_PERIOD, ArmConfig
from drake_contact.plant.planar_arm import tip_pose
from drake_contact.sensing.filters import butterworth_digital

T = CONTROL_PERIOD
#: Joint angles (rad) the probe's PD drives toward from q0: all three move.
TARGET_OFFSET = np.array([0.03, -0.04, 0.05])
#: The probe's PD gains per joint (N m/rad, N m s/rad).
GAINS = np.array([[15.0, 8.0, 0.5], [1.5, 0.6, 0.02]])
#: The probe's torque step, (s, N m on joint 3), at a sample instant.
STEP_AT_S, STEP_NM = 0.2, 0.05


class Probe(LeafSystem):
    """Reads the measured signals and the true state; outputs a PD torque
    on what it reads (computed where it is read: a direct-feedthrough law),
    and from ``STEP_AT_S`` on adds a torque step on joint 3. Its periodic
    update records every input."""

    def __init__(self, q0):
        super().__init__()
        self.q_target = np.asarray(q0) + TARGET_OFFSET
        self.records = []
        # Keyed by the signal's role, each port named as the station names it.
        self.inputs = {role: self.DeclareVectorInputPort(name, size) for role, name, size in (
            ("joint_positions", "joint_positions_estimated", 3),
            ("joint_velocities", "joint_velocities_estimated", 3),
            ("tip_pose", "tip_pose_measured", 3), ("tip_velocity", "tip_velocity_measured", 3),
            ("force", "force_filtered", 1), ("plant_state", "plant_state", 6))}
        self.DeclareVectorOutputPort("joint_torque_commanded", 3, self._torque)
        self.DeclarePeriodicDiscreteUpdateEvent(1e-3, 0.0, self._record)

    def law(self, t, q, qdot):
        tau = GAINS[0] * (self.q_target - q) - GAINS[1] * qdot
        if t >= STEP_AT_S - 1e-9:
            tau[2] += STEP_NM
        return tau

    def _torque(self, context, output):
        q = self.inputs["joint_positions"].Eval(context)
        qdot = self.inputs["joint_velocities"].Eval(context)
        output.SetFromVector(self.law(context.get_time(), q, qdot))

    def _record(self, context, discrete_state):
        self.records.append((context.get_time(), {
            name: port.Eval(context).copy() for name, port in self.inputs.items()}))


def _simulate(monkeypatch, time_step, duration=0.4):
    scenario = load_scenario("push_constant", [f"arm.time_step={time_step}",
                                               "simulation.settle_window=0.1",
                                               "joint_friction.enabled=false"], duration=duration)
    probe = Probe(scenario.arm.initial_positions)
    monkeypatch.setattr(station_module, "MakeController", lambda name, options: probe)
    builder = DiagramBuilder()
    station = builder.AddSystem(MakeContactDiagram(scenario))
    logs = {name: LogVectorOutput(station.GetOutputPort(name), builder, time_step) for name in (
        "joint_state_true", "joint_positions_measured", "joint_torque_commanded",
        "joint_torque_applied", "force_measured", "force_filtered", "tip_pose_measured",
        "tip_velocity_measured", "joint_velocities_estimated", "joint_positions_estimated")}
    diagram = builder.Build()
    simulator = Simulator(diagram)
    simulator.AdvanceTo(duration)
    context = simulator.get_context()
    logged = {name: log.FindLog(context) for name, log in logs.items()}
    times = logged["joint_state_true"].sample_times()
    # Every sample but the last (the run ends there, before its update).
    at_samples = np.flatnonzero(np.abs(times / T - np.round(times / T)) < 1e-6)[:-1]
    data = {name: log.data().T[at_samples] for name, log in logged.items()}
    fine = {name: log.data().T for name, log in logged.items()}
    return scenario, probe, times[at_samples], data, times, fine


@pytest.fixture(scope="module", params=[1e-3, 2.5e-4], ids=["h=1ms", "h=0.25ms"])
def sampled(request):
    with pytest.MonkeyPatch.context() as monkeypatch:
        yield _simulate(monkeypatch, request.param)


def _records(probe, times):
    """The probe's records at the logged sample times (the update at t = 0
    included), as arrays by input name."""
    by_time = {round(t / T): inputs for t, inputs in probe.records}
    rows = [by_time[round(t / T)] for t in times]
    return {name: np.array([row[name] for row in rows]) for name in rows[0]}


def test_every_sampled_system_reads_the_state_at_t_n(sampled):
    _, probe, times, data, _, _ = sampled
    seen = _records(probe, times)
    # The true state the probe reads in its update at t_n is the plant's
    # state logged at t_n, and the arm moves: no sample is read twice.
    np.testing.assert_array_equal(seen["plant_state"], data["joint_state_true"])
    assert np.all(np.any(np.diff(seen["plant_state"][50:, :3], axis=0) != 0, axis=1))
    # What it reads of the sensing is what the station logs at t_n.
    for name, logged in (("joint_positions", "joint_positions_estimated"),
                         ("joint_velocities", "joint_velocities_estimated"),
                         ("tip_pose", "tip_pose_measured"),
                         ("tip_velocity", "tip_velocity_measured"),
                         ("force", "force_filtered")):
        np.testing.assert_array_equal(seen[name], data[logged], err_msg=name)


def test_joint_velocities_are_appendix_e_formulas_of_the_encoder_readings(sampled):
    """u1v = (u1 - u1_1)/T, u2v likewise (raw backward differences), and
    u3vf = F35 of (u3 - u3_1)/T, with u3f = F35 u3 in the kinematics. F35 is
    the 2nd-order Butterworth at 35 Hz designed for 1 kHz by the bilinear
    transform with pre-warping (scipy.signal.butter): b = [0.010432,
    0.020865, 0.010432], a = [1, -1.690996, 0.732726], which Appendix E
    prints to four digits (0.0104, 0.0209, 0.0104; 1.691, -0.7327)."""
    scenario, probe, times, data, _, _ = sampled
    b, a = butterworth_digital(scenario.estimator.cutoff_hz, 1.0 / T)
    np.testing.assert_allclose(b, [0.0104, 0.0209, 0.0104], atol=6e-5)
    np.testing.assert_allclose(-a[1:], [1.691, -0.7327], atol=6e-5)
    seen = _records(probe, times)
    u = data["joint_positions_measured"]            # the encoder readings at t_n
    assert times[0] == 0.0
    assert np.count_nonzero(np.diff(u[:, 0])) > 20 and np.count_nonzero(np.diff(u[:, 1])) > 20
    diff = np.diff(u, axis=0) / T                   # from t_1 on
    np.testing.assert_allclose(seen["joint_velocities"][1:, :2], diff[:, :2], rtol=0, atol=1e-9)
    # At rest before t_0: every history starts at the reading at q0.
    np.testing.assert_allclose(seen["joint_velocities"][0], [0.0, 0.0, 0.0], rtol=0, atol=1e-9)
    u3vf = signal.lfilter(b, a, np.concatenate([[0.0], diff[:, 2]]))
    np.testing.assert_allclose(seen["joint_velocities"][:, 2], u3vf, rtol=0, atol=1e-9)
    rest = np.full(5000, u[0, 2])
    u3f = signal.lfilter(b, a, np.concatenate([rest, u[:, 2]]))[len(rest):]
    q_hat = np.column_stack([u[:, 0], u[:, 1], u3f])
    np.testing.assert_allclose(seen["joint_positions"], q_hat, rtol=0, atol=1e-9)
    assert np.max(np.abs(seen["joint_velocities"][:, 2])) > 0.05


def test_each_filter_is_its_difference_equation_on_the_samples_at_t_n(sampled):
    scenario, probe, times, data, _, _ = sampled
    b, a = butterworth_digital(scenario.estimator.cutoff_hz, 1.0 / T)
    # Tip velocity: F35 of the backward difference of the tip pose read, the
    # pose FK(u1, u2, u3f), from rest.
    q_hat = data["joint_positions_estimated"]
    pose = np.array([tip_pose(q) for q in q_hat])
    np.testing.assert_allclose(data["tip_pose_measured"], pose, rtol=0, atol=1e-12)
    diff = np.vstack([np.zeros(3), np.diff(pose, axis=0) / T])
    np.testing.assert_allclose(data["tip_velocity_measured"], signal.lfilter(b, a, diff, axis=0),
                               rtol=0, atol=1e-9)
    # The force: the 120 Hz Butterworth of the ADC reading at t_n.
    b_f, a_f = butterworth_digital(scenario.dsp.force_filter_cutoff_hz, 1.0 / T)
    np.testing.assert_allclose(data["force_filtered"][:, 0],
                               signal.lfilter(b_f, a_f, data["force_measured"][:, 0]),
                               rtol=0, atol=1e-9)
    assert np.ptp(data["force_measured"]) > 0.5   # the sensor's noise moves it


def test_the_law_acts_from_t_n_and_only_on_the_t_n_sample(sampled):
    scenario, probe, times, data, all_times, fine = sampled
    seen = _records(probe, times)
    # The torque logged at t_n is the law of the inputs read at t_n.
    law = np.array([probe.law(t, q, qdot) for t, q, qdot in zip(
        times, seen["joint_positions"], seen["joint_velocities"])])
    np.testing.assert_array_equal(data["joint_torque_commanded"][1:], law[1:])
    # The plant steps with it from t_n: between samples the applied torque
    # is held (the DAC), changing only at the 1 ms samples.
    applied = fine["joint_torque_applied"]
    sample = np.abs(all_times / T - np.round(all_times / T)) < 1e-6
    held = np.all(applied[1:] == applied[:-1], axis=1)
    assert np.all(held[~sample[1:]])
    np.testing.assert_array_equal(applied[sample][1:len(law)], law[1:])


def test_a_torque_step_at_t_n_moves_the_plant_at_t_n_plus_h(monkeypatch):
    """The step enters the law at t_n = 0.2 s; the arm's joint 3 velocity
    responds at the very next plant step, with the step's sign."""
    for h in (1e-3, 2.5e-4):
        _, probe, _, _, all_times, fine = _simulate(monkeypatch, h, duration=STEP_AT_S + 0.003)
        n = int(np.flatnonzero(np.isclose(all_times, STEP_AT_S, atol=1e-9, rtol=0))[0])
        applied = fine["joint_torque_applied"][:, 2]
        assert applied[n] - applied[n - 1] == pytest.approx(STEP_NM, abs=1e-3)
        v3 = fine["joint_state_true"][:, 5]
        # Without the step the velocity would have changed as in the step before.
        change = (v3[n + 1] - v3[n]) - (v3[n] - v3[n - 1])
        assert change > 0.5 * STEP_NM / 0.01 * h  # joint 3's inertia is about 0.0013-0.01 kg m^2


def test_plant_steps_that_do_not_fall_on_the_samples_are_refused():
    for h in (1e-4, 2e-4, 1e-3 / 3):
        with pytest.raises(ScenarioError, match=r"arm.time_step = .* 0.001 / 2\*\*k s"):
            ArmConfig(time_step=h).validate()
    for h in (1e-3, 5e-4, 2.5e-4, 1.25e-4, 1e-3 / 64):
        ArmConfig(time_step=h).validate()


def test_the_sample_hold_option_is_gone_in_one_line():
    with pytest.raises(ScenarioError, match=r"^simulation.sample_hold is gone: .*delete the line$"):
        load_scenario("push_constant", ["simulation.sample_hold=true"])
