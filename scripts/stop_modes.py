"""Why a reference solve stops: the lowest eigenpairs of the constrained tangent at its last
converged state, on two meshes (issue 55; the numbers go to docs/reference.md).

For each pull whose solve stopped on the coarsest shipped mesh (data/reference_pulls.json), the
pull is followed again on the 8 mm and the 6 mm mesh to where the 8 mm solve stopped, and at
that state (and at rest) the lowest eigenvalues of the tangent K on the displacements that keep
the grasp where it is (W u = 0) are found by shift-invert Lanczos on the saddle-point matrix
[[K, W^T], [W, 0]]. A loss of stability of the tissue (a fold or crease, a structural mode) shows
on both meshes at about the same displacement, with the same mode shape: the eigenvalue over its
value at rest near 0 on both, and the modes alike where they are large (MAC, the modal assurance
criterion, of the two meshes' modes sampled at the same surface points near 1). A mode of the
discretisation does neither. The mode's peak is also placed against the hemisphere's convex hull
(its depth below the hull: a fold of the cortex lies centimetres below it, the crown of a gyrus
at about 0).

    .venv/bin/python scripts/stop_modes.py [--pulls extra1-anterior,...] [--json FILE]
"""

from __future__ import annotations

import argparse
import json
import math
import time

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from scipy.spatial import ConvexHull

from analysis.verification.tissue_pulls import SHIPPED_PULLS_INFO, build_problem, grasp_matrix
from sim.geometry.patch import patch_area_points
from sim.geometry.tetmesh import hemisphere_surface, mesh_hemisphere
from sim.geometry.volume import locate
from sim.models.fem import FiniteStrain, hold
from sim.pulls import make_pulls, scene_with, test_pulls
from sim.scene import DEFAULT_SCENE, grasp_radius

SIZES_MM = (8.0, 6.0)
RECORD_MAX = 0.012  # m: the reference's longest pull
SAMPLE_RADIUS = 0.030  # m: the surface points around the grasp where two meshes' modes are compared


def lowest_modes(K: sp.csr_matrix, W: sp.csr_matrix, k: int = 3, sigma: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The `k` eigenvalues of K nearest `sigma` (default: just below the smallest diagonal's
    scale, so the lowest) on the subspace W u = 0, and their modes (n, k)."""
    n, m = K.shape[0], W.shape[0]
    sigma = -1e-6 * float(np.abs(K.diagonal()).mean()) if sigma is None else sigma
    A = sp.bmat([[K - sigma * sp.identity(n, format="csr"), W.T], [W, None]], format="csc")
    lu = spla.splu(A)

    def op(x):
        return lu.solve(np.concatenate([x, np.zeros(m)]))[:n]

    vals, vecs = spla.eigsh(spla.LinearOperator((n, n), matvec=op, dtype=np.float64), k=k, which="LM", tol=1e-8)
    lam = sigma + 1.0 / vals
    order = np.argsort(lam)
    return lam[order], vecs[:, order]


def positive_definite(K: sp.csr_matrix, W: sp.csr_matrix) -> bool:
    """Is K positive definite on W u = 0? CHOLMOD's L L^T of K + c W^T W (c large: the
    constraint's directions pushed far up) succeeds exactly then."""
    import sksparse.cholmod as cholmod

    WtW = (W.T @ W).tocsc()
    c = 1e6 * float(np.abs(K.diagonal()).max()) / max(float(WtW.diagonal().max()), 1e-300)
    try:
        cholmod.cholesky((K + c * WtW).tocsc(), mode="supernodal")
    except cholmod.CholmodNotPositiveDefiniteError:
        return False
    return True


def point_matrix(space, nodes, tets, points: np.ndarray) -> sp.csr_matrix:
    """P (3 M, n_free): the displacement at each point, interpolated with its element's shape functions."""
    tet, bary = locate(nodes, tets, points)
    shape = space.element.shape(np.atleast_2d(bary))  # (M, nodes per element)
    el = space.elements[tet]
    col_of = -np.ones(3 * space.n_all, dtype=np.int64)
    col_of[space.free] = np.arange(len(space.free))
    rows, cols, vals = [], [], []
    for i in range(3):
        r = np.repeat(3 * np.arange(len(points)) + i, el.shape[1])
        c = col_of[3 * el.ravel() + i]
        keep = c >= 0
        rows.append(r[keep])
        cols.append(c[keep])
        vals.append(shape.ravel()[keep])
    return sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(3 * len(points), len(space.free)))


def mac(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.dot(a, b) ** 2 / (np.dot(a, a) * np.dot(b, b)))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pulls", default="", help="comma-separated pull names (default: every pull whose 8 mm solve stopped)")
    ap.add_argument("--json", default="", help="write the results here too")
    args = ap.parse_args()
    scene = scene_with(DEFAULT_SCENE)
    law = scene.spec.material.law
    unit = law.scaled(1.0 / law.shear_modulus)
    radius = grasp_radius(scene)
    info = json.loads(SHIPPED_PULLS_INFO.read_text())
    stopped = {e["pull"]: e for e in info["entries"] if e.get("shape", 0) == 0 and e["size_mm"] == SIZES_MM[0] and not e["converged"]}
    names = [n for n in args.pulls.split(",") if n] or sorted(stopped)
    pulls = {p.name: p for p in make_pulls(scene) + test_pulls(scene)}
    out = []
    for name in names:
        p = pulls[name]
        # the coarsest mesh's own stop, found again here: the first mesh below follows as far as it goes
        d_stop = RECORD_MAX
        verts, tris, _ = hemisphere_surface(scene.mesh, p.hemisphere)
        hull = ConvexHull(verts)
        near = verts[np.linalg.norm(verts - np.asarray(p.point), axis=1) <= SAMPLE_RADIUS]
        row = {"pull": name, "meshes": []}
        modes = []
        for size in SIZES_MM:
            t0 = time.perf_counter()
            body = mesh_hemisphere(verts, tris, size * 1e-3)
            problem = build_problem(scene, p.hemisphere, body)
            system = FiniteStrain(problem.space, unit)
            W = grasp_matrix(problem, *patch_area_points(scene.mesh, p.vertex, radius))
            res = hold(system, W, np.asarray(p.direction) * d_stop, fractions=(1.0,), first_step=0.05)
            d_at = res.fraction_done * d_stop
            if size == SIZES_MM[0]:
                d_stop = d_at  # the finer mesh is followed to the coarsest one's last converged state
            lam0, _ = lowest_modes(system.evaluate(np.zeros(3 * problem.space.n_all))["K"], W)
            K = system.evaluate(res.u)["K"]
            pd = positive_definite(K, W)
            # positive definite: the lowest eigenvalues; if not, those nearest a shift far below 0 (the most negative)
            lam, vec = lowest_modes(K, W) if pd else lowest_modes(K, W, sigma=-1e3 * abs(float(lam0[0])))
            P = point_matrix(problem.space, body.nodes, body.tets, near)
            shape = P @ vec[:, 0]
            modes.append(shape)
            full = problem.space.from_free(vec[:, 0], corners=True)
            peak = body.nodes[int(np.argmax(np.linalg.norm(full, axis=1)))]
            depth = float(-np.max(hull.equations[:, :3] @ peak + hull.equations[:, 3]))  # distance inside the hull
            row["meshes"].append({"size_mm": size, "reached_mm": d_at * 1e3, "converged": bool(res.report.converged), "reason": res.report.reason,
                                  "shifts": int(res.report.shifts), "positive_definite": pd, "min_jacobian": float(res.report.min_jacobian),
                                  "lowest_at_rest": lam0.tolist(), "lowest": lam.tolist(),
                                  "ratio_to_rest": float(lam[0] / lam0[0]), "peak_m": peak.tolist(),
                                  "peak_from_grasp_mm": float(np.linalg.norm(peak - np.asarray(p.point)) * 1e3),
                                  "peak_depth_below_hull_mm": depth * 1e3, "seconds": time.perf_counter() - t0})
            print(json.dumps(row["meshes"][-1] | {"pull": name}), flush=True)
        row["stop_mm"] = d_stop * 1e3
        row["mac_lowest"] = mac(modes[0], modes[1]) if len(modes) == 2 else math.nan
        out.append(row)
        print(f"{name}: stop {d_stop * 1e3:.1f} mm; lowest/rest " + ", ".join(f"{m['size_mm']:g} mm {m['ratio_to_rest']:.3g}" for m in row["meshes"])
              + f"; MAC {row['mac_lowest']:.2f}", flush=True)
    if args.json:
        with open(args.json, "w") as f:
            json.dump(out, f, indent=1)


if __name__ == "__main__":
    main()
