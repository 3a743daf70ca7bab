"""Making the synthetic observer's truth table (`studyctl calibrate truth`): the converged
reference's finite-strain path along each hand's pull and the small-strain transfer to the grasp
places around it (analysis/verification/truth.py says how the table is read)."""

from __future__ import annotations

import hashlib
import json
import time
from pathlib import Path

import numpy as np

from analysis.errors import InputError
from analysis.verification.convergence import converge
from analysis.verification.regions import scene_regions
from analysis.verification.tissue_pulls import (
    RECORD_XS,
    body_membrane,
    build_problem,
    combined_sample,
    grasp_matrix,
    require_converged,
    small_strain_factor,
    solve_pull,
)
from analysis.verification.truth import TRUTH_SIZES_MM, hand_sets, truth_key, user_truth_path
from analysis.verification.truth_band import truth_samples
from sim.files import save_npz
from sim.geometry.patch import patch_area_points
from sim.geometry.tetmesh import hemisphere_surface, mesh_hemisphere
from sim.models.fem.grasp import compliances, symmetric_inverse
from sim.pulls import hand_pulls, scene_with
from sim.scene import grasp_radius


def _small_strain(scene, hemis, vertices, labels, sizes_mm, radius, progress) -> tuple[np.ndarray, np.ndarray]:
    """The small-strain compliance per pascal of shear modulus (sizes, n, 3, 3) at `vertices` on
    each mesh, and h (sizes, hemispheres)."""
    mesh, law = scene.mesh, scene.spec.material.law
    C = np.zeros((len(sizes_mm), len(vertices), 3, 3))
    hs = np.zeros((len(sizes_mm), len(hemis)))
    for j, h in enumerate(hemis):
        sel = np.flatnonzero(labels[vertices] == h)
        verts, tris, _ = hemisphere_surface(mesh, h)
        for i, size in enumerate(sizes_mm):
            body = mesh_hemisphere(verts, tris, size * 1e-3)
            problem = build_problem(scene, h, body)
            hs[i, j] = body.h
            Ws = [grasp_matrix(problem, *patch_area_points(mesh, int(vertices[k]), radius)) for k in sel]
            if any(W.nnz == 0 for W in Ws):
                raise InputError("--vertices: a grasp patch lies in clamped elements (below the clamp plane)")
            C[i, sel] = compliances(small_strain_factor(problem, law, scene_regions(scene), body_membrane(scene, law)), Ws)
            if progress is not None:
                progress(f"hemisphere {h}, {size:g} mm: small-strain stiffness at {len(sel)} grasp places")
            del problem
    return C, hs


def _extrapolated_stiffness(C: np.ndarray, hs: np.ndarray) -> tuple[np.ndarray, float, str, float]:
    """K from compliances on the meshes (sizes, 3, 3) with h (sizes,): Richardson on the trace
    with the order observed (none where it cannot be trusted); (K, order, status, gci)."""
    conv = converge([np.trace(c) for c in C], hs)
    order = np.argsort(hs)
    Ck = C[order[0]]
    if conv["extrapolated"]:
        Ck = Ck + (Ck - C[order[1]]) / (conv["r21"] ** conv["p_used"] - 1.0)
    return symmetric_inverse(Ck), conv["p_used"], conv["status"], conv["gci"]


def build_truth(scene_path, out: Path | str | None = None, vertices=None, sizes_mm=TRUTH_SIZES_MM, check: bool = True,
                jobs: int | None = None, progress=None) -> dict:
    """The truth table of a scene: each hand's finite-strain path (the reference's solves on
    `sizes_mm`, Richardson), the small-strain stiffness at every grasp place (default: within
    10 mm of the hands) and its transfer; with `check`, the transfer's error at the place farthest
    from each hand's vertex, solved directly on the coarsest mesh."""
    start = time.perf_counter()
    scene = scene_with(scene_path)
    mesh, law = scene.mesh, scene.spec.material.law
    key = truth_key(scene)
    radius = grasp_radius(scene)
    out = Path(out) if out is not None else user_truth_path(scene)
    out.parent.mkdir(parents=True, exist_ok=True)
    labels = mesh.labels if mesh.labels is not None else np.zeros(len(mesh.vertices), dtype=np.int64)
    pulls = hand_pulls(scene)
    sets = hand_sets(scene)
    if vertices is None:
        vertices = np.unique(np.concatenate(list(sets.values())))
    # the hands' own vertices always: their paths are the table's exact part
    vertices = np.unique(np.concatenate([np.asarray(vertices, dtype=np.int64).ravel(), [p.vertex for p in pulls]]))
    if len(vertices) == 0 or vertices.min() < 0 or vertices.max() >= len(mesh.vertices):
        raise InputError(f"--vertices: surface vertex ids must be in 0..{len(mesh.vertices) - 1}")
    # each place follows the path of the nearest hand on its hemisphere
    path = np.full(len(vertices), -1)
    for k, v in enumerate(vertices):
        near = [(float(np.linalg.norm(mesh.vertices[v] - mesh.vertices[p.vertex])), h) for h, p in enumerate(pulls)
                if p.hemisphere == int(labels[v])]
        if not near:
            raise InputError(f"--vertices: vertex {int(v)} is on a hemisphere no hand of the scene grasps")
        path[k] = min(near)[1]
    centres = np.array([p.vertex for p in pulls], dtype=np.int64)
    hemis = sorted(set(int(labels[v]) for v in np.concatenate([vertices, centres])))
    sizes_mm = sorted((float(s) for s in sizes_mm), reverse=True)
    # the paths: the reference's finite-strain solves along each hand's pull
    truth = truth_samples(scene_path, pulls, RECORD_XS, sizes_mm, jobs=jobs, stiffness_for={p.name for p in pulls},
                          progress=(lambda k, n: progress(f"reference paths: {k}/{n} solves")) if progress else None)
    refs = truth["refs"]["pulls"]
    require_converged(refs, "observer truth")
    # the small-strain stiffness at every place and at the hands' own vertices
    all_v = np.concatenate([vertices, centres])
    C, hs = _small_strain(scene, hemis, all_v, labels, sizes_mm, radius, progress)
    K0 = np.zeros((len(all_v), 3, 3))
    orders, status, gci = np.zeros(len(all_v)), [], np.zeros(len(all_v))
    for k, v in enumerate(all_v):
        j = hemis.index(int(labels[v]))
        K0[k], orders[k], st, gci[k] = _extrapolated_stiffness(C[:, k], hs[:, j])
        status.append(st)
    Kc = K0[len(vertices):]
    transfer = np.einsum("nij,njk->nik", K0[: len(vertices)], np.linalg.inv(Kc)[path])
    s = np.concatenate([[0.0], RECORD_XS])
    F = np.zeros((len(pulls), len(s), 3))
    K = np.zeros((len(pulls), len(s), 3, 3))
    path_gci = np.zeros((len(pulls), len(s)))
    path_band = np.zeros((len(pulls), len(s)))  # mesh and law, root-sum-square (analysis.verification.truth_band)
    path_decided = np.ones((len(pulls), len(s)), dtype=bool)
    for h, p in enumerate(pulls):
        r = refs[p.name]
        fine = int(np.argmin(r["h_m"]))
        K[h, 0] = Kc[h]
        for m in range(len(RECORD_XS)):
            c = combined_sample(r["force_per_pa"][:, m], r["h_m"])
            F[h, m + 1] = c["force"]
            finest = float(np.linalg.norm(r["force_per_pa"][fine, m]))
            K[h, m + 1] = r["stiffness_per_pa"][fine, m] * (c["force_n"] / finest)
            path_gci[h, m + 1] = c["band_rel"]
            t = truth["pulls"][p.name][m]
            path_band[h, m + 1], path_decided[h, m + 1] = t["band_rel"], t["decided"]
    _fill_unknown(path_band)  # where an ensemble law did not get: the path's widest known band
    checks = _check_transfer(scene, pulls, sets, path, vertices, C, refs, sizes_mm, radius, progress) if check else []
    # the transfer's error at each hand's farthest place, along the path (0 at rest, where it is exact):
    # a place off the hand's vertex carries it in its band (analysis.verification.truth.Truth.band)
    transfer_error = np.zeros((len(pulls), len(s)))
    for c in checks:
        h = [p.name for p in pulls].index(c["hand"])
        transfer_error[h, 1:] = [c["error_at_mm"][f"{x * 1e3:g}"] for x in RECORD_XS]
    _fill_unknown(transfer_error)  # past where the direct solve stopped: its largest error
    save_npz(out, compressed=True, vertices=vertices, path=path, transfer=transfer, s=s, direction=np.array([p.direction for p in pulls]),
             force_per_pa=F, stiffness_per_pa=K, path_gci=path_gci, path_band=path_band, path_decided=path_decided,
             path_band_rel=np.where(path_decided, 0.0, path_band), transfer_error=transfer_error,
             path_vertex=np.array([p.vertex for p in pulls], dtype=np.int64), path_pulls=np.array([p.name for p in pulls]),
             K0_per_pa=K0, K0_per_pa_meshes=np.linalg.inv(C), small_strain_order=orders, small_strain_status=np.asarray(status), small_strain_gci=gci,
             h_m=hs, sizes_mm=np.asarray(sizes_mm), transfer_check=np.asarray([json_line(c) for c in checks]),
             **{k: np.asarray(v) for k, v in key.items()})
    rep = {"out": str(out), "vertices": int(len(vertices)), "paths": [p.name for p in pulls], "sizes_mm": list(sizes_mm),
            "seconds": time.perf_counter() - start, "path_gci_median": float(np.median(path_gci[:, 1:])),
            "path_gci_max": float(np.max(path_gci[:, 1:])), "small_strain_gci_median": float(np.median(gci)),
            "ensemble": truth["ensemble"],
            "path_first_undecided_mm": {p.name: (float(s[int(np.argmin(path_decided[h]))] * 1e3) if not path_decided[h].all() else None)
                                   for h, p in enumerate(pulls)},
            "path_band_median_undecided": float(np.median(path_band[~path_decided])) if (~path_decided).any() else 0.0,
            "transfer_checks": checks, "force_at_n": {p.name: {f"{x * 1e3:g} mm": float(np.linalg.norm(F[h, m]) * law.shear_modulus)
                                                             for m, x in enumerate(s) if m and m % 2 == 0} for h, p in enumerate(pulls)}}
    # the record beside the table: its SHA-256 (the shipped one is checked against it) and how it was made
    out.with_suffix(".json").write_text(json.dumps({"sha256": hashlib.sha256(out.read_bytes()).hexdigest(), "made_by": "studyctl calibrate truth",
                                                    "law": law.params()} | {k: v for k, v in rep.items() if k != "out"}, indent=1) + "\n")
    return rep


def _fill_unknown(a: np.ndarray) -> None:
    """In place, each row's NaNs by the row's largest known value (0 if it has none)."""
    for row in a:
        known = np.isfinite(row)
        row[~known] = row[known].max() if known.any() else 0.0


def json_line(obj) -> str:
    return json.dumps(obj)


def _check_transfer(scene, pulls, sets, path, vertices, C, refs, sizes_mm, radius, progress) -> list[dict]:
    """Per hand: the place of its set farthest from its vertex, its path solved directly on the
    coarsest mesh, against the transfer of the hand's path on that mesh."""
    mesh = scene.mesh
    coarse = 0  # sizes_mm is coarse to fine
    out = []
    n = len(vertices)
    for h, p in enumerate(pulls):
        mine = np.flatnonzero(path == h)
        if not len(mine):
            continue
        far = mine[int(np.argmax(np.linalg.norm(mesh.vertices[vertices[mine]] - mesh.vertices[p.vertex], axis=1)))]
        v = int(vertices[far])
        verts, tris, _ = hemisphere_surface(mesh, p.hemisphere)
        problem = build_problem(scene, p.hemisphere, mesh_hemisphere(verts, tris, sizes_mm[coarse] * 1e-3))
        law = scene.spec.material.law  # the scene's whole body, as the hand's path was solved
        direct = solve_pull(problem, law, *patch_area_points(mesh, v, radius), np.asarray(p.direction), RECORD_XS,
                            regional=scene_regions(scene), membrane=body_membrane(scene, law), marginal=False)
        # the transfer on the same mesh: K0(v) K0(c)^-1 applied to the hand's own path there
        T = np.linalg.inv(C[coarse, far]) @ C[coarse, n + h]
        pred = refs[p.name]["force_per_pa"][coarse] @ T.T
        err = np.linalg.norm(pred - direct["force_per_pa"], axis=1) / np.linalg.norm(direct["force_per_pa"], axis=1)
        out.append({"hand": p.name, "vertex": v, "distance_mm": float(np.linalg.norm(mesh.vertices[v] - mesh.vertices[p.vertex]) * 1e3),
                    "mesh_mm": sizes_mm[coarse], "converged": direct["converged"],
                    "error_max": float(np.nanmax(err)), "error_median": float(np.nanmedian(err)),
                    "error_at_mm": {f"{x * 1e3:g}": float(e) for x, e in zip(RECORD_XS, err)}})
        if progress is not None:
            progress(f"transfer check, {p.name}: vertex {v} ({out[-1]['distance_mm']:.1f} mm away): largest error {out[-1]['error_max']:.1%}")
        del problem
    return out
