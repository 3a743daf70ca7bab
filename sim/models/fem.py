"""Finite element tissue model on linear tetrahedra.

- `LinearFem`: small-strain isotropic linear elasticity, vectorised assembly, Dirichlet
  condition on the fixed nodes, a sparse Cholesky factorisation (CHOLMOD, `sim.linalg.Factor`,
  with a fill-reducing ordering) reused for every solve.
- The haptic contract (`FemModel`): a grasp precomputes the condensed compliance of the grasp
  point, ``C = W K^-1 W^T`` (3 solves), where ``W`` interpolates nodal displacements at the
  embedded grasp point; a servo tick is ``f = C^-1 d`` (3x3), two grasps are coupled through
  the 6x6 block matrix; the deformation of a frame is ``u = K^-1 W^T f`` from the same
  precomputed responses, mapped to the surface by the embedding.
- `neo_hookean_solve`: the nonlinear reference (compressible neo-Hookean, load stepping,
  Newton iterations with the same grasp constraint), for accuracy comparisons.

Degrees of freedom are node-major: dof ``3 i + c`` is component c of node i. SI units.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp

from sim.errors import ParameterError
from sim.laws import Linearised, PairTable
from sim.linalg import Factor, SingularSystemError, shifted_factor
from sim.models.base import POISSON_MAX, POISSON_MIN, pull_problem
from sim.patch import GRASP_RADIUS

__all__ = ["Factor", "SingularSystemError"]  # re-exported: they live in sim.linalg

ASSEMBLIES = 0  # stiffness assemblies in this process (tests: a scene without FEM makes none)
# Locking follows the element. Linear tetrahedra are already far too stiff at the brain's
# Poisson 0.45: on the scene's meshes a 10 mm pull needed 1.63-1.70x the force of quadratic
# tetrahedra (8, 6 and 4 mm). The P1 error grows like 1/(1 - 2 nu), so P1 is flagged from 0.4
# on; quadratic tetrahedra only close to incompressibility.
LOCKING_POISSON = {1: 0.4, 2: 0.49}
COROT_FORCE_LIMIT = 3.0  # a corotational force this many times the linear one for the same grasp is a runaway


def lame(young: float, poisson: float) -> tuple[float, float]:
    lam = young * poisson / ((1 + poisson) * (1 - 2 * poisson))
    mu = young / (2 * (1 + poisson))
    return lam, mu


def check_material(young: float, poisson: float) -> None:
    if not (math.isfinite(young) and young > 0):
        raise ParameterError(f"young: {young!r} is out of range; allowed: a finite number > 0 Pa")
    if not (math.isfinite(poisson) and POISSON_MIN <= poisson < POISSON_MAX):
        raise ParameterError(f"poisson: {poisson!r} is out of range; allowed: [{POISSON_MIN:g}, {POISSON_MAX:g})")


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


def element_stiffness(grads: np.ndarray, vol: np.ndarray, lam: float, mu: float) -> np.ndarray:
    """Element matrices (m, 12, 12): K[a i, b j] = V (lam g_ai g_bj + mu (g_aj g_bi + d_ij g_a.g_b))."""
    gg = np.einsum("mak,mbk->mab", grads, grads)
    K = np.empty((len(grads), 4, 3, 4, 3))
    for i in range(3):  # nine (m, 4, 4) blocks: 6x faster than one 5-index einsum
        for j in range(3):
            blk = lam * grads[:, :, i, None] * grads[:, None, :, j] + mu * grads[:, :, j, None] * grads[:, None, :, i]
            if i == j:
                blk += mu * gg
            K[:, :, i, :, j] = blk
    K *= np.abs(vol)[:, None, None, None, None]
    return K.reshape(len(grads), 12, 12)


# -- quadratic (P2) tetrahedra -------------------------------------------------------------
# Ten nodes: the four corners, then the mid-points of the edges in this order (local corners).
P2_EDGES = np.array([(0, 1), (1, 2), (0, 2), (0, 3), (1, 3), (2, 3)])
# Degree-2 Gauss rule on the tetrahedron (exact for the P2 stiffness of a straight element):
# barycentric points (a, b, b, b) and permutations, each weighing a quarter of the volume.
_A, _B = 0.5854101966249685, 0.1381966011250105
P2_POINTS = np.array([[_A, _B, _B, _B], [_B, _A, _B, _B], [_B, _B, _A, _B], [_B, _B, _B, _A]])


def p2_mesh(nodes: np.ndarray, tets: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(nodes with the edge mid-points appended, (m, 10) tets, (n_edges, 2) corner pairs)."""
    pairs = np.sort(tets[:, P2_EDGES], axis=2).reshape(-1, 2)
    edges, inverse = np.unique(pairs, axis=0, return_inverse=True)
    mids = 0.5 * (nodes[edges[:, 0]] + nodes[edges[:, 1]])
    tets10 = np.hstack([tets, len(nodes) + inverse.reshape(len(tets), 6)])
    return np.vstack([nodes, mids]), tets10, edges


def p2_gradients(grads: np.ndarray) -> np.ndarray:
    """Gradients of the ten quadratic shape functions at the four quadrature points, (m, 4, 10, 3),
    from the (constant) gradients of the barycentric coordinates `grads` (m, 4, 3).

    Corners N_i = L_i (2 L_i - 1): grad = (4 L_i - 1) grad L_i; edges N_ij = 4 L_i L_j:
    grad = 4 (L_j grad L_i + L_i grad L_j)."""
    out = np.empty((len(grads), len(P2_POINTS), 10, 3))
    for q, L in enumerate(P2_POINTS):
        out[:, q, :4] = (4.0 * L - 1.0)[None, :, None] * grads
        for e, (i, j) in enumerate(P2_EDGES):
            out[:, q, 4 + e] = 4.0 * (L[j] * grads[:, i] + L[i] * grads[:, j])
    return out


def p2_element_stiffness(grads: np.ndarray, vol: np.ndarray, lam: float, mu: float) -> np.ndarray:
    """P2 element matrices (m, 30, 30): the P1 formula summed over the quadrature points.

    With T[(a i), (b j)] = sum_q G_qai G_qbj (one batched matrix product), K[a i, b j] =
    V/4 (lam T[ai, bj] + mu T[aj, bi] + mu d_ij sum_k T[ak, bk])."""
    m = len(grads)
    G = p2_gradients(grads)  # (m, q, 10, 3)
    A = G.transpose(0, 2, 3, 1).reshape(m, 30, len(P2_POINTS))
    T = np.matmul(A, A.transpose(0, 2, 1)).reshape(m, 10, 3, 10, 3)
    gg = np.einsum("maibi->mab", T)
    K = lam * T + mu * T.transpose(0, 1, 4, 3, 2)
    K += mu * gg[:, :, None, :, None] * np.eye(3)[None, None, :, None, :]
    K *= (np.abs(vol) / len(P2_POINTS))[:, None, None, None, None]
    return K.reshape(m, 30, 30)


def element_dofs(tets: np.ndarray) -> np.ndarray:
    # int32 halves the memory traffic of assembly (dof counts stay far below 2**31)
    k = tets.shape[1]
    return (3 * tets[:, :, None].astype(np.int32) + np.arange(3, dtype=np.int32)).reshape(len(tets), 3 * k)


def assemble(element_matrices: np.ndarray, tets: np.ndarray, n_nodes: int) -> sp.csr_matrix:
    global ASSEMBLIES
    ASSEMBLIES += 1
    dofs = element_dofs(tets)
    k = dofs.shape[1]
    rows = np.repeat(dofs, k, axis=1).ravel()
    cols = np.tile(dofs, (1, k)).ravel()
    return sp.coo_matrix((element_matrices.ravel(), (rows, cols)), shape=(3 * n_nodes, 3 * n_nodes)).tocsr()


@dataclass
class Timings:
    assembly_s: float = 0.0
    factorisation_s: float = 0.0


class LinearFem:
    """Small-strain linear elasticity on linear (order 1) or quadratic (order 2) tetrahedra
    with nodes `fixed` clamped.

    ``LinearFem(nodes, tets, young, poisson, fixed).solve(forces)`` returns the static nodal
    displacements (n, 3) for nodal forces (n, 3). With ``order=2`` the quadratic elements are
    built from the corner mesh: forces and displacements stay on the n corner nodes, the
    mid-edge nodes are internal (a mid-edge node is clamped when both its corners are).
    """

    def __init__(self, nodes, tets, young: float, poisson: float, fixed, order: int = 1):
        nodes = np.asarray(nodes, dtype=np.float64)
        tets = np.asarray(tets, dtype=np.int64)
        fixed = np.asarray(fixed, dtype=bool)
        if nodes.ndim != 2 or nodes.shape[1] != 3 or tets.ndim != 2 or tets.shape[1] != 4:
            raise ParameterError("nodes must be (n, 3) and tets (m, 4)")
        if fixed.shape != (len(nodes),):
            raise ParameterError(f"fixed: must be a boolean mask over the {len(nodes)} nodes")
        if len(tets) == 0 or tets.min() < 0 or tets.max() >= len(nodes):
            raise ParameterError(f"tets: indices must be in 0..{len(nodes) - 1}")
        check_material(young, poisson)
        if order not in (1, 2):
            raise ParameterError(f"order: {order!r} is not an element order; allowed: 1 (linear), 2 (quadratic tetrahedra)")
        if not fixed.any():
            raise SingularSystemError("fixed: no fixed nodes; the stiffness is singular (rigid-body motion is free)")
        self.nodes, self.tets, self.fixed = nodes, tets, fixed
        self.young, self.poisson = float(young), float(poisson)
        self.lam, self.mu = lame(young, poisson)
        self.timings = Timings()
        start = time.perf_counter()
        self.grads, vol = shape_gradients(nodes, tets)
        if np.any(vol < 0):
            raise ParameterError(f"tets: {int(np.sum(vol < 0))} elements are inverted (negative volume)")
        self.volumes = vol
        self.order = order
        self.n_all = len(nodes)  # corners, then (order 2) the mid-edge nodes
        if order == 1:
            self.element_matrices = element_stiffness(self.grads, vol, self.lam, self.mu)  # kept for the corotational update
            self.stiffness = assemble(self.element_matrices, tets, len(nodes))
        else:
            all_nodes, tets10, edges = p2_mesh(nodes, tets)
            self.n_all = len(all_nodes)
            self.stiffness = assemble(p2_element_stiffness(self.grads, vol, self.lam, self.mu), tets10, self.n_all)
            fixed = np.concatenate([fixed, fixed[edges].all(axis=1)])
        self.timings.assembly_s = time.perf_counter() - start
        fixed_dofs = np.repeat(fixed, 3)
        self.free = np.flatnonzero(~fixed_dofs)  # free dof -> global dof
        self.reduced = self.stiffness[self.free][:, self.free].tocsr()
        self._factor: Factor | None = None

    @property
    def locking(self) -> bool:
        """The element locks (is too stiff) at this Poisson ratio (see LOCKING_POISSON)."""
        return self.poisson >= LOCKING_POISSON[self.order]

    @property
    def factor(self) -> Factor:
        if self._factor is None:
            start = time.perf_counter()
            self._factor = Factor(self.reduced)
            self.timings.factorisation_s = time.perf_counter() - start
        return self._factor

    def solve_free(self, b: np.ndarray) -> np.ndarray:
        return self.factor.solve(b)

    def solve(self, forces) -> np.ndarray:
        f = np.asarray(forces, dtype=np.float64).reshape(-1)
        if f.shape != (3 * len(self.nodes),):
            raise ParameterError(f"forces: must be ({len(self.nodes)}, 3)")
        full = np.zeros(3 * self.n_all)
        full[: len(f)] = f  # loads on the corners; mid-edge nodes carry none
        u = np.zeros(3 * self.n_all)
        u[self.free] = self.solve_free(full[self.free])
        return u[: 3 * len(self.nodes)].reshape(-1, 3)

    def to_free(self, u_nodes: np.ndarray) -> np.ndarray:
        if self.order != 1:
            raise ParameterError("order: the corotational and neo-Hookean solvers need linear (order 1) tetrahedra")
        return np.asarray(u_nodes).reshape(-1)[self.free]

    def from_free(self, u_free: np.ndarray) -> np.ndarray:
        """Corner displacements (n, 3) of a free-dof vector."""
        u = np.zeros(3 * self.n_all)
        u[self.free] = u_free
        return u[: 3 * len(self.nodes)].reshape(-1, 3)


# -- grasp constraint ----------------------------------------------------------------------


def constraint_matrix(fem: LinearFem, tet_nodes: np.ndarray, weights: np.ndarray) -> sp.csr_matrix:
    """W (3, n_free): the displacement of the embedded point = W u_free."""
    col_of = -np.ones(3 * fem.n_all, dtype=np.int64)
    col_of[fem.free] = np.arange(len(fem.free))
    rows, cols, vals = [], [], []
    for node, w in zip(tet_nodes, weights):
        for c in range(3):
            j = col_of[3 * node + c]
            if j >= 0:  # fixed nodes do not move
                rows.append(c)
                cols.append(j)
                vals.append(w)
    return sp.csr_matrix((vals, (rows, cols)), shape=(3, len(fem.free)))


@dataclass
class FemContact:
    part: int  # which independent system (hemisphere) the grasp point is in
    W: sp.csr_matrix  # (3, n_free of that part)
    U: np.ndarray  # (n_free, 3): K^-1 W^T
    C: np.ndarray  # (3, 3) compliance at the grasp point
    K: tuple  # C^-1 as 9 floats, row-major (the per-tick stiffness)


def _same(held: tuple, now: tuple) -> bool:
    """The same grasps: the very contact objects a cache was made for. The cache holds them, so
    their identity cannot pass to a new grasp (an id() key could: Python reuses a freed
    object's id, and a new grasp then met the last one's pair stiffness or state)."""
    return len(held) == len(now) and all(x is y for x, y in zip(held, now))


class FemModel:
    """The linear FEM under the tissue-model contract (see module docstring).

    Each connected component of the volume (each hemisphere) is its own system with its own
    factorisation: they share no node, so grasps on different hemispheres are uncoupled, and
    two factorisations of half the size cost less than one of the whole.
    """

    name = "fem"

    def __init__(self, surface, volume, young: float, poisson: float, fixed_nodes: np.ndarray, formulation: str = "linear", grasp_radius: float = GRASP_RADIUS,
                 order: int = 1):
        from sim.volume import embed

        if formulation not in ("linear", "corotational"):
            raise ParameterError(f"formulation: {formulation!r} is not available for the haptic model; allowed: linear, corotational")
        if order == 2 and formulation != "linear":
            raise ParameterError("order: quadratic tetrahedra (order 2) run the linear formulation only")
        self.surface = surface
        self.volume = volume
        self.formulation = formulation
        self.grasp_radius = grasp_radius
        self.parts: list[LinearFem] = []
        self.part_nodes: list[np.ndarray] = []  # global node indices of each part
        self.node_part = np.empty(volume.n_nodes, dtype=np.int64)
        self.node_local = np.empty(volume.n_nodes, dtype=np.int64)
        tet_comp = volume.component[volume.tets[:, 0]]
        for k, label in enumerate(np.unique(volume.component)):
            nodes = np.flatnonzero(volume.component == label)
            self.node_part[nodes] = k
            self.node_local[nodes] = np.arange(len(nodes))
            tets = self.node_local[volume.tets[tet_comp == label]]
            self.parts.append(LinearFem(volume.nodes[nodes], tets, young, poisson, fixed_nodes[nodes], order=order))
            self.part_nodes.append(nodes)
        start = time.perf_counter()
        self.embedding = embed(volume, surface.vertices, surface.labels)
        self.embed_s = time.perf_counter() - start
        for part in self.parts:  # factorise now, not in the first grasp (two threads: no faster)
            _ = part.factor
        surface.prepare_queries()
        self._pair_of: tuple | None = None  # (the two contacts' data, their pair stiffness)
        self._out = np.zeros_like(surface.vertices)
        # corotational state, per part: (contact ids, free-dof displacement, multipliers)
        self._corot: dict[int, tuple] = {}
        self.inverted_frames = 0  # frames in which an element was inverted (det F <= 0)
        self.tangent_updates = 0  # warped-stiffness refactorisations
        self.restarts = 0  # corotational iterations that diverged and restarted from linear
        # a corotational iteration that runs away (measured on held-out bench pulls: elements
        # invert near 20 mm and the force then grows to 1e4 N within a few frames) is caught when
        # its force exceeds COROT_FORCE_LIMIT times the linear force for the same grasp; the servo
        # then renders nothing until the grasp is released
        self.unstable = False
        self.frame_flops = math.nan  # the last frame's counted work
        if formulation == "corotational":
            try:
                from sim.kernels import warm_up
            except ImportError:  # the SVD path needs no compiling
                pass
            else:
                warm_up()  # compiled now, not in the first frame of a trial

    @property
    def timings(self) -> dict:
        return {
            "assembly_s": sum(p.timings.assembly_s for p in self.parts),
            "factorisation_s": sum(p.timings.factorisation_s for p in self.parts),
            "embedding_s": self.embed_s,
        }

    @property
    def locking(self) -> bool:
        return self.parts[0].locking

    def diagnostics(self) -> dict:
        """Counts a run reports: numerical trouble is visible, never silent."""
        return {
            "formulation": self.formulation,
            "order": self.parts[0].order,
            "locking": self.locking,
            "inverted_frames": self.inverted_frames,
            "tangent_updates": self.tangent_updates,
            "restarts": self.restarts,
            "unstable": self.unstable,
        }

    def grasp(self, point, hand: int = 0):
        from sim.models.base import Contact

        v = self.surface.nearest_vertex(point)
        patch, share = self.grasp_patch(v)
        tet_nodes = self.volume.tets[self.embedding.tet[patch]]  # (k, 4)
        part = int(self.node_part[tet_nodes[0, 0]])
        fem = self.parts[part]
        weights = self.embedding.weights[patch] * share[:, None]  # the patch's mean displacement
        W = constraint_matrix(fem, self.node_local[tet_nodes.ravel()], weights.ravel())
        if W.nnz == 0:
            raise SingularSystemError("grasp point lies in a clamped element: it cannot move")
        U = fem.solve_free(np.ascontiguousarray(W.T.toarray()))
        C = W @ U
        C = 0.5 * (C + C.T)
        Kc = np.linalg.inv(C)
        data = FemContact(part=part, W=W, U=U, C=C, K=tuple(float(x) for x in Kc.ravel()))
        anchor = tuple(float(c) for c in self.surface.vertices[v])
        normal = tuple(float(c) for c in self.surface.vertex_normals[v])
        return Contact(hand=hand, vertex=int(v), point=anchor, normal=normal, data=data, law=Linearised(K=data.K))

    def grasp_patch(self, vertex: int) -> tuple[np.ndarray, np.ndarray]:
        """(surface vertices, weights): the mean displacement of the surface area within
        `grasp_radius` of `vertex`, same hemisphere (`sim.patch`): a finite contact area.

        (Holding a single point, or the few vertices inside the radius, would make the force
        fall without limit as the mesh is refined: the compliance of a point load in 3D
        elasticity is unbounded.)
        """
        from sim.patch import patch_vertex_weights

        return patch_vertex_weights(self.surface, vertex, self.grasp_radius)

    def _pair(self, a, b) -> np.ndarray:
        held = self._pair_of
        if held is None or not _same(held[0], (a.data, b.data)):
            C12 = a.data.W @ b.data.U if a.data.part == b.data.part else np.zeros((3, 3))
            C = np.block([[a.data.C, C12], [C12.T, b.data.C]])
            held = self._pair_of = ((a.data, b.data), np.linalg.inv(0.5 * (C + C.T)))  # only the current pair is ever needed
        return held[1]

    def force(self, contact, displacement):
        if self.unstable:
            return (0.0, 0.0, 0.0)
        # linear: -K d; corotational: the last frame's state plus the linear tangent since
        return contact.law.force(displacement)

    def pair_law(self, contacts):
        """The coupled 6x6 law of two grasps on one hemisphere (linear formulation), else None."""
        if len(contacts) == 2 and contacts[0].data.part == contacts[1].data.part and self.formulation == "linear":
            return PairTable(K=[float(x) for x in self._pair(contacts[0], contacts[1]).ravel()])
        return None

    def forces(self, contacts, displacements):
        pair = self.pair_law(contacts)
        if pair is not None:
            return pair.forces(displacements[0], displacements[1])
        return [c.law.force(d) for c, d in zip(contacts, displacements)]

    def grasp_forces(self, contacts, displacements) -> np.ndarray:
        """Forces on the tissue at the grasp points that hold them at `displacements`, (3k,)."""
        if len(contacts) == 2:
            return self._pair(contacts[0], contacts[1]) @ np.concatenate(displacements)
        return np.concatenate([np.asarray(c.data.K).reshape(3, 3) @ np.asarray(d) for c, d in zip(contacts, displacements)]) if contacts else np.zeros(0)

    def nodal_displacement(self, contacts, displacements) -> np.ndarray:
        """Displacement of every volume node, (n_nodes, 3)."""
        f = self.grasp_forces(contacts, displacements)
        u = np.zeros((self.volume.n_nodes, 3))
        for k, c in enumerate(contacts):
            part = self.parts[c.data.part]
            u[self.part_nodes[c.data.part]] += part.from_free(c.data.U @ f[3 * k : 3 * k + 3])
        return u

    def deformation(self, contacts, displacements) -> np.ndarray:
        if not contacts:
            self.frame_flops = float(3 * len(self._out))  # zeroing: every call sets its count (none is left over)
            self._out[:] = 0.0
            self._corot.clear()
            self.unstable = False  # released: the next grasp starts from the linear solution
            return self._out
        displacements = [np.asarray(d, dtype=np.float64) for d in displacements]
        # counted work of the frame (studyctl/observer.py): dense products with the grasps'
        # responses (6 flops per free dof and grasp), the embedding (6 per entry), zeroing
        self.frame_flops = float(6 * self.embedding.matrix.nnz + 3 * self.volume.n_nodes
                                 + sum(6 * len(self.parts[c.data.part].free) for c in contacts) + 72 * len(contacts))
        if self.formulation == "corotational":
            u = self._corotational_frame(contacts, displacements)
        else:
            u = self.nodal_displacement(contacts, displacements)
        self._out[:] = self.embedding.matrix @ u
        return self._out

    def _corotational_frame(self, contacts, displacements) -> np.ndarray:
        """Advance each grasped part's corotational state by one preconditioned step
        (warm-started from the last frame), publish the linearisation for the servo, and
        return the nodal displacement. Two grasps on one part are solved together.

        The step is preconditioned by the linear stiffness until that stops reducing the
        residual; then the warped stiffness at the current state is factorised and used (a
        modified Newton method spread over frames: a refactorisation costs a few frames).
        """
        u_nodes = np.zeros((self.volume.n_nodes, 3))
        refreshed = False
        for part_id in sorted({c.data.part for c in contacts}, key=lambda p: (-self._corot.get(p, {}).get("since", 0), p)):
            idx = [k for k, c in enumerate(contacts) if c.data.part == part_id]
            cs = [contacts[k] for k in idx]
            d = np.concatenate([displacements[k] for k in idx])
            fem = self.parts[part_id]
            W = sp.vstack([c.data.W for c in cs]).tocsr()
            key = tuple(c.data for c in cs)
            state = self._corot.get(part_id)
            if state is None or not _same(state["key"], key):  # new grasp set: start from the linear solution
                U = np.hstack([c.data.U for c in cs])
                pre = _Precond(solve=fem.solve_free, U=U, C=W @ U)
                lam = np.linalg.solve(pre.C, d)
                u = np.zeros(3 * len(fem.nodes))
                u[fem.free] = U @ lam
                state = {"key": key, "u": u, "lam": lam, "active": np.zeros(0, dtype=np.int64), "pre": pre, "hist": [], "since": 0}
            if len(state["active"]) == 0:
                # corotate the elements that move: those touching a node displaced by more than
                # 5% of the largest displacement; the rest rotate negligibly and stay linear
                mag = np.linalg.norm(state["u"].reshape(-1, 3), axis=1)
                if mag.max() > 1e-6:
                    state["active"] = np.flatnonzero((mag > 0.05 * mag.max())[fem.tets].any(axis=1))
            if len(state["active"]):
                u, lam, res, jmin, R = corotational_step(fem, W, state["pre"], state["u"], state["lam"], d, state["active"])
                # approximate count: rotation and 12x12 product per active element, two solves
                self.frame_flops += 600 * len(state["active"]) + 8 * fem.factor.nnz_L
                if jmin <= 0:
                    self.inverted_frames += 1
                if not (res < 1.0 and np.all(np.isfinite(u))):  # diverged: restart from linear with a fresh tangent
                    self._corot.pop(part_id, None)
                    u, lam = state["u"], state["lam"]
                    self.restarts += 1
                else:
                    hist = (state["hist"] + [res])[-6:]
                    state["since"] += 1
                    # far from equilibrium (the hand moves, or the preconditioner has aged) and no
                    # refresh in the last 3 frames: refactorise the warped tangent at this state
                    # and at most one part per frame (two hands on two hemispheres: the second
                    # part waits a frame instead of doubling this frame's time)
                    if res > 1e-3 and state["since"] >= 3 and not refreshed:
                        refreshed = True
                        self.tangent_updates += 1
                        factor = fem.factor.with_values(_warped_active(fem, R, state["active"]))  # the linear factor's analysis
                        Uw = factor.solve(np.ascontiguousarray(W.T.toarray()))
                        # the warped stiffness has the linear one's pattern: the same factor size (no L copied here)
                        self.frame_flops += fem.factor.factor_flops + 4 * fem.factor.nnz_L * W.shape[0]
                        state["pre"] = _Precond(solve=factor.solve, U=Uw, C=W @ Uw)
                        state["since"] = 0
                    state.update(u=u, lam=lam, hist=hist)
                    self._corot[part_id] = state
            else:  # nothing moves yet: the linear solution for the current d
                pre = state["pre"]
                lam = np.linalg.solve(pre.C, d)
                u = np.zeros(3 * len(fem.nodes))
                u[fem.free] = pre.U @ lam
                state.update(u=u, lam=lam)
                self._corot[part_id] = state
            for j, c in enumerate(cs):
                linear = float(np.linalg.norm(np.asarray(c.data.K).reshape(3, 3) @ d[3 * j : 3 * j + 3]))
                if not np.linalg.norm(lam[3 * j : 3 * j + 3]) <= COROT_FORCE_LIMIT * linear + 1e-3:  # NaN too
                    self.unstable = True
            for j, c in enumerate(cs):  # publish for the servo: this frame's state and where it was
                c.law.update(f_frame=tuple(float(x) for x in lam[3 * j : 3 * j + 3]), d_frame=tuple(float(x) for x in d[3 * j : 3 * j + 3]))
            u_nodes[self.part_nodes[part_id]] = u.reshape(-1, 3)
        return u_nodes


def _warped_active(fem: LinearFem, R: np.ndarray, active: np.ndarray) -> sp.csc_matrix:
    """Warped stiffness on the free dofs with only the `active` elements rotated: the linear
    reduced stiffness plus the change of those elements, added straight into a copy of its
    values (where each element entry lands is found once per active set; the matrix is
    symmetric, so its CSR arrays serve as CSC)."""
    cached = getattr(fem, "_warp_map", None)
    if cached is None or cached[0] is not active:
        Kr = fem.reduced
        Kr.sum_duplicates()  # canonical: sorted indices, so keys below increase
        n = Kr.shape[0]
        where = -np.ones(3 * len(fem.nodes), dtype=np.int64)
        where[fem.free] = np.arange(len(fem.free))
        dofs = where[element_dofs(fem.tets[active])]  # (m, 12) free index or -1
        rows = np.repeat(dofs, 12, axis=1).ravel()
        cols = np.tile(dofs, (1, 12)).ravel()
        valid = (rows >= 0) & (cols >= 0)
        keys = np.repeat(np.arange(n, dtype=np.int64), np.diff(Kr.indptr)) * n + Kr.indices
        query = rows[valid] * n + cols[valid]
        pos = np.minimum(np.searchsorted(keys, query), len(keys) - 1)
        if not np.array_equal(keys[pos], query):  # an entry outside the pattern (a dropped zero): assemble
            pos = None
        fem._warp_map = cached = (active, valid, pos)
    _, valid, pos = cached
    K5 = fem.element_matrices[active].reshape(-1, 4, 3, 4, 3)
    Kw = np.einsum("mij,majbk,mlk->maibl", R, K5, R, optimize=True)  # R K_ab R^T for every 3x3 block
    Kr = fem.reduced
    if pos is None:
        delta = assemble((Kw - K5).reshape(-1, 12, 12), fem.tets[active], len(fem.nodes))
        return (Kr + delta[fem.free][:, fem.free]).tocsc()
    data = Kr.data + np.bincount(pos, weights=(Kw - K5).ravel()[valid], minlength=len(Kr.data))
    return sp.csc_matrix((data, Kr.indices, Kr.indptr), shape=Kr.shape)


def fixed_nodes(volume, surface, fixed_surface_mask: np.ndarray, axis: int) -> np.ndarray:
    """Volume nodes at or below the highest clamped surface height (the scene's fixed region)."""
    limit = surface.vertices[fixed_surface_mask, axis].max() if fixed_surface_mask.any() else -np.inf
    return volume.nodes[:, axis] <= limit


def build(mesh, spec, scene=None):
    """Construct from a scene's model spec (`sim.scene.ModelSpec`)."""
    from sim.scene import AXES
    from sim.volume import voxel_volume

    opts = spec.options
    resolution = float(opts.get("resolution", 0.004))
    volume = voxel_volume(mesh, resolution)
    material = scene.spec.material
    axis = AXES[scene.spec.fixed.axis]
    fixed = fixed_nodes(volume, mesh, scene.fixed_mask, axis)
    return FemModel(mesh, volume, material.young, material.poisson, fixed, opts.get("formulation", "linear"), opts.get("grasp_radius", GRASP_RADIUS),
                    order=int(opts.get("order", 1)))


# -- corotational (stiffness warping) ------------------------------------------------------


def _element_arrays(fem: LinearFem, elements: np.ndarray | None) -> tuple:
    """Contiguous tets, gradients and element matrices of `elements` (all when None) for the
    compiled kernels; kept for the last set asked for (a grasp's active elements, every frame)."""
    cached = getattr(fem, "_element_arrays", None)
    if cached is not None and cached[0] is elements:
        return cached[1]
    sel = slice(None) if elements is None else elements
    arrays = (np.ascontiguousarray(fem.tets[sel], dtype=np.int64), np.ascontiguousarray(fem.grads[sel]),
              np.ascontiguousarray(fem.element_matrices[sel]))
    fem._element_arrays = (elements, arrays)
    return arrays


def _kernels():
    try:
        import sim.kernels as kernels
    except ImportError:
        return None
    return kernels


def element_rotations(fem: LinearFem, u: np.ndarray, elements: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Rotation of each element's polar decomposition F = R S, and det F, for nodal u (3n,)."""
    kernels = _kernels()
    if kernels is None:
        tets = fem.tets if elements is None else fem.tets[elements]
        grads = fem.grads if elements is None else fem.grads[elements]
        ue = u[element_dofs(tets)].reshape(-1, 4, 3)
        F = np.eye(3) + np.einsum("mai,maj->mij", ue, grads)
        return _svd_rotations(F), np.linalg.det(F)
    tets, grads, _ = _element_arrays(fem, elements)
    F = np.empty((len(tets), 3, 3))
    kernels.deformation_gradients(np.ascontiguousarray(u, dtype=np.float64), tets, grads, F)
    polar_rotations = kernels.polar_rotations  # compiled scaled-Newton polar iteration: 16x the batched SVD, the same R to 1e-14
    R, det = np.empty_like(F), np.empty(len(F))
    left = polar_rotations(np.ascontiguousarray(F), R, det)
    if left.any():  # inverted (det F <= 0): the SVD's nearest rotation
        R[left] = _svd_rotations(F[left])
    return R, det


def _svd_rotations(F: np.ndarray) -> np.ndarray:
    Uf, _, Vt = np.linalg.svd(F)
    flip = np.linalg.det(Uf) * np.linalg.det(Vt) < 0  # a reflection: make it the nearest rotation
    Uf[flip, :, 2] *= -1.0
    return Uf @ Vt


def corotational_internal_force(fem: LinearFem, u: np.ndarray, R: np.ndarray, elements: np.ndarray | None = None) -> np.ndarray:
    """f = sum_e R_e K_e (R_e^T x_e - X_e): linear elasticity in each element's rotated frame.

    With `elements`, only those are corotated (R given for them); the others stay linear,
    which is what they are when their rotation is negligible.
    """
    kernels = _kernels()
    if kernels is not None and elements is not None:  # one compiled pass over the elements
        tets, _, Ke = _element_arrays(fem, elements)
        out = fem.stiffness @ u
        kernels.corotated_minus_linear(np.ascontiguousarray(u, dtype=np.float64), np.ascontiguousarray(fem.nodes, dtype=np.float64), tets, Ke, np.ascontiguousarray(R), out)
        return out
    tets = fem.tets if elements is None else fem.tets[elements]
    Ke = fem.element_matrices if elements is None else fem.element_matrices[elements]
    dofs = element_dofs(tets)
    X = fem.nodes[tets]  # (m, 4, 3)
    ue = u[dofs].reshape(-1, 4, 3)
    local = np.matmul(X + ue, R) - X  # R^T x - X, per node (batched products: faster than einsum here)
    fl = np.matmul(Ke, local.reshape(-1, 12, 1)).reshape(-1, 4, 3)
    fe = np.matmul(fl, R.transpose(0, 2, 1))  # R f per node
    n = 3 * len(fem.nodes)
    if elements is None:
        return np.bincount(dofs.ravel(), weights=fe.ravel(), minlength=n)
    linear = np.einsum("mij,mj->mi", Ke, ue.reshape(-1, 12))
    return fem.stiffness @ u + np.bincount(dofs.ravel(), weights=(fe.reshape(-1, 12) - linear).ravel(), minlength=n)


def warped_stiffness(fem: LinearFem, R: np.ndarray) -> sp.csr_matrix:
    """sum_e R_e K_e R_e^T on the free dofs (the stiffness-warping tangent, dR ignored)."""
    K5 = fem.element_matrices.reshape(-1, 4, 3, 4, 3)
    Kw = np.einsum("mij,majbk,mlk->maibl", R, K5, R, optimize=True)  # R K_ab R^T for every 3x3 block
    return assemble(Kw.reshape(-1, 12, 12), fem.tets, len(fem.nodes))[fem.free][:, fem.free]


@dataclass
class _Precond:
    solve: object  # callable: b -> K^-1 b on the free dofs
    U: np.ndarray  # K^-1 W^T
    C: np.ndarray  # W K^-1 W^T


def corotational_step(fem: LinearFem, W, pre: _Precond, u: np.ndarray, lam_mult: np.ndarray, d: np.ndarray, elements=None):
    """One preconditioned step towards corotational equilibrium with W u = d.
    Returns (u, lam_mult, relative residual, min det F, rotations)."""
    R, J = element_rotations(fem, u, elements)
    f_int = corotational_internal_force(fem, u, R, elements)[fem.free]
    r = f_int - (W.T @ lam_mult)
    gap = W @ u[fem.free] - d
    res = max(float(np.linalg.norm(r)) / max(float(np.linalg.norm(f_int)), 1e-30), float(np.linalg.norm(gap)) / max(float(np.linalg.norm(d)), 1e-12))
    Kr = pre.solve(-r)
    dl = np.linalg.solve(pre.C, -gap - W @ Kr)
    u = u.copy()
    u[fem.free] += Kr + pre.U @ dl
    return u, lam_mult + dl, res, float(J.min()), R


def corotational_solve(fem: LinearFem, W, U: np.ndarray, target: np.ndarray, steps: int = 5, tol: float = 1e-7, max_iter: int = 100):
    """Static corotational solve with the grasp point held at `target` (3,).

    Load steps, each iterated to a relative residual below `tol`. The steps are preconditioned
    by the linear stiffness (already factorised, so cheap); when that stalls (less than a
    halving of the residual over four steps) the warped stiffness at the current state is
    factorised and used instead (a modified Newton method). The warped stiffness omits the
    derivative of the rotations, so convergence is linear, not quadratic: at large pulls
    expect tens of iterations per step. Returns (nodal displacements, force holding the grasp
    point, NewtonReport).
    """
    pre = _Precond(solve=fem.solve_free, U=U, C=W @ U)
    u = np.zeros(3 * len(fem.nodes))
    lam_mult = np.zeros(3)
    report = NewtonReport(load_steps=steps)
    Wt = np.ascontiguousarray(W.T.toarray())
    report.completed_steps = 0
    for step in range(1, steps + 1):
        d = np.asarray(target, dtype=np.float64) * step / steps
        hist: list[float] = []
        good = (u, lam_mult)
        for _ in range(max_iter):
            u, lam_mult, res, jmin, R = corotational_step(fem, W, pre, u, lam_mult, d)
            report.min_jacobian = min(report.min_jacobian, jmin)
            hist.append(res)
            if not math.isfinite(res) or jmin <= 0 or res > 1e3 * min(hist):
                # diverging (or an element turned inside out): return the state before this load step
                u, lam_mult = good
                report.converged = False
                report.iterations.append(len(hist))
                report.residuals.append(hist)
                return u.reshape(-1, 3), lam_mult, report
            if len(hist) > 1 and res < tol:
                break
            if len(hist) >= 5 and hist[-1] > 0.5 * hist[-5]:
                factor = Factor(warped_stiffness(fem, R))
                Uw = factor.solve(Wt)
                pre = _Precond(solve=factor.solve, U=Uw, C=W @ Uw)
                report.tangent_updates += 1
        else:
            report.converged = False
        if report.converged:
            report.completed_steps = step
        report.iterations.append(len(hist))
        report.residuals.append(hist)
    return u.reshape(-1, 3), lam_mult, report


# -- nonlinear reference -------------------------------------------------------------------


@dataclass
class NewtonReport:
    load_steps: int
    iterations: list[int] = field(default_factory=list)  # per load step
    residuals: list[list[float]] = field(default_factory=list)  # relative residual per iteration
    converged: bool = True
    min_jacobian: float = 1.0  # smallest det(F) seen: <= 0 means an inverted element
    tangent_updates: int = 0  # refactorisations (corotational solver)
    completed_steps: int | None = None  # load steps solved; fewer than load_steps when the solve diverged


def neo_hookean_solve(fem: LinearFem, W: sp.csr_matrix, target: np.ndarray, steps: int = 10, tol: float = 1e-8, max_iter: int = 25,
                      on_step=None):
    """Static compressible neo-Hookean solve with the grasp point held at `target` (3,).

    Linear tetrahedra (order 1) only.
    Energy density ``mu/2 (I1 - 3) - mu ln J + lam/2 (ln J)^2``; the constraint ``W u = d`` is
    imposed with a Lagrange multiplier (Schur complement, 3 extra solves per iteration). The
    displacement is applied in `steps` equal increments, each solved by Newton's method to a
    relative residual below `tol`. Returns (nodal displacements, force holding the grasp
    point (3,), NewtonReport). `on_step(step, u (n, 3), force (3,))`, if given, sees each
    converged load step (a whole force-displacement curve from one solve).
    """
    if fem.order != 1:
        raise ParameterError("order: the neo-Hookean solve runs on linear (order 1) tetrahedra")
    lam, mu = fem.lam, fem.mu
    g = fem.grads  # reference gradients (m, 4, 3)
    V = np.abs(fem.volumes)
    tets = fem.tets
    free = fem.free
    n = len(fem.nodes)
    dofs = element_dofs(tets)
    rows = np.repeat(dofs, 12, axis=1).ravel()
    cols = np.tile(dofs, (1, 12)).ravel()
    u = np.zeros(3 * n)
    Wt = W.T.toarray()
    report = NewtonReport(load_steps=steps)
    lam_mult = np.zeros(3)
    scale = max(float(np.linalg.norm(target)), 1e-12)
    for step in range(1, steps + 1):
        d = target * step / steps
        res_hist: list[float] = []
        for it in range(max_iter):
            ue = u[dofs].reshape(-1, 4, 3)
            F = np.eye(3) + np.einsum("mai,maj->mij", ue, g)  # F_ij = d_ij + sum_a u_ai g_aj
            J = np.linalg.det(F)
            report.min_jacobian = min(report.min_jacobian, float(J.min()))
            if np.any(J <= 0):
                report.converged = False
                report.iterations.append(it)
                report.residuals.append(res_hist)
                return u.reshape(-1, 3), lam_mult, report
            Finv = np.linalg.inv(F)
            FinvT = np.transpose(Finv, (0, 2, 1))
            lnJ = np.log(J)
            P = mu * (F - FinvT) + (lam * lnJ)[:, None, None] * FinvT
            fe = V[:, None, None] * np.einsum("mij,maj->mai", P, g)  # (m, 4, 3)
            f_int = np.bincount(dofs.ravel(), weights=fe.ravel(), minlength=3 * n)
            # tangent A_iJkL = mu d_ik d_JL + (mu - lam lnJ) Finv_Li Finv_Jk + lam Finv_Ji Finv_Lk
            c1 = (mu - lam * lnJ)
            GA = np.einsum("mLi,maL->mai", Finv, g)  # g_a . Finv  -> (m, 4, 3), index i
            GB = np.einsum("mJk,mbJ->mbk", Finv, g)  # same contraction for b, index k
            Ke = (
                mu * np.einsum("maJ,mbJ->mab", g, g)[:, :, None, :, None] * np.eye(3)[None, None, :, None, :]
                + c1[:, None, None, None, None] * np.einsum("mbi,mak->maibk", GA, GB)
                + lam * np.einsum("mai,mbk->maibk", GA, GB)
            ) * V[:, None, None, None, None]
            Kt = sp.coo_matrix((Ke.reshape(-1, 12, 12).ravel(), (rows, cols)), shape=(3 * n, 3 * n)).tocsr()
            Kff = Kt[free][:, free]
            r = f_int[free] - Wt @ lam_mult  # residual: internal force minus the grasp force
            gap = W @ u[free] - d
            res = float(np.linalg.norm(r)) / max(float(np.linalg.norm(f_int[free])), float(np.linalg.norm(Wt @ lam_mult)), 1e-30)
            res_hist.append(max(res, float(np.linalg.norm(gap)) / scale))
            if it > 0 and res_hist[-1] < tol:
                break
            factor = shifted_factor(0.5 * (Kff + Kff.T))  # indefinite tangent: shifted, see sim.linalg
            # [K  -W^T] [du ]   [-r  ]
            # [W   0  ] [dl ] = [-gap]
            Kr = factor.solve(-r)
            KW = factor.solve(Wt)
            S = W @ KW  # (3, 3)
            dl = np.linalg.solve(S, -gap - W @ Kr)
            du = Kr + KW @ dl
            u[free] += du
            lam_mult += dl
        else:
            report.converged = False
        report.iterations.append(len(res_hist))
        report.residuals.append(res_hist)
        if on_step is not None:
            on_step(step, u.reshape(-1, 3).copy(), lam_mult.copy())
    return u.reshape(-1, 3), lam_mult, report


# -- one static pull, the `studyctl model fem` command ------------------------------------

FORMULATIONS = ("linear", "corotational", "neo-hookean")


def static_pull(scene, grasp, displacement, resolution: float | None = None, formulation: str = "linear", steps: int = 5,
                order: int | None = None) -> dict:
    """Grasp the scene's brain at `grasp` and hold the grasp point at `displacement` (m).

    Returns the force on the hand, the largest displacement, the phase times, and for the
    nonlinear formulations the convergence history.
    """
    from sim.scene import AXES
    from sim.volume import describe, voxel_volume

    if formulation not in FORMULATIONS:
        raise ParameterError(f"formulation: {formulation!r} is not one of {', '.join(FORMULATIONS)}")
    if (problem := pull_problem(displacement)) is not None:
        raise ParameterError(f"displacement: {problem}")
    d = np.asarray(displacement, dtype=np.float64)
    spec = scene.model_spec if scene.model_spec.name == "fem" else None
    if resolution is None:
        resolution = float(spec.options["resolution"]) if spec else 0.004
    if not 0.003 <= resolution <= 0.008:
        raise ParameterError(f"resolution: {resolution * 1e3:g} mm is out of range; allowed: 3..8 mm")
    times: dict[str, float] = {}
    t0 = time.perf_counter()
    mesh = scene.mesh
    volume = voxel_volume(mesh, resolution)
    times["mesh_s"] = time.perf_counter() - t0
    material = scene.spec.material
    fixed = fixed_nodes(volume, mesh, scene.fixed_mask, AXES[scene.spec.fixed.axis])
    if order is None:
        order = int(spec.options.get("order", 1)) if spec else 1
    if order == 2 and formulation != "linear":
        raise ParameterError(f"order: quadratic tetrahedra (order 2) run the linear formulation only, not {formulation}")
    model = FemModel(mesh, volume, material.young, material.poisson, fixed, grasp_radius=spec.options.get("grasp_radius", GRASP_RADIUS) if spec else GRASP_RADIUS,
                     order=order)
    times.update({k: v for k, v in model.timings.items()})
    t0 = time.perf_counter()
    contact = model.grasp(grasp, 0)
    times["grasp_s"] = time.perf_counter() - t0
    reps = 20000
    t0 = time.perf_counter()
    dt = tuple(float(x) for x in d)
    for _ in range(reps):
        model.force(contact, dt)
    times["tick_s"] = (time.perf_counter() - t0) / reps
    t0 = time.perf_counter()
    model.deformation([contact], [d])
    times["frame_s"] = time.perf_counter() - t0
    part = model.parts[contact.data.part]
    out = {
        "formulation": formulation,
        "order": order,
        "resolution_mm": resolution * 1e3,
        "volume": describe(volume),
        "part": {"nodes": int(part.n_all), "tets": int(len(part.tets)), "free_dofs": int(len(part.free))},
        "grasp_vertex": contact.vertex,
        "grasp_point": list(contact.point),
        "displacement": d.tolist(),
        "locking": model.locking,
    }
    if formulation == "linear":
        force = -np.asarray(model.force(contact, dt))
        u = model.nodal_displacement([contact], [d])
        out["converged"] = True
    elif formulation == "neo-hookean":
        t0 = time.perf_counter()
        u_part, lam_mult, rep = neo_hookean_solve(part, contact.data.W, d, steps=steps)
        times["solve_s"] = time.perf_counter() - t0
        force = lam_mult
        u = np.zeros((volume.n_nodes, 3))
        u[model.part_nodes[contact.data.part]] = u_part
        out.update(_report(rep))
    else:
        t0 = time.perf_counter()
        u_part, lam_mult, rep = corotational_solve(part, contact.data.W, contact.data.U, d, steps=steps)
        times["solve_s"] = time.perf_counter() - t0
        force = lam_mult
        u = np.zeros((volume.n_nodes, 3))
        u[model.part_nodes[contact.data.part]] = u_part
        out.update(_report(rep))
    # the hand feels minus the force that holds the tissue at d
    out["force_n"] = (-np.asarray(force)).tolist()
    out["force_magnitude_n"] = float(np.linalg.norm(force))
    out["max_displacement_m"] = float(np.linalg.norm(u, axis=1).max())
    out["times_ms"] = {k.removesuffix("_s"): v * 1e3 for k, v in times.items()}
    out["times_ms"]["tick"] = times["tick_s"] * 1e3
    return out


def _report(rep: NewtonReport) -> dict:
    return {
        "converged": rep.converged,
        "load_steps": rep.load_steps,
        "iterations": rep.iterations,
        "final_residuals": [r[-1] if r else None for r in rep.residuals],
        "min_jacobian": rep.min_jacobian,
        "inverted_elements": rep.min_jacobian <= 0,
        "tangent_updates": rep.tangent_updates,
        # a solve that stopped early returns the state of its last solved load step
        "completed_steps": rep.completed_steps,
    }
