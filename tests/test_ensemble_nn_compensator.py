"""The NN compensator over the arm axis: one system for N environments,
each environment bit for bit the single-environment system with its config
(learning rates, ranges, offsets, initial weights, robust gains, targets),
fed the same inputs, with environments entering and leaving contact at
different samples; outputs and every state group compared each sample."""

import dataclasses as dc
import functools

import numpy as np
import pytest
import yaml

from drake_contact.control.controller_model import ArmModel, ControllerModelConfig
from drake_contact.control.nn_compensator import (
    CompensatorNetwork, NnCompensator, NnCompensatorConfig, load_initial_weights)
from drake_contact.errors import ScenarioError
from drake_contact.plant.arm import CONTROL_PERIOD, THESIS_Q0, ApplySampledUpdates

SAMPLES = 300
COUNT = 4


@pytest.fixture(scope="module")
def other_weights(tmp_path_factory):
    """A second initial-weights file: Appendix E's, perturbed."""
    W, V = load_initial_weights(NnCompensatorConfig().initial_weights)
    rng = np.random.default_rng(9)
    path = tmp_path_factory.mktemp("nn") / "weights.yaml"
    path.write_text(yaml.safe_dump({
        "input_to_hidden": (W + rng.normal(0, 0.02, W.shape)).tolist(),
        "hidden_to_output": (V + rng.normal(0, 0.02, V.shape)).tolist()}))
    return str(path)


def _mixed(base, other_weights):
    """COUNT configs of base's structure with different numbers."""
    configs = []
    for i in range(COUNT):
        change = {"learning_rate": base.learning_rate * (1.0 + 0.7 * i),
                  "output_half_ranges": [20.0 - 2 * i, 10.0 + i, 1.0 + 0.25 * i],
                  "input_offsets": [0.0, 0.01, 0.01 + 0.002 * i, 0.0, 0.01, 0.01, 0.0,
                                    0.1 * i, 0.0]}
        if i % 2:
            change["initial_weights"] = other_weights
        if base.leakage or base.e_modification or base.dead_zone_n:
            change.update(leakage=base.leakage * (1 + i), e_modification=base.e_modification * i,
                          dead_zone_n=base.dead_zone_n * (1 + i))
        if base.weight_bound:
            change["weight_bound"] = base.weight_bound * (1 + i)
        if base.reference_time_constant_s:
            change["reference_time_constant_s"] = base.reference_time_constant_s * (1 + i)
        configs.append(dc.replace(base, **change))
    return configs


STRUCTURES = {
    "thesis": NnCompensatorConfig(learning_rate=5e-3),
    "appendix_e": NnCompensatorConfig(learning_rate=5e-3, output_layer="appendix_e"),
    "fixed": NnCompensatorConfig(learning=False),
    # Every robust option at once; the rates large enough that the
    # projection bounds some steps and the dead zone holds some.
    "robust": NnCompensatorConfig(learning_rate=0.02, leakage=0.5, e_modification=0.1,
                                  dead_zone_n=0.6, normalized=True, weight_bound=0.05,
                                  reference_time_constant_s=0.02),
}

Y_DESIRED = [0.0, 1e-3, -2e-3, 5e-4]
PHI_DESIRED = [0.0, -1e-3, 0.0, 2e-3]


@functools.cache
def _model():
    return ArmModel(ControllerModelConfig())


@functools.cache
def _inputs(k):
    """Every environment's inputs at sample k: poses and torques that
    wander, J at a configuration that moves, forces around f_d, and modes:
    env 0 in contact from sample 40 on, env 1 always, env 2 in and out
    every 25 samples, env 3 never until sample 200."""
    t = k * CONTROL_PERIOD
    model = _model()
    rows = []
    for i in range(COUNT):
        q = np.array(THESIS_Q0) + 0.05 * np.sin(3.0 * t + i) * np.array([1.0, -1.0, 0.5])
        J = model.evaluate(q, np.zeros(3))[1]
        pose = np.array([0.456 + 0.001 * i, 1e-3 * np.sin(20 * t + i), -2e-3 * np.cos(15 * t)])
        tau = np.array([3.1 + i, -0.4 + 0.1 * np.sin(30 * t), 0.02 * i])
        f_d = 20.0 - 5.0 * i
        force = f_d + (0.5 if (k + i) % 7 == 0 else 4.0 * np.sin(11 * t + i))
        mode = [k >= 40, True, (k // 25) % 2 == 0, k >= 200][i]
        rows.append((pose, J.ravel(), tau, force, f_d, float(mode)))
    return rows


PORTS = ("tip_pose", "tip_jacobian", "hybrid_torque", "force", "force_desired", "mode")


def _fix(system, context, rows):
    for p, name in enumerate(PORTS):
        system.GetInputPort(name).FixValue(
            context, np.concatenate([np.atleast_1d(row[p]) for row in rows]))


def _state_parts(context, i, count):
    """Environment i's part of each state group: weights, previous pose
    (env-major), held [J^T n, n] (field-major), f_m."""
    weights, previous, held, reference = (context.get_discrete_state(g).value()
                                          for g in range(4))
    size = CompensatorNetwork.size
    return (weights[size * i:size * (i + 1)], previous[3 * i:3 * i + 3],
            np.concatenate([held[3 * i:3 * i + 3], held[3 * count + 3 * i:3 * count + 3 * i + 3]]),
            reference[i:i + 1])


@pytest.mark.parametrize("structure", list(STRUCTURES))
def test_mixed_configs_equal_their_single_systems_bit_for_bit(structure, other_weights):
    configs = _mixed(STRUCTURES[structure], other_weights)
    ensemble = NnCompensator(configs, Y_DESIRED, PHI_DESIRED)
    singles = [NnCompensator(c, y, phi) for c, y, phi in zip(configs, Y_DESIRED, PHI_DESIRED)]
    contexts = [s.CreateDefaultContext() for s in [ensemble] + singles]
    together = contexts[0]
    assert ensemble.GetOutputPort("joint_torque").size() == 3 * COUNT
    learned = np.zeros(COUNT, dtype=bool)
    initial = CompensatorNetwork(configs).w0
    for k in range(1, SAMPLES + 1):
        rows = _inputs(k)
        _fix(ensemble, together, rows)
        for i, (system, context) in enumerate(zip(singles, contexts[1:])):
            _fix(system, context, rows[i:i + 1])
        # Between samples (a plant step finer than 1 ms) the held values;
        # at the sample, this sample's.
        for t in ((k - 0.5) * CONTROL_PERIOD, k * CONTROL_PERIOD):
            for context in contexts:
                context.SetTime(t)
            torque = ensemble.GetOutputPort("joint_torque").Eval(together)
            n = ensemble.GetOutputPort("nn_output").Eval(together)
            for i, (system, context) in enumerate(zip(singles, contexts[1:])):
                where = f"{structure}: sample {k}, env {i}, t = {t}"
                np.testing.assert_array_equal(
                    torque[3 * i:3 * i + 3], system.GetOutputPort("joint_torque").Eval(context),
                    err_msg=where)
                np.testing.assert_array_equal(
                    n[3 * i:3 * i + 3], system.GetOutputPort("nn_output").Eval(context),
                    err_msg=where)
        for system, context in zip([ensemble] + singles, contexts):
            ApplySampledUpdates(system, context)
        for i, context in enumerate(contexts[1:]):
            law = singles[i].GetSubsystemByName("law")
            alone = _state_parts(law.GetMyContextFromRoot(context), 0, 1)
            both = _state_parts(ensemble.GetSubsystemByName("law").GetMyContextFromRoot(together),
                                i, COUNT)
            for part, (a, b) in enumerate(zip(both, alone)):
                np.testing.assert_array_equal(a, b, err_msg=f"{structure}: sample {k}, env {i}, "
                                                            f"state group {part}")
            learned[i] |= not np.array_equal(alone[0], initial[i])
    assert learned.all() == STRUCTURES[structure].learning


def test_robust_case_holds_and_bounds_some_steps(other_weights):
    """The robust structure above reaches its branches: the dead zone holds
    the weights at some sample in contact, the projection clips others."""
    configs = _mixed(STRUCTURES["robust"], other_weights)
    net = CompensatorNetwork(configs)
    weights = net.w0.copy()
    held = clipped = 0
    for k in range(1, 120):
        rows = _inputs(k)
        inputs = np.array([np.concatenate([r[0], r[0], r[2]]) for r in rows])
        error = np.array([[r[4] - r[3], y - r[0][1], phi - r[0][2]]
                          for r, y, phi in zip(rows, Y_DESIRED, PHI_DESIRED)])
        new, _ = net.train(weights, inputs, error)
        held += np.count_nonzero((new == weights).all(axis=1))
        bound = np.array([c.weight_bound for c in configs])
        clipped += np.count_nonzero(np.isclose(np.linalg.norm(new - net.w0, axis=1), bound,
                                               rtol=1e-12))
        weights = new
    assert held > 0 and clipped > 0


def test_one_config_keeps_todays_ports_and_state():
    system = NnCompensator(NnCompensatorConfig())
    sizes = {name: system.GetInputPort(name).size() for name in PORTS}
    assert sizes == {"tip_pose": 3, "tip_jacobian": 9, "hybrid_torque": 3, "force": 1,
                     "force_desired": 1, "mode": 1}
    assert system.GetOutputPort("joint_torque").size() == 3
    assert system.GetOutputPort("nn_output").size() == 3
    law = system.GetSubsystemByName("law")
    context = law.CreateDefaultContext()
    assert [context.get_discrete_state(g).size() for g in range(4)] == [159, 3, 6, 1]


@pytest.mark.parametrize("change,field", [
    ({"output_layer": "appendix_e"}, "controller.nn.output_layer"),
    ({"learning": False}, "controller.nn.learning"),
    ({"learning_rate": 0.0}, "controller.nn.learning_rate"),
    ({"leakage": 0.5}, "controller.nn.leakage"),
    ({"normalized": True}, "controller.nn.normalized"),
    ({"reference_time_constant_s": 0.05}, "controller.nn.reference_time_constant_s"),
])
def test_configs_that_differ_in_structure_are_refused(change, field):
    with pytest.raises(ScenarioError, match=field.replace(".", r"\.") + ":"):
        NnCompensator([NnCompensatorConfig(), dc.replace(NnCompensatorConfig(), **change)])


def test_robust_configs_that_differ_in_an_option_switched_on_are_refused():
    robust = NnCompensatorConfig(leakage=0.5)
    with pytest.raises(ScenarioError, match=r"controller\.nn\.weight_bound:"):
        NnCompensator([robust, dc.replace(robust, weight_bound=0.1)])


def test_each_config_is_validated_with_its_environment_named():
    bad = dc.replace(NnCompensatorConfig(), learning_rate=2.0)
    with pytest.raises(ScenarioError, match=r"controller\.nn\[1\]\.learning_rate"):
        NnCompensator([NnCompensatorConfig(), bad])
