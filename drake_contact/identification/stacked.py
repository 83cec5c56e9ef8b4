"""The identifiers' arithmetic for one environment or N (the arm axis),
written once.

One environment's buffers have no environment axis and its scalars (the
inputs it reads, its constants, a dot product) are floats, so that at N = 1
every operation is what the one-environment code did (numpy's per-call cost
on 3- and 4-vectors is most of a sample's time; a float's arithmetic is a
tenth of a numpy call's). N environments' buffers have a leading axis of N
and their scalars are columns (N, 1), which broadcast against their rows as
a float does against one environment's vector: the same expression serves
both. The products go through :func:`products`: ``np.dot`` for one
environment, ``np.matmul`` over the stack for N, which calls BLAS's gemv or
dot once per environment with the arguments ``np.dot`` passes for one, so
each environment's sums are bit for bit its own
(tests/test_ensemble_identifiers.py). Elementwise operations are the same
IEEE operations whatever the shape.
"""

import numpy as np



def constants(values, one):
    """Per-environment constants: a float for one environment, else a
    column (N, 1)."""
    array = np.asarray(values, dtype=float)
    return float(array[0]) if one else array[:, None]


def at(k, one):
    """The index of each environment's k-th value on a buffer's last axis:
    a scalar for one environment, a column (N, 1) view for N."""
    return k if one else (slice(None), slice(k, k + 1))


def every(k, stride, one):
    """The index of each environment's k-th value in an env-major input of
    ``stride`` values per environment: a scalar for one, a column (N, 1)
    for N."""
    return k if one else (slice(k, None, stride), None)


def together(values, one):
    """Scalars of each environment side by side: one environment's array,
    or N's rows (N, k) from their columns."""
    return np.array(values) if one else np.concatenate(values, axis=-1)


def _matvec(A, x, out):
    np.matmul(A, x[..., None], out=out[..., None])


def _rowdot(a, b):
    return np.matmul(a[:, None, :], b[:, :, None])[:, 0]


def products(one):
    """(matvec, rowdot) for one environment or N: matvec(A, x, out) puts
    A x into ``out`` (one environment's (r, c) and (c,), or N's stacked);
    rowdot(a, b) is a . b (a float for one, a column (N, 1) for N's rows).
    For one environment both are ``np.dot`` itself (no Python call in
    between: they run several times per sample)."""
    return (np.dot, np.dot) if one else (_matvec, _rowdot)


def stepped(started, paused, one):
    """Which environments an identifier steps at this sample: those past
    their switch (``started``, (N,); None: all) whose force reading is not
    flagged (``paused``: :func:`drake_contact.plant.arm.held_while_flagged`).
    Returns (step, started): step False when none is stepped; started the
    mask to step by (None: all)."""
    if paused is None:
        return True, started
    if one:
        return False, None
    started = ~paused if started is None else started & ~paused
    return bool(started.any()), started
