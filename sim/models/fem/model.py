"""The FEM under the tissue-model contract: `FemModel` and `build`.

A grasp precomputes the condensed compliance of its patch, ``C = W K^-1 W^T`` (3 solves,
`sim.models.fem.grasp`); a servo tick is ``f = C^-1 d`` (3x3); two grasps on one hemisphere
are coupled through the 6x6 block matrix; a frame's deformation is ``u = K^-1 W^T f`` from the
same precomputed responses, mapped to the surface by the embedding (each surface vertex
interpolated with its element's own shape functions).
"""

from __future__ import annotations

import copy
import hashlib
import math
import time
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from sim.errors import ParameterError
from sim.geometry.patch import GRASP_RADIUS, patch_area_points
from sim.geometry.tetmesh import body_volume
from sim.geometry.volume import centroid_tree, embed, locate
from sim.laws import Linearised, PairTable
from sim.models.base import Contact
from sim.models.builtin import FemBase, FemOptions
from sim.models.fem import corotational_kernels
from sim.models.fem.corotational import Precond, corotational_step, evaluate, warped_active
from sim.models.fem.grasp import condense, constraint_matrix, symmetric_inverse
from sim.models.fem.linear import LinearFem
from sim.scene import AXES

DEFAULT_RESOLUTION = FemOptions.resolution  # m: the shipped body-fitted mesh the scene's FEM runs on (docs/fem.md)
DEFAULT_ORDER = 2  # quadratic tetrahedra: P1 locks at the brain's Poisson ratio (FemOptions' default for the linear formulation)

GRASPS_KEPT = 16  # condensed grasps kept per model (`FemModel.grasp`): a session's grasps land on a few vertices
COROT_FORCE_LIMIT = 3.0  # a corotational force this many times the linear one for the same grasp is a runaway
# Assembled, factorised parts by content: a process that builds the same scene again (a session's
# conditions, each synthetic participant, a sweep's cases) reuses them; they are slow to build
# and large (docs/fem.md), so only a few are kept.
_PARTS: dict = {}
PARTS_KEPT = 4


def shared_part(nodes: np.ndarray, tets: np.ndarray, young: float, poisson: float, fixed: np.ndarray, order: int) -> LinearFem:
    """A factorised `LinearFem`, the same object for the same content (it is not changed by use)."""
    digest = hashlib.sha256()
    for a in (nodes, tets, fixed):
        digest.update(np.ascontiguousarray(a).tobytes())
    key = (digest.hexdigest(), float(young), float(poisson), int(order))
    part = _PARTS.pop(key, None)
    if part is None:
        part = LinearFem(nodes, tets, young, poisson, fixed, order=order)
        _ = part.factor  # factorise now, not in the first grasp (two threads: no faster)
        while len(_PARTS) >= PARTS_KEPT:
            _PARTS.pop(next(iter(_PARTS)))  # the least recently used
    _PARTS[key] = part
    return part

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


class FemModel(FemBase):
    """The linear FEM under the tissue-model contract (see module docstring).

    Each connected component of the volume (each hemisphere) is its own system with its own
    factorisation: they share no node, so grasps on different hemispheres are uncoupled, and
    two factorisations of half the size cost less than one of the whole.
    """

    name = "fem"

    def __init__(self, surface, volume, young: float, poisson: float, fixed_nodes: np.ndarray, formulation: str = "linear", grasp_radius: float = GRASP_RADIUS,
                 order: int = 1):
        if formulation not in ("linear", "corotational"):
            raise ParameterError(f"formulation: {formulation!r} is not available for the haptic model; allowed: linear, corotational")
        if order == 2 and formulation != "linear":
            raise ParameterError("order: quadratic tetrahedra (order 2) run the linear formulation only")
        self.surface = surface
        self.volume = volume
        self.formulation = formulation
        self.grasp_radius = grasp_radius
        self.parts: list[LinearFem] = []
        self.offsets: list[int] = []  # where each part's nodes (corners, then mid-edge) start in the model's node vector
        if np.any(np.diff(volume.component) < 0):
            raise ParameterError("volume: nodes must be grouped by component (hemisphere)")
        tet_comp = volume.component[volume.tets[:, 0]]
        self.tet_part = np.empty(len(volume.tets), dtype=np.int64)
        self.tet_local = np.empty(len(volume.tets), dtype=np.int64)
        offset = 0
        for k, label in enumerate(np.unique(volume.component)):
            nodes = np.flatnonzero(volume.component == label)
            sel = np.flatnonzero(tet_comp == label)
            self.tet_part[sel], self.tet_local[sel] = k, np.arange(len(sel))
            self.parts.append(shared_part(volume.nodes[nodes], volume.tets[sel] - nodes[0], young, poisson, fixed_nodes[nodes], order))
            self.offsets.append(offset)
            offset += self.parts[-1].n_all
        self.n_model_nodes = offset
        start = time.perf_counter()
        self.embedding = embed(volume, surface.vertices, surface.labels)
        self.surface_matrix = self._surface_matrix()
        self.embed_s = time.perf_counter() - start
        surface.prepare_queries()
        # one-time work of a grasp, done now: a run's first grasps took over the grasp budget
        # building each part's centroid tree (about 100 ms on the 8 mm P2 mesh)
        self.centroid_trees = [centroid_tree(part.nodes, part.tets) for part in self.parts]
        self._pair_of: tuple | None = None  # (the two contacts' data, their pair stiffness)
        self._grasps: dict[int, tuple] = {}  # surface vertex -> its condensed grasp (`grasp`)
        # surface vertex -> (part, W, the factor's unscaled solve of W^T): the costly part of a
        # grasp (location and three solves), shared with every stiffness-scaled
        # copy (`with_stiffness`: the same factor), whose grasps then cost a division and W U
        self._located: dict[int, tuple] = {}
        self._out = np.zeros_like(surface.vertices)
        self._pending: tuple | None = ("zero",)  # the last frame's surface, not computed yet (`advance`)
        # corotational state, per part: (contact ids, free-dof displacement, multipliers)
        self._corot: dict[int, tuple] = {}
        self.inverted_frames = 0  # frames in which an element was inverted (det F <= 0)
        self.tangent_updates = 0  # warped-stiffness refactorisations
        self.restarts = 0  # corotational iterations that diverged and restarted from linear
        self.halvings = 0  # corotational steps halved by the line search (near inverted elements)
        # a corotational iteration that runs away (elements invert on a long pull and the force
        # grows within a few frames: docs/fem.md) is caught when its force exceeds
        # COROT_FORCE_LIMIT times the linear force for the same grasp; the servo then renders
        # nothing until the grasp is released
        self.unstable = False
        self.frame_flops = math.nan  # the last frame's counted work
        if formulation == "corotational":
            corotational_kernels.warm_up()  # compiled now, not in the first frame of a trial

    def _surface_matrix(self) -> sp.csr_matrix:
        """(surface vertices, model nodes): each vertex interpolated with its element's shape functions."""
        tet, bary = self.embedding.tet, self.embedding.weights
        rows, cols, vals = [], [], []
        for k, part in enumerate(self.parts):
            sel = np.flatnonzero(self.tet_part[tet] == k)
            nodes = part.elements[self.tet_local[tet[sel]]]
            rows.append(np.repeat(sel, nodes.shape[1]))
            cols.append((self.offsets[k] + nodes).ravel())
            vals.append(part.element.shape(bary[sel]).ravel())
        return sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(len(tet), self.n_model_nodes))

    def with_stiffness(self, scale: float) -> FemModel:
        """This model with Young's modulus times `scale` (the discrimination task's stimulus):
        the parts scaled (`LinearFem.scaled`, the factors reused), the mesh and embedding
        shared, no grasp or frame state carried over. Equal to building it with E * scale."""
        out = copy.copy(self)
        out.parts = [p.scaled(scale) for p in self.parts]
        out._pair_of, out._corot, out._out, out._grasps, out._pending = None, {}, np.zeros_like(self._out), {}, ("zero",)
        out.inverted_frames = out.tangent_updates = out.restarts = out.halvings = 0
        out.unstable, out.frame_flops = False, math.nan
        return out

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
            "halvings": self.halvings,
            "unstable": self.unstable,
        }

    def grasp(self, point, hand: int = 0):
        v = int(self.surface.nearest_vertex(point))
        data = FemContact(*self._condensed(v))  # a new object per grasp: caches keyed by identity see a new grasp
        anchor = tuple(float(c) for c in self.surface.vertices[v])
        normal = tuple(float(c) for c in self.surface.vertex_normals[v])
        return Contact(hand=hand, vertex=int(v), point=anchor, normal=normal, data=data, law=Linearised(K=data.K))

    @property
    def condensed_vertices(self) -> frozenset[int]:
        """The surface vertices whose grasp is condensed and kept (a grasp there costs a look-up)."""
        return frozenset(self._grasps)

    def prepare_grasps(self, points) -> None:
        """Condense the grasps at `points` now (the scene's hands start there): a grasp's work at a
        new vertex (its patch located, three solves: 200-300 ms on the 8 mm P2 mesh) is then the
        build's, and the run's first grasps there cost a cache look-up."""
        for point in points:
            self._condensed(int(self.surface.nearest_vertex(point)))

    def _condensed(self, v: int) -> tuple:
        """(part, W, U, C, K) of a grasp at surface vertex `v`: a function of the vertex alone,
        computed once per model (three solves and the patch's location; the motor model grasps the same few vertices in every trial of a session). U and C are
        read-only: every grasp at `v` shares them."""
        hit = self._grasps.pop(v, None)
        if hit is None:
            located = self._located.pop(v, None)
            if located is None:
                part = int(self.tet_part[self.embedding.tet[v]])
                fem = self.parts[part]
                # the patch's area mean, each quadrature point interpolated in its element: the
                # reference's functional (its vertex mean, a handful of point constraints, would soften
                # without limit as the mesh is refined: 13% from 8 to 4 mm on P2)
                points, weights = patch_area_points(self.surface, v, self.grasp_radius)
                tet, bary = locate(fem.nodes, fem.tets, points, tree=self.centroid_trees[part])
                W = constraint_matrix(fem, tet, bary, weights)  # `condense` refuses a patch that cannot move
                located = (part, W, fem.factor.unscaled_solve(np.ascontiguousarray(W.T.toarray())))
                while len(self._located) >= GRASPS_KEPT:
                    self._located.pop(next(iter(self._located)))
            self._located[v] = located
            part, W, unscaled = located
            fem = self.parts[part]
            U, C, Kc = condense(fem, W, unscaled)
            U.flags.writeable = C.flags.writeable = False
            hit = (part, W, U, C, tuple(float(x) for x in Kc.ravel()))
            while len(self._grasps) >= GRASPS_KEPT:
                self._grasps.pop(next(iter(self._grasps)))  # the least recently used
        self._grasps[v] = hit
        return hit

    def _pair(self, a, b) -> np.ndarray:
        held = self._pair_of
        if held is None or not _same(held[0], (a.data, b.data)):
            C12 = a.data.W @ b.data.U if a.data.part == b.data.part else np.zeros((3, 3))
            C = np.block([[a.data.C, C12], [C12.T, b.data.C]])
            held = self._pair_of = ((a.data, b.data), symmetric_inverse(C))  # only the current pair is ever needed
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

    def tick_laws(self, contacts):
        """Each contact's law, unless the model is unstable or the two grasps are coupled (or a
        subclass computes its forces otherwise)."""
        if type(self).force is not FemModel.force or type(self).forces is not FemModel.forces:
            return None
        if self.unstable or self.pair_law(contacts) is not None:
            return None
        return [c.law for c in contacts]

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
        """Displacement of every node of the model, (n_model_nodes, 3): each part's corners, then its mid-edge nodes."""
        f = self.grasp_forces(contacts, displacements)
        u = np.zeros((self.n_model_nodes, 3))
        for k, c in enumerate(contacts):
            part, start = self.parts[c.data.part], self.offsets[c.data.part]
            u[start : start + part.n_all] += part.from_free(c.data.U @ f[3 * k : 3 * k + 3], corners=False)
        return u

    def reset(self) -> None:
        """Back to rest: no frame state, and a model that gave up renders again (the accuracy
        bench resets between pulls; without this a corotational give-up zeroed every later pull)."""
        self._corot.clear()
        self._pair_of = None
        self._pending = ("zero",)
        self.unstable = False

    def deformation(self, contacts, displacements) -> np.ndarray:
        self.advance(contacts, displacements)
        return self.surface_displacement()

    def advance(self, contacts, displacements) -> None:
        """The frame's state (the corotational update and its laws); the surface waits for
        `surface_displacement` (the linear formulation's force never needs it)."""
        if not contacts:
            self.frame_flops = float(3 * len(self._out))  # zeroing: every call sets its count (none is left over)
            self._pending = ("zero",)
            self._corot.clear()
            self.unstable = False  # released: the next grasp starts from the linear solution
            return
        displacements = [np.asarray(d, dtype=np.float64) for d in displacements]
        # counted work of the frame as a session runs it (studyctl/synthetic/observer.py), the surface
        # included: dense products with the grasps' responses (6 flops per free dof and grasp),
        # the embedding (2 per entry and component), zeroing
        self.frame_flops = float(2 * self.surface_matrix.nnz + 3 * self.n_model_nodes
                                 + sum(6 * len(self.parts[c.data.part].free) for c in contacts) + 72 * len(contacts))
        if self.formulation == "corotational":
            self._pending = ("nodes", self._corotational_frame(contacts, displacements))
        else:
            self._pending = ("grasps", list(contacts), displacements)

    def surface_displacement(self) -> np.ndarray:
        pending, self._pending = self._pending, None
        if pending is None:  # asked again: this frame's surface is there already
            return self._out
        if pending[0] == "zero":
            self._out[:] = 0.0
        else:
            u = pending[1] if pending[0] == "nodes" else self.nodal_displacement(pending[1], pending[2])
            self._out[:] = self.surface_matrix @ u
        return self._out

    def _corotational_frame(self, contacts, displacements) -> np.ndarray:
        """Advance each grasped part's corotational state by one preconditioned step
        (warm-started from the last frame), publish the linearisation for the servo, and
        return the nodal displacement. Two grasps on one part are solved together.

        The step is preconditioned by the linear stiffness until that stops reducing the
        residual; then the warped stiffness at the current state is factorised and used (a
        modified Newton method spread over frames: a refactorisation costs a few frames).
        """
        u_nodes = np.zeros((self.n_model_nodes, 3))
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
                pre = Precond(solve=fem.solve_free, U=U, C=W @ U)
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
                at = state.get("at")
                if at is None or at.u is not state["u"]:
                    at = evaluate(fem, state["u"], state["active"])
                at_new, lam, res, jmin, halvings = corotational_step(fem, W, state["pre"], at, state["lam"], d, state["active"])
                u, R = at_new.u, at.R
                # approximate count: rotation, energy and 12x12 product per active element and
                # line-search trial, two solves
                self.frame_flops += 700 * len(state["active"]) * (1 + max(halvings, 0)) + 8 * fem.factor.nnz_L
                self.halvings += max(halvings, 0)
                if jmin <= 0:
                    self.inverted_frames += 1
                if not (res < 1.0 and np.all(np.isfinite(u))):  # diverged: restart from linear with a fresh tangent
                    self._corot.pop(part_id, None)
                    u, lam = state["u"], state["lam"]
                    self.restarts += 1
                else:
                    state["at"] = at_new
                    if halvings != 0:  # the tangent has aged past a full step: refresh it now
                        state["since"] = max(state["since"], 3)
                    hist = (state["hist"] + [res])[-6:]
                    state["since"] += 1
                    # far from equilibrium (the hand moves, or the preconditioner has aged) and no
                    # refresh in the last 3 frames: refactorise the warped tangent at this state
                    # and at most one part per frame (two hands on two hemispheres: the second
                    # part waits a frame instead of doubling this frame's time)
                    if res > 1e-3 and state["since"] >= 3 and not refreshed:
                        refreshed = True
                        self.tangent_updates += 1
                        factor = fem.factor.with_values(warped_active(fem, R, state["active"]))  # the linear factor's analysis
                        Uw = factor.solve(np.ascontiguousarray(W.T.toarray()))
                        # the warped stiffness has the linear one's pattern: the same factor size (no L copied here)
                        self.frame_flops += fem.factor.factor_flops + 4 * fem.factor.nnz_L * W.shape[0]
                        state["pre"] = Precond(solve=factor.solve, U=Uw, C=W @ Uw)
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
            u_nodes[self.offsets[part_id] : self.offsets[part_id] + fem.n_all] = u.reshape(-1, 3)
        return u_nodes



def fixed_nodes(volume, surface, fixed_surface_mask: np.ndarray, axis: int) -> np.ndarray:
    """Volume nodes at or below the highest clamped surface height (the scene's fixed region)."""
    limit = surface.vertices[fixed_surface_mask, axis].max() if fixed_surface_mask.any() else -np.inf
    return volume.nodes[:, axis] <= limit


def build(mesh, opts: dict, scene):
    """Construct from a scene's FEM options (`sim.models.builtin.FemOptions`, as a dict)."""
    volume = body_volume(mesh, float(opts.get("resolution", DEFAULT_RESOLUTION)))
    material = scene.spec.material
    fixed = fixed_nodes(volume, mesh, scene.fixed_mask, AXES[scene.spec.fixed.axis])
    model = FemModel(mesh, volume, material.young, material.poisson, fixed, opts.get("formulation", "linear"), opts.get("grasp_radius", GRASP_RADIUS),
                     order=int(opts.get("order", DEFAULT_ORDER)))
    model.prepare_grasps([h.start for h in scene.spec.hands])
    return model
