"""Linear tetrahedra that do not lock: the average nodal pressure element (Bonet and Burton
1998; Joldes, Wittek and Miller 2009 use it for brain tissue) for a finite-strain law, as a
system for `newton.hold`.

A P1 element has one J, so a nearly incompressible law (kappa = 50 mu, the tissue's) forces
every element to keep its volume and the mesh locks (how stiff on the bench's pulls:
docs/fem.md). Here the volumetric energy is taken per node instead: with V_n the quarter-volumes of
the elements around node n (current) and V0_n at rest, J_n = V_n / V0_n and

    E = sum_e V0_e W_iso(F_e) + sum_n V0_n U(J_n),   U(J) = kappa/4 (J^2 - 1 - 2 ln J),

so the volume is kept over each node's patch rather than in every element. The isochoric part
is `FiniteStrain`'s (kappa 0); the volumetric force and tangent are below. The tangent's
volumetric term couples the patches of neighbouring nodes, so its pattern is wider than P1's.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from sim.errors import ParameterError
from sim.hyperelastic import Hyperelastic, volumetric
from sim.models.fem.finite_strain import FiniteStrain


def volumes(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Signed volumes (m,) of tetrahedra with corners x (m, 4, 3), and their gradients (m, 4, 3)."""
    c1, c2, c3 = x[:, 1] - x[:, 0], x[:, 2] - x[:, 0], x[:, 3] - x[:, 0]
    g = np.empty_like(x)
    g[:, 1] = np.cross(c2, c3) / 6.0
    g[:, 2] = np.cross(c3, c1) / 6.0
    g[:, 3] = np.cross(c1, c2) / 6.0
    g[:, 0] = -(g[:, 1] + g[:, 2] + g[:, 3])
    return np.einsum("mi,mi->m", c1, g[:, 1]), g


def _skew(v: np.ndarray) -> np.ndarray:
    """[v]_x (m, 3, 3): [v]_x w = v x w."""
    S = np.zeros(v.shape[:-1] + (3, 3))
    S[..., 0, 1], S[..., 0, 2], S[..., 1, 2] = -v[..., 2], v[..., 1], -v[..., 0]
    return S - np.swapaxes(S, -1, -2)


def volume_hessians(x: np.ndarray) -> np.ndarray:
    """d2V/dx dx (m, 12, 12) of tetrahedra with corners x (m, 4, 3). In the edge vectors
    c_i = x_i - x_0: V = c1 . (c2 x c3) / 6, whose second derivatives are skew matrices of the
    third edge (d(c2 x c3)/dc2 = -[c3]_x, ...); the corner x_0 enters as minus their sum."""
    c = x[:, 1:] - x[:, :1]  # (m, 3, 3)
    Hc = np.zeros((len(x), 3, 3, 3, 3))  # [a, i, b, j]: d2V / dc_a,i dc_b,j
    for a, b, k, sign in ((0, 1, 2, -1.0), (0, 2, 1, 1.0), (1, 2, 0, -1.0)):
        blk = sign * _skew(c[:, k]) / 6.0
        Hc[:, a, :, b, :] = blk
        Hc[:, b, :, a, :] = np.swapaxes(blk, -1, -2)
    H = np.zeros((len(x), 4, 3, 4, 3))
    H[:, 1:, :, 1:, :] = Hc
    H[:, 0, :, 1:, :] = -Hc.sum(axis=1)
    H[:, 1:, :, 0, :] = -Hc.sum(axis=3)
    H[:, 0, :, 0, :] = Hc.sum(axis=(1, 3))
    return H.reshape(len(x), 12, 12)


class NodalPressure:
    """The law `law` on a P1 `TetSpace` with averaged nodal volumes; `evaluate` as `FiniteStrain`'s."""

    def __init__(self, space, law: Hyperelastic):
        if getattr(space, "order", 1) != 1:
            raise ParameterError("order: the nodal-pressure element is linear (order 1)")
        self.space, self.law = space, law
        self.iso = FiniteStrain(space, law)
        self.iso.kappa = 0.0  # the volumetric energy is the nodes' (below)
        self.kappa = float(law.bulk_modulus)
        self.X = np.asarray(space.all_nodes, dtype=np.float64)
        self.T = np.asarray(space.elements, dtype=np.int64)
        n, m = len(self.X), len(self.T)
        V0, _ = volumes(self.X[self.T])
        if np.any(V0 <= 0):
            raise ParameterError(f"tets: element {int(np.flatnonzero(V0 <= 0)[0])} is inverted or degenerate at rest")
        self.A = sp.csr_matrix((np.full(4 * m, 0.25), (self.T.ravel(), np.repeat(np.arange(m), 4))), shape=(n, m))
        self.V0n = self.A @ V0
        self.dofs = (3 * self.T[:, :, None] + np.arange(3)).reshape(m, 12)
        self.free = space.free
        # the element Hessians' entries on free dofs, found once
        pos = self.iso.free_pos
        rows, cols = pos[np.repeat(self.dofs, 12, axis=1).ravel()], pos[np.tile(self.dofs, (1, 12)).ravel()]
        self._keep = (rows >= 0) & (cols >= 0)
        self._rows, self._cols = rows[self._keep], cols[self._keep]
        self._grad_rows = np.repeat(np.arange(m), 12)

    def evaluate(self, u: np.ndarray, tangent: bool = True) -> dict:
        """As `FiniteStrain.evaluate`: force `f` on every dof, tangent `K` on the free dofs,
        `energy`, `min_jacobian` (also <= 0 when a node's patch has turned inside out)."""
        st = self.iso.evaluate(u, tangent)
        x = self.X[self.T] + u.reshape(-1, 3)[self.T]
        V, g = volumes(x)
        Jn = (self.A @ V) / self.V0n
        if st["min_jacobian"] <= 0 or np.any(Jn <= 0):
            return st | {"min_jacobian": min(st["min_jacobian"], float(Jn.min()), 0.0), "energy": np.inf}
        un, up, upp = volumetric(self.kappa, Jn)  # U, U', U'' at each node
        pe = self.A.T @ up  # per element: the mean of its nodes' U'
        f = st["f"].copy()
        np.add.at(f, self.dofs.ravel(), (pe[:, None] * g.reshape(-1, 12)).ravel())
        out = st | {"f": f, "energy": st["energy"] + float(np.sum(self.V0n * un)),
                    "nodal_j_range": (float(Jn.min()), float(Jn.max()))}
        if tangent:
            N = 3 * len(self.X)
            G = sp.csr_matrix((g.ravel(), (self._grad_rows, self.dofs.ravel())), shape=(len(self.T), N))
            B = (self.A @ G).tocsc()[:, self.free]  # dV_n / du on the free dofs
            H = volume_hessians(x) * pe[:, None, None]
            nf = len(self.free)
            K2 = sp.csr_matrix((H.ravel()[self._keep], (self._rows, self._cols)), shape=(nf, nf))
            out["K"] = (st["K"] + (B.T @ sp.diags(upp / self.V0n) @ B) + K2).tocsr()
        return out
