"""What the sampled systems read from the sensing: ``simulation.sample_hold``.

At each sample the plant steps with the sampled systems (controllers,
identifiers), and the sensing's discrete systems update after it. Read
directly, a filter's state has already taken in the very sample it is read
with: a backward difference reads 0. With the hold (the DSP's sample) every
sampled system reads the textbook filter of the encoder samples; without it
(the default of every bundled scenario until the reproduction is
re-validated) joints 1 and 2's velocities read 0: the known defect these
tests pin down (README, "Known defects").
"""

import numpy as np
import pytest
from scipy import signal

from drake_contact.app.runner import run
from drake_contact.plant.arm import CONTROL_PERIOD
from drake_contact.scenario import load_scenario
from drake_contact.sensing.filters import butterworth_digital

#: push_constant pushing from t = 0: the arm moves from the first samples.
PUSH_AT_ONCE = "controller.push.start_time=0"


def _run(tmp_path, hold):
    scenario = load_scenario("push_constant", [PUSH_AT_ONCE,
                                               f"simulation.sample_hold={str(hold).lower()}"],
                             duration=1.0)
    result = run(scenario, tmp_path, figures=False)
    assert result.status == "completed"
    return scenario, result.log


def _textbook_velocity(scenario, pose):
    """The estimator's velocity as the DSP computes it from these samples:
    F((x_n - x_(n-1)) / T), F the estimator's Butterworth, from rest."""
    b, a = butterworth_digital(scenario.estimator.cutoff_hz, 1.0 / CONTROL_PERIOD)
    diff = np.array([1.0, -1.0]) / CONTROL_PERIOD
    return signal.lfilter(np.polymul(b, diff), np.polymul(a, [1.0, 0.0]), pose, axis=0)


def test_with_the_hold_the_controller_reads_backward_differences(tmp_path):
    scenario, log = _run(tmp_path, True)
    q = log["joint_positions_estimated"][1:]
    qdot = log["joint_velocities_estimated"][1:]
    # Joints 1 and 2 are read as counted: their velocity is the backward
    # difference of the angles the controller reads, sample by sample.
    np.testing.assert_allclose(qdot[1:, :2], np.diff(q[:, :2], axis=0) / CONTROL_PERIOD,
                               atol=1e-9)
    assert np.count_nonzero(qdot[:, 0]) > 50 and np.count_nonzero(qdot[:, 1]) > 50
    # The tip velocity is the textbook filtered difference of the tip pose read.
    pose = log["tip_pose_measured"][1:]
    np.testing.assert_allclose(log["tip_velocity_measured"][1:],
                               _textbook_velocity(scenario, pose), rtol=1e-9, atol=1e-9)


def test_without_the_hold_joints_1_and_2_read_no_velocity(tmp_path):
    scenario, log = _run(tmp_path, False)
    counted = log["joint_positions_measured"]
    assert np.count_nonzero(np.diff(counted[:, 0])) > 50   # joint 1's counts change ...
    assert np.all(log["joint_velocities_estimated"][1:, :2] == 0.0)   # ... read as at rest
    # The filtered tip velocity reads z (H - D) + D, not H: a sample ahead.
    pose = log["tip_pose_measured"][1:]
    error = log["tip_velocity_measured"][1:] - _textbook_velocity(scenario, pose)
    assert np.max(np.abs(error[:, 0])) > 1e-3


def test_the_identifiers_read_held_signals_with_the_hold():
    from drake_contact.diagram import MakeContactDiagram
    for hold in (False, True):
        scenario = load_scenario("identify_styrofoam", [f"simulation.sample_hold={str(hold).lower()}"])
        station = MakeContactDiagram(scenario)
        identifiers = station.GetSubsystemByName("identifiers")
        held = [s.get_name() for s in identifiers.GetSystems()
                if s.get_name().startswith("sample_")]
        latched = [s.get_name() for s in station.GetSystems()
                   if s.get_name().startswith("dsp_sample_")]
        if hold:
            # The matched filters' outputs are held here; the signals the
            # identifiers read directly come from the station's own holds.
            assert held and all(n.startswith("sample_matched_") for n in held)
            assert len(latched) == 9
            assert identifiers.HasInputPort("force_held")
            assert not identifiers.HasInputPort("joint_velocities_held")  # nobody reads it
        else:
            assert held == [] and latched == []
            assert not identifiers.HasInputPort("force_held")
