"""The DSP's kinematic estimator at 1 kHz (thesis chapter 4, Appendix E).

From the quantized encoder angles q_m:

1. q3 through the 35 Hz Butterworth (the 2,000-count encoder of joint 3 is
   coarse), q1 and q2 as read: q_hat = (q1_m, q2_m, F(q3_m));
2. the tip pose x_hat = FK(q_hat) from the controller's model of the arm;
3. velocity = F((x_hat[n] - x_hat[n-1]) / T), acceleration = F of the backward
   difference of the unfiltered velocity; F is the 35 Hz filter (Appendix E);
4. joint velocities for the controllers' dynamic model: backward differences
   of the encoder readings, joint 3's through F once (Appendix E's u1v, u2v
   and u3vf; joints 1-2 unfiltered).

Controllers and identifiers read these outputs, never the true state.
Filters and differences are Drake ``LinearSystem``s and the forward
kinematics a closed form in C++: no Python runs here per step. Lag: for a signal of frequency w the velocity lags by
the backward difference's half sample plus the 35 Hz filter's group delay
(6.4 ms at low frequency): see :func:`velocity_lag_s`.
"""

import dataclasses as dc

import numpy as np
from pydrake import symbolic
from pydrake.systems.framework import Diagram, DiagramBuilder
from pydrake.systems.primitives import Demultiplexer, LinearSystem
from scipy import signal

from drake_contact.arm_axis import LinearSystemBank, StackedSymbolicSystem
from drake_contact.blocks import AddSubdiagram, environment_configs
from drake_contact.plant.arm import CONTROL_PERIOD
from drake_contact.errors import ScenarioError
from drake_contact.plant.planar_arm import tip_pose
from drake_contact.plant.tip_kinematics import check_closed_forms
from drake_contact.sensing.filters import butterworth_digital, differencing_filter_system


@dc.dataclass
class EstimatorConfig:
    """The kinematic estimator's filter."""

    # Cut-off of the 2nd-order Butterworth on q3, velocities and
    # accelerations (Hz), at 1 kHz.
    cutoff_hz: float = 35.0

    def validate(self, prefix="estimator"):
        if not (0.01 <= self.cutoff_hz < 500):
            raise ScenarioError(
                f"{prefix}.cutoff_hz = {self.cutoff_hz} is out of range: must be in [0.01, 500) Hz")


def velocity_lag_s(cutoff_hz, frequency_hz, period=CONTROL_PERIOD):
    """Predicted lag (s) of the estimated velocity behind the true one for a
    sinusoid: half a sample of backward difference plus the filter's group
    delay at that frequency."""
    b, a = butterworth_digital(cutoff_hz, 1.0 / period)
    _, gd = signal.group_delay((b, a), w=[frequency_hz], fs=1.0 / period)
    return 0.5 * period + float(gd[0]) * period


class ForwardKinematics(Diagram):
    """Input: joint_positions (3, rad). Output: tip_pose (3: x, y, phi; m,
    rad), phi = q1 + q2 + q3, by the closed forms of the arm (planar_arm),
    evaluated in C++ (a ``SymbolicVectorSystem``). ``plant_model``: the
    controller's model of the arm, against whose kinematics the closed forms
    are checked once, here."""

    def __init__(self, plant_model, count=1):
        super().__init__()
        check_closed_forms(plant_model)
        pieces = []
        for _ in range(count):
            q = symbolic.MakeVectorVariable(3, "q")
            pieces.append({"input": q, "output": tip_pose(q, sin=symbolic.sin,
                                                          cos=symbolic.cos)})
        builder = DiagramBuilder()
        fk = builder.AddNamedSystem("closed_form", StackedSymbolicSystem(pieces))
        builder.ExportInput(fk.get_input_port(), "joint_positions")
        builder.ExportOutput(fk.get_output_port(), "tip_pose")
        builder.BuildInto(self)


def _joint_filters(b, a, period):
    """One LinearSystem: input q_m (3); outputs [q_hat (3), qdot_hat (3)].

    q_hat = (q1, q2, F q3); qdot_hat = ((1 - z^-1)/T) q_m, joint 3's
    through F: Appendix E's u1v, u2v (raw backward differences) and u3vf =
    F35 of the raw u3's difference (not of the filtered u3f)."""
    diff = np.array([1.0, -1.0]) / period
    channels = [
        ([1.0], [1.0]),                                        # q1
        ([1.0], [1.0]),                                        # q2
        (b, a),                                                # F q3
        (diff, [1.0, 0.0]),                                    # q1 diff
        (diff, [1.0, 0.0]),                                    # q2 diff
        (np.polymul(b, diff), np.polymul(a, [1.0, 0.0])),      # F q3 diff
    ]
    inputs = [0, 1, 2, 0, 1, 2]
    blocks = [signal.tf2ss(num, den) for num, den in channels]
    n = sum(blk[0].shape[0] for blk in blocks)
    A = np.zeros((n, n))
    B = np.zeros((n, 3))
    C = np.zeros((6, n))
    D = np.zeros((6, 3))
    i = 0
    for out, ((a_, b_, c_, d_), inp) in enumerate(zip(blocks, inputs)):
        m = a_.shape[0]
        A[i:i + m, i:i + m] = a_
        B[i:i + m, inp] = b_[:, 0] if m else 0.0
        C[out, i:i + m] = c_[0] if m else 0.0
        D[out, inp] = d_[0, 0]
        i += m
    return LinearSystem(A, B, C, D, period)


def _start_at_rest(system: LinearSystem, u0):
    """Sets ``system``'s default state to its steady state for the constant
    input ``u0`` (its history as if the input had always been u0)."""
    A, B = system.A(), system.B()
    system.configure_default_state(np.linalg.solve(np.eye(A.shape[0]) - A, B @ np.asarray(u0)))


def AddKinematicEstimator(builder: DiagramBuilder, plant_model, config, rest_reading, *,
                          name="estimator"):
    """Adds the estimator as the sub-diagram ``name``; returns it. Ports:
    ``joint_positions_measured`` (input, 3, rad) and outputs ``tip_pose``
    (3), ``tip_velocity`` (3), ``tip_acceleration`` (3), ``joint_positions``
    (3: q_hat), ``joint_velocities`` (3), and the unfiltered differences
    ``tip_velocity_raw``, ``tip_acceleration_raw`` (3). With a list of N
    configs and N rest readings, the estimators of N arms on the arm axis
    (every port N times its size, arm i's values at ``[k i, k (i + 1))``),
    each filter a :class:`~drake_contact.arm_axis.LinearSystemBank` that
    gives each arm its own filter's values bit for bit.

    Start-up: every filter and difference starts at rest at the encoders'
    reading ``rest_reading`` (3, rad: q0 as the encoders read it): the
    filtered q3 at q3, every velocity and acceleration at 0. (Appendix E
    starts the previous encoder and tip readings at the pose but the filters'
    histories at 0, which reads the orientation 0.78 rad off at the first
    samples, an artefact of the program's start the thesis's runs begin
    long after.)"""
    configs = environment_configs(config, EstimatorConfig, "estimator")
    readings = np.reshape(np.asarray(rest_reading, dtype=float), (len(configs), 3))
    count = len(configs)
    filters = {"joint_filters": [], "tip_rates": [], "tip_rates_raw": []}
    for c, reading in zip(configs, readings):
        c.validate()
        b, a = butterworth_digital(c.cutoff_hz, 1.0 / CONTROL_PERIOD)
        rest_pose = tip_pose(reading)
        joints = _joint_filters(b, a, CONTROL_PERIOD)
        _start_at_rest(joints, reading)
        rates = differencing_filter_system(b, a, CONTROL_PERIOD, channels=3)
        # Unfiltered differences too (the thesis's Fig 6.3 identifies on these).
        raw = differencing_filter_system([1.0], [1.0], CONTROL_PERIOD, channels=3)
        _start_at_rest(rates, rest_pose)
        _start_at_rest(raw, rest_pose)
        for key, system in zip(filters, (joints, rates, raw)):
            filters[key].append(system)

    def role(key):
        # Outputs [first 3, last 3] per arm; a bank gives them field-major.
        return filters[key][0] if count == 1 else LinearSystemBank(filters[key],
                                                                    output_sizes=[3, 3])

    def build(builder):
        joints = builder.AddNamedSystem(f"{name}_joint_filters", role("joint_filters"))
        split = builder.AddNamedSystem(f"{name}_joint_split", Demultiplexer([3 * count] * 2))
        fk = builder.AddNamedSystem(f"{name}_forward_kinematics",
                                    ForwardKinematics(plant_model, count))
        rates = builder.AddNamedSystem(f"{name}_tip_rates", role("tip_rates"))
        rates_split = builder.AddNamedSystem(f"{name}_tip_rates_split",
                                             Demultiplexer([3 * count] * 2))
        raw = builder.AddNamedSystem(f"{name}_tip_rates_raw", role("tip_rates_raw"))
        raw_split = builder.AddNamedSystem(f"{name}_tip_rates_raw_split",
                                           Demultiplexer([3 * count] * 2))
        builder.Connect(fk.GetOutputPort("tip_pose"), raw.get_input_port())
        builder.Connect(raw.get_output_port(), raw_split.get_input_port())
        builder.Connect(joints.get_output_port(), split.get_input_port())
        builder.Connect(split.get_output_port(0), fk.GetInputPort("joint_positions"))
        builder.Connect(fk.GetOutputPort("tip_pose"), rates.get_input_port())
        builder.Connect(rates.get_output_port(), rates_split.get_input_port())
        return {
            "joint_positions_measured": joints.get_input_port(),
            "tip_pose": fk.GetOutputPort("tip_pose"),
            "tip_velocity": rates_split.get_output_port(0),
            "tip_acceleration": rates_split.get_output_port(1),
            "joint_positions": split.get_output_port(0),
            "joint_velocities": split.get_output_port(1),
            "tip_velocity_raw": raw_split.get_output_port(0),
            "tip_acceleration_raw": raw_split.get_output_port(1),
        }
    return AddSubdiagram(builder, name, build)
