"""The one grasp constraint and its condensation, for the haptic model and the reference alike.

A grasp holds a weighted mean of the displacement at points inside the body (the grasp
patch's quadrature points, `sim.geometry.patch`): ``W u = d`` with W (3, n_free), each point
interpolated with its element's own shape functions. Condensed on the grasp, the force
that holds the patch at d is ``(W K^-1 W^T)^-1 d`` (a Lagrange multiplier): `condense`.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from sim.linalg import SingularSystemError


def constraint_matrix(fem, tet: np.ndarray, bary: np.ndarray, weights: np.ndarray) -> sp.csr_matrix:
    """W (3, n_free): sum_k weights_k u(point k), point k at barycentric `bary[k]` (4,) of
    element `tet[k]` of `fem` (a `LinearFem`); clamped nodes contribute nothing."""
    tet = np.atleast_1d(np.asarray(tet, dtype=np.int64))
    shape = fem.element.shape(np.atleast_2d(bary)) * np.asarray(weights, dtype=np.float64).reshape(-1, 1)
    nodes = fem.elements[tet]  # (k, nodes per element)
    col_of = -np.ones(3 * fem.n_all, dtype=np.int64)
    col_of[fem.free] = np.arange(len(fem.free))
    cols = col_of[3 * nodes.ravel()[:, None] + np.arange(3)]  # (k * nodes, 3)
    vals = np.repeat(shape.ravel()[:, None], 3, axis=1)
    rows = np.broadcast_to(np.arange(3), cols.shape)
    keep = cols >= 0
    return sp.csr_matrix((vals[keep], (rows[keep], cols[keep])), shape=(3, len(fem.free)))


def symmetric_inverse(C: np.ndarray) -> np.ndarray:
    """The inverse of a compliance, symmetrised first (W K^-1 W^T is symmetric up to round-off)."""
    return np.linalg.inv(0.5 * (C + C.T))


def condense(fem, W: sp.csr_matrix, unscaled: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(U = K^-1 W^T (n_free, 3), the compliance C = W U symmetrised (3, 3), the stiffness C^-1).
    `unscaled`: the factor's `unscaled_solve` of W^T, kept from an earlier grasp of this patch on
    a model sharing the factor (`LinearFem.scaled`): the same U without solving again."""
    if W.nnz == 0:
        raise SingularSystemError("grasp patch lies in clamped elements: it cannot move")
    U = fem.solve_free(np.ascontiguousarray(W.T.toarray())) if unscaled is None else fem.factor.rescaled(unscaled)
    C = W @ U
    C = 0.5 * (C + C.T)
    return U, C, np.linalg.inv(C)


def pull_stiffness(fem, tet: np.ndarray, bary: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """The condensed stiffness (3, 3): the force holding the points' weighted mean at d is K d."""
    return condense(fem, constraint_matrix(fem, tet, bary, weights))[2]


def compliances(factor, Ws: list) -> np.ndarray:
    """The symmetrised compliances W K^-1 W^T (k, 3, 3) of several grasps, from one solve with
    3k right-hand sides (the stiffness field's and the observer truth's many grasps); `factor`
    a factorised K (`sim.linalg.Factor`)."""
    U = factor.solve(np.ascontiguousarray(sp.hstack([W.T for W in Ws]).toarray()))
    C = np.stack([W @ U[:, 3 * j : 3 * j + 3] for j, W in enumerate(Ws)])
    return 0.5 * (C + np.swapaxes(C, 1, 2))
