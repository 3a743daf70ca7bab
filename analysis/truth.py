"""Making the synthetic observer's truth table (`studyctl calibrate truth`): the converged P2
reference's grasp stiffness around the scene's hands, solved on three body-fitted meshes and
extrapolated. Reading it is the study library's (studyctl/truth.py)."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from sim.files import save_npz
from studyctl.errors import InputError
from studyctl.truth import TRUTH_SIZES_MM, hand_vertices, truth_key, user_truth_path


def build_truth(scene_path, out: Path | str | None = None, vertices=None, sizes_mm=TRUTH_SIZES_MM, progress=None) -> dict:
    """Solve the P2 reference at `vertices` (default: around the scene's hands) on each mesh
    size, extrapolate the compliance with the order observed on its trace (Richardson; no
    extrapolation where the order cannot be trusted), and write the table."""
    from analysis.convergence import converge
    from analysis.reference import _premesh, build_problem, grasp_matrix
    from sim.models.fem.grasp import compliances, symmetric_inverse
    from sim.patch import patch_area_points
    from sim.reference import scene_with
    from sim.tetmesh import hemisphere_surface, mesh_hemisphere

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
            body = mesh_hemisphere(verts, tris, size * 1e-3)
            problem = build_problem(scene, h, body)
            hs[i, j] = body.h
            Ws = [grasp_matrix(problem, *patch_area_points(mesh, int(vertices[k]), key["grasp_radius"])) for k in sel]
            if any(W.nnz == 0 for W in Ws):
                raise InputError("--vertices: a grasp patch lies in clamped elements (below the clamp plane)")
            C[i, sel] = compliances(problem.fem, Ws)
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
        K[k] = symmetric_inverse(Ck)
        orders[k], gci[k] = conv["p_used"], conv["gci"]
        status.append(conv["status"])
    save_npz(out, compressed=True, vertices=vertices, K_per_pa=K, K_per_pa_meshes=np.linalg.inv(C), h_m=hs, sizes_mm=np.asarray(sizes_mm),
             order=orders, gci=gci, status=np.asarray(status), **{k: np.asarray(v) for k, v in key.items()})
    return {"out": str(out), "vertices": int(len(vertices)), "sizes_mm": list(sizes_mm), "seconds": time.perf_counter() - start,
            "status": {s: status.count(s) for s in sorted(set(status))}, "gci_median": float(np.median(gci)), "gci_max": float(np.max(gci)),
            "order_median": float(np.median(orders))}
