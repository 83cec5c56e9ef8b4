"""The identifiers over the arm axis: one RlsIdentifier or NnIdentifier (and
one AddIdentifiers sub-diagram) serving N environments equals, bit for bit,
N one-environment ones on the same inputs, through the contact switch."""

import dataclasses as dc
import sys

import textwrap

import numpy as np
import pytest
from pydrake.systems.framework import DiagramBuilder

from drake_contact import load_scenario
from drake_contact.errors import ScenarioError
from drake_contact.identification.identifiers import AddIdentifiers, IdentifierConfig
from drake_contact.identification.nn_identifier import NnIdentifier, NnIdentifierConfig
from drake_contact.identification.rls_identifier import RlsConfig, RlsIdentifier
from drake_contact.plant.arm import CONTROL_PERIOD
from drake_contact.plugins import MakeIdentifier
from test_plugins import IDENTIFIERS

SAMPLES = 300
SIZES = {"force": 1, "tip_pose": 3, "tip_velocity": 3, "tip_acceleration": 3}


def _signals(count, samples, seed):
    """Per sample, per environment, each input: a wall's response with
    noise; environment i's switch at sample 20 + (samples - 60) i // N (before it,
    contact_info's first entry is -1)."""
    rng = np.random.default_rng(seed)
    t = np.arange(samples) * CONTROL_PERIOD
    out = []
    for i in range(count):
        switch = 20 + (samples - 60) * i // count
        x = 0.45 + 2e-3 * (1 - np.exp(-np.maximum(t - switch * CONTROL_PERIOD, 0) / 0.03))
        x = x + 1e-4 * np.sin(2 * np.pi * (3 + i) * t) + rng.normal(0, 1e-6, samples)
        v, a = np.gradient(x, CONTROL_PERIOD), np.gradient(np.gradient(x, CONTROL_PERIOD),
                                                           CONTROL_PERIOD)
        f = 5.0 + (7000.0 + 3000 * i) * (x - x[switch]) + rng.normal(0, 0.3, samples)
        env = []
        for k in range(samples):
            contact = [switch * CONTROL_PERIOD, x[switch], 0.01, 0.02] if k >= switch \
                else [-1.0, 0.0, 0.0, 0.0]
            env.append({"force": [f[k]], "tip_pose": [x[k], 0.1, 0.2],
                        "tip_velocity": [v[k], 0.3, 0.4], "tip_acceleration": [a[k], 0.5, 0.6],
                        "contact_info": contact})
        out.append(env)
    return out


def _step(system, context, values):
    """Fixes ``values`` {port: vector} and takes one sampled discrete step."""
    for name, value in values.items():
        system.GetInputPort(name).FixValue(context, value)
    context.SetDiscreteState(system.EvalUniquePeriodicDiscreteUpdate(context))


def _compare(make_one, make_many, count, samples=SAMPLES, seed=0):
    """Steps the N-environment system and N one-environment systems on the
    same signals; returns the number of mismatched values (outputs and
    state, every sample)."""
    signals = _signals(count, samples, seed)
    many = make_many()
    many_context = many.CreateDefaultContext()
    ones = [make_one(i) for i in range(count)]
    one_contexts = [s.CreateDefaultContext() for s in ones]
    outputs = [many.get_output_port(p).get_name() for p in range(many.num_output_ports())]
    mismatches = 0
    for k in range(samples):
        _step(many, many_context, {name: np.concatenate([signals[i][k][name]
                                                         for i in range(count)])
                                   for name in signals[0][k]})
        for i, (one, context) in enumerate(zip(ones, one_contexts)):
            _step(one, context, signals[i][k])
            for name in outputs:
                mine = one.GetOutputPort(name).Eval(context)
                size = len(mine)
                theirs = many.GetOutputPort(name).Eval(many_context)[size * i:size * (i + 1)]
                mismatches += np.count_nonzero(mine != theirs)
            for g in range(context.num_discrete_state_groups()):
                mine = context.get_discrete_state(g).value()
                size = len(mine)
                theirs = many_context.get_discrete_state(g).value()[size * i:size * (i + 1)]
                mismatches += np.count_nonzero(mine != theirs)
    # The run reached training in every environment.
    impedance = many.GetOutputPort("impedance").Eval(many_context).reshape(count, 3)
    initial = many.GetOutputPort("impedance").Eval(many.CreateDefaultContext()).reshape(count, 3)
    assert np.all(impedance[:, 2] != initial[:, 2])
    return mismatches


def _rls_configs(count, **structure):
    return [RlsConfig(theta0=[0.0, 0.0, 1e5 * (1 + i)], forgetting_factor=1.0 - 1e-3 * (i % 3),
                      p0=[1e2, 1e6, 1e12 * (1 + i), 1e4],
                      stiffness_drift=(1e-9 * (1 + i)) if structure.get("drift") else 0.0,
                      change_threshold_n=(0.5 + 0.1 * i) if structure.get("detect") else 0.0,
                      change_holdoff_s=0.05 + 0.01 * i, change_time_constant_s=0.01 + 0.005 * i,
                      force_offset=structure.get("force_offset", False))
            for i in range(count)]


@pytest.mark.parametrize("count", [1, 2, 3, 16])
@pytest.mark.parametrize("structure", [{}, {"force_offset": True},
                                       {"force_offset": True, "drift": True, "detect": True}])
def test_rls_over_n_environments_is_each_alone_bit_for_bit(count, structure):
    configs = _rls_configs(count, **structure)
    samples = 120 if count == 16 else SAMPLES
    assert _compare(lambda i: RlsIdentifier(configs[i]), lambda: RlsIdentifier(configs),
                    count, samples) == 0


def _nn_configs(count, **structure):
    return [dc.replace(NnIdentifierConfig(**structure), learning_rate=1e-4 * (1 + 0.2 * i),
                       force_offset=bool(i % 2), input_scale=[1000.0 * (1 + 0.1 * i), 100.0, 1.0],
                       probe=[2e-3 / (1 + i), 1e-2, 1.0], output_scale_n=20.0 + i,
                       initial_weight_std=0.3 + 0.05 * i,
                       scale_floor=[1e-6 * (1 + i), 1e-4, 1e-2, 0.1])
            for i in range(count)]


NN_STRUCTURES = [{}, {"output_layer": "appendix_e"},
                 {"normalization": "running", "learning_rate": 0.05},
                 {"normalization": "running", "readout": "operating_point"},
                 {"normalization": "running", "readout": "operating_point",
                  "readout_time_constant_s": 0.5},
                 {"normalization": "running", "readout": "jacobian"}]


@pytest.mark.parametrize("count", [1, 2, 3, 16])
@pytest.mark.parametrize("structure", NN_STRUCTURES)
def test_nn_over_n_environments_is_each_alone_bit_for_bit(count, structure):
    """Mixed rates, scales, probes, anchors and seeds: each environment's
    weights come from its own seed, as alone."""
    configs = _nn_configs(count, **structure)
    seeds = [7 + 3 * i for i in range(count)]
    samples = 120 if count == 16 else SAMPLES
    assert _compare(lambda i: NnIdentifier(configs[i], seeds[i]),
                    lambda: NnIdentifier(configs, seeds), count, samples) == 0


@pytest.mark.parametrize("system, field", [
    (lambda: RlsIdentifier([RlsConfig(), RlsConfig(force_offset=True)]), "force_offset"),
    (lambda: RlsIdentifier([RlsConfig(), RlsConfig(change_threshold_n=1.0)]),
     "change_threshold_n"),
    (lambda: NnIdentifier([NnIdentifierConfig(), NnIdentifierConfig(output_layer="appendix_e")],
                          [0, 1]), "output_layer"),
    (lambda: NnIdentifier([NnIdentifierConfig(normalization="running"),
                           NnIdentifierConfig()], [0, 1]), "normalization")])
def test_environments_must_share_a_structure(system, field):
    with pytest.raises(ScenarioError, match=f"{field}.*share a structure") as error:
        system()
    assert "\n" not in str(error.value)


def test_make_identifier_checks_ports_at_n_times_their_size():
    rls = MakeIdentifier("rls", [{}, {"forgetting_factor": 0.99}, {}], count=3)
    assert rls.GetInputPort("tip_pose").size() == 9
    assert rls.GetOutputPort("impedance").size() == 9
    nn = MakeIdentifier("nn", [{"seed": 1}, {"seed": 2}], count=2)
    assert nn.GetOutputPort("force_estimate").size() == 2
    with pytest.raises(ScenarioError, match="must be a vector of size 2"):
        MakeIdentifier("rls", {}, count=2)


VARIANTS = [[], ["environment.stiffness=20000"],
            ["environment.damping=300", "force_sensor.analog_cutoff_hz=100"]]


def _identify_scenarios():
    """identify_styrofoam three ways: walls, a sensor chain (the matched
    filters), seeds, a forgetting factor and a learning rate."""
    scenarios = [load_scenario("identify_styrofoam", overrides, seed=seed)
                 for overrides, seed in zip(VARIANTS, (3, 4, 5))]
    scenarios[1].identifiers[0].rls.forgetting_factor = 0.999
    scenarios[2].identifiers[4].nn.learning_rate = 2e-4
    return scenarios


def _mismatches_of_sub_diagrams(scenarios, samples=SAMPLES):
    """Drives AddIdentifiers over ``scenarios`` and one per scenario on the
    same inputs; returns (mismatched output values, values compared, the
    N-environment sub-diagram and its context)."""
    count = len(scenarios)

    def built(scenario):
        system = AddIdentifiers(DiagramBuilder(), scenario)
        return system, system.CreateDefaultContext()

    many, many_context = built(scenarios)
    ones = [built(s) for s in scenarios]
    inputs = [many.get_input_port(p).get_name() for p in range(many.num_input_ports())]
    outputs = [many.get_output_port(p).get_name() for p in range(many.num_output_ports())]
    signals = _signals(count, samples, seed=2)
    mismatches = compared = 0
    for k in range(samples):
        values = []
        for i, (one, context) in enumerate(ones):
            value = {name: np.resize(signals[i][k].get(name.replace("_raw", ""), [0.0]),
                                     one.GetInputPort(name).size()) for name in inputs}
            for name, v in value.items():
                one.GetInputPort(name).FixValue(context, v)
            values.append(value)
        for name in inputs:
            many.GetInputPort(name).FixValue(many_context,
                                             np.concatenate([v[name] for v in values]))
        for i, (one, context) in enumerate(ones):
            for name in outputs:
                mine = one.GetOutputPort(name).Eval(context)
                size = len(mine)
                theirs = many.GetOutputPort(name).Eval(many_context)[size * i:size * (i + 1)]
                mismatches += np.count_nonzero(mine != theirs)
                compared += size
        time = (k + 1) * CONTROL_PERIOD
        for system, context in [(many, many_context)] + ones:
            context.SetDiscreteState(system.EvalUniquePeriodicDiscreteUpdate(context))
            context.SetTime(time)
    assert compared == samples * count * sum(
        ones[0][0].GetOutputPort(n).size() for n in outputs)
    return mismatches, many, many_context


def test_add_identifiers_over_three_scenarios_is_three_alone_bit_for_bit():
    """identify_styrofoam with other walls, a forgetting factor, another
    sensor chain (the matched filters) and seeds: one sub-diagram for the
    three, driven like three single ones, equals them at every sample."""
    scenarios = _identify_scenarios()
    mismatches, many, context = _mismatches_of_sub_diagrams(scenarios)
    assert mismatches == 0
    sizes = {many.get_input_port(p).get_name(): many.get_input_port(p).size()
             for p in range(many.num_input_ports())}
    assert {"contact_info": 12, "force": 3, "force_raw": 3, "tip_pose": 9}.items() <= sizes.items()
    # The estimates moved after the switch (the comparison is not vacuous).
    estimate = many.GetOutputPort("impedance_rls").Eval(context).reshape(len(scenarios), 3)
    assert np.all(estimate[:, 2] != 2.0e5)


# The plug-ins' tests' ratio identifier: one environment, no ``ensemble``.
PLUGIN = "from pydrake.systems.framework import LeafSystem\n" + textwrap.dedent(
    IDENTIFIERS["ratio"])


@pytest.fixture
def ratio_plugin(tmp_path):
    """A one-environment identifier plug-in (no ``ensemble``), installed as
    pip would (a .dist-info with entry_points.txt on the path)."""
    site = tmp_path / "site"
    (site / "ratio_plugin").mkdir(parents=True)
    (site / "ratio_plugin" / "__init__.py").write_text(PLUGIN)
    info = site / "ratio_plugin-1.0.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: ratio_plugin\nVersion: 1.0\n")
    (info / "entry_points.txt").write_text(
        "[drake_contact.identifiers]\nratio = ratio_plugin:make\n")
    sys.path.insert(0, str(site))
    yield
    sys.path.remove(str(site))
    sys.modules.pop("ratio_plugin", None)


def test_a_plugin_without_ensemble_runs_as_copies_behind_glue(ratio_plugin):
    """N copies of a one-environment plug-in behind a Demultiplexer per
    input and a Multiplexer per output: the same env-major ports, each
    environment what its copy computes alone."""
    scenarios = _identify_scenarios()[:2]
    for i, scenario in enumerate(scenarios):
        scenario.identifiers = [IdentifierConfig(name="ratio", kind="ratio",
                                                 options={"floor": 1e-4 * (1 + i)}),
                                scenario.identifiers[0]]
    mismatches, many, context = _mismatches_of_sub_diagrams(scenarios)
    assert mismatches == 0
    inner = {s.get_name(): s for s in many.GetSystems()}
    copies = {s.get_name() for s in inner["identifier_ratio"].GetSystems()}
    assert {"identifier_ratio_0", "identifier_ratio_1"} <= copies
    assert many.GetOutputPort("impedance_ratio").size() == 6
    assert np.all(many.GetOutputPort("impedance_ratio").Eval(context)[2::3] != 0.0)


def test_add_identifiers_systems_one_per_entry_and_banks_of_filters():
    many = AddIdentifiers(DiagramBuilder(), _identify_scenarios())
    one = AddIdentifiers(DiagramBuilder(), _identify_scenarios()[0])
    names = sorted(s.get_name() for s in many.GetSystems())
    assert names == sorted(s.get_name() for s in one.GetSystems())
    inner = {s.get_name(): s for s in many.GetSystems()}
    assert type(inner["identifier_rls"]).__name__ == "RlsIdentifier"
    assert type(inner["matched_pose"]).__name__ == "LinearSystemBank"
    assert many.GetInputPort("tip_pose").size() == 9


def test_add_identifiers_refuses_environments_with_other_identifiers():
    scenarios = _identify_scenarios()
    scenarios[2].identifiers[1].signals = "raw"
    with pytest.raises(ScenarioError, match="environment 2.*share a structure"):
        AddIdentifiers(DiagramBuilder(), scenarios)
