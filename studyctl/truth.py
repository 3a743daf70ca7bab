"""The truth a synthetic participant perceives: the body-fitted P2 reference's grasp stiffness.

The observer (studyctl/observer.py) judges every condition's rendered force against the force
the converged reference gives for the same hand motion and grasp: linear elasticity on
quadratic tetrahedra of body-fitted meshes of 8, 5.5 and 4 mm (fTetWild), Richardson-
extrapolated (analysis/reference.py, docs/reference.md). It is none of the study's models and
nothing is calibrated against it (the located plate-spring's field is solved on the 8 mm mesh
alone, and is not a study condition).

Only grasp places are needed, so the truth is a table: the condensed stiffness per pascal
(3 x 3) at the surface vertices within `TRUTH_RADIUS` of the scene's hands, shipped in
`data/observer_truth.npz` (fTetWild is not deterministic: a rebuilt table differs by up to
about 1.5%, which is why it is shipped rather than rebuilt on each machine). Another scene or
another grasp place needs `studyctl calibrate truth` (about 3.5 minutes on 2 cores), which
writes a table to the cache folder that `load_truth` reads next to the shipped one.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from brainsim_assets import path as _asset
from studyctl.errors import InputError

TRUTH_FILE = _asset("data/observer_truth.npz")
TRUTH_RADIUS = 0.010  # m around each hand's start: the motor model's grasps land within a few mm
TRUTH_SIZES_MM = (8.0, 5.5, 4.0)


@dataclass(frozen=True)
class Truth:
    """K per pascal at surface vertices; `force` scales by the scene's Young's modulus."""

    vertices: np.ndarray  # (n,) surface vertex ids
    K_per_pa: np.ndarray  # (n, 3, 3)
    young: float  # the scene's modulus, Pa
    digest: str  # the surface the table belongs to
    grasp_radius: float

    def K(self, vertex: int) -> np.ndarray:
        hit = np.flatnonzero(self.vertices == int(vertex))
        if not len(hit):
            raise InputError(f"observer truth: no reference stiffness for grasp vertex {int(vertex)}; compute it with "
                             "`studyctl calibrate truth --scene FILE --vertices ...` (docs/synthetic.md)")
        return self.young * self.K_per_pa[hit[0]]


def truth_key(scene) -> dict:
    """What the table depends on: the surface, the clamp, Poisson's ratio and the grasp radius
    (not Young's modulus: linear elasticity scales with it)."""
    from sim.field import mesh_digest
    from sim.scene import clamp_limit

    fem = scene.spec.models.get("fem")
    axis, limit = clamp_limit(scene)
    return {"digest": mesh_digest(scene.mesh), "clamp_axis": int(axis), "clamp_height": float(limit),
            "poisson": float(scene.spec.material.poisson),
            "grasp_radius": float(fem.options.get("grasp_radius", 0.005)) if fem else 0.005}


def user_truth_path(scene) -> Path:
    """Where `studyctl calibrate truth` puts a table for a scene the shipped one does not cover."""
    import hashlib
    import json

    from sim.volume import cache_dir

    key = json.dumps(truth_key(scene), sort_keys=True)
    return cache_dir() / f"truth-{hashlib.sha256(key.encode()).hexdigest()[:20]}.npz"


def _read(path: Path, key: dict):
    """The table at `path` if it was made for `key`, else None (with why)."""
    try:
        z = np.load(path, allow_pickle=False)
    except (OSError, ValueError) as exc:
        raise InputError(f"{path}: cannot read the observer truth table: {exc}") from None
    for name, want in key.items():
        have = z[name].item() if z[name].shape == () else z[name]
        same = have == want if isinstance(want, str) else math.isclose(float(have), float(want), rel_tol=1e-9, abs_tol=1e-12)
        if not same:
            return None, f"{name}: {have} there, {want} here"
    return z, ""


def load_truth(scene, path: Path | str | None = None) -> Truth:
    """The truth for this scene: `path`, else the shipped table and the one `calibrate truth`
    made for this scene (their grasp places together). A table made for another surface,
    clamp, Poisson's ratio or grasp radius is refused by name."""
    key = truth_key(scene)
    paths = [Path(path)] if path is not None else [p for p in (TRUTH_FILE, user_truth_path(scene)) if p.exists()]
    vertices, K, why = [], [], []
    for p in paths:
        z, reason = _read(p, key)
        if z is None:
            why.append(f"{p}: made for another scene ({reason})")
            continue
        vertices.append(z["vertices"])
        K.append(z["K_per_pa"])
    if not vertices:
        raise InputError(("; ".join(why) or "no observer truth table") + "; make one with `studyctl calibrate truth --scene FILE`")
    return Truth(vertices=np.concatenate(vertices), K_per_pa=np.concatenate(K), young=float(scene.spec.material.young),
                 digest=key["digest"], grasp_radius=key["grasp_radius"])


def hand_vertices(scene, radius: float = TRUTH_RADIUS) -> np.ndarray:
    """Surface vertices within `radius` of where each hand grasps (same hemisphere)."""
    from analysis.reference import patch_vertices

    mesh = scene.mesh
    out = [patch_vertices(mesh, mesh.nearest_vertex(hand.script(mesh).start), radius) for hand in scene.spec.hands]
    return np.unique(np.concatenate(out)) if out else np.zeros(0, dtype=np.int64)


def build_truth(scene_path, out: Path | str | None = None, vertices=None, sizes_mm=TRUTH_SIZES_MM, progress=None) -> dict:
    """Solve the P2 reference at `vertices` (default: around the scene's hands) on each mesh
    size, extrapolate the compliance with the order observed on its trace (Richardson; no
    extrapolation where the order cannot be trusted), and write the table."""
    import scipy.sparse as sp

    from analysis.reference import (
        ENVELOPE_FRACTION,
        _premesh,
        build_problem,
        converge,
        grasp_matrix,
        hemisphere_surface,
        mesh_hemisphere,
    )
    from sim.patch import patch_area_points
    from sim.reference import scene_with

    scene = scene_with(scene_path)
    mesh = scene.mesh
    key = truth_key(scene)
    out = Path(out) if out is not None else user_truth_path(scene)
    out.parent.mkdir(parents=True, exist_ok=True)
    vertices = hand_vertices(scene) if vertices is None else np.unique(np.asarray(vertices, dtype=np.int64))
    labels = mesh.labels if mesh.labels is not None else np.zeros(len(mesh.vertices), dtype=np.int64)
    if len(vertices) == 0 or vertices.min() < 0 or vertices.max() >= len(mesh.vertices):
        raise InputError(f"--vertices: surface vertex ids must be in 0..{len(mesh.vertices) - 1}")
    start = time.perf_counter()
    hemis = sorted(set(int(labels[v]) for v in vertices))
    _premesh(mesh, hemis, list(sizes_mm), 1, None)
    C = np.zeros((len(sizes_mm), len(vertices), 3, 3))
    hs = np.zeros((len(sizes_mm), len(hemis)))
    for j, h in enumerate(hemis):
        sel = np.flatnonzero(labels[vertices] == h)
        verts, tris, _ = hemisphere_surface(mesh, h)
        for i, size in enumerate(sizes_mm):
            body = mesh_hemisphere(verts, tris, size * 1e-3, ENVELOPE_FRACTION * size * 1e-3)
            problem = build_problem(scene, h, body)
            hs[i, j] = body.h
            Ws = [grasp_matrix(problem, *patch_area_points(mesh, int(vertices[k]), key["grasp_radius"])) for k in sel]
            if any(W.nnz == 0 for W in Ws):
                raise InputError("--vertices: a grasp patch lies in clamped elements (below the clamp plane)")
            U = problem.fem.solve_free(np.ascontiguousarray(sp.hstack([W.T for W in Ws]).toarray()))
            for n, (k, W) in enumerate(zip(sel, Ws)):
                c = W @ U[:, 3 * n:3 * n + 3]
                C[i, k] = 0.5 * (c + c.T)
            if progress is not None:
                progress(f"hemisphere {h}, {size:g} mm: {len(sel)} grasps")
            del problem
    K = np.zeros((len(vertices), 3, 3))
    orders, status, gci = np.zeros(len(vertices)), [], np.zeros(len(vertices))
    for k in range(len(vertices)):
        j = hemis.index(int(labels[vertices[k]]))
        fine = int(np.argmin(hs[:, j]))
        conv = converge([np.trace(C[i, k]) for i in range(len(sizes_mm))], hs[:, j])
        Ck = C[fine, k]
        if conv["extrapolated"]:
            second = int(np.argsort(hs[:, j])[1])
            Ck = Ck + (Ck - C[second, k]) / (conv["r21"] ** conv["p_used"] - 1.0)
        K[k] = np.linalg.inv(0.5 * (Ck + Ck.T))
        orders[k], gci[k] = conv["p_used"], conv["gci"]
        status.append(conv["status"])
    tmp = out.with_name(out.name + ".tmp.npz")  # whole or not at all
    np.savez_compressed(tmp, vertices=vertices, K_per_pa=K, K_per_pa_meshes=np.linalg.inv(C), h_m=hs, sizes_mm=np.asarray(sizes_mm),
                        order=orders, gci=gci, status=np.asarray(status), **{k: np.asarray(v) for k, v in key.items()})
    tmp.replace(out)
    return {"out": str(out), "vertices": int(len(vertices)), "sizes_mm": list(sizes_mm), "seconds": time.perf_counter() - start,
            "status": {s: status.count(s) for s in sorted(set(status))}, "gci_median": float(np.median(gci)), "gci_max": float(np.max(gci)),
            "order_median": float(np.median(orders))}
