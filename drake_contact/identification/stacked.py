"""The identifiers' arithmetic for one environment or N (the arm axis),
written once.

One environment's buffers have no environment axis and its per-environment
constants are Python floats, so that at N = 1 every operation is what the
one-environment code did (numpy's per-call cost on 3- and 4-vectors is most
of a sample's time; a Python float's arithmetic is a tenth of a numpy
call's). N environments' buffers have a leading axis of N and their
constants are (N,) arrays. The products go through :func:`matvec` and
:func:`rowdot`: ``np.dot`` for one environment, ``np.matmul`` over the stack
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


def matvec(A, x, out):
    """out = A x: one environment's (r, c) and (c,), or N's stacked."""
    if A.ndim == 2:
        np.dot(A, x, out=out)
    else:
        np.matmul(A, x[..., None], out=out[..., None])


def rowdot(a, b):
    """a . b: one environment's vectors (a float), or N's rows ((N,))."""
    if a.ndim == 1:
        return np.dot(a, b)
    return np.matmul(a[:, None, :], b[:, :, None])[:, 0, 0]
