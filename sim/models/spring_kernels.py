"""Compiled kernels (numba) of the mass-spring model's passes over its springs: one memory pass
instead of several sparse products and temporaries. The callers (`mass_spring`, `local_global`,
`newton`) keep a NumPy path for an install without numba (`python -m bench mass_spring` prints
both)."""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True, fastmath=False, inline="always")
def _spring_vector(x, i, j):
    """x_i - x_j and its length, the geometry of every pass over the springs."""
    d0 = x[i, 0] - x[j, 0]
    d1 = x[i, 1] - x[j, 1]
    d2 = x[i, 2] - x[j, 2]
    return d0, d1, d2, np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)


@numba.njit(cache=True, fastmath=False)
def _spring_sum(x, ei, ej, k, rest, free_pos, n_free, gradient):
    """sum over springs of c (x_i - x_j), +at i and -at j, on the free rows, with c = k rest / |d|
    (the local/global right-hand side) or, with `gradient`, k - that = k (1 - rest / |d|) (the
    springs' energy gradient). One loop for both; the flag is constant through it."""
    out = np.zeros((n_free, 3))
    for s in range(ei.shape[0]):
        i, j = ei[s], ej[s]
        d0, d1, d2, length = _spring_vector(x, i, j)
        c = k[s] * (rest[s] / length if length > 0.0 else 1.0)  # a zero-length spring adds nothing either way
        if gradient:
            c = k[s] - c
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


@numba.njit(cache=True, fastmath=False)
def spring_rhs(x, ei, ej, k, rest, free_pos, n_free):
    """sum over springs of k (x_i - x_j) rest / |x_i - x_j|, +at i and -at j, on the free rows:
    the local/global step's A^T diag(k) d with every spring projected to its rest length."""
    return _spring_sum(x, ei, ej, k, rest, free_pos, n_free, False)


@numba.njit(cache=True, fastmath=False)
def spring_gradient(x, ei, ej, k, rest, free_pos, n_free):
    """The springs' energy gradient on the free rows: k (1 - rest / |d|) d, d = x_i - x_j,
    +at i and -at j (the Newton solver's right-hand side, `sim/models/newton_krylov.py`)."""
    return _spring_sum(x, ei, ej, k, rest, free_pos, n_free, True)


@numba.njit(cache=True, fastmath=False)
def explicit_substeps(x, v, m, fixed, ei, ej, k, rest, anchor_nodes, anchor_ptr, anchor_k, anchor_target, external, damping, h, n_sub):
    """`n_sub` symplectic Euler steps of `h` in place (`MassSpring._explicit`: velocity, then
    position with the new velocity; clamped nodes do not move). Forces: the springs
    k (|d| - rest) / |d| d (a zero-length spring adds nothing), the anchors k (mean(x[nodes]) -
    target) / |nodes| on each of their nodes, `external` and the damping -damping m v. One pass
    over the springs and one over the nodes a step, where the NumPy step makes about ten."""
    n = x.shape[0]
    f = np.empty((n, 3))
    for _ in range(n_sub):
        for i in range(n):
            for c in range(3):
                f[i, c] = external[i, c] - damping * m[i] * v[i, c]
        for s in range(ei.shape[0]):
            i, j = ei[s], ej[s]
            d0, d1, d2, length = _spring_vector(x, i, j)
            mag = k[s] * (length - rest[s]) / (length if length > 0.0 else 1.0)
            f[i, 0] -= mag * d0
            f[i, 1] -= mag * d1
            f[i, 2] -= mag * d2
            f[j, 0] += mag * d0
            f[j, 1] += mag * d1
            f[j, 2] += mag * d2
        for a in range(anchor_k.shape[0]):
            lo, hi = anchor_ptr[a], anchor_ptr[a + 1]
            cnt = hi - lo
            if cnt == 0:  # an anchor on no node pulls nothing (as the NumPy step)
                continue
            for c in range(3):
                mean = 0.0
                for p in range(lo, hi):
                    mean += x[anchor_nodes[p], c]
                g = anchor_k[a] * (mean / cnt - anchor_target[a, c]) / cnt
                for p in range(lo, hi):
                    f[anchor_nodes[p], c] -= g
        for i in range(n):
            if fixed[i]:
                for c in range(3):
                    v[i, c] = 0.0
                continue
            for c in range(3):
                v[i, c] += h * (f[i, c] / m[i])
                x[i, c] += h * v[i, c]


@numba.njit(cache=True, fastmath=False)
def spring_energy(x, ei, ej, k, rest):
    """sum over springs of k/2 (|x_i - x_j| - rest)^2: the springs' part of the local/global
    objective, for Anderson acceleration's energy safeguard."""
    total = 0.0
    for s in range(ei.shape[0]):
        length = _spring_vector(x, ei[s], ej[s])[3]
        stretch = length - rest[s]
        total += 0.5 * k[s] * stretch * stretch
    return total


@numba.njit(cache=True, fastmath=False)
def spring_hessian_product(x, ei, ej, k, rest, free_pos, p):
    """The springs' exact Hessian at x times p (free rows; clamped nodes do not move), matrix
    free: per spring k (n n^T + (1 - rest/|d|) (I - n n^T)) (p_i - p_j), n = d / |d|. The
    transverse term is not clamped (it is negative for a compressed spring): Newton keeps its
    quadratic convergence and PCG watches for negative curvature instead."""
    out = np.zeros_like(p)
    for s in range(ei.shape[0]):
        i, j = ei[s], ej[s]
        d0, d1, d2, length = _spring_vector(x, i, j)
        if length <= 0.0:
            continue
        fi, fj = free_pos[i], free_pos[j]
        q0 = q1 = q2 = 0.0
        if fi >= 0:
            q0, q1, q2 = p[fi, 0], p[fi, 1], p[fi, 2]
        if fj >= 0:
            q0, q1, q2 = q0 - p[fj, 0], q1 - p[fj, 1], q2 - p[fj, 2]
        inv = 1.0 / length
        n0, n1, n2 = d0 * inv, d1 * inv, d2 * inv
        along = n0 * q0 + n1 * q1 + n2 * q2
        t = 1.0 - rest[s] * inv
        a = k[s] * (1.0 - t) * along
        b = k[s] * t
        h0, h1, h2 = a * n0 + b * q0, a * n1 + b * q1, a * n2 + b * q2
        if fi >= 0:
            out[fi, 0] += h0
            out[fi, 1] += h1
            out[fi, 2] += h2
        if fj >= 0:
            out[fj, 0] -= h0
            out[fj, 1] -= h1
            out[fj, 2] -= h2
    return out


def warm_up() -> None:
    """Compile (or load from numba's cache) every spring kernel for the argument types the model
    passes, on tiny inputs: spent when a model is built rather than in the first deformation frame
    of a trial, where it would stall the participant's view (the cost: docs/scenes.md)."""
    x = np.zeros((2, 3))
    idx = np.array([0], dtype=np.int64)
    free_pos = np.array([0, 1], dtype=np.int64)
    spring_rhs(x, idx, idx + 1, np.ones(1), np.ones(1), free_pos, 2)
    spring_energy(x, idx, idx + 1, np.ones(1), np.ones(1))
    spring_gradient(x, idx, idx + 1, np.ones(1), np.ones(1), free_pos, 2)
    spring_hessian_product(x, idx, idx + 1, np.ones(1), np.ones(1), free_pos, x)
    explicit_substeps(x.copy(), np.zeros((2, 3)), np.ones(2), np.zeros(2, dtype=np.bool_), idx, idx + 1, np.ones(1), np.ones(1), idx,
                      free_pos, np.ones(1), np.zeros((1, 3)), np.zeros((2, 3)), 0.0, 1e-3, 1)
