"""A converged reference for the accuracy bench: quadratic tetrahedra on body-fitted meshes,
refined three times, with Richardson extrapolation and Roache's grid convergence index.

Why: the voxel-tetrahedral meshes of sim/volume.py change their boundary with the spacing
(a staircase of cells), so refining them does not converge to one geometry; and linear (P1)
tetrahedra lock at the brain's Poisson ratio of 0.45. Here:

- Each hemisphere's closed pial surface is meshed with fTetWild (`pytetwild`, MPL-2.0) at
  three target edge lengths (`mesh_hemisphere`); the boundary follows the surface within an
  envelope that shrinks with the edge length, so geometry and field refine together.
- Quadratic (P2) tetrahedra, small-strain linear elasticity (`sim.models.fem.LinearFem` with
  ``order=2``), the scene's material and clamp: nodes at or below the highest clamped surface
  vertex (`sim.models.fem.fixed_nodes`, the same plane as the scene's FEM).
- The grasp as in `FemModel.grasp`: the mean displacement of the surface vertices within the
  grasp radius of the grasp vertex, each embedded in its containing (or nearest) tetrahedron
  and interpolated with the element's own quadratic shape functions; the force holding the
  patch at ``d`` is ``(W K^-1 W^T)^-1 d`` (a Lagrange multiplier, condensed).
- The accuracy bench's pulls and displacements (`analysis.accuracy`). Linear elasticity makes
  the force proportional to the displacement and to Young's modulus: one solve per pull (3
  right-hand sides) serves every sampled displacement and modulus.
- `richardson`: observed order, extrapolated value and GCI band from three meshes with any
  refinement ratios (Celik et al. 2008, J. Fluids Eng. 130: 078001), with a conservative
  fallback for oscillatory or diverging sequences; `richardson2` for two meshes (assumed order).

Meshes are cached on disk (``$BRAINSIM_CACHE/reference``): fTetWild takes 0.5-1.5 minutes per
hemisphere and size on 2 cores. The numbers are in docs/reference.md.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from sim.files import save_npz
from sim.jsonable import jsonable
from sim.mesh import patch_vertices
from sim.patch import patch_area_points
from sim.scene import DEFAULT_SCENE, clamp_limit, grasp_radius

MESHER_VERSION = 1  # part of the mesh cache key: bump when the meshing rule changes
ENVELOPE_FRACTION = 0.1  # fTetWild's envelope (max distance of the mesh boundary from the surface) = this x edge length
DEFAULT_SIZES_MM = (8.0, 5.5, 4.0)  # fTetWild target edge lengths, coarse to fine
QUICK_SIZES_MM = (20.0, 16.0)
FORMULATIONS = ("linear", "neo-hookean")
GCI_FS3 = 1.25  # Roache's factor of safety, three meshes with a reasonable observed order
GCI_FS_FALLBACK = 3.0  # two meshes, or an order that cannot be trusted: with the assumed order
ASSUMED_ORDER = 2.0
ORDER_RANGE = (0.5, 4.0)  # observed orders outside this are not trusted (P2: 2 for the energy norm's square... up to 4 for smooth functionals)


# -- fTetWild --------------------------------------------------------------------------------

def _pytetwild():
    """pytetwild's `tetrahedralize`. Its package imports PyVista on import only to register a
    `.tetwild` accessor on PyVista meshes (0.4.2); without PyVista, that module is stubbed
    (the accessor is not used here, and PyVista's VTK is a 100 MB dependency)."""
    try:
        import pyvista  # noqa: F401
    except ImportError:
        import types

        sys.modules.setdefault("pytetwild._accessor", types.ModuleType("pytetwild._accessor"))
    try:
        from pytetwild import tetrahedralize
    except ImportError as exc:  # pragma: no cover - a dependency in pyproject.toml
        from sim.errors import MeshError

        raise MeshError(f"body-fitted meshing needs pytetwild (pip install 'pytetwild>=0.4'): {exc}") from None
    return tetrahedralize


def hemisphere_surface(mesh, label: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One labelled component of a surface: (vertices (k, 3), triangles (t, 3) local, global vertex ids)."""
    if mesh.labels is None:
        ids = np.arange(mesh.n_vertices)
        return mesh.vertices, np.asarray(mesh.triangles, dtype=np.int64), ids
    ids = np.flatnonzero(mesh.labels == label)
    local = -np.ones(mesh.n_vertices, dtype=np.int64)
    local[ids] = np.arange(len(ids))
    tri = mesh.triangles[np.all(mesh.labels[mesh.triangles] == label, axis=1)]
    return mesh.vertices[ids], local[tri], ids


def enclosed_volume(vertices: np.ndarray, triangles: np.ndarray) -> float:
    """Volume enclosed by a closed, outward-oriented triangle surface (divergence theorem)."""
    a, b, c = (vertices[triangles[:, k]] for k in range(3))
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


def tet_volumes(nodes: np.ndarray, tets: np.ndarray) -> np.ndarray:
    a, b, c, d = (nodes[tets[:, k]] for k in range(4))
    return np.einsum("ij,ij->i", np.cross(b - a, c - a), d - a) / 6.0


@dataclass(frozen=True, eq=False)
class BodyMesh:
    nodes: np.ndarray  # (n, 3) m
    tets: np.ndarray  # (m, 4), positively oriented
    edge_length: float  # fTetWild's target edge length, m
    envelope: float  # fTetWild's envelope, m
    seconds: float  # meshing time (0 when read from the cache)
    cached: bool = False

    @property
    def volume(self) -> float:
        return float(tet_volumes(self.nodes, self.tets).sum())

    @property
    def h(self) -> float:
        """Characteristic element size (V / n_tets)^(1/3), m: the refinement measure."""
        return (self.volume / len(self.tets)) ** (1.0 / 3.0)

    def describe(self) -> dict:
        v = tet_volumes(self.nodes, self.tets)
        return {"target_edge_mm": self.edge_length * 1e3, "envelope_mm": self.envelope * 1e3, "nodes": int(len(self.nodes)),
                "tets": int(len(self.tets)), "h_mm": self.h * 1e3, "volume_cm3": float(v.sum() * 1e6),
                "min_tet_volume_mm3": float(v.min() * 1e9), "mesh_s": self.seconds, "cached": self.cached}


def _cache_root() -> Path:
    from sim.volume import cache_dir

    return cache_dir() / "reference"


def _mesh_path(vertices, triangles, edge_length: float, envelope: float) -> Path:
    digest = hashlib.sha256()
    for a in (np.ascontiguousarray(vertices, dtype=np.float64) * 1e3, np.ascontiguousarray(triangles, dtype=np.int32)):
        digest.update(a.tobytes())
    digest.update(repr((round(edge_length, 9), round(envelope, 9), MESHER_VERSION)).encode())
    return _cache_root() / f"tetwild-{digest.hexdigest()[:20]}.npz"


def mesh_hemisphere(vertices: np.ndarray, triangles: np.ndarray, edge_length: float, envelope: float | None = None,
                    threads: int = 1, use_cache: bool = True) -> BodyMesh:
    """Body-fitted tetrahedral mesh of a closed surface (metres) with fTetWild.

    `edge_length`: target edge length (m); `envelope`: the largest distance of the mesh's
    boundary from the surface (m, default ENVELOPE_FRACTION x edge_length); `threads`: fTetWild's
    (0 = every core; on this surface 2 are no faster than 1). fTetWild is not deterministic
    (two runs give meshes with a few % different node counts, at any thread count): the
    cache is what makes a reference reproducible. fTetWild refines near the surface as far as the envelope needs (the pial surface is
    folded), so the node count is not (V / edge^3). Meshed in millimetres; returned in metres
    with every tetrahedron positively oriented. Cached on disk by content and parameters.
    """
    from sim.errors import MeshError

    if not (0.5e-3 <= edge_length <= 0.05):
        raise MeshError(f"edge_length: {edge_length * 1e3:g} mm is out of range; allowed: 0.5..50 mm")
    envelope = ENVELOPE_FRACTION * edge_length if envelope is None else float(envelope)
    v_mm = np.ascontiguousarray(vertices, dtype=np.float64) * 1e3
    tri = np.ascontiguousarray(triangles, dtype=np.int32)
    diag = float(np.linalg.norm(v_mm.max(axis=0) - v_mm.min(axis=0)))
    path = _mesh_path(vertices, triangles, edge_length, envelope)
    if use_cache and path.exists():
        with np.load(path) as z:
            return BodyMesh(z["nodes"], z["tets"], edge_length, envelope, float(z["seconds"]), cached=True)
    tetrahedralize = _pytetwild()
    start = time.perf_counter()
    nodes, tets = tetrahedralize(v_mm, tri, edge_length_abs=edge_length * 1e3, epsilon=envelope * 1e3 / diag, num_threads=threads)
    seconds = time.perf_counter() - start
    nodes = np.asarray(nodes, dtype=np.float64) * 1e-3
    tets = np.asarray(tets, dtype=np.int64)
    if len(tets) == 0:
        raise MeshError("fTetWild returned no tetrahedra")
    vol = tet_volumes(nodes, tets)
    flip = vol < 0  # fTetWild's orientation is the opposite of ours
    tets[flip] = tets[flip][:, [0, 2, 1, 3]]
    used = np.unique(tets)
    if len(used) < len(nodes):  # drop unreferenced nodes (none expected)
        remap = -np.ones(len(nodes), dtype=np.int64)
        remap[used] = np.arange(len(used))
        nodes, tets = nodes[used], remap[tets]
    if np.any(np.abs(tet_volumes(nodes, tets)) <= 0):
        raise MeshError("fTetWild returned a degenerate tetrahedron")
    if use_cache:
        save_npz(path, compressed=True, nodes=nodes, tets=tets, seconds=seconds)
    return BodyMesh(nodes, tets, edge_length, envelope, seconds)


# -- the P2 problem ---------------------------------------------------------------------------

def p2_weights(bary: np.ndarray) -> np.ndarray:
    """Quadratic shape functions (k, 10) at barycentric points (k, 4): corners L_i (2 L_i - 1),
    then the edges of `sim.models.fem.P2_EDGES`, 4 L_i L_j (the order of `p2_mesh`'s tets)."""
    from sim.models.fem import P2_EDGES

    corners = bary * (2.0 * bary - 1.0)
    edges = 4.0 * bary[:, P2_EDGES[:, 0]] * bary[:, P2_EDGES[:, 1]]
    return np.hstack([corners, edges])


def locate(nodes: np.ndarray, tets: np.ndarray, points: np.ndarray, k: int = 32) -> tuple[np.ndarray, np.ndarray]:
    """Containing (or nearest) tetrahedron of each point and its barycentric coordinates, as
    `sim.volume.embed` does: among the k tetrahedra with the nearest centroids, the one whose
    smallest barycentric coordinate is largest (>= 0: inside)."""
    from scipy.spatial import cKDTree

    from sim.volume import barycentric

    points = np.atleast_2d(np.asarray(points, dtype=np.float64))
    tree = cKDTree(nodes[tets].mean(axis=1))
    kk = min(k, len(tets))
    _, cand = tree.query(points, k=kk)
    cand = np.asarray(cand).reshape(len(points), kk)
    w = barycentric(nodes, tets[cand.ravel()], np.repeat(points, kk, axis=0)).reshape(len(points), kk, 4)
    pick = w.min(axis=2).argmax(axis=1)
    rows = np.arange(len(points))
    return cand[rows, pick], w[rows, pick]


@dataclass
class Problem:
    """One hemisphere at one mesh size: the factorised P2 stiffness and its grasp queries."""

    label: int
    mesh: BodyMesh
    fem: object  # sim.models.fem.LinearFem, order 2, Young's modulus 1 Pa
    tets10: np.ndarray  # (m, 10) node ids of the P2 elements (corners, then `p2_mesh`'s edge nodes)
    fixed_nodes: int
    build_s: float
    factor_s: float = 0.0


def build_problem(scene, label: int, mesh: BodyMesh) -> Problem:
    """P2 linear elasticity (E = 1 Pa, the scene's Poisson ratio) on a body-fitted hemisphere
    mesh, clamped like the scene's FEM; factorised now."""
    from sim.models.fem import LinearFem, p2_mesh

    start = time.perf_counter()
    axis, limit = clamp_limit(scene)
    fixed = mesh.nodes[:, axis] <= limit
    fem = LinearFem(mesh.nodes, mesh.tets, 1.0, scene.spec.material.poisson, fixed, order=2)
    _, tets10, _ = p2_mesh(mesh.nodes, mesh.tets)  # the numbering LinearFem used (deterministic)
    build_s = time.perf_counter() - start
    problem = Problem(label=label, mesh=mesh, fem=fem, tets10=tets10, fixed_nodes=int(fixed.sum()), build_s=build_s)
    _ = fem.factor
    problem.factor_s = fem.timings.factorisation_s
    return problem


def grasp_matrix(problem: Problem, points: np.ndarray, weights: np.ndarray | None = None, interpolation: str = "p2"):
    """W (3, n_free): the weighted mean displacement of `points` (weights sum to 1; default
    equal: the grasp patch's surface vertices, as `FemModel.grasp`), each embedded in its
    containing or nearest tetrahedron. `interpolation`: "p2" (the element's quadratic shape
    functions, mid-edge nodes included) or "corners" (barycentric weights on the corner
    nodes, as `FemModel.grasp` does on order-2 meshes)."""
    import scipy.sparse as sp

    points = np.atleast_2d(points)
    weights = np.full(len(points), 1.0 / len(points)) if weights is None else np.asarray(weights, dtype=np.float64)
    tet, bary = locate(problem.mesh.nodes, problem.mesh.tets, points)
    if interpolation == "p2":
        nodes, shape = problem.tets10[tet], p2_weights(bary)
    elif interpolation == "corners":
        nodes, shape = problem.mesh.tets[tet], bary
    else:
        raise ValueError(f"interpolation: {interpolation!r}; allowed: p2, corners")
    # as `sim.models.fem.constraint_matrix`, vectorised (thousands of quadrature points)
    fem = problem.fem
    col_of = -np.ones(3 * fem.n_all, dtype=np.int64)
    col_of[fem.free] = np.arange(len(fem.free))
    cols = col_of[3 * nodes.ravel()[:, None] + np.arange(3)]  # (k, 3)
    vals = np.repeat((shape * weights[:, None]).ravel()[:, None], 3, axis=1)
    rows = np.broadcast_to(np.arange(3), cols.shape)
    keep = cols >= 0  # fixed nodes do not move
    return sp.csr_matrix((vals[keep], (rows[keep], cols[keep])), shape=(3, len(fem.free)))


def pull_stiffness(problem: Problem, points: np.ndarray, weights: np.ndarray | None = None, interpolation: str = "p2") -> np.ndarray:
    """The condensed stiffness (3, 3) per pascal of Young's modulus: the force holding the
    patch's mean displacement at d is K d (N for E = 1 Pa and d in m)."""
    from sim.models.fem import SingularSystemError

    W = grasp_matrix(problem, points, weights, interpolation)
    if W.nnz == 0:
        raise SingularSystemError("grasp patch lies in clamped elements: it cannot move")
    U = problem.fem.solve_free(np.ascontiguousarray(W.T.toarray()))
    C = W @ U
    return np.linalg.inv(0.5 * (C + C.T))


# -- compressible neo-Hookean on P2 --------------------------------------------------------

@dataclass
class NewtonLog:
    load_steps: int
    iterations: list = field(default_factory=list)  # per load step
    final_residuals: list = field(default_factory=list)
    shifts: int = 0  # Newton iterations whose tangent needed a shift (indefinite)
    converged: bool = True
    min_jacobian: float = 1.0


def p2_neo_hookean_solve(problem: Problem, W, target: np.ndarray, steps: int = 6, tol: float = 1e-6, max_iter: int = 40, on_step=None):
    """Static compressible neo-Hookean solve on the P2 mesh with the grasp (W u = d) held at
    `target` (3,): energy density ``mu/2 (I1 - 3) - mu ln J + lam/2 (ln J)^2`` integrated with
    the 4-point rule at each element's quadrature points (as `sim.models.fem.neo_hookean_solve`
    does on P1 with one point); `steps` equal load steps, each Newton-iterated to a relative
    residual below `tol` with the multiplier condensed (Schur complement); an indefinite tangent
    is factorised shifted (`sim.linalg.shifted_factor`). Returns (u (n_all, 3), force holding the
    patch (3,), NewtonLog). `on_step(step, force)` sees each converged load step."""
    import scipy.sparse as sp

    from sim.linalg import shifted_factor
    from sim.models.fem import element_dofs, p2_gradients

    fem = problem.fem
    lam, mu = fem.lam, fem.mu
    G = p2_gradients(fem.grads)  # (m, q, 10, 3)
    m, nq = G.shape[:2]
    wq = np.abs(fem.volumes) / nq
    dofs = element_dofs(problem.tets10)  # (m, 30)
    rows = np.repeat(dofs, 30, axis=1).ravel()
    cols = np.tile(dofs, (1, 30)).ravel()
    free = fem.free
    n = 3 * fem.n_all
    u = np.zeros(n)
    Wt = np.ascontiguousarray(W.T.toarray())
    lam_mult = np.zeros(3)
    log = NewtonLog(load_steps=steps)
    scale = max(float(np.linalg.norm(target)), 1e-12)
    for step in range(1, steps + 1):
        d = np.asarray(target, dtype=np.float64) * step / steps
        hist: list[float] = []
        for it in range(max_iter):
            ue = u[dofs].reshape(m, 10, 3)
            F = np.eye(3) + np.einsum("mai,mqaj->mqij", ue, G)
            J = np.linalg.det(F)
            log.min_jacobian = min(log.min_jacobian, float(J.min()))
            if np.any(J <= 0):
                log.converged = False
                log.iterations.append(it)
                log.final_residuals.append(hist[-1] if hist else None)
                return u.reshape(-1, 3), lam_mult, log
            Finv = np.linalg.inv(F)
            FinvT = np.swapaxes(Finv, 2, 3)
            lnJ = np.log(J)
            P = mu * (F - FinvT) + (lam * lnJ)[..., None, None] * FinvT
            fe = np.einsum("m,mqij,mqaj->mai", wq, P, G)
            f_int = np.bincount(dofs.ravel(), weights=fe.ravel(), minlength=n)
            r = f_int[free] - Wt @ lam_mult
            gap = W @ u[free] - d
            res = float(np.linalg.norm(r)) / max(float(np.linalg.norm(f_int[free])), float(np.linalg.norm(Wt @ lam_mult)), 1e-30)
            hist.append(max(res, float(np.linalg.norm(gap)) / scale))
            if it > 0 and hist[-1] < tol:
                break
            # tangent: A_iJkL = mu d_ik d_JL + (mu - lam lnJ) Finv_Li Finv_Jk + lam Finv_Ji Finv_Lk
            X = np.einsum("mqLi,mqaL->mqai", Finv, G).reshape(m, nq, 30)  # (g_a . Finv)_i
            c1 = (mu - lam * lnJ) * wq[:, None]  # (m, q)
            K = (lam * np.matmul(np.swapaxes(X * wq[:, None, None], 1, 2), X)).reshape(m, 10, 3, 10, 3)
            K += np.matmul(np.swapaxes(X * c1[..., None], 1, 2), X).reshape(m, 10, 3, 10, 3).transpose(0, 1, 4, 3, 2)
            gg = np.einsum("mqaj,mqbj->mab", G * wq[:, None, None, None], G)
            K += mu * gg[:, :, None, :, None] * np.eye(3)[None, None, :, None, :]
            Kt = sp.coo_matrix((K.ravel(), (rows, cols)), shape=(n, n)).tocsr()
            Kff = Kt[free][:, free]
            del K, Kt
            factor = shifted_factor(0.5 * (Kff + Kff.T))
            log.shifts += int(factor.shift > 0)
            Kr = factor.solve(-r)
            KW = factor.solve(Wt)
            dl = np.linalg.solve(W @ KW, -gap - W @ Kr)
            u[free] += Kr + KW @ dl
            lam_mult = lam_mult + dl
            del factor
        else:
            log.converged = False
        log.iterations.append(len(hist))
        log.final_residuals.append(hist[-1])
        if not log.converged:
            return u.reshape(-1, 3), lam_mult, log
        if on_step is not None:
            on_step(step, lam_mult.copy())
    return u.reshape(-1, 3), lam_mult, log


def neo_hookean_pull(problem: Problem, points, weights, direction, xs, min_steps: int = 6, tol: float = 1e-6) -> dict:
    """Forces (per pascal, (len(xs), 3)) holding the patch at each x in `xs` (equal steps
    x_max k / n) along `direction`: one solve, at least `min_steps` load steps in all."""
    xs = np.asarray(xs, dtype=np.float64)
    W = grasp_matrix(problem, points, weights)
    sub = max(1, math.ceil(min_steps / len(xs)))
    forces = np.full((len(xs), 3), np.nan)

    def on_step(step, lam_mult):
        if step % sub == 0:
            forces[step // sub - 1] = lam_mult

    t0 = time.perf_counter()
    _, _, log = p2_neo_hookean_solve(problem, W, np.asarray(direction) * xs[-1], steps=sub * len(xs), tol=tol, on_step=on_step)
    return {"force_per_pa": forces, "converged": log.converged, "iterations": log.iterations, "shifts": log.shifts,
            "min_jacobian": log.min_jacobian, "seconds": time.perf_counter() - t0}


NONLINEAR_CACHE_VERSION = 1


def _nonlinear_path(mesh_path: Path, scene, radius: float, pull, xs) -> Path:
    axis, limit = clamp_limit(scene)
    key = json.dumps([NONLINEAR_CACHE_VERSION, mesh_path.stem, scene.spec.material.poisson, axis, round(limit, 9), radius,
                      pull.vertex, [round(c, 12) for c in pull.direction], [round(float(x), 9) for x in xs]])
    return _cache_root() / f"neohookean-{hashlib.sha256(key.encode()).hexdigest()[:20]}.npz"


def _nonlinear_task(args) -> dict:
    """One neo-Hookean pull on one mesh (a worker process): cached on disk per pull."""
    scene_path, label, size_mm, pull, xs, radius = args
    from sim.reference import scene_with

    scene = scene_with(scene_path)
    verts, tris, _ = hemisphere_surface(scene.mesh, label)
    edge = size_mm * 1e-3
    path = _nonlinear_path(_mesh_path(verts, tris, edge, ENVELOPE_FRACTION * edge), scene, radius, pull, xs)
    if path.exists():
        with np.load(path) as z:
            return {k: (z[k] if z[k].ndim else z[k].item()) for k in z.files} | {"cached": True}
    problem = build_problem(scene, label, mesh_hemisphere(verts, tris, edge))
    r = neo_hookean_pull(problem, *patch_area_points(scene.mesh, pull.vertex, radius), np.asarray(pull.direction), xs)
    out = {"force_per_pa": r["force_per_pa"], "converged": bool(r["converged"]), "iterations": int(sum(r["iterations"])),
           "shifts": int(r["shifts"]), "min_jacobian": float(r["min_jacobian"]), "seconds": float(r["seconds"])}
    if r["converged"]:
        save_npz(path, **out)
    return out | {"cached": False}


def pull_references(scene_path, pulls, xs, sizes_mm=DEFAULT_SIZES_MM, nonlinear_mm: float | None = None,
                    threads: int = 1, jobs: int | None = None, progress=None) -> dict:
    """The reference of every pull in `pulls` (any, not only the bench's): per pull
    ``{"h_m": [coarse..fine], "linear_per_pa": (sizes, n, 3), "nonlinear_per_pa": (n, 3) or None,
    "nonlinear": solve info}``, plus ``"meshes"``.

    Linear P2 on every size (one condensed 3 x 3 stiffness per pull and mesh); with
    `nonlinear_mm`, the compressible neo-Hookean pull on that mesh too (worker processes, cached
    per pull: about 1.7 minutes per pull on the 8 mm mesh on this 2-core machine)."""
    from sim.reference import scene_with

    scene = scene_with(scene_path)
    mesh = scene.mesh
    xs = np.asarray(xs, dtype=np.float64)
    radius = grasp_radius(scene)
    sizes = sorted((float(x) for x in sizes_mm), reverse=True)
    labels = sorted({p.hemisphere for p in pulls})
    patches = {p.name: patch_area_points(mesh, p.vertex, radius) for p in pulls}
    _premesh(mesh, labels, sorted(set(sizes) | ({float(nonlinear_mm)} if nonlinear_mm else set())), threads, jobs)
    out = {p.name: {"h_m": [], "linear_per_pa": [], "nonlinear_per_pa": None, "nonlinear": None} for p in pulls}
    n_steps = len(labels) * len(sizes) + (len(pulls) if nonlinear_mm else 0)
    step = 0
    if nonlinear_mm:
        tasks = [(str(scene_path), p.hemisphere, float(nonlinear_mm), p, xs, radius) for p in pulls]
        jobs = max(1, min(jobs or os.cpu_count() or 1, len(tasks)))
        if jobs == 1:
            results = []
            for t in tasks:
                results.append(_nonlinear_task(t))
                step += 1
                if progress is not None:
                    progress(step, n_steps)
        else:
            import multiprocessing
            from concurrent.futures import ProcessPoolExecutor

            results = []
            with ProcessPoolExecutor(max_workers=jobs, mp_context=multiprocessing.get_context("spawn")) as pool:
                for r in pool.map(_nonlinear_task, tasks):
                    results.append(r)
                    step += 1
                    if progress is not None:
                        progress(step, n_steps)
        for p, r in zip(pulls, results):
            out[p.name]["nonlinear_per_pa"] = np.asarray(r.pop("force_per_pa"))
            out[p.name]["nonlinear"] = r | {"mesh_mm": float(nonlinear_mm)}
    meshes = []
    for label in labels:
        verts, tris, _ = hemisphere_surface(mesh, label)
        for size in sizes:
            bm = mesh_hemisphere(verts, tris, size * 1e-3, threads=threads)
            prob = build_problem(scene, label, bm)
            for p in pulls:
                if p.hemisphere == label:
                    K = pull_stiffness(prob, *patches[p.name])
                    out[p.name]["linear_per_pa"].append(np.outer(xs, K @ np.asarray(p.direction)))
                    out[p.name]["h_m"].append(bm.h)
            meshes.append(bm.describe() | {"hemisphere": int(label), "free_dofs": int(len(prob.fem.free)),
                                           "assembly_s": prob.build_s, "factor_s": prob.factor_s})
            del prob
            step += 1
            if progress is not None:
                progress(step, n_steps)
    for r in out.values():
        r["linear_per_pa"] = np.stack(r["linear_per_pa"])
    return {"pulls": out, "meshes": meshes, "grasp_radius_m": radius, "sizes_mm": sizes,
            "patch_points": {k: int(len(v[0])) for k, v in patches.items()}}


def combined_sample(linear_forces, hs, nonlinear_force=None, nonlinear_index: int = 0) -> dict:
    """The reference at one sample: Richardson on the linear magnitudes (`converge`); with a
    neo-Hookean force on mesh `nonlinear_index` (into `linear_forces`, coarse to fine), the
    neo-Hookean value corrected by the linear sequence's discretisation error:
    F = F_nh(mesh) x F_lin,ext / F_lin(mesh) (a correction factor: the mesh error is taken to
    be the same fraction for both formulations). Returns the force vector, its magnitude, the
    GCI half-band (N, relative to the magnitude) and the convergence record."""
    mags = [float(np.linalg.norm(f)) for f in linear_forces]
    conv = converge(mags, hs)
    finest = mags[int(np.argmin(hs))]
    if nonlinear_force is None:
        vec = np.asarray(linear_forces[int(np.argmin(hs))], dtype=np.float64) * conv["f_ext"] / finest
        formulation = "linear"
    else:
        nl = np.asarray(nonlinear_force, dtype=np.float64)
        vec = nl * conv["f_ext"] / mags[nonlinear_index]
        formulation = "neo-hookean"
    mag = float(np.linalg.norm(vec))
    return {"force": vec, "force_n": mag, "band_rel": conv["gci"], "band_half_n": conv["gci"] * mag, "status": conv["status"],
            "order": conv["p"], "extrapolated": conv["extrapolated"], "linear_forces_n": mags, "formulation": formulation}


# -- Richardson extrapolation and the grid convergence index -------------------------------

def _observed_order(e21: float, e32: float, r21: float, r32: float) -> float:
    """Celik et al. (2008) eq. 3: p from  p ln r21 = ln|e32/e21| + ln((r21^p - s)/(r32^p - s)),
    s = sign(e32/e21); solved by bisection on [1e-3, 30] (reduces to ln(e32/e21)/ln r for r21 = r32)."""
    s = math.copysign(1.0, e32 / e21)
    ratio = math.log(abs(e32 / e21))

    def g(p):
        a, b = r21**p - s, r32**p - s
        if a <= 0 or b <= 0:
            return math.nan
        return p * math.log(r21) - ratio - math.log(a / b)

    if abs(r21 - r32) < 1e-12 * r21:
        return ratio / math.log(r21)
    lo, hi = 1e-3, 30.0
    glo, ghi = g(lo), g(hi)
    if not (math.isfinite(glo) and math.isfinite(ghi)) or glo * ghi > 0:
        # no bracket: the fixed-point iteration of Celik's procedure
        p = ratio / math.log(r21)
        for _ in range(200):
            a, b = r21**p - s, r32**p - s
            if a <= 0 or b <= 0:
                return math.nan
            p_new = abs(ratio + math.log(a / b)) / math.log(r21)
            if abs(p_new - p) < 1e-14:
                return p_new
            p = p_new
        return p
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        gm = g(mid)
        if gm == 0 or hi - lo < 1e-15:
            return mid
        if gm * glo > 0:
            lo, glo = mid, gm
        else:
            hi = mid
    return 0.5 * (lo + hi)


def richardson(f1: float, f2: float, f3: float, h1: float, h2: float, h3: float, fs: float = GCI_FS3,
               order_range: tuple[float, float] = ORDER_RANGE, assumed_order: float = ASSUMED_ORDER) -> dict:
    """Observed order, Richardson-extrapolated value and Roache's GCI from three meshes,
    1 finest (h1 < h2 < h3), any ratios r21 = h2/h1, r32 = h3/h2.

    - Monotone convergence (0 < R < 1, R = (f2 - f1)/(f3 - f2)) with an observed order p in
      `order_range`: ``f_ext = f1 + (f1 - f2)/(r21^p - 1)``, ``GCI = fs |(f1 - f2)/f1| /
      (r21^p - 1)`` (fs = 1.25), band ``f1 (1 +- GCI)``.
    - Otherwise (oscillatory R < 0, diverging R > 1, p outside the range, or f1 = f2 = f3
      within rounding): no extrapolation (f_ext = f1) and a conservative band: the larger of
      the GCI with fs = 3 and the `assumed_order`, and the largest spread |f_i - f1| / |f1|.
    Returns a dict: p (observed, NaN when undefined), p_used, f_ext, gci (relative), band
    (lo, hi), status ("monotone", "oscillatory", "diverging", "order out of range",
    "converged"), r21, r32, R, fs, extrapolated (bool).
    """
    if not (h1 < h2 < h3):
        raise ValueError(f"richardson: need h1 < h2 < h3 (finest first), got {h1:g}, {h2:g}, {h3:g}")
    r21, r32 = h2 / h1, h3 / h2
    e21, e32 = f2 - f1, f3 - f2
    scale = max(abs(f1), abs(f2), abs(f3), 1e-300)
    out = {"r21": r21, "r32": r32, "f1": f1, "f2": f2, "f3": f3}
    if abs(e21) <= 1e-13 * scale and abs(e32) <= 1e-13 * scale:
        return out | {"status": "converged", "R": math.nan, "p": math.nan, "p_used": math.nan, "fs": fs, "f_ext": f1,
                      "gci": 0.0, "band": (f1, f1), "extrapolated": False}
    R = e21 / e32 if e32 != 0 else math.inf
    p = math.nan
    if 0 < R < 1:
        p = _observed_order(e21, e32, r21, r32)
        status = "monotone" if order_range[0] <= p <= order_range[1] else "order out of range"
    elif R < 0:
        status = "oscillatory"
    else:
        status = "diverging"
    if status == "monotone":
        f_ext = f1 + (f1 - f2) / (r21**p - 1.0)
        gci = fs * abs(e21 / f1) / (r21**p - 1.0)
        out |= {"p_used": p, "fs": fs, "extrapolated": True}
    else:
        f_ext = f1
        gci = max(GCI_FS_FALLBACK * abs(e21 / f1) / (r21**assumed_order - 1.0),
                  max(abs(f2 - f1), abs(f3 - f1)) / abs(f1))
        out |= {"p_used": assumed_order, "fs": GCI_FS_FALLBACK, "extrapolated": False}
    return out | {"status": status, "R": R, "p": p, "f_ext": f_ext, "gci": gci, "band": (f1 - gci * abs(f1), f1 + gci * abs(f1))}


def richardson2(f1: float, f2: float, h1: float, h2: float, order: float = ASSUMED_ORDER, fs: float = GCI_FS_FALLBACK) -> dict:
    """Two meshes (1 finest): no observed order; Richardson with the assumed `order` and
    Roache's two-mesh factor of safety fs = 3."""
    if not h1 < h2:
        raise ValueError(f"richardson2: need h1 < h2 (finest first), got {h1:g}, {h2:g}")
    r21 = h2 / h1
    d = r21**order - 1.0
    f_ext = f1 + (f1 - f2) / d
    gci = fs * abs((f2 - f1) / f1) / d
    return {"r21": r21, "r32": math.nan, "f1": f1, "f2": f2, "f3": math.nan, "status": "two meshes", "R": math.nan,
            "p": math.nan, "p_used": order, "fs": fs, "f_ext": f_ext, "gci": gci,
            "band": (f1 - gci * abs(f1), f1 + gci * abs(f1)), "extrapolated": True}


def converge(forces, hs) -> dict:
    """`richardson` (three meshes) or `richardson2` (two) on forces ordered like hs (any order)."""
    order = np.argsort(hs)
    f = [float(forces[i]) for i in order]
    h = [float(hs[i]) for i in order]
    if len(f) == 3:
        return richardson(*f, *h)
    if len(f) == 2:
        return richardson2(*f, *h)
    raise ValueError(f"converge: need two or three meshes, got {len(f)}")


# -- the reference ------------------------------------------------------------------------

@dataclass(frozen=True)
class ReferenceConfig:
    scene: Path = DEFAULT_SCENE
    sizes_mm: tuple[float, ...] = DEFAULT_SIZES_MM  # fTetWild target edge lengths
    young: float | None = None  # Pa; None: the scene's (forces are proportional to it)
    max_pull: float = 0.024  # m, the accuracy bench's (analysis.accuracy.AccuracyConfig)
    samples: int = 6
    pulls: tuple[str, ...] | None = None  # pull names to run; None: all of the bench's
    interpolation: str = "p2"
    formulation: str = "linear"  # or "neo-hookean" (slow: a Newton solve per pull and size)
    functional: str = "area"  # the grasp: mean displacement of the surface area ("area") or of its vertices ("vertices")
    threads: int = 1  # fTetWild's threads per mesh (more are no faster on this surface: measured)
    jobs: int | None = None  # meshes made at once in worker processes (default: every core)
    quick: bool = False
    extra: dict = field(default_factory=dict)


def quick_config(**kw) -> ReferenceConfig:
    """Two coarse meshes (20 and 16 mm), the left hand's two pulls (one hemisphere), 2 samples."""
    return ReferenceConfig(**({"sizes_mm": QUICK_SIZES_MM, "samples": 2, "pulls": ("left-lateral", "left-anterior"), "quick": True} | kw))


def jnd_verdict(force: float, band_half: float) -> dict:
    """Is the band narrower than the force JND? Relative: half-band / force below the JND
    fraction (10% at or above 0.5 N, 25% below, `sim.calibrate.jnd`); absolute: half-band below
    0.05 N (10% of 0.5 N)."""
    from sim.calibrate import jnd

    rel = band_half / force if force > 0 else math.inf
    frac = float(jnd(np.array(force)))
    return {"band_rel": rel, "jnd_fraction": frac, "within_jnd_rel": bool(rel < frac), "within_jnd_abs": bool(band_half < 0.05)}


def run_reference(cfg: ReferenceConfig, progress=None) -> dict:
    """Mesh, solve and extrapolate every pull; returns {"samples", "pulls", "meshes", "meta"}."""
    from analysis.accuracy import AccuracyConfig, sample_displacements
    from sim.reference import make_pulls, scene_with

    t_start = time.perf_counter()
    scene = scene_with(cfg.scene)
    young = float(cfg.young if cfg.young is not None else scene.spec.material.young)
    pulls = make_pulls(scene)
    if cfg.pulls is not None:
        unknown = set(cfg.pulls) - {p.name for p in pulls}
        if unknown:
            from sim.errors import ParameterError

            raise ParameterError(f"pulls: {', '.join(sorted(unknown))} not among {', '.join(p.name for p in pulls)}")
        pulls = [p for p in pulls if p.name in cfg.pulls]
    xs = sample_displacements(AccuracyConfig(max_pull=cfg.max_pull, samples=cfg.samples))
    radius = grasp_radius(scene)
    mesh = scene.mesh
    sizes = sorted((float(s) for s in cfg.sizes_mm), reverse=True)  # coarse to fine
    labels = sorted({p.hemisphere for p in pulls})
    # the grasp functional: the mean displacement of the surface within the grasp radius
    # ("area", converges) or of the surface vertices there ("vertices", FemModel.grasp's)
    patches = {}
    for p in pulls:
        if cfg.functional == "area":
            patches[p.name] = patch_area_points(mesh, p.vertex, radius)
        elif cfg.functional == "vertices":
            ids = patch_vertices(mesh, p.vertex, radius)
            patches[p.name] = (mesh.vertices[ids], None)
        else:
            from sim.errors import ParameterError

            raise ParameterError(f"functional: {cfg.functional!r}; allowed: area, vertices")
    if cfg.formulation not in FORMULATIONS:
        from sim.errors import ParameterError

        raise ParameterError(f"formulation: {cfg.formulation!r}; allowed: {', '.join(FORMULATIONS)}")
    nonlinear = cfg.formulation == "neo-hookean"
    # per pull and size: force per pascal at each sampled displacement, (n_xs, 3)
    F: dict[str, list[np.ndarray]] = {p.name: [] for p in pulls}
    solves: dict[str, list[dict]] = {p.name: [] for p in pulls}
    made = _premesh(mesh, labels, sizes, cfg.threads, cfg.jobs)
    meshes = []
    n_steps, step = len(labels) * len(sizes), 0
    for label in labels:
        verts, tris, _ = hemisphere_surface(mesh, label)
        surf_vol = enclosed_volume(verts, tris)
        for size in sizes:
            bm = mesh_hemisphere(verts, tris, size * 1e-3, threads=cfg.threads)
            prob = build_problem(scene, label, bm)
            t0 = time.perf_counter()
            for p in pulls:
                if p.hemisphere != label:
                    continue
                direction = np.asarray(p.direction)
                if nonlinear:
                    r = neo_hookean_pull(prob, *patches[p.name], direction, xs)
                    F[p.name].append(r["force_per_pa"])
                    solves[p.name].append({k: r[k] for k in ("converged", "iterations", "shifts", "min_jacobian", "seconds")})
                else:
                    K = pull_stiffness(prob, *patches[p.name], interpolation=cfg.interpolation)
                    F[p.name].append(np.outer(xs, K @ direction))  # linear: proportional to the displacement
            solve_s = time.perf_counter() - t0
            meshes.append(bm.describe() | {"cached": bm.cached and (label, size) not in made, "hemisphere": int(label), "surface_volume_cm3": surf_vol * 1e6,
                                           "volume_error": bm.volume / surf_vol - 1.0,
                                           "p2_nodes": int(prob.fem.n_all), "free_dofs": int(len(prob.fem.free)),
                                           "fixed_corner_nodes": prob.fixed_nodes, "assembly_s": prob.build_s,
                                           "factor_s": prob.factor_s, "solve_s": solve_s})
            del prob
            step += 1
            if progress is not None:
                progress(step, n_steps)
    h_of = {(m["hemisphere"], m["target_edge_mm"]): m["h_mm"] * 1e-3 for m in meshes}
    samples, pull_rows = [], []
    for p in pulls:
        hs = [h_of[(p.hemisphere, s)] for s in sizes]
        per_pa = np.stack(F[p.name])  # (sizes, xs, 3)
        pull_rows.append({"pull": p.name, "hemisphere": p.hemisphere, "grasp_vertex": p.vertex, "patch_points": int(len(patches[p.name][0])),
                          "direction": list(p.direction), "h_mm": [h * 1e3 for h in hs], "force_per_pa": per_pa.tolist(),
                          "solves": solves[p.name]})
        for k, x in enumerate(xs):
            f = [float(np.linalg.norm(per_pa[i, k])) * young for i in range(len(sizes))]
            if not all(math.isfinite(v) for v in f):  # a nonlinear solve that stopped early
                samples.append({"pull": p.name, "displacement_mm": float(x) * 1e3, "forces_n": f, "h_mm": [h * 1e3 for h in hs],
                                "target_edge_mm": sizes, "status": "not solved", "order": math.nan, "order_used": math.nan, "fs": math.nan,
                                "extrapolated": False, "force_ext_n": math.nan, "gci": math.nan, "band_n": [math.nan, math.nan],
                                "band_half_n": math.nan, "band_rel": math.nan, "jnd_fraction": math.nan, "within_jnd_rel": False,
                                "within_jnd_abs": False})
                continue
            conv = converge(f, hs)
            f_fine = f[-1]
            half = conv["gci"] * f_fine
            samples.append({"pull": p.name, "displacement_mm": float(x) * 1e3, "forces_n": f, "h_mm": [h * 1e3 for h in hs],
                            "target_edge_mm": sizes, "order": conv["p"], "order_used": conv["p_used"], "status": conv["status"],
                            "R": conv["R"], "fs": conv["fs"], "extrapolated": conv["extrapolated"], "force_ext_n": conv["f_ext"],
                            "gci": conv["gci"], "band_n": [f_fine - half, f_fine + half], "band_half_n": half}
                           | jnd_verdict(f_fine, half))
    meta = {"scene": str(cfg.scene), "young_pa": young, "scene_young_pa": scene.spec.material.young, "poisson": scene.spec.material.poisson,
            "element": "P2 (10-node tetrahedra)",
            "formulation": "compressible neo-Hookean" if nonlinear else "small-strain linear elasticity",
            "mesher": "fTetWild (pytetwild)", "envelope_fraction": ENVELOPE_FRACTION, "sizes_mm": sizes,
            "grasp_radius_m": radius, "interpolation": cfg.interpolation, "functional": cfg.functional,
            "clamp": dict(zip(("axis", "height_m"), clamp_limit(scene))),
            "max_pull_m": cfg.max_pull, "samples_per_pull": cfg.samples, "quick": cfg.quick,
            "gci_fs": GCI_FS3 if len(sizes) == 3 else GCI_FS_FALLBACK, "seconds": time.perf_counter() - t_start}
    return {"samples": samples, "pulls": pull_rows, "meshes": meshes, "meta": meta}


def _mesh_task(args) -> None:
    verts, tris, size, threads = args
    mesh_hemisphere(verts, tris, size * 1e-3, threads=threads)


def _premesh(mesh, labels, sizes, threads: int, jobs: int | None) -> set:
    """Make the meshes missing from the cache, several at once: fTetWild uses about one core
    whatever its thread count, so two hemispheres mesh in the time of one on 2 cores.
    Returns the (label, size) pairs it made."""
    jobs = jobs or os.cpu_count() or 1
    tasks, made = [], set()
    for label in labels:
        verts, tris, _ = hemisphere_surface(mesh, label)
        for s in sizes:
            if not _mesh_path(verts, tris, s * 1e-3, ENVELOPE_FRACTION * s * 1e-3).exists():
                tasks.append((verts, tris, s, threads))
                made.add((label, s))
    tasks.sort(key=lambda t: t[2])  # the finest (slowest) first
    if jobs <= 1 or len(tasks) <= 1:
        for t in tasks:
            _mesh_task(t)
        return made
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    with ProcessPoolExecutor(max_workers=min(jobs, len(tasks)), mp_context=multiprocessing.get_context("spawn")) as pool:
        list(pool.map(_mesh_task, tasks))
    return made


def markdown(result: dict) -> str:
    """The reference table as Markdown."""
    m = result["meta"]
    sizes = m["sizes_mm"]
    lines = [f"P2 {m['formulation']} on fTetWild meshes (target edges {', '.join(f'{s:g}' for s in sizes)} mm), "
             f"E = {m['young_pa'] / 1e3:g} kPa, nu = {m['poisson']:g}; GCI factor of safety {m['gci_fs']:g}"
             + (" (quick)" if m["quick"] else "") + ".", "",
             "| pull | d (mm) | " + " | ".join(f"F @ {s:g} mm (N)" for s in sizes) + " | order | status | extrapolated (N) | band (N) | band % | < JND (rel) | < 0.05 N |",
             "|---|---|" + "---|" * len(sizes) + "---|---|---|---|---|---|---|"]
    for s in result["samples"]:
        lines.append(f"| {s['pull']} | {s['displacement_mm']:g} | " + " | ".join(f"{f:.4f}" for f in s["forces_n"])
                     + f" | {_fmt(s['order'], '.2f')} | {s['status']} | {_fmt(s['force_ext_n'], '.4f')} | {s['band_n'][0]:.4f}..{s['band_n'][1]:.4f} | "
                     f"{s['gci']:.1%} | {'yes' if s['within_jnd_rel'] else 'no'} | {'yes' if s['within_jnd_abs'] else 'no'} |")
    lines += ["", "| hemisphere | target edge (mm) | nodes | tets | h (mm) | P2 dofs (free) | volume error | mesh s | factor s |",
              "|---|---|---|---|---|---|---|---|---|"]
    for g in result["meshes"]:
        lines.append(f"| {g['hemisphere']} | {g['target_edge_mm']:g} | {g['nodes']} | {g['tets']} | {g['h_mm']:.2f} | {g['free_dofs']} | "
                     f"{g['volume_error']:+.2%} | {g['mesh_s']:.1f}{' (cached)' if g['cached'] else ''} | {g['factor_s']:.1f} |")
    return "\n".join(lines) + "\n"


def _fmt(x, spec: str) -> str:
    return "-" if x is None or (isinstance(x, float) and not math.isfinite(x)) else format(x, spec)


def write_outputs(result: dict, out_dir) -> list[Path]:
    """reference.json and reference.md."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    files = [out / "reference.json", out / "reference.md"]
    files[0].write_text(json.dumps(jsonable(result), indent=2))
    files[1].write_text(markdown(result))
    return files

