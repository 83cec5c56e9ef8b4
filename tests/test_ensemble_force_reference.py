"""ForceReference over the arm axis: one system for N environments, each
environment bit for bit the single-environment system with its config, fed
the same contact_info, through approach, contact in the past and (an input
no diagram gives, but the law defines) contact in the future; square waves
of different lengths, sines, holds and probes."""

import dataclasses as dc

import numpy as np
import pytest

from drake_contact.control.force_reference import (
    ForceReference, ForceReferenceConfig, ForceSchedule)
from drake_contact.errors import ScenarioError
from drake_contact.plant.arm import CONTROL_PERIOD, ApplySampledUpdates

SAMPLES = 600

#: Numbers differ per environment; the structure (the probe off) does not.
MIXED = [
    ForceReferenceConfig(levels=[20.0, 10.0], half_period_s=0.1),
    ForceReferenceConfig(levels=[15.0], sine_amplitude_n=4.0, sine_frequency_hz=7.0),
    ForceReferenceConfig(levels=[5.0, 12.0, 0.0], half_period_s=0.07, hold_s=0.12,
                         sine_amplitude_n=-2.0, sine_frequency_hz=3.0),
    ForceReferenceConfig(levels=[0.0, 8.0], half_period_s=0.05, hold_s=0.03),
    ForceReferenceConfig(levels=[20.0]),
]

PROBED = [
    ForceReferenceConfig(levels=[20.0], probe_amplitude_n=3.0, probe_frequencies_hz=[1.7, 9.0]),
    ForceReferenceConfig(levels=[10.0, 14.0], half_period_s=0.09, probe_amplitude_n=1.0,
                         probe_frequencies_hz=[4.0, 23.0]),
    ForceReferenceConfig(levels=[12.0], hold_s=0.1, sine_amplitude_n=1.5, probe_amplitude_n=0.5,
                         probe_frequencies_hz=[2.5, 0.7]),
]


def _contact_times(k, count):
    """Each environment's time of first contact at sample k: never; from
    the first sample; switching at 0.1 s; at 0.25 s; and one whose contact
    time lies ahead of the sample until 0.3 s (since < 0)."""
    t = k * CONTROL_PERIOD
    times = [-1.0, 0.0, 0.1 if t >= 0.1 else -1.0, 0.25 if t >= 0.25 else -1.0,
             0.3 if t >= 0.15 else -1.0]
    return times[:count]


def _contact_info(times):
    return np.concatenate([[t, 0.45 + 0.01 * i, 1e-3 * i, -2e-3 * i]
                           for i, t in enumerate(times)])


def _run_side_by_side(configs):
    ensemble = ForceReference(configs)
    singles = [ForceReference(c) for c in configs]
    systems = [ensemble] + singles
    contexts = [s.CreateDefaultContext() for s in systems]
    count = len(configs)
    assert ensemble.GetInputPort("contact_info").size() == 4 * count
    assert ensemble.GetOutputPort("force_desired").size() == count
    distinct = set()
    for k in range(1, SAMPLES + 1):
        times = _contact_times(k, count)
        info = _contact_info(times)
        for i, (system, context) in enumerate(zip(systems, contexts)):
            context.SetTime(k * CONTROL_PERIOD)
            value = info if i == 0 else info[4 * (i - 1):4 * i]
            system.GetInputPort("contact_info").FixValue(context, value)
            ApplySampledUpdates(system, context)
        together = ensemble.GetOutputPort("force_desired").Eval(contexts[0])
        for i in range(count):
            alone = singles[i].GetOutputPort("force_desired").Eval(contexts[i + 1])
            np.testing.assert_array_equal(together[i:i + 1], alone, err_msg=f"sample {k}, env {i}")
        distinct.update(together.tolist())
    return distinct


def test_mixed_configs_equal_their_single_systems_bit_for_bit():
    distinct = _run_side_by_side(MIXED)
    assert len(distinct) > 50  # levels, sines and holds all moved


def test_probed_configs_equal_their_single_systems_bit_for_bit():
    distinct = _run_side_by_side(PROBED)
    assert len(distinct) > 50


def test_schedule_at_equals_each_config_at():
    """The schedule's (N,) evaluation at once equals each config's own,
    negative times (before contact) included."""
    schedule = ForceSchedule(MIXED)
    rng = np.random.default_rng(4)
    for _ in range(200):
        since = np.where(rng.random(len(MIXED)) < 0.2, -rng.random(len(MIXED)),
                         rng.uniform(0.0, 1.0, len(MIXED)))
        expected = [c.at(s) for c, s in zip(MIXED, since)]
        np.testing.assert_array_equal(schedule.at(since), expected)


def test_one_config_keeps_todays_ports_and_state():
    system = ForceReference(ForceReferenceConfig(levels=[20.0, 10.0]))
    assert system.GetInputPort("contact_info").size() == 4
    assert system.GetOutputPort("force_desired").size() == 1
    context = system.CreateDefaultContext()
    assert context.num_discrete_state_groups() == 1
    np.testing.assert_array_equal(context.get_discrete_state(0).value(), [20.0])


@pytest.mark.parametrize("change,field", [
    ({"probe_amplitude_n": 2.0}, "force_reference.probe_amplitude_n"),
])
def test_configs_that_differ_in_structure_are_refused(change, field):
    with pytest.raises(ScenarioError, match=field.replace(".", r"\.")):
        ForceReference([ForceReferenceConfig(), dc.replace(ForceReferenceConfig(), **change)])


def test_probes_with_different_frequency_counts_are_refused():
    one = ForceReferenceConfig(probe_amplitude_n=1.0, probe_frequencies_hz=[1.7])
    two = dc.replace(one, probe_frequencies_hz=[1.7, 3.0])
    with pytest.raises(ScenarioError, match=r"force_reference\.probe_frequencies_hz"):
        ForceReference([one, two])


def test_each_config_is_validated_with_its_environment_named():
    bad = dc.replace(ForceReferenceConfig(), half_period_s=-1.0)
    with pytest.raises(ScenarioError, match=r"force_reference\[1\]\.half_period_s"):
        ForceReference([ForceReferenceConfig(), bad])
