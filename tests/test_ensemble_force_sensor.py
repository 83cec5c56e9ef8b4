"""The FS6-120A for N environments at once (the arm axis): environment i is,
bit for bit, the single sensor with configs[i], its inputs and its noise."""

import dataclasses as dc
import zlib

import numpy as np
import pytest
from pydrake.common import RandomGenerator
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import ConstantVectorSource, LogVectorOutput, RandomSource

from drake_contact.diagram import _NOISE_KEY_PREFIX, leaf_systems
from drake_contact.errors import ScenarioError
from drake_contact.sensing.force_sensor import AddForceSensor, ForceSensor, ForceSensorConfig

# Four environments of one structure, every other field different: noise
# level and shape, offset and drift, calibration cross-talk, ADC resolution
# and range (env 2 clips), glitch height and length, both analog filters,
# output scale.
MIXED = [
    {},
    {"noise_scale": 0.0, "offset_n": -2.0, "offset_drift_n_per_s": 0.37, "adc_bits": 10,
     "calibration_matrix": [[1.0, 0.02, -0.01], [0.03, 0.98, 0.0], [0.0, 0.01, 1.01]]},
    {"adc_full_scale": [5.0, 5.0, 0.5], "dac_glitch_n": -0.7, "dac_ripple_n": 0.0,
     "dac_glitch_duration_s": 2 / 12000,
     "analog_cutoff_hz": 200.0, "output_bandwidth_hz": 800.0, "output_scale_n_per_v": 123.0},
    {"noise_std": [1.5, 0.2, 0.05], "noise_scale": 2.0, "offset_n": 0.0,
     "dac_glitch_n": 3.0, "dac_ripple_n": -1.1, "dac_glitch_duration_s": 1 / 12000},
]
# Structures (the same for every environment of an ensemble): today's; two
# ADC samples in some frames; a slow ADC whose glitch lasts over frames, on
# a 24 kHz grid with a 4th-order gauge filter.
STRUCTURES = {
    "480Hz": ({}, [{}, {}, {}, {}]),
    "2kHz": ({"adc_rate_hz": 2000.0}, [{}, {}, {}, {}]),
    "slow_adc_24kHz": ({"fine_rate_hz": 24000.0, "adc_rate_hz": 100.0, "analog_order": 4},
                       [{}, {}, {"dac_glitch_duration_s": 30 / 24000},
                        {"dac_glitch_duration_s": 50 / 24000}]),
}


def configs_of(structure, calibration="mixed"):
    shared, per_env = STRUCTURES[structure]
    envs = []
    for fields, more in zip(MIXED, per_env):
        fields = fields | more | shared
        if calibration == "identity":
            fields.pop("calibration_matrix", None)
        envs.append(dc.replace(ForceSensorConfig(), **fields))
    return envs


def env_states(values, n, nx, ticks):
    """Each environment's discrete state of an N-environment sensor, in the
    single sensor's order: [voltage, frame (ticks), gauge filter (nx), held,
    glitch ticks left, output stage (2)]."""
    voltage, frame, internal = (values.get_vector(g).value() for g in range(3))
    gauges, held, left, output = np.split(internal, np.cumsum([nx * n, n, n]))
    return [np.concatenate([voltage[i:i + 1], frame[i * ticks:(i + 1) * ticks],
                            gauges[i * nx:(i + 1) * nx], held[i:i + 1], left[i:i + 1],
                            output[2 * i:2 * i + 2]]) for i in range(n)]


def inputs(frame, env, ticks, rng, bad=None):
    """A wrench that differs per environment (env 2's clips the ADC), a
    tilted tip, and gauge noise; ``bad``: {(frame, env): kind} puts NaN in
    the wrench or the tip angle, or inf in Fy."""
    wrench = np.array([-20.0 + 15.0 * np.sin(0.05 * frame + env),
                       3.0 * np.cos(0.1 * frame + 2 * env), 0.4 * (env - 1.5)])
    wrench *= 10.0 if env == 2 else 1.0
    tip = np.array([0.45, 0.0, 0.02 * np.sin(0.03 * frame + env), 0.0, 0.0, 0.0])
    kind = (bad or {}).get((frame, env))
    if kind == "nan_wrench":
        wrench[0] = np.nan
    elif kind == "inf_fy":
        wrench[1] = np.inf
    elif kind == "nan_phi":
        tip[2] = np.nan
    return wrench, tip, rng.normal(size=3 * ticks)


def run_side_by_side(configs, frames, t_start, bad=None):
    """Drives one N-environment sensor and N single sensors with the same
    inputs frame by frame; returns each environment's states over the run,
    [env][frame], from both."""
    n = len(configs)
    ensemble, singles = ForceSensor(configs), [ForceSensor(c) for c in configs]
    nx, ticks = ensemble._nx, ensemble.ticks_per_frame
    contexts = [s.CreateDefaultContext() for s in [ensemble] + singles]
    rng = np.random.default_rng(11)
    together, alone = [[] for _ in range(n)], [[] for _ in range(n)]
    for frame in range(frames):
        per_env = [inputs(frame, env, ticks, rng, bad) for env in range(n)]
        for i, (system, context) in enumerate(zip([ensemble] + singles, contexts)):
            chosen = per_env if i == 0 else [per_env[i - 1]]
            context.SetTime(t_start + frame * 1e-3)
            for port, k in (("wrench", 0), ("tip_state", 1), ("gauge_noise", 2)):
                system.GetInputPort(port).FixValue(
                    context, np.concatenate([values[k] for values in chosen]))
            new = system.EvalUniquePeriodicDiscreteUpdate(context)
            for group in range(new.num_groups()):
                context.SetDiscreteState(group, new.get_vector(group).value().copy())
            if i == 0:
                for env, state in enumerate(env_states(new, n, nx, ticks)):
                    together[env].append(state)
                # The outputs are the state's, env-major.
                assert np.array_equal(system.GetOutputPort("voltage").Eval(context),
                                      new.get_vector(0).value(), equal_nan=True)
            else:
                alone[i - 1].append(np.concatenate(
                    [new.get_vector(g).value() for g in range(new.num_groups())]))
    return np.array(together), np.array(alone)


@pytest.mark.parametrize("calibration", ["mixed", "identity"])
@pytest.mark.parametrize("structure", list(STRUCTURES))
def test_each_environment_is_its_single_sensor_bit_for_bit(structure, calibration):
    together, alone = run_side_by_side(configs_of(structure, calibration), 300, 0.0137)
    assert np.array_equal(together.view(np.int64), alone.view(np.int64))
    # The environments do differ (else the comparison would prove little).
    assert all(not np.array_equal(together[0], together[i]) for i in range(1, 4))


@pytest.mark.filterwarnings("ignore:invalid value encountered:RuntimeWarning")
def test_a_diverged_environment_leaves_the_others_bit_for_bit():
    bad = {(40, 1): "nan_wrench", (70, 3): "nan_phi", (90, 2): "inf_fy"}
    together, alone = run_side_by_side(configs_of("480Hz"), 150, 0.0, bad)
    assert np.array_equal(together[0].view(np.int64), alone[0].view(np.int64))
    # A diverged environment's numbers and NaN are where its single run has
    # them (a NaN's sign bit may differ: it depends on the array's layout).
    for env in (1, 2, 3):
        assert np.array_equal(together[env], alone[env], equal_nan=True)
        assert np.isnan(together[env][-1]).any()
    assert np.array_equal(together[1][:40].view(np.int64), alone[1][:40].view(np.int64))


def seed_as_single_runs(diagram, context, seeds):
    """Seeds each noise source as drake_contact.diagram.SeedNoise seeds the
    single run's source of that name (``@i`` is environment i's) with that
    environment's seed."""
    for system in leaf_systems(diagram):
        if isinstance(system, RandomSource):
            name, _, env = system.get_name().partition("@")
            key = zlib.crc32((_NOISE_KEY_PREFIX + name).encode())
            system.SetRandomContext(system.GetMyMutableContextFromRoot(context), RandomGenerator(
                (seeds[int(env or 0)] * 1_000_003 + key) % 2**31))


def simulate_sensor(configs, seeds, wrenches, tips):
    builder = DiagramBuilder()
    sensor = AddForceSensor(builder, configs)
    for port, value in (("wrench", wrenches), ("tip_state", tips)):
        source = builder.AddSystem(ConstantVectorSource(np.concatenate(value)))
        builder.Connect(source.get_output_port(), sensor.GetInputPort(port))
    logs = [LogVectorOutput(sensor.GetOutputPort(port), builder, 1e-3)
            for port in ("voltage", "voltage_frame")]
    diagram = builder.Build()
    simulator = Simulator(diagram)
    seed_as_single_runs(diagram, simulator.get_mutable_context(), seeds)
    simulator.AdvanceTo(0.3)
    names = sorted(s.get_name() for s in leaf_systems(diagram) if isinstance(s, RandomSource))
    return names, [log.FindLog(simulator.get_context()).data() for log in logs]


def test_each_environment_has_its_single_runs_noise():
    configs = [ForceSensorConfig(), ForceSensorConfig(noise_scale=0.5, offset_n=1.0),
               ForceSensorConfig(noise_std=[2.0, 0.1, 0.01])]
    seeds = [7, 1234, 7]  # env 2 draws env 0's samples, at another noise level
    wrenches = [np.array([-20.0, 1.0, 0.1]), np.array([-5.0, 0.0, 0.0]),
                np.array([-40.0, -2.0, 0.3])]
    tips = [np.array([0.45, 0.0, phi, 0.0, 0.0, 0.0]) for phi in (0.0, 0.01, -0.02)]
    names, (voltage, frame) = simulate_sensor(configs, seeds, wrenches, tips)
    assert names == [f"force_sensor_gauge_noise@{i}" for i in range(3)]
    ticks = len(frame) // 3
    for env, config in enumerate(configs):
        name, (voltage_1, frame_1) = simulate_sensor(
            config, [seeds[env]], [wrenches[env]], [tips[env]])
        assert name == ["force_sensor_gauge_noise"]  # a single run's name
        assert np.array_equal(voltage[env], voltage_1[0])
        assert np.array_equal(frame[env * ticks:(env + 1) * ticks], frame_1)
    assert not np.array_equal(voltage[0], voltage[2])


def test_ports_are_env_major_and_one_environment_is_the_single_sensor():
    one, three = ForceSensor(ForceSensorConfig()), ForceSensor([ForceSensorConfig()] * 3)
    for port, size in (("wrench", 3), ("tip_state", 6), ("gauge_noise", 36)):
        assert one.GetInputPort(port).size() == size
        assert three.GetInputPort(port).size() == 3 * size
    for port, size in (("voltage", 1), ("voltage_frame", 12)):
        assert one.GetOutputPort(port).size() == size
        assert three.GetOutputPort(port).size() == 3 * size
    assert one.num_envs == 1 and three.num_envs == 3
    single = one.CreateDefaultContext().get_discrete_state()
    together = three.CreateDefaultContext().get_discrete_state()
    assert all(np.array_equal(state, env_states(single, 1, 9, 12)[0])
               for state in env_states(together, 3, 9, 12))


@pytest.mark.parametrize("field,value", [("analog_order", 4), ("fine_rate_hz", 24000.0),
                                         ("adc_rate_hz", 2000.0)])
def test_environments_of_another_structure_are_refused(field, value):
    other = dc.replace(ForceSensorConfig(), **{field: value})
    with pytest.raises(ScenarioError, match=rf"force_sensor\.{field} differs between environments"):
        ForceSensor([ForceSensorConfig(), ForceSensorConfig(), other])


def test_a_bad_setting_names_its_environment():
    with pytest.raises(ScenarioError, match=r"force_sensor\[1\]\.adc_bits = 1 is out of range"):
        ForceSensor([ForceSensorConfig(), ForceSensorConfig(adc_bits=1)])
    with pytest.raises(ScenarioError, match="no environment"):
        ForceSensor([])
