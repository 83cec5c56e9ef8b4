"""Random ``--set key=value`` overrides against the scenario checks.

Every override a user can type is either accepted, and the scenario then
builds and runs (its first 1 ms control step logs finite signals), or
refused with a ScenarioError: one line naming the field, which the command
line prints with exit status 2. Anything else (another exception, a
message of several lines, an accepted value that yields NaN) would reach
the user as a traceback or a broken run.

The keys are every leaf field of :class:`Scenario`, found by walking its
dataclasses (a new field is fuzzed without touching this file), plus the
baselines' ``controller.options`` and a few unknown keys.
"""

import dataclasses as dc
import json
import math
import re
import typing

import numpy as np
import pytest
from hypothesis import event, example, given, settings
from hypothesis import strategies as st
from pydrake.systems.analysis import Simulator

from drake_contact.scoring.metrics import compute_metrics
from drake_contact.simulation import MakeRunDiagram, check_logs_fit
from drake_contact.control.baselines import AdmittanceConfig, ImpedanceConfig, ParallelForceConfig
from drake_contact.control.hybrid_controller import CONTACT_LAWS as HYBRID_LAWS
from drake_contact.control.nn_compensator import OUTPUT_LAYERS
from drake_contact.diagram import SeedNoise
from drake_contact.errors import ScenarioError
from drake_contact.identification.identifiers import SIGNALS
from drake_contact.plant.arm import CONTROL_PERIOD
from drake_contact.plant.compliant_wall import CONTACT_LAWS as WALL_LAWS
from drake_contact.plant.joint_physics import FRICTION_MODELS
from drake_contact.control.safety_supervisor import CONTACT_LOSS_REACTIONS
from drake_contact.faults import FAULT_KINDS, START_FROM
from drake_contact.plugins import installed_controllers, installed_identifiers
from drake_contact.scenario import Scenario, dump_scenario, load_scenario
from drake_contact.sensing.dsp import ANTI_ALIASING_MODES

from test_cli import drake_contact

#: Scenarios the overrides apply to: each controller family, identifiers,
#: the decoupled law fed by one, and scenario text with no controller
#: section. ``controller.name=...`` overrides reach the baselines and plug-ins.
BASES = ("push_constant", "nn_styrofoam", "identify_styrofoam", "adaptive_hybrid",
         "environment: {stiffness: 6.2e4}", "controller: {name: impedance}")


def _default(field):
    if field.default is not dc.MISSING:
        return field.default
    if field.default_factory is not dc.MISSING:
        return field.default_factory()
    return None


def leaf_fields(schema, prefix=""):
    """(dotted key, type hint, default) of every leaf of the dataclass
    ``schema``; a list of dataclasses (``identifiers``) is a leaf."""
    hints = typing.get_type_hints(schema)
    for field in dc.fields(schema):
        hint, key = hints[field.name], f"{prefix}{field.name}"
        if dc.is_dataclass(hint):
            yield from leaf_fields(hint, f"{key}.")
        else:
            yield key, hint, _default(field)


#: The scenario's fields: dotted key -> (type hint, default).
LEAVES = {key: (hint, default) for key, hint, default in leaf_fields(Scenario)}
#: The baselines' ``controller.options``, typed by their own dataclasses.
OPTION_LEAVES = {key: (hint, default) for schema in (ImpedanceConfig, AdmittanceConfig,
                                                     ParallelForceConfig)
                 for key, hint, default in leaf_fields(schema, "controller.options.")}
#: Keys that are no field: a typo, a new top-level key, a leaf used as a
#: section, a key in a list.
UNKNOWN_KEYS = ("environment.stifness", "bogus", "simulation.duration.x",
                "controller.hybrid.approach.nope", "identifiers.0.name", "arm..time_step",
                "controller.options.1x")

#: Every name a string field accepts somewhere, so that overrides also pass.
NAMES = sorted({*installed_controllers(), *installed_identifiers(), *WALL_LAWS, *HYBRID_LAWS,
                *FRICTION_MODELS, *ANTI_ALIASING_MODES, *OUTPUT_LAYERS, *SIGNALS,
                *FAULT_KINDS, *START_FROM, *CONTACT_LOSS_REACTIONS,
                *(d for h, d in LEAVES.values() if h is str)})

SPECIAL_FLOATS = (0.0, -0.0, -1.0, 1e300, -1e300, 1e12, -1e12, 1e-300, 5e-324, math.nan,
                  math.inf, -math.inf)
#: Finite numbers up to 1e300 in magnitude: near the largest double (1.8e308)
#: any product of two in-range values overflows (a gain times an error), which
#: no range check short of physical bounds on every gain could prevent.
HUGE = 1e300
SPECIAL_INTS = (0, -1, 1, 3, 2**31, 2**32, 2**63, 10**30)
JUNK_STRINGS = ("", " ", "soft", "a b", "line\nbreak", "é", "../x", "/", "-1", "nan", "True")
#: Values as typed, not all YAML: junk, and spellings a user might try.
RAW_VALUES = ("", " ", "[1, 2", "{a: }", "{a: 1", "]", ":", "- 1", "!!python/none", "&a *a",
              "*a", "nan", "NaN", ".nan", "inf", "-.inf", "1e3", "1,5", "0x10", "1_000", "~",
              "null", "yes", "[]", "{}", "[[1, 2], [3]]", "[.nan, 1, 1]", "'", "\"", "#",
              "a=b", "1 # comment", "[1, 2, 3, 4]", "{name: x}", "- a\n- b", "\t")


def to_yaml(value) -> str:
    """``value`` as the one-line YAML a user types after ``key=``."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if value is None:
        return "null"
    if isinstance(value, float):
        if math.isnan(value):
            return ".nan"
        if math.isinf(value):
            return ".inf" if value > 0 else "-.inf"
        return repr(value)
    if isinstance(value, int):
        return str(value)
    if isinstance(value, str):
        return json.dumps(value)  # a double-quoted YAML string
    if isinstance(value, list):
        return "[" + ", ".join(to_yaml(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{to_yaml(k)}: {to_yaml(v)}" for k, v in value.items()) + "}"
    raise TypeError(value)


def _numbers(default):
    """Floats near a default (mostly valid; three draws in five), the
    special ones and any up to HUGE."""
    near = st.sampled_from([default * f for f in (1.0, 0.5, 2.0, 10.0, -1.0)] if default
                           else [0.001, 1.0, 7.0])
    return st.one_of(near, near, near, st.sampled_from(SPECIAL_FLOATS), st.floats(-HUGE, HUGE))


def _ints(default):
    near = [default, default + 1, default * 2, default // 2] if default else [1, 2]
    return st.one_of(st.sampled_from(near), st.sampled_from(SPECIAL_INTS), st.integers())


junk = st.recursive(
    st.one_of(st.none(), st.booleans(), st.sampled_from(SPECIAL_FLOATS),
              st.sampled_from(SPECIAL_INTS), st.sampled_from(JUNK_STRINGS),
              st.sampled_from(NAMES), st.text(max_size=8)),
    lambda inner: st.one_of(st.lists(inner, max_size=4),
                            st.dictionaries(st.sampled_from(("a", "x", "1", "name")), inner,
                                            max_size=2)),
    max_leaves=6)


def typed_value(hint, default):
    """Python values of the field's type (near its default or special), or
    of any type."""
    origin = typing.get_origin(hint)
    if origin is list:
        (item,) = typing.get_args(hint)
        if dc.is_dataclass(item):  # identifiers: entries of random leaves
            entry = st.dictionaries(
                st.sampled_from([k for k, _, _ in leaf_fields(item)]),
                st.deferred(lambda: st.one_of(
                    *(typed_value(h, d) for _, h, d in leaf_fields(item)), junk)),
                max_size=3).map(_nest)
            return st.lists(entry, max_size=2)
        default = list(default or [])
        items = typed_value(item, default[0] if default else None)
        edited = st.tuples(st.integers(0, max(len(default) - 1, 0)), items).map(
            lambda edit: [edit[1] if i == edit[0] else v for i, v in enumerate(default)]
            or [edit[1]])
        return st.one_of(st.just(default), edited, st.lists(items, max_size=4))
    if origin is dict:
        return st.dictionaries(st.sampled_from(("gain", "a", "1x", "")), junk, max_size=2)
    if hint is float:
        return _numbers(default)
    if hint is int:
        return _ints(default)
    if hint is bool:
        return st.booleans()
    if hint is str:
        return st.one_of(st.sampled_from(NAMES), st.sampled_from(JUNK_STRINGS), st.text(max_size=6))
    return junk


def _nest(flat: dict) -> dict:
    """{"rls.p0": v} -> {"rls": {"p0": v}}; a clash keeps the first."""
    out = {}
    for key, value in flat.items():
        *parents, leaf = key.split(".")
        node = out
        for part in parents:
            node = node.setdefault(part, {})
            if not isinstance(node, dict):
                break
        else:
            node.setdefault(leaf, value)
    return out


@st.composite
def overrides(draw):
    """A list of one to three ``key=value`` strings (mostly one: each more
    makes a refusal likelier, and accepted ones must run too)."""
    items = []
    for _ in range(draw(st.sampled_from((1, 1, 1, 2, 3)))):
        which = draw(st.integers(0, 9))
        if which == 0:
            key, hint, default = draw(st.sampled_from(UNKNOWN_KEYS)), None, None
        else:
            leaves = OPTION_LEAVES if which == 1 else LEAVES
            key = draw(st.sampled_from(sorted(leaves)))
            hint, default = leaves[key]
        kind = draw(st.integers(0, 9))
        if kind < 7 and hint is not None:
            text = to_yaml(draw(typed_value(hint, default)))
        elif kind < 9:
            text = to_yaml(draw(junk))
        else:
            text = draw(st.sampled_from(RAW_VALUES))
        items.append(f"{key}={text}")
    return items


def names_a_key(message: str, items) -> bool:
    """Whether the message names the field of one of the ``key=value``
    overrides: its dotted key, its leaf name as a word, or the scenario
    field the key lies in (``controller.options`` for
    ``controller.options.gain``)."""
    for item in items:
        key = item.partition("=")[0].strip()
        parts = key.split(".")
        fields = {".".join(parts[:i]) for i in range(1, len(parts))} & set(LEAVES)
        if key in message or any(field in message for field in fields):
            return True
        if parts[-1] and re.search(rf"(?<!\w){re.escape(parts[-1])}(?!\w)", message):
            return True
    return False


def run_one_step(base, items):
    """What ``drake-contact run`` does, up to its first control step: load
    and validate, write the resolved scenario, build, check the logs fit,
    simulate 1 ms, score. Returns the station's logged signals."""
    scenario = load_scenario(base, items)
    dump_scenario(scenario)
    diagram, loggers = MakeRunDiagram(scenario)
    check_logs_fit(loggers, scenario.simulation.duration)
    simulator = Simulator(diagram)
    context = simulator.get_mutable_context()
    SeedNoise(diagram, context)
    simulator.Initialize()
    simulator.AdvanceTo(CONTROL_PERIOD)
    log = loggers.collect(context)
    compute_metrics(scenario, log, wall_s=1.0)
    # The station's own signals; the log's derived stiffness_ratio and
    # displacement_measured are NaN before contact by definition.
    return {name: loggers.latest(name, 2)[1] for name in loggers.columns}


#: Overrides that once reached the user as a traceback, a message of two
#: lines or naming another field, or were accepted and gave NaN at once:
#: (base scenario, overrides). Found by this fuzz (F), by a sweep of every
#: leaf over SPECIAL_FLOATS and every identifier field (S), or by reading the
#: code the fuzz pointed at (R).
FOUND = [
    # Tracebacks.
    ("push_constant", ["force_sensor.adc_rate_hz=5e-324"]),  # F: OverflowError
    ("push_constant", ["force_sensor.adc_rate_hz=1e-300"]),  # F: 1e304 frame plans, out of memory
    ("push_constant", ["force_sensor.fine_rate_hz=1e12", "force_sensor.adc_rate_hz=1000"]),  # R
    # R: a slow ADC with a long glitch had millions of frame plans (now made when met).
    ("push_constant", ["force_sensor.adc_rate_hz=1", "force_sensor.dac_glitch_duration_s=0.4"]),
    ("nn_styrofoam", ["force_sensor.calibration_matrix=[[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0], "
                      "[0.0, 0.0, 1.0]]"]),  # F: ValueError, a ragged matrix
    ("nn_styrofoam", ["estimator.cutoff_hz=5e-324"]),  # F: ValueError from scipy
    ("environment: {stiffness: 6.2e4}", ["environment.damping=30.0"]),  # F: TypeError
    ("nn_styrofoam", ["dsp.force_filter_cutoff_hz=5e-324"]),  # S: ValueError from scipy
    ("nn_styrofoam", ["force_sensor.adc_full_scale=[5e-324, 500.0, 20.0]"]),  # S: ZeroDivisionError
    ("nn_styrofoam", ["force_sensor.analog_cutoff_hz=5e-324"]),  # S: OverflowError
    ("nn_styrofoam", ["force_sensor.output_bandwidth_hz=5e-324"]),  # S: LinAlgError
    ("nn_styrofoam", ["arm.time_step=5e-324"]),  # S: OverflowError
    ("nn_styrofoam", ["dsp.adc_range_v=.inf"]),  # S: RuntimeError from Drake's symbolic
    ("nn_styrofoam", ["encoders.counts_per_revolution=[4294967296, 0, 0]"]),  # S: TypeError
    ("nn_styrofoam", ["simulation.seed=1000000000000000000000000000000"]),  # S: TypeError
    ("nn_styrofoam", ["environment.stiffness_drift_per_s=.nan"]),  # S: RuntimeError
    ("nn_styrofoam", ["joint_friction.bristle_frequency_hz=5e-324"]),  # S: ZeroDivisionError
    ("sensor_spectrum", ["dsp.anti_aliasing.C1=5e-324"]),  # S: ZeroDivisionError
    # Two lines, or another field named.
    ("nn_styrofoam", ['controller.name="a\\nb"']),  # S
    ("push_constant", ['environment.law="a\\nb"']),  # S
    ("push_constant", ["force_reference.sine_amplitude_n=.nan"]),  # F: named sine_frequency_hz
    ("identify_styrofoam", ["force_sensor.adc_rate_hz=1e12"]),  # F: named dac_glitch_duration_s
    # Accepted, and NaN or inf at the first step.
    ("identify_styrofoam", ["controller.hybrid.y_desired=1.7976931348623157e+308"]),  # F
    ("identify_styrofoam", ["controller.hybrid.approach.start_x=-.inf"]),  # F
    ("push_constant", ["force_sensor.dac_glitch_n=-.inf"]),  # F
    ("adaptive_hybrid", ["controller.hybrid.model.friction_levels=[.inf, 0.2, 0.004]"]),  # S
    ("nn_styrofoam", ["environment.surface_x=-1e300"]),  # S
    ("nn_styrofoam", ["dsp.scale_n_per_v=.inf"]),  # S
    ("nn_styrofoam", ["force_sensor.noise_std=[.inf, 0.75, 0.01]"]),  # S
    ("nn_styrofoam", ["force_sensor.offset_drift_n_per_s=.nan"]),  # S
    ("sensor_spectrum", ["dsp.anti_aliasing.R1=1e-300"]),  # S
    ("nn_styrofoam", ["identifiers=[{name: x, kind: nn, nn: {probe: [5e-324, 0.01, 1.0]}}]"]),  # S
    ("nn_styrofoam", ["identifiers=[{name: x, kind: nn, nn: {output_scale_n: .inf}}]"]),  # S
]


def _with_examples(test):
    for base, items in reversed(FOUND):
        test = example(base=base, items=items)(test)
    return test


@settings(max_examples=500, deadline=None, derandomize=True, database=None)
@_with_examples
@given(base=st.sampled_from(BASES), items=overrides())
def test_an_override_is_accepted_and_runs_or_refused_in_one_line_naming_it(base, items):
    try:
        signals = run_one_step(base, items)
    except ScenarioError as e:
        event("refused")
        message = str(e)
        assert "\n" not in message and message.strip(), repr(message)
        assert names_a_key(message, items), f"{message!r} names none of {items}"
        return
    event("accepted, one step run")
    bad = [name for name, values in signals.items() if not np.all(np.isfinite(values))]
    assert not bad, f"{items} accepted, but the first step logs non-finite {bad}"


def test_the_fuzz_reaches_every_leaf_and_both_outcomes():
    """The strategy's keys are the scenario's fields (so the fuzz follows the
    schema), and the property can fail both ways."""
    assert {"simulation.duration", "environment.stiffness", "torque_limits", "identifiers",
            "controller.options", "controller.hybrid.approach.step_m",
            "dsp.anti_aliasing.mode", "faults", "safety.enabled",
            "safety.force_limit_n"} <= set(LEAVES)
    assert "controller.options.stiffness_x" in OPTION_LEAVES
    assert run_one_step("push_constant", ["environment.stiffness=6.2e4"])
    with pytest.raises(ScenarioError) as info:
        run_one_step("push_constant", ["environment.stiffness=.nan"])
    assert names_a_key(str(info.value), ["environment.stiffness=.nan"])
    assert not names_a_key("simulation.duration = 1 is out of range", ["arm.time_step=1"])


#: Overrides the fuzz found, through the real command: (--set value, text
#: of its one line). Before the fixes: out of memory, a ValueError traceback,
#: a message of two lines, and an accepted wall whose first step commands
#: infinite torques.
CLI_REFUSED = [
    ("force_sensor.adc_rate_hz=1e-300",
     "force_sensor.adc_rate_hz = 1e-300 is out of range: must be in [1, fine_rate_hz"),
    ("force_sensor.calibration_matrix=[[1, 0], [0, 1, 0], [0, 0, 1]]",
     "force_sensor.calibration_matrix = [[1.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]] is out "
     "of range: must be a finite 3 x 3 matrix"),
    ('controller.name="a\\nb"', "controller.name = 'a\\nb' is unknown"),
    ("environment.surface_x=-1e300",
     "environment.surface_x = -1e+300 is out of range: must be in [-1, 1] m"),
]


@pytest.mark.parametrize("item,message", CLI_REFUSED)
def test_the_command_refuses_a_bad_override_in_one_line(tmp_path, item, message):
    result = drake_contact("run", "push_constant", "--out", str(tmp_path / "o"), "--no-figures",
                           "--no-baseline", "--set", item, cwd=tmp_path)
    assert result.returncode == 2, result.stderr
    assert result.stderr.count("\n") == 1 and message in result.stderr, result.stderr
    assert "Traceback" not in result.stderr
    assert not (tmp_path / "o").exists()  # refused before the folder is made


def test_the_command_runs_a_scenario_without_a_controller_section(tmp_path):
    """A scenario file that leaves the controller out (a TypeError before),
    with a good override."""
    scenario = tmp_path / "wall.yaml"
    scenario.write_text("environment: {stiffness: 6.2e4}\n")
    result = drake_contact("run", str(scenario), "--out", str(tmp_path / "o"), "--no-figures",
                           "--no-baseline", "--duration", "0.5",
                           "--set", "force_sensor.noise_std=[0.5, 0.5, 0.0]",
                           "--set", "controller.push.start_time=2.1", cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    assert "completed" in result.stdout and result.stderr == ""
