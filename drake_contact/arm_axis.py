"""Drake primitives for N environments at once, on the arm axis.

An ensemble (:func:`drake_contact.diagram.MakeEnsembleDiagram`) serves N
environments with one system per role: every port carries N times its
one-environment size, environment i's values at ``[k i, k (i + 1))``. A
role that the one-environment station builds from Drake's C++ primitives
gets here the one system that gives each environment, bit for bit, what
the primitive gives it alone:

- :class:`LinearSystemBank`: N discrete ``LinearSystem``s (or
  ``MatrixGain``s, or stateless ``AffineSystem``s) as one Python system.
  One block-diagonal ``LinearSystem`` is not an option: Eigen sums a large
  product in another order than a small one (measured: from 8 environments
  of the estimator's 21-state filter on, the bits differ), it costs
  quadratically in N, and a NaN in one environment reaches all of them.
  The bank does each environment's products in the order Drake's
  ``LinearSystem`` does them for one (checked by
  ``tests/test_arm_axis.py``): x' = (sum_j A_ij x_j) + (sum_j B_ij u_j),
  y = (sum_j C_ij x_j) + (sum_j D_ij u_j) (+ y0 for an affine output),
  each sum left to right from 0, one numpy operation over all
  environments at each step of the sums.
- :func:`StackedSymbolicSystem`: N environments' expressions (one
  environment's for a ``SymbolicVectorSystem``) as one system: for N > 1
  a :class:`CompiledExpressions`, which evaluates them with numpy over
  all environments, each operation the one Drake's ``Expression.Evaluate``
  does in its order (a sum from its constant over its terms in Drake's
  order, each term times its coefficient; a product from its constant;
  ``max(a, b)`` as ``a < b ? b : a``; libm's exp), so each environment's
  values are bit for bit its own ``SymbolicVectorSystem``'s (checked by
  ``tests/test_arm_axis.py`` on every symbolic role of the station).
  Drake's own evaluation walks each expression with a hash-map lookup
  per variable: N times the cost of one (measured: a third of an
  ensemble's step at N = 64), where numpy's is one operation per node for
  all N.

Why one system and not N copies: each discrete system's update notifies
everything downstream of it in the diagram, and in an ensemble the
downstream of any environment reaches the shared plant and so all N, so N
copies of a discrete role cost O(N^2) per step (measured: 174 us per
environment-step at N = 64 for the plant with copies of the wall and the
friction, 27 at N = 1).
"""

import math
import operator
from types import SimpleNamespace

import numpy as np
from pydrake import symbolic
from pydrake.systems.framework import BasicVector, LeafSystem
from pydrake.systems.primitives import AffineSystem, LinearSystem, SymbolicVectorSystem

from drake_contact.errors import ScenarioError


# --- Kernels written once for one environment and for N -----------------


def _where(condition, a, b):
    return a if condition else b


def _clip(x, low, high):
    return min(max(x, low), high)


def _floor(x):
    return float(math.floor(x))


def _array_maximum(a, b):
    return np.where(b > a, b, a)


def _array_minimum(a, b):
    return np.where(b < a, b, a)


def _array_clip(x, low, high):
    return _array_minimum(_array_maximum(x, low), high)


def _array_pow(base, exponent):
    return libm_pow(base, exponent)


#: The operations of an arm-axis kernel (one code for one environment and
#: for N), on one environment's Python floats: ``where(c, a, b)`` is ``a if
#: c else b``, ``maximum``/``minimum``/``clip`` Python's ``max``/``min``,
#: ``floor`` a float, ``any``/``all`` of a bool the bool. A Python float
#: operation costs some 30 ns, numpy's on an array of one about 1 us.
SCALAR_OPS = SimpleNamespace(where=_where, maximum=max, minimum=min, clip=_clip, floor=_floor,
                             copysign=math.copysign, sin=math.sin, cos=math.cos,
                             pow=operator.pow, any=bool, all=bool)
#: The same operations elementwise on arrays (N,), each environment's
#: result bit for bit its Python float result: ``maximum(a, b)`` is
#: ``where(b > a, b, a)``, Python's ``max(a, b)`` (NaN and signed zeros
#: included, where ``np.maximum`` differs), ``pow`` C's pow
#: (:func:`libm_pow`), and so on.
ARRAY_OPS = SimpleNamespace(where=np.where, maximum=_array_maximum, minimum=_array_minimum,
                            clip=_array_clip, floor=np.floor, copysign=np.copysign, sin=np.sin,
                            cos=np.cos, pow=_array_pow, any=np.any, all=np.all)


def arm_axis_ops(count):
    """The kernel operations for ``count`` environments: Python floats for
    one, arrays (count,) for more."""
    return SCALAR_OPS if count == 1 else ARRAY_OPS


def per_environment(values):
    """One environment's value as a Python float; N environments' as an
    array (N,) (the kernel's operands, see :func:`arm_axis_ops`)."""
    values = list(values)
    return float(values[0]) if len(values) == 1 else np.array(values, dtype=float)


def check_switches(configs, switches, prefix):
    """Raises ScenarioError naming ``prefix.<field>`` if the environments'
    configs differ in an option they switch (``switches(config)``: the
    options by field; their numbers may differ)."""
    def said(value):
        return ("on" if value else "off") if isinstance(value, bool) else repr(value)
    first = switches(configs[0])
    for i, config in enumerate(configs[1:], start=1):
        for field, value in switches(config).items():
            if value != first[field]:
                raise ScenarioError(
                    f"{prefix}.{field}: environment {i} has it {said(value)} and environment "
                    f"0 {said(first[field])}: the environments must share a structure (which "
                    "options are on), not only their numbers")


# --- Drake primitives for N environments --------------------------------------


class _SparseProduct:
    """M v for N environments' matrices M_e (r x c) of one shape, each row's
    sum taken left to right over the columns from 0, as Eigen does for one
    environment; v and the result are (c, N) and (r, N). Columns that are 0
    in every environment are left out of each row's sum (adding an exact 0
    changes a finite sum only in the sign of a zero)."""

    def __init__(self, matrices):
        stack = np.stack([np.asarray(m, dtype=float) for m in matrices])  # (N, r, c)
        count, self.rows, _ = stack.shape
        mask = np.any(stack != 0.0, axis=0)
        rows, self.cols = np.nonzero(mask)  # row by row, columns ascending
        self.nnz = rows.size
        # The products' values, one row per nonzero, and a zero row at the end.
        self.values = np.ascontiguousarray(stack[:, rows, self.cols].T)  # (nnz, N)
        per_row = mask.sum(axis=1)
        width = int(per_row.max()) if self.rows else 0
        # slots[t, i]: the t-th nonzero of row i, or the zero row.
        self.slots = np.full((width, self.rows), self.nnz)
        start = np.concatenate([[0], np.cumsum(per_row)[:-1]])
        for i in range(self.rows):
            self.slots[:per_row[i], i] = start[i] + np.arange(per_row[i])
        self._products = np.zeros((self.nnz + 1, count))

    def __call__(self, v):
        products = self._products
        np.multiply(self.values, v[self.cols], out=products[:self.nnz])
        total = np.zeros((self.rows, products.shape[1]))
        for slot in self.slots:
            total += products[slot]
        return total


def _matrices(system):
    """(A, B, C, D, y0, period) of a LinearSystem, MatrixGain or stateless
    AffineSystem; ScenarioError for anything else."""
    if isinstance(system, LinearSystem):
        if system.num_states() and system.time_period() <= 0:
            raise ValueError(f"LinearSystemBank serves discrete LinearSystems: "
                             f"'{system.get_name()}' is continuous (time_period 0)")
        return (system.A(), system.B(), system.C(), system.D(), None, system.time_period())
    if isinstance(system, AffineSystem) and system.num_states() == 0:
        return (system.A(), system.B(), system.C(), system.D(), system.y0(), 0.0)
    raise ScenarioError(f"LinearSystemBank serves LinearSystems and stateless AffineSystems, "
                        f"not {type(system).__name__} '{system.get_name()}'")


class LinearSystemBank(LeafSystem):
    """N discrete linear systems of one shape and period (one per
    environment; their matrices and initial states may differ) as one
    system, each environment's values bit for bit those of its system
    alone (see the module doc).

    Ports keep the systems' own names (``u0``, ``y0``): input N m,
    env-major; output N p, env-major, or with ``output_sizes`` (summing to
    p) field-major, each field's values for environments 0..N-1 then the
    next field's, for a Demultiplexer to split into arm-axis ports. The
    state is N k, env-major, starting at each system's default state. The
    output reads the input only if some D is nonzero, as Drake's
    LinearSystem does."""

    def __init__(self, systems, *, output_sizes=None):
        super().__init__()
        systems = list(systems)
        parts = [_matrices(s) for s in systems]
        first = systems[0]
        shapes = {tuple(np.shape(m) for m in p[:4]) + (p[5],) for p in parts}
        if len(shapes) != 1:
            raise ScenarioError(f"LinearSystemBank: the systems like '{first.get_name()}' differ "
                                "in shape or period; an ensemble's environments share a structure")
        self.count = count = len(systems)
        A, B, C, D, y0, period = parts[0]
        self._k, self._m, self._p = A.shape[0], B.shape[1], C.shape[0]
        self._A = _SparseProduct([p[0] for p in parts])
        self._B = _SparseProduct([p[1] for p in parts])
        self._C = _SparseProduct([p[2] for p in parts])
        self._D = _SparseProduct([p[3] for p in parts])
        self._fields = np.cumsum([0] + list(output_sizes or [self._p]))
        if self._fields[-1] != self._p:
            raise ScenarioError(f"LinearSystemBank: output_sizes {output_sizes} do not sum to "
                                f"the output's {self._p}")
        self._y0 = None if y0 is None else np.stack([p[4] for p in parts], axis=1)  # (p, N)
        self._u = self.DeclareVectorInputPort(first.get_input_port().get_name(),
                                              self._m * count) if self._m else None
        prerequisites = set()
        if self._k:
            initial = np.concatenate([
                s.CreateDefaultContext().get_discrete_state_vector().CopyToVector()
                for s in systems])
            self._x = self.DeclareDiscreteState(initial)
            self.DeclarePeriodicDiscreteUpdateEvent(period, 0.0, self._update)
            prerequisites.add(self.xd_ticket())
        if self._D.nnz:
            prerequisites.add(self._u.ticket())
        if not prerequisites:
            prerequisites.add(self.nothing_ticket())
        self.DeclareVectorOutputPort(first.get_output_port().get_name(), self._p * count,
                                     self._output, prerequisites_of_calc=prerequisites)

    def _inputs(self, context):
        return self._u.Eval(context).reshape(self.count, self._m).T

    def _state(self, context):
        return context.get_discrete_state(self._x).value().reshape(self.count, self._k).T

    def _update(self, context, discrete_state):
        x = self._state(context)
        xn = self._A(x) + self._B(self._inputs(context)) if self._m else self._A(x)
        discrete_state.set_value(self._x, xn.T.ravel())

    def _output(self, context, output: BasicVector):
        y = self._C(self._state(context)) if self._k else None
        if self._D.nnz:
            d = self._D(self._inputs(context))
            y = d if y is None else y + d
        elif y is None:
            y = np.zeros((self._p, self.count))
        if self._y0 is not None:
            y = y + self._y0
        output.SetFromVector(np.concatenate([y[start:end].T.ravel() for start, end in
                                             zip(self._fields[:-1], self._fields[1:])]))


def StackedSymbolicSystem(pieces, *, input_sizes=None, output_sizes=None,
                          time_period=0.0):
    """One system for N environments from their pieces: per environment a
    mapping with ``input`` (variables), ``output`` (expressions), and
    optionally ``state``, ``dynamics`` and ``time`` (a variable). One piece
    gives its ``SymbolicVectorSystem``; N give a :class:`CompiledExpressions`
    whose every environment's values are bit for bit its own system's.

    The input vector is field-major by ``input_sizes`` (default: one
    field): field f's values for environments 0..N-1, env-major, then the
    next field's, so a Multiplexer of the fields' arm-axis ports feeds it.
    The output is field-major by ``output_sizes`` likewise, for a
    Demultiplexer to split into arm-axis ports. The state is env-major and
    starts at 0.

    Raises ValueError for pieces of different sizes, fields that do not sum
    to the input or output, or a state without ``time_period`` (a
    continuous system, which only one piece could give), and TypeError for
    an output or dynamics that is not an expression (a bare ``Variable``:
    wrap it, ``Expression(v)``), so that one piece and N behave alike."""
    pieces = list(pieces)
    _check_pieces(pieces, input_sizes, output_sizes, time_period)
    if len(pieces) > 1:
        return CompiledExpressions(pieces, input_sizes=input_sizes, output_sizes=output_sizes,
                                   time_period=time_period)
    (piece,) = pieces
    return SymbolicVectorSystem(time=piece.get("time"), state=list(piece.get("state", [])),
                                input=list(piece["input"]),
                                dynamics=list(piece.get("dynamics", [])),
                                output=list(piece["output"]), time_period=time_period)


def _check_pieces(pieces, input_sizes, output_sizes, time_period):
    if not pieces:
        raise ValueError("StackedSymbolicSystem: no pieces (one per environment)")
    sizes = {(len(p["input"]), len(p.get("state", [])), len(p["output"]),
              len(p.get("dynamics", []))) for p in pieces}
    if len(sizes) != 1:
        raise ValueError(f"StackedSymbolicSystem: the pieces differ in their sizes "
                         f"(input, state, output, dynamics): {sorted(sizes)}")
    ((m, k, p, d),) = sizes
    if d != k:
        raise ValueError(f"StackedSymbolicSystem: {d} dynamics for a state of {k}")
    if k and not time_period > 0:
        raise ValueError("StackedSymbolicSystem: a state needs a time_period > 0 (a discrete "
                         f"update); got {time_period}")
    for name, fields, size in (("input_sizes", input_sizes, m), ("output_sizes", output_sizes, p)):
        if fields is not None and sum(fields) != size:
            raise ValueError(f"StackedSymbolicSystem: {name} {list(fields)} do not sum to {size}")
    for piece in pieces:
        for key in ("output", "dynamics"):
            for e in piece.get(key, []):
                if not isinstance(e, (symbolic.Expression, float, int)):
                    raise TypeError(f"StackedSymbolicSystem: {key} {e!r} is a "
                                    f"{type(e).__name__}, not an Expression (wrap a Variable "
                                    "as Expression(v))")


class _Program:
    """One environment's expressions as straight-line numpy code: each node
    a register, computed as Drake's ``Expression.Evaluate`` computes it.
    Registers are shared by equal (operation, operands), constants by
    value; ``signature`` is the code with the constants' values left out,
    so environments that differ only in constants share one compiled
    function over arrays."""

    def __init__(self, variables):
        self._index = {v.get_id(): i for i, v in enumerate(variables)}
        self.code, self.constants = [], []
        self._memo = {}

    def _reg(self, key):
        if key not in self._memo:
            self._memo[key] = len(self.code)
            self.code.append(key)
        return self._memo[key]

    def _constant_value(self, register):
        op = self.code[register]
        return self.constants[op[1]] if op[0] == "const" else None

    def constant(self, value):
        value = float(value)
        key = ("const", value)
        if key not in self._memo:
            self._memo[key] = len(self.code)
            self.code.append(("const", len(self.constants)))
            self.constants.append(value)
        return self._memo[key]

    def expression(self, e):
        if not isinstance(e, symbolic.Expression):
            return self.constant(e)
        kind = e.get_kind()
        _, args = e.Unapply()
        K = symbolic.ExpressionKind
        if kind == K.Constant:
            return self.constant(args[0])
        if kind == K.Var:
            return self._reg(("var", self._index[args[0].get_id()]))
        if kind == K.Add:
            # constant + term_1 * coeff_1 + ..., in Drake's order; Unapply
            # gives each term times its coefficient, a product whose
            # constant is the coefficient.
            total = self.constant(args[0])
            for addend in args[1:]:
                coeff, factors = 1.0, [addend]
                if addend.get_kind() == K.Mul:
                    _, parts = addend.Unapply()
                    coeff, factors = parts[0], parts[1:]
                term = self.expression(factors[0])
                for factor in factors[1:]:
                    term = self._reg(("mul", term, self.expression(factor)))
                if coeff != 1.0:  # x * 1 is x, bit for bit
                    term = self._reg(("mul", term, self.constant(coeff)))
                total = self._reg(("add", total, term))
            return total
        if kind == K.Mul:
            # 1 * x is x and -1 * x is -x, bit for bit.
            constant, first = args[0], self.expression(args[1])
            product = (first if constant == 1.0 else self._reg(("neg", first))
                       if constant == -1.0 else
                       self._reg(("mul", self.constant(constant), first)))
            for factor in args[2:]:
                product = self._reg(("mul", product, self.expression(factor)))
            return product
        if kind == K.IfThenElse:
            return self._reg(("where", self.formula(args[0]), self.expression(args[1]),
                              self.expression(args[2])))
        name = _UNARY.get(kind) or _BINARY.get(kind)
        if name in ("max", "min"):
            # max(a, -inf) and min(a, inf) are a, NaN included (std::max(a, b)
            # is a < b ? b : a).
            a, b = self.expression(args[0]), self.expression(args[1])
            if self._constant_value(b) == (-math.inf if name == "max" else math.inf):
                return a
            return self._reg((name, a, b))
        if name is None:
            raise TypeError(f"CompiledExpressions: expression kind {kind} is not supported")
        return self._reg((name, *(self.expression(a) for a in args)))

    def formula(self, f):
        kind = f.get_kind()
        F = symbolic.FormulaKind
        if kind == F.True_:
            return self._reg(("bool", True))
        if kind == F.False_:
            return self._reg(("bool", False))
        _, args = f.Unapply()
        if kind in _RELATIONS:
            return self._reg((_RELATIONS[kind], self.expression(args[0]),
                              self.expression(args[1])))
        if kind == F.Not:
            return self._reg(("not", self.formula(args[0])))
        if kind in (F.And, F.Or):
            result = self.formula(args[0])
            for other in args[1:]:
                result = self._reg(("and" if kind == F.And else "or", result,
                                    self.formula(other)))
            return result
        raise TypeError(f"CompiledExpressions: formula kind {kind} is not supported")

    def signature(self, outputs):
        return tuple(self.code), tuple(outputs)


_UNARY = {symbolic.ExpressionKind.Abs: "abs", symbolic.ExpressionKind.Floor: "floor",
          symbolic.ExpressionKind.Ceil: "ceil", symbolic.ExpressionKind.Sqrt: "sqrt",
          symbolic.ExpressionKind.Sin: "sin", symbolic.ExpressionKind.Cos: "cos",
          symbolic.ExpressionKind.Exp: "exp"}
_BINARY = {symbolic.ExpressionKind.Div: "div", symbolic.ExpressionKind.Pow: "pow",
           symbolic.ExpressionKind.Max: "max", symbolic.ExpressionKind.Min: "min"}
_RELATIONS = {symbolic.FormulaKind.Lt: "<", symbolic.FormulaKind.Leq: "<=",
              symbolic.FormulaKind.Gt: ">", symbolic.FormulaKind.Geq: ">=",
              symbolic.FormulaKind.Eq: "==", symbolic.FormulaKind.Neq: "!="}


# The C library's exp and pow, which Drake's evaluation calls (numpy's
# differ from them in the last bit for some arguments on AVX-512 machines),
# element by element.
_EXP = np.frompyfunc(math.exp, 1, 1)
_POW = np.frompyfunc(math.pow, 2, 1)
#: Python's exp is finite up to here (exp(709.78) = 1.797e308); above it,
#: where C's exp overflows to inf and Python's raises, numpy's is used.
_EXP_LIMIT = 709.78


def _libm_exp(x):
    x = np.asarray(x, dtype=float)
    result = _EXP(np.minimum(x, _EXP_LIMIT)).astype(float)  # NaN stays NaN
    over = x > _EXP_LIMIT
    if over.any():
        result[over] = np.exp(x[over])
    return result


def libm_pow(base, exponent):
    """C's pow (Python's ``**`` on floats) elementwise on arrays, bit for
    bit (numpy's power may round differently)."""
    base, exponent = np.broadcast_arrays(np.asarray(base, dtype=float),
                                         np.asarray(exponent, dtype=float))
    # Where Python raises (a negative base to a fraction, 0 to a negative
    # power, overflow) C gives NaN or inf: numpy's power gives those too.
    with np.errstate(all="ignore"):
        special = (((base < 0) & (exponent != np.floor(exponent)))
                   | ((base == 0) & (exponent < 0)) | ~np.isfinite(base)
                   | ~np.isfinite(exponent) | (np.abs(exponent) * np.log2(np.abs(base) + 1.0)
                                                > 1000.0))
        safe_base = np.where(special, 1.0, base)
        safe_exponent = np.where(special, 1.0, exponent)
        return np.where(special, np.power(base, exponent),
                        _POW(safe_base, safe_exponent).astype(float))


def _line(register, op):
    name, *args = op
    r = [f"r{a}" for a in args]
    if name == "const":
        return f"r{register} = C[{args[0]}]"
    if name == "var":
        return f"r{register} = V[{args[0]}]"
    if name == "bool":
        return f"r{register} = {args[0]}"
    binary = {"add": "+", "mul": "*", "div": "/", "<": "<", "<=": "<=", ">": ">",
              ">=": ">=", "==": "==", "!=": "!=", "and": "&", "or": "|"}
    if name in binary:
        return f"r{register} = {r[0]} {binary[name]} {r[1]}"
    calls = {"abs": "np.abs", "floor": "np.floor", "ceil": "np.ceil", "sqrt": "np.sqrt",
             "sin": "np.sin", "cos": "np.cos", "exp": "_libm_exp", "not": "np.logical_not",
             "neg": "np.negative",
             "pow": "_libm_pow"}
    if name in calls:
        return f"r{register} = {calls[name]}({', '.join(r)})"
    if name == "max":  # std::max(a, b): a < b ? b : a
        return f"r{register} = np.where({r[0]} < {r[1]}, {r[1]}, {r[0]})"
    if name == "min":  # std::min(a, b): b < a ? b : a
        return f"r{register} = np.where({r[1]} < {r[0]}, {r[1]}, {r[0]})"
    if name == "where":
        return f"r{register} = np.where({r[0]}, {r[1]}, {r[2]})"
    raise NotImplementedError(name)


def _compile(code, outputs):
    """A function (V, C) -> tuple of the outputs' arrays, from a program's
    code (see :class:`_Program`)."""
    lines = ["def run(V, C):"] + [f"    {_line(i, op)}" for i, op in enumerate(code)]
    lines.append(f"    return ({''.join(f'r{o}, ' for o in outputs)})")
    namespace = {"np": np, "_libm_exp": _libm_exp, "_libm_pow": libm_pow}
    exec("\n".join(lines), namespace)
    return namespace["run"]


class _Group:
    """The environments whose expressions share a signature: one compiled
    function over arrays of their values."""

    def __init__(self, envs, code, outputs, constants):
        self.envs = np.asarray(envs)
        self.where = None  # each variable's index in the values vector, per environment
        self.run = _compile(code, outputs)
        self.constants = [np.asarray(c) for c in np.array(constants, dtype=float).T]


def _groups(programs, outputs):
    by_signature = {}
    for env, (program, out) in enumerate(zip(programs, outputs)):
        by_signature.setdefault(program.signature(out), []).append(env)
    return [_Group(envs, programs[envs[0]].code, outputs[envs[0]],
                   [programs[e].constants for e in envs]) for envs in by_signature.values()]


def _field_major_positions(count, sizes):
    """(count, sum(sizes)) positions of each environment's values in a
    vector that holds field f's values for environments 0..count-1, then
    the next field's."""
    positions = np.zeros((count, sum(sizes)), dtype=int)
    offset = 0
    for f, size in enumerate(sizes):
        start = sum(sizes[:f])
        for env in range(count):
            positions[env, start:start + size] = offset + np.arange(size)
            offset += size
    return positions


class CompiledExpressions(LeafSystem):
    """N environments' pieces (see :func:`StackedSymbolicSystem`) evaluated
    with numpy over all of them, each environment's values bit for bit
    what its own ``SymbolicVectorSystem`` gives (see the module doc). Ports
    as the stacked ``SymbolicVectorSystem``'s: input ``u0`` (field-major by
    ``input_sizes``), output ``y0`` (field-major by ``output_sizes``),
    state env-major, updated every ``time_period`` (0: no state)."""

    def __init__(self, pieces, *, input_sizes=None, output_sizes=None, time_period=0.0):
        super().__init__()
        pieces = list(pieces)
        count = len(pieces)
        m = len(pieces[0]["input"])
        k = len(pieces[0].get("state", []))
        p = len(pieces[0]["output"])
        input_fields = input_sizes or [m]
        output_fields = output_sizes or [p]
        # Where each environment's input, state and outputs sit in the
        # system's vectors: the values vector is [u; x; t].
        input_at = _field_major_positions(count, input_fields)
        output_at = _field_major_positions(count, output_fields)
        state_at = m * count + np.arange(count * k).reshape(count, k)
        time_at = np.full((count, 1), m * count + k * count)
        self._where = np.hstack([input_at, state_at, time_at])  # (N, m + k + 1)
        self._output_at, self._count, self._k = output_at, count, k
        outputs, dynamics, uses = [], [], {"input": False, "state": False, "time": False}
        for piece in pieces:
            time = piece.get("time")
            variables = (list(piece["input"]) + list(piece.get("state", []))
                         + [time if time is not None else symbolic.Variable("unused_time")])
            out = _Program(variables)
            outputs.append((out, [out.expression(e) for e in piece["output"]]))
            dyn = _Program(variables)
            dynamics.append((dyn, [dyn.expression(e) for e in piece.get("dynamics", [])]))
            used = {v.get_id() for e in piece["output"]
                    for v in (symbolic.Expression(e) if not isinstance(e, symbolic.Expression)
                              else e).GetVariables()}
            uses["input"] |= any(v.get_id() in used for v in piece["input"])
            uses["state"] |= any(v.get_id() in used for v in piece.get("state", []))
            uses["time"] |= time is not None and time.get_id() in used
        self._outputs = _groups([o for o, _ in outputs], [r for _, r in outputs])
        self._dynamics = _groups([d for d, _ in dynamics], [r for _, r in dynamics])
        self._u = self.DeclareVectorInputPort("u0", m * count)
        prerequisites = set()
        if k:
            initial = np.zeros(k * count)
            self._x = self.DeclareDiscreteState(initial)
            self.DeclarePeriodicDiscreteUpdateEvent(time_period, 0.0, self._update)
        if uses["input"]:
            prerequisites.add(self._u.ticket())
        if uses["state"]:
            prerequisites.add(self.xd_ticket())
        if uses["time"]:
            prerequisites.add(self.time_ticket())
        self.DeclareVectorOutputPort("y0", p * count, self._output,
                                     prerequisites_of_calc=prerequisites or
                                     {self.nothing_ticket()})

    def _values(self, context):
        state = context.get_discrete_state(self._x).value() if self._k else np.zeros(0)
        return np.concatenate([self._u.Eval(context), state, [context.get_time()]])

    def _evaluate(self, groups, values, size):
        out = np.empty((self._count, size))
        with np.errstate(all="ignore"):
            for group in groups:
                if group.where is None:
                    group.where = self._where[group.envs].T.copy()  # (variables, Ng)
                results = group.run(values[group.where], group.constants)
                if results:
                    out[group.envs] = np.stack(results, axis=1)
        return out

    def _output(self, context, output):
        y = self._evaluate(self._outputs, self._values(context), self._output_at.shape[1])
        flat = np.empty(y.size)
        flat[self._output_at] = y
        output.SetFromVector(flat)

    def _update(self, context, discrete_state):
        x = self._evaluate(self._dynamics, self._values(context), self._k)
        discrete_state.set_value(self._x, x.ravel())
