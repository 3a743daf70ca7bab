"""Compiled kernels (numba) for the passes over springs: one memory pass instead of several
sparse products and temporaries. Imported only where numba is installed; the callers keep a
NumPy path (`python -m bench mass_spring` prints both)."""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True, fastmath=False)
def spring_rhs(x, ei, ej, k, rest, free_pos, n_free):
    """sum over springs of k (x_i - x_j) rest / |x_i - x_j|, +at i and -at j, on the free rows:
    the local/global step's A^T diag(k) d with every spring projected to its rest length."""
    out = np.zeros((n_free, 3))
    for s in range(ei.shape[0]):
        i, j = ei[s], ej[s]
        d0 = x[i, 0] - x[j, 0]
        d1 = x[i, 1] - x[j, 1]
        d2 = x[i, 2] - x[j, 2]
        length = np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
        c = k[s] * (rest[s] / length if length > 0.0 else 1.0)
        fi, fj = free_pos[i], free_pos[j]
        if fi >= 0:
            out[fi, 0] += c * d0
            out[fi, 1] += c * d1
            out[fi, 2] += c * d2
        if fj >= 0:
            out[fj, 0] -= c * d0
            out[fj, 1] -= c * d1
            out[fj, 2] -= c * d2
    return out
