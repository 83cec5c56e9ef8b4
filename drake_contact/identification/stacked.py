"""The identifiers' arithmetic for one environment or N (the arm axis),
written once.

One environment's buffers have no environment axis and its per-environment
constants are Python floats, so that at N = 1 every operation is what the
one-environment code did (numpy's per-call cost on 3- and 4-vectors is most
of a sample's time; a Python float's arithmetic is a tenth of a numpy
call's). N environments' buffers have a leading axis of N and their
constants are (N,) arrays. The products go through :func:`products`: ``np.dot`` for one environment, ``np.matmul`` over the stack
for N, which calls BLAS's gemv or dot once per environment with the
arguments ``np.dot`` passes for one, so each environment's sums are bit for
bit its own (tests/test_ensemble_identifiers.py).
"""

import numpy as np


def constants(values, one):
    """Per-environment constants: a Python float for one environment, else
    an (N,) array."""
    array = np.asarray(values, dtype=float)
    return float(array[0]) if one else array


def column(values, one):
    """Per-environment scalars to scale an environment's vector: as they
    are for one environment, else (N, 1)."""
    return values if one else values[:, None]


def _matvec(A, x, out):
    np.matmul(A, x[..., None], out=out[..., None])


def _rowdot(a, b):
    return np.matmul(a[:, None, :], b[:, :, None])[:, 0, 0]


def products(one):
    """(matvec, rowdot) for one environment or N: matvec(A, x, out) puts
    A x into ``out`` (one environment's (r, c) and (c,), or N's stacked);
    rowdot(a, b) is a . b (a float for one, (N,) for N's rows). For one
    environment both are ``np.dot`` itself (no Python call in between: it
    runs several times per sample)."""
    return (np.dot, np.dot) if one else (_matvec, _rowdot)
