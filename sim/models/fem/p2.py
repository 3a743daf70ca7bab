"""Quadratic (P2, 10-node) tetrahedra on straight elements: the four corners, then the edge
mid-points in the order of EDGES; a degree-2 Gauss rule of four points integrates the
stiffness exactly."""

from __future__ import annotations

import numpy as np
from scipy.special import roots_jacobi

NODES = 10
EDGES = np.array([(0, 1), (1, 2), (0, 2), (0, 3), (1, 3), (2, 3)])  # local corners of the mid-edge nodes
# barycentric points (a, b, b, b) and permutations, each weighing a quarter of the volume
_A, _B = 0.5854101966249685, 0.1381966011250105
POINTS = np.array([[_A, _B, _B, _B], [_B, _A, _B, _B], [_B, _B, _A, _B], [_B, _B, _B, _A]])


def mesh(nodes: np.ndarray, tets: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(nodes with the edge mid-points appended, (m, 10) elements, (n_edges, 2) corner pairs)."""
    pairs = np.sort(tets[:, EDGES], axis=2).reshape(-1, 2)
    edges, inverse = np.unique(pairs, axis=0, return_inverse=True)
    mids = 0.5 * (nodes[edges[:, 0]] + nodes[edges[:, 1]])
    tets10 = np.hstack([tets, len(nodes) + inverse.reshape(len(tets), 6)])
    return np.vstack([nodes, mids]), tets10, edges


def shape(bary: np.ndarray) -> np.ndarray:
    """Shape functions (k, 10) at barycentric points (k, 4): corners L_i (2 L_i - 1), edges 4 L_i L_j."""
    bary = np.asarray(bary, dtype=np.float64)
    corners = bary * (2.0 * bary - 1.0)
    edges = 4.0 * bary[:, EDGES[:, 0]] * bary[:, EDGES[:, 1]]
    return np.hstack([corners, edges])


def quadrature_gradients(grads: np.ndarray) -> np.ndarray:
    """Gradients of the ten shape functions at the four quadrature points, (m, 4, 10, 3), from
    the (constant) gradients of the barycentric coordinates `grads` (m, 4, 3).

    Corners N_i = L_i (2 L_i - 1): grad = (4 L_i - 1) grad L_i; edges N_ij = 4 L_i L_j:
    grad = 4 (L_j grad L_i + L_i grad L_j)."""
    out = np.empty((len(grads), len(POINTS), 10, 3))
    for q, L in enumerate(POINTS):
        out[:, q, :4] = (4.0 * L - 1.0)[None, :, None] * grads
        for e, (i, j) in enumerate(EDGES):
            out[:, q, 4 + e] = 4.0 * (L[j] * grads[:, i] + L[i] * grads[:, j])
    return out


def shape_derivatives(bary: np.ndarray) -> np.ndarray:
    """dN_k/dL_i (p, 10, 4) at barycentric points (p, 4); a shape function's gradient is
    sum_i dN_k/dL_i grad L_i (`quadrature_gradients` at the Gauss points)."""
    bary = np.atleast_2d(np.asarray(bary, dtype=np.float64))
    out = np.zeros((len(bary), 10, 4))
    for i in range(4):
        out[:, i, i] = 4.0 * bary[:, i] - 1.0
    for e, (i, j) in enumerate(EDGES):
        out[:, 4 + e, i] = 4.0 * bary[:, j]
        out[:, 4 + e, j] = 4.0 * bary[:, i]
    return out


def node_points() -> np.ndarray:
    """The ten nodes' barycentric coordinates (10, 4), in the element's node order."""
    eye = np.eye(4)
    return np.vstack([eye, 0.5 * (eye[EDGES[:, 0]] + eye[EDGES[:, 1]])])


def conical_rule(n: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """Stroud's conical product rule of n^3 points on the tetrahedron (barycentric (n^3, 4),
    weights summing to 1): Gauss-Jacobi in the two collapsed directions, Gauss-Legendre in the
    third, exact for polynomials of degree 2n - 1 (Stroud 1971, Approximate Calculation of
    Multiple Integrals, 8.4)."""
    xs, ws = [], []
    for a in (2, 1, 0):  # the weights (1 - s)^2, (1 - t), 1 of the collapsed cube's Jacobian
        x, w = roots_jacobi(n, a, 0)
        xs.append(0.5 * (x + 1.0))
        ws.append(w / 2.0 ** (a + 1))
    s, t, v = (g.ravel() for g in np.meshgrid(*xs, indexing="ij"))
    w = np.einsum("i,j,k->ijk", *ws).ravel() * 6.0  # the unit tetrahedron's volume is 1/6
    l1, l2 = s, (1.0 - s) * t
    l3 = (1.0 - s) * (1.0 - t) * v
    return np.column_stack([1.0 - l1 - l2 - l3, l1, l2, l3]), w


CHUNK = 512  # elements per pass: the temporaries stay in cache (faster than one pass over all: docs/fem.md)


def element_stiffness(grads: np.ndarray, vol: np.ndarray, lam: float, mu: float) -> np.ndarray:
    """Element matrices (m, 30, 30): the P1 formula summed over the quadrature points.

    With T[(a i), (b j)] = sum_q G_qai G_qbj (one batched matrix product), K[a i, b j] =
    V/4 (lam T[ai, bj] + mu T[aj, bi] + mu d_ij sum_k T[ak, bk])."""
    out = np.empty((len(grads), 30, 30))
    for a in range(0, len(grads), CHUNK):
        out[a : a + CHUNK] = _element_stiffness(grads[a : a + CHUNK], vol[a : a + CHUNK], lam, mu)
    return out


def _element_stiffness(grads: np.ndarray, vol: np.ndarray, lam: float, mu: float) -> np.ndarray:
    m = len(grads)
    G = quadrature_gradients(grads)  # (m, q, 10, 3)
    A = G.transpose(0, 2, 3, 1).reshape(m, 30, len(POINTS))
    T = np.matmul(A, A.transpose(0, 2, 1)).reshape(m, 10, 3, 10, 3)
    gg = np.einsum("maibi->mab", T)
    K = lam * T + mu * T.transpose(0, 1, 4, 3, 2)
    K += mu * gg[:, :, None, :, None] * np.eye(3)[None, None, :, None, :]
    K *= (np.abs(vol) / len(POINTS))[:, None, None, None, None]
    return K.reshape(m, 30, 30)
