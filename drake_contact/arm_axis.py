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
- :func:`StackedSymbolicSystem`: N environments' expressions for one
  ``SymbolicVectorSystem``. Each expression is evaluated as it is alone.

Why one system and not N copies: each discrete system's update notifies
everything downstream of it in the diagram, and in an ensemble the
downstream of any environment reaches the shared plant and so all N, so N
copies of a discrete role cost O(N^2) per step (measured: 174 us per
environment-step at N = 64 for the plant with copies of the wall and the
friction, 27 at N = 1).
"""

import numpy as np
from pydrake import symbolic
from pydrake.systems.framework import BasicVector, LeafSystem
from pydrake.systems.primitives import AffineSystem, LinearSystem, SymbolicVectorSystem

from drake_contact.errors import ScenarioError


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


def _expression(e):
    return e if isinstance(e, symbolic.Expression) else symbolic.Expression(e)


def StackedSymbolicSystem(pieces, *, input_sizes=None, output_sizes=None,
                          time_period=0.0):
    """One ``SymbolicVectorSystem`` for N environments from their pieces:
    per environment a mapping with ``input`` (variables), ``output``
    (expressions), and optionally ``state``, ``dynamics`` and ``time`` (a
    variable, shared in the result). Each environment's expressions are
    evaluated as they are alone, so its values are bit for bit its own
    system's.

    The input vector is field-major by ``input_sizes`` (default: one
    field): field f's values for environments 0..N-1, env-major, then the
    next field's, so a Multiplexer of the fields' arm-axis ports feeds it.
    The output is field-major by ``output_sizes`` likewise, for a
    Demultiplexer to split into arm-axis ports. The state is env-major."""
    pieces = list(pieces)
    time = symbolic.Variable("t")

    def shared_time(piece, expressions):
        if piece.get("time") is None:
            return list(expressions)
        return [_expression(e).Substitute(piece["time"], time) for e in expressions]

    def field_major(vectors, sizes):
        sizes = sizes or [len(vectors[0])]
        result, offset = [], 0
        for size in sizes:
            for vector in vectors:
                result.extend(vector[offset:offset + size])
            offset += size
        return result

    inputs = field_major([list(p["input"]) for p in pieces], input_sizes)
    outputs = field_major([shared_time(p, p["output"]) for p in pieces], output_sizes)
    state = [v for p in pieces for v in p.get("state", [])]
    dynamics = [e for p in pieces for e in shared_time(p, p.get("dynamics", []))]
    uses_time = any(p.get("time") is not None for p in pieces)
    return SymbolicVectorSystem(time=time if uses_time else None, state=state, input=inputs,
                                dynamics=dynamics, output=outputs, time_period=time_period)
