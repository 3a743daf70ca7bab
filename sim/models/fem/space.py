"""The discretisation every FEM solve shares: P1 or P2 tetrahedra on a corner mesh, the
clamped degrees of freedom, shape-function gradients and quadrature (`TetSpace`). Linear
elasticity (`linear.LinearFem`) and the finite-strain laws (`finite_strain`) build on it."""

from __future__ import annotations

import numpy as np

from sim.errors import ParameterError
from sim.linalg import SingularSystemError
from sim.models.fem import p1, p2

ELEMENTS = {1: p1, 2: p2}


def _check(nodes: np.ndarray, tets: np.ndarray, fixed: np.ndarray, order: int) -> None:
    if nodes.ndim != 2 or nodes.shape[1] != 3 or tets.ndim != 2 or tets.shape[1] != 4:
        raise ParameterError("nodes must be (n, 3) and tets (m, 4)")
    if fixed.shape not in ((len(nodes),), (len(nodes), 3)):
        raise ParameterError(f"fixed: must be a boolean mask over the {len(nodes)} nodes (or their 3 components)")
    if len(tets) == 0 or tets.min() < 0 or tets.max() >= len(nodes):
        raise ParameterError(f"tets: indices must be in 0..{len(nodes) - 1}")
    if order not in ELEMENTS:
        raise ParameterError(f"order: {order!r} is not an element order; allowed: 1 (linear), 2 (quadratic tetrahedra)")
    if not fixed.any():
        raise SingularSystemError("fixed: no fixed nodes; the stiffness is singular (rigid-body motion is free)")


class TetSpace:
    """Linear (order 1) or quadratic (order 2) tetrahedra on the corner mesh (nodes, tets), with
    `fixed` clamped: a node mask (n,) or a per-component mask (n, 3). With order 2, `elements`
    (m, 10) index `all_nodes`, the corners then the mid-edge nodes; a mid-edge component is
    clamped when it is clamped at both corners. `free` maps free dof -> global dof (3 i + c)."""

    def __init__(self, nodes, tets, fixed, order: int = 1):
        nodes = np.asarray(nodes, dtype=np.float64)
        tets = np.asarray(tets, dtype=np.int64)
        fixed = np.asarray(fixed, dtype=bool)
        _check(nodes, tets, fixed, order)
        self.nodes, self.tets, self.fixed = nodes, tets, fixed
        self.order = order
        self.element = ELEMENTS[order]
        self.grads, vol = p1.shape_gradients(nodes, tets)
        if np.any(vol < 0):
            raise ParameterError(f"tets: {int(np.sum(vol < 0))} elements are inverted (negative volume)")
        self.volumes = vol
        dof_fixed = fixed if fixed.ndim == 2 else np.repeat(fixed[:, None], 3, axis=1)
        if order == 1:
            self.all_nodes, self.elements = nodes, tets
        else:
            self.all_nodes, self.elements, edges = p2.mesh(nodes, tets)
            dof_fixed = np.vstack([dof_fixed, dof_fixed[edges[:, 0]] & dof_fixed[edges[:, 1]]])
        self.n_all = len(self.all_nodes)
        self.free = np.flatnonzero(~dof_fixed.ravel())  # free dof -> global dof

    def quadrature(self) -> tuple[np.ndarray, np.ndarray]:
        """Shape-function gradients at the quadrature points (m, q, k, 3) and the points' weights (m, q)."""
        G = self.element.quadrature_gradients(self.grads)
        return G, np.repeat(np.abs(self.volumes)[:, None] / G.shape[1], G.shape[1], axis=1)

    def from_free(self, u_free: np.ndarray, corners: bool = True) -> np.ndarray:
        """Displacements (n, 3) of a free-dof vector: the corners, or every node (n_all, 3)."""
        u = np.zeros(3 * self.n_all)
        u[self.free] = u_free
        return (u[: 3 * len(self.nodes)] if corners else u).reshape(-1, 3)
