"""Linear (P1, 4-node) tetrahedra: the shape functions are the barycentric coordinates, their
gradients constant per element; one quadrature point integrates the stiffness exactly."""

from __future__ import annotations

import numpy as np

from sim.errors import ParameterError

NODES = 4
POINTS = np.array([[0.25, 0.25, 0.25, 0.25]])  # the centroid, weight 1


def shape_gradients(nodes: np.ndarray, tets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Gradients of the four linear shape functions, (m, 4, 3), and signed volumes (m,)."""
    x0 = nodes[tets[:, 0]]
    J = np.stack([nodes[tets[:, k]] - x0 for k in (1, 2, 3)], axis=2)  # columns: edge vectors
    det = np.linalg.det(J)
    vol = det / 6.0
    if np.any(~np.isfinite(vol)) or np.any(np.abs(vol) <= 1e-30):
        bad = int(np.flatnonzero(~(np.abs(vol) > 1e-30))[0])
        raise ParameterError(f"tets: element {bad} is degenerate (zero volume)")
    inv = np.linalg.inv(J)  # rows: gradients of N1, N2, N3
    g = np.empty((len(tets), 4, 3))
    g[:, 1:, :] = inv
    g[:, 0, :] = -inv.sum(axis=1)
    return g, vol


def shape(bary: np.ndarray) -> np.ndarray:
    """Shape functions (k, 4) at barycentric points (k, 4): the coordinates themselves."""
    return np.asarray(bary, dtype=np.float64)


def quadrature_gradients(grads: np.ndarray) -> np.ndarray:
    """Shape-function gradients at the quadrature points, (m, 1, 4, 3)."""
    return grads[:, None]


def element_stiffness(grads: np.ndarray, vol: np.ndarray, lam: float, mu: float) -> np.ndarray:
    """Element matrices (m, 12, 12): K[a i, b j] = V (lam g_ai g_bj + mu (g_aj g_bi + d_ij g_a.g_b))."""
    gg = np.einsum("mak,mbk->mab", grads, grads)
    K = np.empty((len(grads), 4, 3, 4, 3))
    for i in range(3):  # nine (m, 4, 4) blocks: faster than one 5-index einsum (docs/fem.md)
        for j in range(3):
            blk = lam * grads[:, :, i, None] * grads[:, None, :, j] + mu * grads[:, :, j, None] * grads[:, None, :, i]
            if i == j:
                blk += mu * gg
            K[:, :, i, :, j] = blk
    K *= np.abs(vol)[:, None, None, None, None]
    return K.reshape(len(grads), 12, 12)
