"""A hyperelastic membrane on a body's boundary (the pia-arachnoid on the brain's surface):
internal forces, the tangent on the free dofs and the energy (`Membrane`), and a body with its
membrane as one system for the Newton solver (`WithMembrane`).

The membrane lies on the boundary faces of the space's tetrahedra (P2: 6-node triangles, the
faces of the boundary tets, so its dofs are the body's and its tangent fits the body's pattern),
thin, incompressible, in plane stress: the energy per reference area is t W(C) with C the 2 x 2
surface Cauchy-Green tensor and the thickness stretch 1 / sqrt(det C). W is the one-term
Ogden membrane, W = 2 mu / alpha^2 (l1^alpha + l2^alpha + (l1 l2)^-alpha - 3), l1, l2 the
in-plane stretches (alpha = 2: neo-Hookean, mu / 2 (tr C + 1 / det C - 3)); its small-strain
shear modulus is mu, its Young's modulus 3 mu. The tangent of tr f(C) is the Daleckii-Krein
divided difference, its limit taken where the stretches are equal (at rest), so it is exact
there too.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from sim.errors import ParameterError
from sim.material import MembraneLaw
from sim.models.fem import p2

# the faces of a tetrahedron (local corners) and, on P2, their mid-edge nodes (indices into p2.EDGES)
FACES = np.array([(1, 2, 3), (0, 2, 3), (0, 1, 3), (0, 1, 2)])
_EDGE_OF = {tuple(sorted(e)): 4 + i for i, e in enumerate(p2.EDGES.tolist())}
FACE_MIDS = np.array([[_EDGE_OF[(a, b)], _EDGE_OF[(b, c)], _EDGE_OF[(a, c)]] for a, b, c in FACES.tolist()])
# degree-4 rule on the triangle (Dunavant): barycentric points and weights (sum 1)
_A1, _B1, _W1 = 0.445948490915965, 0.108103018168070, 0.223381589678011
_A2, _B2, _W2 = 0.091576213509771, 0.816847572980459, 0.109951743655322
TRI_POINTS = np.array([[_A1, _A1, _B1], [_A1, _B1, _A1], [_B1, _A1, _A1], [_A2, _A2, _B2], [_A2, _B2, _A2], [_B2, _A2, _A2]])
TRI_WEIGHTS = np.array([_W1] * 3 + [_W2] * 3)


def boundary_faces(space) -> np.ndarray:
    """The boundary faces of the space's elements: (f, 6) node indices on P2 (corners, then the
    mid-edge nodes of edges 01, 12, 02), (f, 3) on P1; oriented as the tets give them."""
    tets = space.tets
    corners = tets[:, FACES].reshape(-1, 3)
    _, inverse, counts = np.unique(np.sort(corners, axis=1), axis=0, return_inverse=True, return_counts=True)
    once = counts[inverse.ravel()] == 1
    if space.order == 1:
        return corners[once]
    mids = space.elements[:, FACE_MIDS].reshape(-1, 3)
    return np.hstack([corners[once], mids[once]])


def _tri_shape_gradients(bary: np.ndarray, gL: np.ndarray, order: int) -> np.ndarray:
    """Gradients (f, q, k, 2) of the triangle's shape functions at barycentric points (q, 3), from
    the barycentric gradients gL (f, 3, 2); P2 mid-edge nodes on edges 01, 12, 02."""
    if order == 1:
        return np.repeat(gL[:, None], len(bary), axis=1)
    out = np.empty((len(gL), len(bary), 6, 2))
    for q, L in enumerate(bary):
        out[:, q, :3] = (4.0 * L - 1.0)[None, :, None] * gL
        for e, (i, j) in enumerate(((0, 1), (1, 2), (0, 2))):
            out[:, q, 3 + e] = 4.0 * (L[j] * gL[:, i] + L[i] * gL[:, j])
    return out


def _divided(p: float, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(a^p - b^p) / (a - b), and p a^(p-1) where a = b: accurate as a -> b."""
    r = (a - b) / b
    small = np.abs(r) < 1e-12
    rs = np.where(small, 1.0, r)
    return b ** (p - 1.0) * np.where(small, p, np.expm1(p * np.log1p(rs)) / rs)


def ogden_stress(C: np.ndarray, mu: float, alpha: float, tangent: bool = True):
    """For (..., 2, 2) surface Cauchy-Green tensors: W, S = 2 dW/dC (..., 2, 2) and D = dS/dC
    (..., 2, 2, 2, 2, minor-symmetric), or None without `tangent`."""
    c = 2.0 * mu / alpha**2
    h = 0.5 * alpha  # l^alpha = a^h for an eigenvalue a of C
    ev, n = np.linalg.eigh(C)
    a, b = ev[..., 0], ev[..., 1]
    det = a * b
    Cinv = np.linalg.inv(C)
    W = c * (a**h + b**h + det**-h - 3.0)
    g = c * h * ev ** (h - 1.0)  # f'(a_i) of f(a) = c a^h
    S = 2.0 * np.einsum("...i,...Ii,...Ji->...IJ", g, n, n) - alpha * c * det[..., None, None] ** -h * Cinv
    if not tangent:
        return W, S, None
    # Daleckii-Krein: d f'(C) = sum_ij f'[a_i, a_j] (n_i^T dC n_j) n_i n_j^T
    dd = np.empty(ev.shape + (2,))
    dd[..., 0, 0] = c * h * (h - 1.0) * a ** (h - 2.0)
    dd[..., 1, 1] = c * h * (h - 1.0) * b ** (h - 2.0)
    dd[..., 0, 1] = dd[..., 1, 0] = c * h * _divided(h - 1.0, b, a)
    nn = np.einsum("...Ii,...Jj->...IJij", n, n)  # (n_i)_I (n_j)_J
    D1 = 2.0 * np.einsum("...ij,...IJij,...KLij->...IJKL", dd, nn, nn)
    inv_inv = np.einsum("...IJ,...KL->...IJKL", Cinv, Cinv)
    dinv = -0.5 * (np.einsum("...IK,...JL->...IJKL", Cinv, Cinv) + np.einsum("...IL,...JK->...IJKL", Cinv, Cinv))
    pw = det[..., None, None, None, None] ** -h
    D2 = -alpha * c * (-h * pw * inv_inv + pw * dinv)
    D = D1 + D2
    D = 0.5 * (D + np.swapaxes(D, -1, -2))  # minor symmetry in KL (dC is symmetric)
    return W, S, D


class Membrane:
    """The law `law` (`MembraneLaw`) on the boundary faces of `space` (a `TetSpace`); `pattern`:
    (indptr, indices) of a CSR pattern on the free dofs that holds the faces' entries (a
    `FiniteStrain`'s), or None for the membrane's own."""

    def __init__(self, space, law: MembraneLaw, faces: np.ndarray | None = None, pattern=None):
        self.space, self.law = space, law
        self.faces = boundary_faces(space) if faces is None else np.asarray(faces, dtype=np.int64)
        X = space.all_nodes[self.faces[:, :3]]  # corners (f, 3, 3): straight faces
        e1 = X[:, 1] - X[:, 0]
        normal = np.cross(e1, X[:, 2] - X[:, 0])
        area2 = np.linalg.norm(normal, axis=1)
        if np.any(area2 <= 0):
            raise ParameterError(f"membrane: {int(np.sum(area2 <= 0))} boundary faces have no area")
        e1 /= np.linalg.norm(e1, axis=1)[:, None]
        e2 = np.cross(normal / area2[:, None], e1)
        self.frame = np.stack([e1, e2], axis=2)  # (f, 3, 2): the face's reference tangent frame
        xy = np.einsum("fki,fia->fka", X - X[:, :1], self.frame)  # corners in the frame (f, 3, 2)
        # barycentric gradients: L = M^-1 [1, x, y]
        M = np.concatenate([np.ones((len(xy), 1, 3)), np.swapaxes(xy, 1, 2)], axis=1)
        gL = np.linalg.inv(M)[:, :, 1:]  # (f, 3, 2)
        self.G = _tri_shape_gradients(TRI_POINTS, gL, space.order)  # (f, q, k, 2)
        self.wq = 0.5 * area2[:, None] * TRI_WEIGHTS[None, :]  # (f, q) reference area
        k = self.faces.shape[1]
        self.dofs = (3 * self.faces[:, :, None] + np.arange(3)).reshape(len(self.faces), 3 * k)
        n = 3 * space.n_all
        self.free_pos = np.full(n, -1, dtype=np.int64)
        self.free_pos[space.free] = np.arange(len(space.free))
        rows = self.free_pos[np.repeat(self.dofs, self.dofs.shape[1], axis=1)].ravel()
        cols = self.free_pos[np.tile(self.dofs, (1, self.dofs.shape[1]))].ravel()
        nf = len(space.free)
        if pattern is None:
            keep = (rows >= 0) & (cols >= 0)
            own = sp.csr_matrix((np.ones(int(keep.sum())), (rows[keep], cols[keep])), shape=(nf, nf))
            own.sum_duplicates()
            own.sort_indices()
            pattern = (own.indptr.astype(np.int64), own.indices.astype(np.int64))
        self.indptr, self.indices = pattern
        # each element entry's place in the pattern's data (-1: a clamped row or column)
        pos = np.full(len(rows), -1, dtype=np.int64)
        ok = (rows >= 0) & (cols >= 0)
        r, cc = rows[ok], cols[ok]
        starts, ends = self.indptr[r], self.indptr[r + 1]
        # the column's place in its row: indices are sorted per row, so a search in each row's slice
        key_rows = np.repeat(np.arange(nf), np.diff(self.indptr))
        flat = key_rows * nf + self.indices
        at = np.searchsorted(flat, r * nf + cc)
        if np.any(at >= len(flat)) or np.any(flat[np.minimum(at, len(flat) - 1)] != r * nf + cc) or np.any((at < starts) | (at >= ends)):
            raise ParameterError("membrane: the tangent pattern given does not hold the boundary faces' entries")
        pos[ok] = at
        self.pos = pos

    def evaluate(self, u: np.ndarray, tangent: bool = True) -> dict:
        """At the displacement `u` (3 n_all,): the internal force on every dof `f`, the tangent on
        the free dofs `K` (CSR in the pattern, or None) and `data` (its values), the energy."""
        law = self.law
        ue = u[self.dofs].reshape(len(self.faces), -1, 3)  # (f, k, 3)
        F = self.frame[:, None] + np.einsum("fki,fqka->fqia", ue, self.G)  # (f, q, 3, 2)
        C = np.einsum("fqia,fqib->fqab", F, F)
        W, S, D = ogden_stress(C, law.mu, law.alpha, tangent)
        tw = law.thickness * self.wq  # (f, q)
        energy = float(np.sum(tw * W))
        # f_ai = sum_q tw F_iI S_IJ dN_a,J
        fe = np.einsum("fq,fqiI,fqIJ,fqaJ->fai", tw, F, S, self.G).reshape(len(self.faces), -1)
        f = np.zeros(3 * self.space.n_all)
        np.add.at(f, self.dofs.ravel(), fe.ravel())
        out = {"f": f, "K": None, "data": None, "energy": energy}
        if tangent:
            nf_, nq, k = self.G.shape[:3]
            # B[(a i), (I J)] = F_iI dN_a,J: the material part is 2 sum_q tw B D B^T (batched products)
            B = np.einsum("fqiI,fqaJ->fqaiIJ", F, self.G).reshape(nf_, nq, 3 * k, 4)
            BD = np.matmul(B, D.reshape(nf_, nq, 4, 4))
            mat = 2.0 * np.einsum("fq,fqmn->fmn", tw, np.matmul(BD, np.swapaxes(B, -1, -2)))
            GS = np.matmul(self.G, S)  # (f, q, k, 2)
            geo = np.einsum("fq,fqab->fab", tw, np.matmul(GS, np.swapaxes(self.G, -1, -2)))
            Ke = mat.reshape(nf_, k, 3, k, 3) + geo[:, :, None, :, None] * np.eye(3)[None, None, :, None, :]
            Ke = Ke.reshape(len(self.faces), 3 * k, 3 * k)
            data = np.zeros(len(self.indices))
            ok = self.pos >= 0
            np.add.at(data, self.pos[ok], Ke.ravel()[ok])
            nf = len(self.space.free)
            out["data"] = data
            out["K"] = sp.csr_matrix((data, self.indices, self.indptr), shape=(nf, nf))
        return out


class WithMembrane:
    """A body (`FiniteStrain`) and a membrane on its boundary as one system for `newton.hold`: the
    forces, tangents and energies summed; the body's own diagnostics (J, mean dilatations) kept."""

    def __init__(self, body, law: MembraneLaw):
        self.body = body
        self.space = body.space
        self.membrane = Membrane(body.space, law, pattern=(body.indptr, body.indices))

    def evaluate(self, u: np.ndarray, tangent: bool = True) -> dict:
        out = dict(self.body.evaluate(u, tangent=tangent))
        mem = self.membrane.evaluate(u, tangent=tangent)
        out["f"] = out["f"] + mem["f"]
        out["energy"] = out["energy"] + mem["energy"]
        out["membrane_energy"] = mem["energy"]
        if tangent:
            K = out["K"]
            out["K"] = sp.csr_matrix((K.data + mem["data"], K.indices, K.indptr), shape=K.shape)
        return out
