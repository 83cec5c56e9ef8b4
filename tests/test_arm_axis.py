"""The arm-axis primitives give each environment, bit for bit, what its own
Drake system gives it alone."""

import numpy as np
import pytest
from pydrake import symbolic
from pydrake.systems.primitives import AffineSystem, LinearSystem, MatrixGain

from drake_contact.arm_axis import LinearSystemBank, StackedSymbolicSystem
from drake_contact.errors import ScenarioError
from drake_contact.sensing.estimator import _joint_filters
from drake_contact.sensing.filters import butterworth_digital, differencing_filter_system


def _station_filters(cutoff_hz):
    b, a = butterworth_digital(cutoff_hz, 1000.0)
    return {"joint_filters": _joint_filters(b, a, 1e-3),
            "tip_rates": differencing_filter_system(b, a, 1e-3, channels=3)}


def _step_alone(system, context, x, u):
    if system.num_input_ports():
        system.get_input_port().FixValue(context, u)
    if x.size:
        context.SetDiscreteState(x)
        xn = np.array(system.EvalUniquePeriodicDiscreteUpdate(context).get_vector().value())
    else:
        xn = x
    return xn.ravel(), np.array(system.get_output_port().Eval(context))


def _compare(systems, steps=150, seed=0):
    """Steps the bank and each system alone from the same states and
    inputs; returns the number of values that differ."""
    rng = np.random.default_rng(seed)
    bank = LinearSystemBank(systems)
    context = bank.CreateDefaultContext()
    alone = [s.CreateDefaultContext() for s in systems]
    k = systems[0].num_states() if hasattr(systems[0], "num_states") else 0
    m = systems[0].get_input_port().size()
    count = len(systems)
    x = np.concatenate([c.get_discrete_state_vector().CopyToVector() if k else np.zeros(0)
                        for c in alone])
    differ = 0
    for _ in range(steps):
        u = rng.normal(scale=rng.choice([1e-3, 1.0, 1e3]), size=m * count)
        bank.get_input_port().FixValue(context, u)
        if k:
            context.SetDiscreteState(x)
            xn = np.array(bank.EvalUniquePeriodicDiscreteUpdate(context).get_vector().value())
        y = np.array(bank.get_output_port().Eval(context))
        p = systems[0].get_output_port().size()
        for i, (s, c) in enumerate(zip(systems, alone)):
            xi, yi = _step_alone(s, c, x[i * k:(i + 1) * k], u[i * m:(i + 1) * m])
            differ += np.sum(yi != y[i * p:(i + 1) * p])
            if k:
                differ += np.sum(xi != xn.ravel()[i * k:(i + 1) * k])
        if k:
            x = xn.ravel()
    return differ


@pytest.mark.parametrize("count", [1, 2, 3, 16, 64])
@pytest.mark.parametrize("name", ["joint_filters", "tip_rates"])
def test_a_bank_of_the_estimators_filters_is_each_filter_alone(name, count):
    # Each environment its own cutoff: the matrices differ per environment.
    systems = [_station_filters(cutoff)[name] for cutoff in np.linspace(20.0, 60.0, count)]
    assert _compare(systems) == 0


@pytest.mark.parametrize("count", [1, 5])
def test_a_bank_of_dense_systems_matrix_gains_and_affine_outputs_is_each_alone(count):
    rng = np.random.default_rng(1)
    dense = [LinearSystem(rng.normal(size=(9, 9)), rng.normal(size=(9, 4)),
                          rng.normal(size=(5, 9)), rng.normal(size=(5, 4)), 1e-3)
             for _ in range(count)]
    gains = [MatrixGain(rng.normal(size=(3, 6))) for _ in range(count)]
    affine = [AffineSystem(D=rng.normal(size=(3, 3)), y0=rng.normal(size=3))
              for _ in range(count)]
    assert _compare(dense) == 0
    assert _compare(gains) == 0
    assert _compare(affine) == 0


def test_a_bank_has_direct_feedthrough_exactly_when_its_systems_do():
    b, a = butterworth_digital(35.0, 1000.0)
    rates = differencing_filter_system(b, a, 1e-3, channels=3)
    delay = LinearSystem(np.zeros((2, 2)), np.eye(2), np.eye(2), np.zeros((2, 2)), 1e-3)
    assert rates.HasDirectFeedthrough(0, 0) and not delay.HasDirectFeedthrough(0, 0)
    assert LinearSystemBank([rates, rates]).HasDirectFeedthrough(0, 0)
    assert not LinearSystemBank([delay, delay]).HasDirectFeedthrough(0, 0)


def test_systems_of_different_shapes_cannot_share_a_bank():
    b, a = butterworth_digital(35.0, 1000.0)
    with pytest.raises(ScenarioError, match="share a structure"):
        LinearSystemBank([_joint_filters(b, a, 1e-3),
                          differencing_filter_system(b, a, 1e-3, channels=3)])


def test_stacked_expressions_are_evaluated_as_alone():
    rng = np.random.default_rng(2)
    pieces, alone = [], []
    for i in range(4):
        t = symbolic.Variable("t")
        u = symbolic.MakeVectorVariable(2, "u")
        s = symbolic.MakeVectorVariable(1, "s")
        gain = float(rng.uniform(0.5, 2.0))
        dynamics = [symbolic.max(s[0] * gain + u[0] * t, -np.inf)]
        output = [s[0] + u[1], symbolic.cos(u[0]) * gain]
        pieces.append({"time": t, "input": u, "state": s, "dynamics": dynamics,
                       "output": output})
        from pydrake.systems.primitives import SymbolicVectorSystem
        alone.append(SymbolicVectorSystem(time=t, state=s, input=u, dynamics=dynamics,
                                          output=output, time_period=1e-3))
    stacked = StackedSymbolicSystem(pieces, input_sizes=[1, 1], output_sizes=[1, 1],
                                    time_period=1e-3)
    context = stacked.CreateDefaultContext()
    u = rng.normal(size=(4, 2))
    state = rng.normal(size=4)
    context.SetTime(0.37)
    context.SetDiscreteState(state)
    stacked.get_input_port().FixValue(context, np.concatenate([u[:, 0], u[:, 1]]))
    y = np.array(stacked.get_output_port().Eval(context))
    xn = np.array(stacked.EvalUniquePeriodicDiscreteUpdate(context).get_vector().value())
    for i, system in enumerate(alone):
        c = system.CreateDefaultContext()
        c.SetTime(0.37)
        c.SetDiscreteState([state[i]])
        system.get_input_port().FixValue(c, u[i])
        yi = np.array(system.get_output_port().Eval(c))
        assert yi[0] == y[i] and yi[1] == y[4 + i]
        assert system.EvalUniquePeriodicDiscreteUpdate(c).get_vector().value()[0] == xn[i]


def test_a_bank_splits_its_output_field_major():
    b, a = butterworth_digital(35.0, 1000.0)
    systems = [_joint_filters(b, a, 1e-3) for _ in range(3)]
    whole = LinearSystemBank(systems)
    split = LinearSystemBank(systems, output_sizes=[3, 3])
    u = np.arange(9.0)
    y = []
    for bank in (whole, split):
        context = bank.CreateDefaultContext()
        bank.get_input_port().FixValue(context, u)
        y.append(np.array(bank.get_output_port().Eval(context)))
    env_major = y[0].reshape(3, 6)
    assert np.array_equal(y[1], np.concatenate([env_major[:, :3].ravel(), env_major[:, 3:].ravel()]))
    with pytest.raises(ScenarioError, match="do not sum"):
        LinearSystemBank(systems, output_sizes=[3, 2])


def _compare_pieces(pieces, sample, steps=200, seed=5, period=1e-3, input_sizes=None,
                    output_sizes=None):
    """Steps the compiled system of ``pieces`` and each piece's own
    SymbolicVectorSystem from the same states, inputs (``sample(rng, env)``
    gives one environment's input) and times; returns how many values
    differ."""
    from pydrake.systems.primitives import SymbolicVectorSystem
    rng = np.random.default_rng(seed)
    count = len(pieces)
    compiled = StackedSymbolicSystem(pieces, input_sizes=input_sizes,
                                     output_sizes=output_sizes, time_period=period)
    alone = [SymbolicVectorSystem(time=p.get("time"), state=list(p.get("state", [])),
                                  input=list(p["input"]), dynamics=list(p.get("dynamics", [])),
                                  output=list(p["output"]), time_period=period)
             for p in pieces]
    contexts = [s.CreateDefaultContext() for s in alone]
    context = compiled.CreateDefaultContext()
    k = len(pieces[0].get("state", []))
    m_fields = input_sizes or [len(pieces[0]["input"])]
    p_fields = output_sizes or [len(pieces[0]["output"])]

    def field_major(per_env, fields):
        out, start = [], 0
        for size in fields:
            out.extend(np.concatenate([v[start:start + size] for v in per_env]))
            start += size
        return np.array(out)

    state = rng.normal(size=(count, k)) * 1e-3
    differ = 0
    for _ in range(steps):
        t = float(rng.choice([0.0, 0.5, 1.0, 2.0, 3.7])) + float(rng.integers(0, 3)) * period
        u = [sample(rng, env) for env in range(count)]
        context.SetTime(t)
        compiled.get_input_port().FixValue(context, field_major(u, m_fields))
        if k:
            context.SetDiscreteState(state.ravel())
        y = np.array(compiled.get_output_port().Eval(context))
        xn = (np.array(compiled.EvalUniquePeriodicDiscreteUpdate(context).get_vector().value())
              if k else None)
        ys, xs = [], []
        for env, (system, c) in enumerate(zip(alone, contexts)):
            c.SetTime(t)
            system.get_input_port().FixValue(c, u[env])
            if k:
                c.SetDiscreteState(state[env])
                xs.append(np.array(system.EvalUniquePeriodicDiscreteUpdate(c).get_vector()
                                   .value()).ravel())
            ys.append(np.array(system.get_output_port().Eval(c)))
        differ += np.sum(field_major(ys, p_fields) != y)
        if k:
            differ += np.sum(np.concatenate(xs) != xn.ravel())
            state = xn.reshape(count, k)
    return differ


def test_the_compiled_wall_is_each_wall_alone():
    from drake_contact.plant.compliant_wall import (
        OUTPUT_SIZES, EnvironmentConfig, contact_law_expressions)
    configs = [EnvironmentConfig(), EnvironmentConfig(stiffness=30000.0, damping=300.0,
                                                      stiffness_drift_per_s=0.05),
               EnvironmentConfig(law="hunt_crossley", friction_coefficient=0.3)]
    pieces = []
    for c in configs:
        t, state, tip, dynamics, outputs = contact_law_expressions(c, 1e-3)
        pieces.append({"time": t, "state": state, "input": tip, "dynamics": dynamics,
                       "output": outputs})

    def tip_state(rng, env):
        # About the surface (0.456 m), in and out of contact, moving or not.
        x = 0.456 + rng.normal(scale=2e-3)
        return np.array([x, rng.normal(scale=1e-2), 0.1, rng.choice([0.0, 1.0]) *
                         rng.normal(scale=0.05), rng.normal(scale=0.05), 0.0])
    assert _compare_pieces(pieces, tip_state, output_sizes=list(OUTPUT_SIZES.values())) == 0


def test_the_compiled_friction_is_each_arms_friction_alone():
    from drake_contact.plant.joint_physics import JointFrictionConfig, _lugre_expressions
    configs = [JointFrictionConfig(), JointFrictionConfig(levels=[0.5, 0.0, 0.01]),
               JointFrictionConfig(bristle_frequency_hz=80.0)]
    pieces = [_lugre_expressions(c, [0.3, 0.05, 0.003], 1e-3) for c in configs]

    def plant_state(rng, env):
        v = rng.normal(scale=0.01, size=3) * rng.integers(0, 2, size=3)  # some at rest
        return np.concatenate([rng.normal(size=3), v])
    assert _compare_pieces(pieces, plant_state) == 0


def test_the_compiled_adc_and_tare_is_each_dsps_alone():
    from drake_contact.sensing.dsp import DspConfig, _adc_tare_expressions
    pieces = [_adc_tare_expressions(DspConfig(), 1),
              _adc_tare_expressions(DspConfig(adc_bits=12, tare_window_s=1.0), 1)]

    def voltage(rng, env):
        return np.array([rng.choice([rng.normal(scale=0.05), 12.0, -12.0])])
    assert _compare_pieces(pieces, voltage) == 0


def test_exp_and_pow_are_the_c_librarys_with_cs_inf_and_nan_where_python_raises():
    import math
    from drake_contact.arm_axis import _libm_exp, libm_pow as _libm_pow
    rng = np.random.default_rng(7)
    x = np.concatenate([rng.uniform(-745.0, 709.78, 20000), [-800.0, 0.0, 709.5, 709.78]])
    assert np.array_equal(_libm_exp(x), [math.exp(v) for v in x])
    with np.errstate(over="ignore"):
        assert np.array_equal(_libm_exp(np.array([710.0, np.inf, -np.inf, np.nan])),
                              [np.inf, np.inf, 0.0, np.nan], equal_nan=True)
    base, exponent = rng.uniform(0.0, 3.0, 20000), rng.uniform(-3.0, 3.0, 20000)
    assert np.array_equal(_libm_pow(base, exponent), [math.pow(b, e) for b, e in
                                                       zip(base, exponent)])
    with np.errstate(all="ignore"):
        special = _libm_pow(np.array([-2.0, 0.0, 1e300]), np.array([0.5, -1.0, 2.0]))
    assert np.isnan(special[0]) and special[1] == np.inf and special[2] == np.inf
