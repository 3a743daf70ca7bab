"""Compiled kernels (numba) of the corotational P1 update (`corotational`): each element's
deformation gradient, the rotation of its polar decomposition, and the rotated internal force's
change from the linear one; and the 3 x 3 inverse the finite-strain pass shares
(`hyperelastic_kernels`). `corotational` keeps a NumPy path for an install without numba."""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True)
def inv3(a, out):
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
        d = inv3(X, Y)
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
            inv3(X, Y)
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
    """Compile (or load from numba's cache) the corotational kernels for the argument types the
    model passes, on tiny inputs: spent when a model is built rather than in the first deformation
    frame of a trial, where it would stall the participant's view (the cost: docs/scenes.md)."""
    polar_rotations(np.eye(3)[None].copy(), np.empty((1, 3, 3)), np.empty(1))
    tets = np.arange(4, dtype=np.int64)[None]
    F = np.empty((1, 3, 3))
    deformation_gradients(np.zeros(12), tets, np.zeros((1, 4, 3)), F)
    corotated_minus_linear(np.zeros(12), np.zeros((4, 3)), tets, np.zeros((1, 12, 12)), F, np.zeros(12))
