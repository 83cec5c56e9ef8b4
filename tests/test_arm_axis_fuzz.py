"""The arm-axis primitives fail loudly outside the subset they support, and
inside it give each environment the bits its own Drake system gives:
a hypothesis fuzz of every supported expression kind against
SymbolicVectorSystem (bits compared, so +0 and -0 differ), and the stacked
roles the other tests do not reach (the tip state and the Jacobian
transpose, the estimator's forward kinematics, the DAC's hold at h < 1 ms,
the finite guard)."""

import math

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from pydrake import symbolic
from pydrake.systems.primitives import LinearSystem, SymbolicVectorSystem

from drake_contact.arm_axis import LinearSystemBank, StackedSymbolicSystem
from drake_contact.diagram import FiniteGuard, SampleHold, _kinematics_model
from drake_contact.plant.tip_kinematics import TipKinematics
from drake_contact.sensing.estimator import ForwardKinematics


def _bits(values):
    return np.ascontiguousarray(values, dtype=float).view(np.uint64)


# --- loud outside the subset ------------------------------------------------

def test_a_bank_refuses_a_continuous_linear_system():
    with pytest.raises(ValueError, match="continuous"):
        LinearSystemBank([LinearSystem([[0.5]], [[1.0]], [[1.0]], [[0.0]])] * 2)


@pytest.mark.parametrize("count", [1, 3])
def test_a_state_without_a_period_is_refused_at_any_count(count):
    pieces = []
    for _ in range(count):
        u, s = symbolic.Variable("u"), symbolic.Variable("s")
        pieces.append({"input": [u], "state": [s], "dynamics": [s + u], "output": [s + 0.0 * u]})
    with pytest.raises(ValueError, match="time_period > 0"):
        StackedSymbolicSystem(pieces)


@pytest.mark.parametrize("count", [1, 3])
def test_a_bare_variable_output_is_refused_at_any_count(count):
    pieces = []
    for _ in range(count):
        u = symbolic.Variable("u")
        pieces.append({"input": [u], "output": [u]})
    with pytest.raises(TypeError, match="not an Expression"):
        StackedSymbolicSystem(pieces)


def test_pieces_of_other_sizes_and_fields_that_do_not_sum_are_refused():
    u, v = symbolic.Variable("u"), symbolic.Variable("v")
    with pytest.raises(ValueError, match="differ in their sizes"):
        StackedSymbolicSystem([{"input": [u], "output": [u * 2.0]},
                               {"input": [u, v], "output": [u * v]}])
    with pytest.raises(ValueError, match="input_sizes"):
        StackedSymbolicSystem([{"input": [u, v], "output": [u * v]}] * 2, input_sizes=[1])


def test_an_unsupported_expression_kind_is_a_type_error():
    u = symbolic.Variable("u")
    with pytest.raises(TypeError, match="not supported"):
        StackedSymbolicSystem([{"input": [u], "output": [symbolic.log(u)]}] * 2)


# --- every supported kind, fuzzed -------------------------------------------

#: Values the inputs, state and time take: signed zeros, the tiny and the
#: huge, and ordinary numbers.
VALUES = st.sampled_from([0.0, -0.0, 1.0, -1.0, 0.5, -2.5, 3.0, 1e-300, -1e-300, 1e300,
                          0.1, 7.25, -0.3, 2.0 ** 0.5])
CONSTANTS = st.sampled_from([0.0, -0.0, 1.0, -1.0, 2.0, 0.5, -3.0, 1e-3, 1e3])
LEAVES = st.one_of(st.tuples(st.just("var"), st.integers(0, 3)),
                   st.tuples(st.just("const"), CONSTANTS))
UNARY = ("abs", "floor", "ceil", "sqrt", "sin", "cos", "exp", "neg")
BINARY = ("add", "sub", "mul", "div", "pow", "max", "min")
RELATIONS = ("<", "<=", ">", ">=", "==", "!=")


def _trees(children):
    relation = st.tuples(st.sampled_from(RELATIONS), children, children)
    condition = st.one_of(relation, st.tuples(st.just("not"), relation),
                          st.tuples(st.sampled_from(["and", "or"]), relation, relation))
    return st.one_of(st.tuples(st.sampled_from(UNARY), children),
                     st.tuples(st.sampled_from(BINARY), children, children),
                     st.tuples(st.just("if"), condition, children, children))


TREES = st.recursive(LEAVES, _trees, max_leaves=8)


def _expression(tree, variables):
    kind, *args = tree
    if kind == "var":
        return symbolic.Expression(variables[args[0]])
    if kind == "const":
        return symbolic.Expression(args[0])
    e = [_expression(a, variables) if kind != "if" else None for a in args]
    unary = {"abs": abs, "floor": symbolic.floor, "ceil": symbolic.ceil, "sqrt": symbolic.sqrt,
             "sin": symbolic.sin, "cos": symbolic.cos, "exp": symbolic.exp,
             "neg": lambda x: -x}
    if kind in unary:
        return unary[kind](e[0])
    binary = {"add": lambda a, b: a + b, "sub": lambda a, b: a - b, "mul": lambda a, b: a * b,
              "div": lambda a, b: a / b, "pow": symbolic.pow, "max": symbolic.max,
              "min": symbolic.min}
    if kind in binary:
        return binary[kind](e[0], e[1])
    return symbolic.if_then_else(_formula(args[0], variables), _expression(args[1], variables),
                                 _expression(args[2], variables))


def _formula(tree, variables):
    kind, *args = tree
    if kind == "not":
        return symbolic.logical_not(_formula(args[0], variables))
    if kind in ("and", "or"):
        join = symbolic.logical_and if kind == "and" else symbolic.logical_or
        return join(_formula(args[0], variables), _formula(args[1], variables))
    a, b = _expression(args[0], variables), _expression(args[1], variables)
    return {"<": a < b, "<=": a <= b, ">": a > b, ">=": a >= b, "==": a == b,
            "!=": a != b}[kind]


def _piece(output_tree, dynamics_tree):
    u = symbolic.MakeVectorVariable(2, "u")
    s, t = symbolic.Variable("s"), symbolic.Variable("t")
    variables = [u[0], u[1], s, t]
    return {"time": t, "input": u, "state": [s],
            "output": [_expression(output_tree, variables)],
            "dynamics": [_expression(dynamics_tree, variables)]}


@settings(max_examples=300, deadline=None, derandomize=True, database=None)
@given(output=TREES, dynamics=TREES, values=st.lists(st.lists(VALUES, min_size=4, max_size=4),
                                                     min_size=3, max_size=3))
def test_every_supported_kind_gives_each_environment_its_bits(output, dynamics, values):
    try:  # Drake folds constants and refuses a NaN (sqrt(-1)) as it builds
        pieces = [_piece(output, dynamics) for _ in values]
    except (RuntimeError, ValueError):
        assume(False)
    alone = []
    # One time for all environments (the stacked system's context has one).
    values = [v[:3] + [values[0][3]] for v in values]
    for piece, (u0, u1, s, t) in zip(pieces, values):
        system = SymbolicVectorSystem(time=piece["time"], state=piece["state"],
                                      input=piece["input"], output=piece["output"],
                                      dynamics=piece["dynamics"], time_period=1e-3)
        context = system.CreateDefaultContext()
        context.SetTime(t)
        context.SetDiscreteState([s])
        system.get_input_port().FixValue(context, [u0, u1])
        try:  # Drake's evaluation refuses a NaN (sqrt(-1), 0 * inf): not compared
            y = np.array(system.get_output_port().Eval(context))
            x = np.array(system.EvalUniquePeriodicDiscreteUpdate(context).get_vector().value())
        except (RuntimeError, ValueError):
            assume(False)
        alone.append((y, x))
    stacked = StackedSymbolicSystem(pieces, input_sizes=[1, 1], time_period=1e-3)
    context = stacked.CreateDefaultContext()
    count = len(values)
    context.SetTime(values[0][3])
    context.SetDiscreteState([v[2] for v in values])
    stacked.get_input_port().FixValue(context, [v[0] for v in values] + [v[1] for v in values])
    y = np.array(stacked.get_output_port().Eval(context))
    x = np.array(stacked.EvalUniquePeriodicDiscreteUpdate(context).get_vector().value())
    for i, (yi, xi) in enumerate(alone):
        assert _bits(y[i]) == _bits(yi[0]), (i, y[i], yi[0], pieces[i]["output"][0])
        assert _bits(x[i]) == _bits(xi[0]), (i, x[i], xi[0], pieces[i]["dynamics"][0])
    assert count == 3


# --- the stacked roles, each environment as alone ----------------------------

def _eval(system, context, name):
    return np.array(system.GetOutputPort(name).Eval(context))


def test_the_tip_state_and_the_jacobian_transpose_are_each_arms_alone():
    rng = np.random.default_rng(5)
    model = _kinematics_model()
    count = 4
    many = TipKinematics(model, count)
    ones = [TipKinematics(model) for _ in range(count)]
    many_context = many.CreateDefaultContext()
    contexts = [o.CreateDefaultContext() for o in ones]
    for _ in range(50):
        state = rng.normal(scale=rng.choice([1e-3, 1.0, 10.0]), size=(count, 6))
        force = rng.normal(scale=20.0, size=(count, 3))
        force[0, 1] = -0.0
        many.GetInputPort("plant_state").FixValue(many_context, state.ravel())
        many.GetInputPort("force_on_tip").FixValue(many_context, force.ravel())
        tip, torque = (_eval(many, many_context, n) for n in ("tip_state", "generalized_force"))
        for i, (one, context) in enumerate(zip(ones, contexts)):
            one.GetInputPort("plant_state").FixValue(context, state[i])
            one.GetInputPort("force_on_tip").FixValue(context, force[i])
            assert np.array_equal(_bits(tip[6 * i:6 * i + 6]),
                                  _bits(_eval(one, context, "tip_state")))
            assert np.array_equal(_bits(torque[3 * i:3 * i + 3]),
                                  _bits(_eval(one, context, "generalized_force")))


def test_the_estimators_forward_kinematics_is_each_arms_alone():
    rng = np.random.default_rng(6)
    model = _kinematics_model()
    count = 3
    many, ones = ForwardKinematics(model, count), [ForwardKinematics(model) for _ in range(3)]
    many_context = many.CreateDefaultContext()
    q = rng.normal(scale=2.0, size=(count, 3))
    many.get_input_port().FixValue(many_context, q.ravel())
    pose = np.array(many.get_output_port().Eval(many_context))
    for i, one in enumerate(ones):
        context = one.CreateDefaultContext()
        one.get_input_port().FixValue(context, q[i])
        assert np.array_equal(_bits(pose[3 * i:3 * i + 3]),
                              _bits(one.get_output_port().Eval(context)))


@pytest.mark.parametrize("h", [5e-4, 2.5e-4, 1e-4])
def test_the_dac_holds_each_environments_torque_as_alone(h):
    rng = np.random.default_rng(7)
    count = 3
    many = SampleHold(1e-3, 3, h, count)
    ones = [SampleHold(1e-3, 3, h) for _ in range(count)]
    many_context = many.CreateDefaultContext()
    contexts = [o.CreateDefaultContext() for o in ones]
    held = np.zeros(3 * count)
    for step in range(int(round(5e-3 / h))):
        t = step * h
        u = rng.normal(size=3 * count)
        many_context.SetTime(t)
        many_context.SetDiscreteState(held)
        many.get_input_port().FixValue(many_context, u)
        y = np.array(many.get_output_port().Eval(many_context))
        update = np.array(many.EvalUniquePeriodicDiscreteUpdate(many_context).get_vector().value())
        at_sample = abs(t - round(t / 1e-3) * 1e-3) < 1e-9
        np.testing.assert_array_equal(y, u if at_sample else held)
        for i, (one, context) in enumerate(zip(ones, contexts)):
            context.SetTime(t)
            context.SetDiscreteState(held[3 * i:3 * i + 3])
            one.get_input_port().FixValue(context, u[3 * i:3 * i + 3])
            assert np.array_equal(_bits(y[3 * i:3 * i + 3]), _bits(one.get_output_port().Eval(
                context)))
            assert np.array_equal(_bits(update[3 * i:3 * i + 3]), _bits(
                one.EvalUniquePeriodicDiscreteUpdate(context).get_vector().value()))
        held = update


def test_the_finite_guard_zeroes_only_non_finite_values_as_alone():
    count = 3
    many, one = FiniteGuard(3, count), FiniteGuard(3)
    u = np.array([1.5, -0.0, math.inf, -math.inf, math.nan, 0.0, -2.0, 1e308, -1e-308])
    many_context, context = many.CreateDefaultContext(), one.CreateDefaultContext()
    many.get_input_port().FixValue(many_context, u)
    y = np.array(many.get_output_port().Eval(many_context))
    for i in range(count):
        one.get_input_port().FixValue(context, u[3 * i:3 * i + 3])
        assert np.array_equal(_bits(y[3 * i:3 * i + 3]), _bits(one.get_output_port().Eval(
            context)))
    assert np.array_equal(_bits(y), _bits([1.5, -0.0, 0.0, 0.0, 0.0, 0.0, -2.0, 1e308, -1e-308]))
