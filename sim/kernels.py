"""Compiled kernels (numba) for the passes over springs: one memory pass instead of several
sparse products and temporaries. Imported only where numba is installed; the callers keep a
NumPy path (`python -m bench mass_spring` prints both)."""

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
    +at i and -at j (the Newton solver's right-hand side, `sim/models/newton.py`)."""
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


@numba.njit(cache=True)
def _inv3(a, out):
    """out = a^-1 for a 3 x 3 matrix; returns det a."""
    c00 = a[1, 1] * a[2, 2] - a[1, 2] * a[2, 1]
    c01 = a[1, 2] * a[2, 0] - a[1, 0] * a[2, 2]
    c02 = a[1, 0] * a[2, 1] - a[1, 1] * a[2, 0]
    det = a[0, 0] * c00 + a[0, 1] * c01 + a[0, 2] * c02
    inv = 1.0 / det
    out[0, 0] = c00 * inv
    out[1, 0] = c01 * inv
    out[2, 0] = c02 * inv
    out[0, 1] = (a[0, 2] * a[2, 1] - a[0, 1] * a[2, 2]) * inv
    out[1, 1] = (a[0, 0] * a[2, 2] - a[0, 2] * a[2, 0]) * inv
    out[2, 1] = (a[0, 1] * a[2, 0] - a[0, 0] * a[2, 1]) * inv
    out[0, 2] = (a[0, 1] * a[1, 2] - a[0, 2] * a[1, 1]) * inv
    out[1, 2] = (a[0, 2] * a[1, 0] - a[0, 0] * a[1, 2]) * inv
    out[2, 2] = (a[0, 0] * a[1, 1] - a[0, 1] * a[1, 0]) * inv
    return det


@numba.njit(cache=True)
def polar_rotations(F, R, det, tol=1e-13, max_iter=40):
    """The rotation of the polar decomposition F = R S of every 3 x 3 F with det F > 0 (scaled
    Newton iteration, Higham 1986: R <- (g R + R^-T / g) / 2); R of the others is left for the
    caller (an inverted element: SVD with the reflection removed). Fills det. Returns the
    indices left over, as a boolean mask."""
    left = np.zeros(F.shape[0], dtype=np.bool_)
    X = np.empty((3, 3))
    Y = np.empty((3, 3))
    for e in range(F.shape[0]):
        for i in range(3):
            for j in range(3):
                X[i, j] = F[e, i, j]
        d = _inv3(X, Y)
        det[e] = d
        if not d > 0.0:
            left[e] = True
            continue
        for _ in range(max_iter):
            nx = 0.0
            ny = 0.0
            for i in range(3):
                for j in range(3):
                    nx += X[i, j] * X[i, j]
                    ny += Y[i, j] * Y[i, j]
            g = np.sqrt(np.sqrt(ny / nx))
            change = 0.0
            for i in range(3):
                for j in range(3):
                    v = 0.5 * (g * X[i, j] + Y[j, i] / g)  # Y^T: R^-T
                    change += (v - X[i, j]) * (v - X[i, j])
                    X[i, j] = v
            if change < tol * tol * 3.0:
                break
            _inv3(X, Y)
        for i in range(3):
            for j in range(3):
                R[e, i, j] = X[i, j]
    return left


@numba.njit(cache=True)
def deformation_gradients(u, tets, grads, F):
    """F = I + sum_a u_a (x) grad N_a for each linear tetrahedron (u: (3n,) nodal displacements)."""
    for e in range(tets.shape[0]):
        for i in range(3):
            for j in range(3):
                F[e, i, j] = 1.0 if i == j else 0.0
        for a in range(4):
            base = 3 * tets[e, a]
            for i in range(3):
                ui = u[base + i]
                for j in range(3):
                    F[e, i, j] += ui * grads[e, a, j]


@numba.njit(cache=True)
def corotated_minus_linear(u, nodes, tets, Ke, R, out):
    """out += sum_e R_e K_e (R_e^T x_e - X_e) - K_e u_e over the given elements, scattered to
    their dofs: the corotational internal force's change from the linear one (x = X + u).
    Returns the energy's change, sum_e 1/2 l_e.K_e l_e - 1/2 u_e.K_e u_e (l = R^T x - X)."""
    local = np.empty(12)
    ue = np.empty(12)
    energy = 0.0
    for e in range(tets.shape[0]):
        for a in range(4):
            n = tets[e, a]
            for i in range(3):
                ue[3 * a + i] = u[3 * n + i]
            for i in range(3):  # (R^T x - X)_i = sum_k R_ki x_k - X_i
                acc = 0.0
                for k in range(3):
                    acc += R[e, k, i] * (nodes[n, k] + u[3 * n + k])
                local[3 * a + i] = acc - nodes[n, i]
        for a in range(4):
            fl0 = 0.0
            fl1 = 0.0
            fl2 = 0.0
            lin0 = 0.0
            lin1 = 0.0
            lin2 = 0.0
            r0 = 3 * a
            for c in range(12):
                lc = local[c]
                uc = ue[c]
                fl0 += Ke[e, r0, c] * lc
                fl1 += Ke[e, r0 + 1, c] * lc
                fl2 += Ke[e, r0 + 2, c] * lc
                lin0 += Ke[e, r0, c] * uc
                lin1 += Ke[e, r0 + 1, c] * uc
                lin2 += Ke[e, r0 + 2, c] * uc
            energy += 0.5 * (local[r0] * fl0 + local[r0 + 1] * fl1 + local[r0 + 2] * fl2
                             - ue[r0] * lin0 - ue[r0 + 1] * lin1 - ue[r0 + 2] * lin2)
            n = tets[e, a]
            for i in range(3):
                out[3 * n + i] += R[e, i, 0] * fl0 + R[e, i, 1] * fl1 + R[e, i, 2] * fl2
            out[3 * n] -= lin0
            out[3 * n + 1] -= lin1
            out[3 * n + 2] -= lin2
    return energy


def warm_up() -> None:
    """Compile (or load from numba's cache) every kernel for the argument types the models pass,
    on tiny inputs, spent when a model is built rather than in the first deformation frame of
    a trial (where it stalled the participant's view; the cost: docs/scenes.md)."""
    x = np.zeros((2, 3))
    idx = np.array([0], dtype=np.int64)
    spring_rhs(x, idx, idx + 1, np.ones(1), np.ones(1), np.array([0, 1], dtype=np.int64), 2)
    spring_energy(x, idx, idx + 1, np.ones(1), np.ones(1))
    spring_gradient(x, idx, idx + 1, np.ones(1), np.ones(1), np.array([0, 1], dtype=np.int64), 2)
    spring_hessian_product(x, idx, idx + 1, np.ones(1), np.ones(1), np.array([0, 1], dtype=np.int64), x)
    explicit_substeps(x.copy(), np.zeros((2, 3)), np.ones(2), np.zeros(2, dtype=np.bool_), idx, idx + 1, np.ones(1), np.ones(1), idx,
                      np.array([0, 1], dtype=np.int64), np.ones(1), np.zeros((1, 3)), np.zeros((2, 3)), 0.0, 1e-3, 1)
    polar_rotations(np.eye(3)[None].copy(), np.empty((1, 3, 3)), np.empty(1))
    tets = np.arange(4, dtype=np.int64)[None]
    F = np.empty((1, 3, 3))
    deformation_gradients(np.zeros(12), tets, np.zeros((1, 4, 3)), F)
    corotated_minus_linear(np.zeros(12), np.zeros((4, 3)), tets, np.zeros((1, 12, 12)), F, np.zeros(12))


@numba.njit(cache=True, fastmath=False)
def vertex_normals(x, triangles):
    """Unit vertex normals of a triangle surface, each the area-weighted mean of its faces'
    normals: one pass over the triangles, then one over the vertices (compiled because the view
    recomputes them every frame; against NumPy: docs/participant.md)."""
    n = np.zeros((x.shape[0], 3))
    for t in range(triangles.shape[0]):
        a, b, c = triangles[t, 0], triangles[t, 1], triangles[t, 2]
        e0 = x[b, 0] - x[a, 0]
        e1 = x[b, 1] - x[a, 1]
        e2 = x[b, 2] - x[a, 2]
        f0 = x[c, 0] - x[a, 0]
        f1 = x[c, 1] - x[a, 1]
        f2 = x[c, 2] - x[a, 2]
        c0 = e1 * f2 - e2 * f1  # |cross| is twice the area: area weighting for free
        c1 = e2 * f0 - e0 * f2
        c2 = e0 * f1 - e1 * f0
        for v in (a, b, c):
            n[v, 0] += c0
            n[v, 1] += c1
            n[v, 2] += c2
    out = np.empty((x.shape[0], 3))
    for v in range(x.shape[0]):
        s = np.sqrt(n[v, 0] ** 2 + n[v, 1] ** 2 + n[v, 2] ** 2)
        s = 1.0 / s if s > 0.0 else 0.0
        out[v, 0] = n[v, 0] * s
        out[v, 1] = n[v, 1] * s
        out[v, 2] = n[v, 2] * s
    return out
