"""The stiffness field behind the location-aware plate-spring model (beyond the paper).

The paper's plate-spring model has one force curve for the whole brain, while the brain's
stiffness at a grasp depends on where it is grasped and which way it is pulled (the bench's
pulls need 0.11-0.30 N at 24 mm at the scene's 3 kPa). Here the reference's condensed
stiffness is sampled over the surface and shipped with the project:

- **Sites**: the ico4 subset of each fsaverage5 hemisphere (its first 2562 vertices, about
  4 mm apart on the pial surface), above the clamp plane.
- **At each site**: the 3 x 3 stiffness that holds the area mean of the grasp patch
  (`sim.geometry.patch`) at a small displacement d, K = (W A^-1 W^T)^-1, on the reference's body-fitted
  P2 mesh (`analysis.verification.reference`, 8 mm target edge), A the tissue law's tangent at rest (its
  small-strain limit; the white matter's inside the white surface where the scene names one,
  as the truth has it), per pascal of the law's shear modulus. The columns A^-1 W^T of all
  sites are solved in blocks with one CHOLMOD factor.
- **Everywhere else**: a Gaussian-weighted mean of the sites within FIELD_REACH on the same
  hemisphere (a positive combination of SPD matrices is SPD); a vertex with no site in reach
  takes its nearest site's.

`sim.models.plate_spring.PlateSpringModel` with a field renders F = -(f(|d|) / (k0 |d|)) E K(v) d:
the stack's curve f sets how the force grows with the pull (its shape, k0 its initial slope:
fitted to the finite-strain reference's stiffening on the calibration pulls), the field sets
how stiff the brain is at the grasped vertex v and in which direction; E is the stack's
modulus, which for the located stack is the law's shear modulus (the field is per pascal of
it). The tick adds one 3 x 3 product to the paper's model.
"""

from __future__ import annotations

import dataclasses
import json
import time
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from analysis.verification.regions import scene_regions
from analysis.verification.tissue_pulls import (
    DEFAULT_SIZES_MM,
    _premesh,
    body_membrane,
    build_problem,
    grasp_matrix,
    pull_references,
    pull_stiffness,
    small_strain_factor,
)
from sim.calibrate import fit
from sim.files import save_npz
from sim.geometry.patch import patch_area_points
from sim.geometry.tetmesh import hemisphere_surface, mesh_hemisphere
from sim.models.fem.grasp import compliances
from sim.models.plate_spring import PlateSpring
from sim.pulls import ICO4_VERTICES, make_pulls, scene_with
from sim.scene import clamp_limit, grasp_radius
from sim.stiffness_field import FIELD_FILE, mesh_digest

FIELD_SIZE_MM = 8.0  # the reference mesh the field is solved on (the coarsest of the reference's three)
FIELD_SIGMA = 0.003  # m, Gaussian width of the interpolation between sites
FIELD_REACH = 0.008  # m, sites farther than this do not contribute
BLOCK = 240  # right-hand sides per CHOLMOD solve (memory: n_free x BLOCK doubles)


def site_stiffness(scene_path, size_mm: float = FIELD_SIZE_MM, sites_per_hemisphere: int = ICO4_VERTICES,
                   progress=None) -> dict:
    """K per pascal of shear modulus (s, 3, 3) at the sites, with the site vertex ids and what it took."""
    scene = scene_with(scene_path)
    mesh = scene.mesh
    radius = grasp_radius(scene)
    axis, limit = clamp_limit(scene)
    labels = mesh.labels if mesh.labels is not None else np.zeros(len(mesh.vertices), dtype=np.int64)
    hemis = sorted(set(int(x) for x in np.unique(labels)))
    _premesh(mesh, hemis, [size_mm], 1, None)
    out_sites, out_K = [], []
    start = time.perf_counter()
    total = sum(min(sites_per_hemisphere, int(np.sum(labels == h))) for h in hemis)
    done = 0
    for h in hemis:
        ids = np.flatnonzero(labels == h)[:sites_per_hemisphere]
        ids = ids[mesh.vertices[ids, axis] > limit]  # a site below the clamp plane cannot move
        verts, tris, _ = hemisphere_surface(mesh, h)
        problem = build_problem(scene, h, mesh_hemisphere(verts, tris, size_mm * 1e-3))
        law = scene.spec.material.law
        factor = small_strain_factor(problem, law, scene_regions(scene), body_membrane(scene, law))  # the scene's whole body
        for b0 in range(0, len(ids), BLOCK // 3):
            block = ids[b0:b0 + BLOCK // 3]
            Ws = [grasp_matrix(problem, *patch_area_points(mesh, int(v), radius)) for v in block]
            keep = [k for k, W in enumerate(Ws) if W.nnz > 0]
            if keep:
                for k, C in zip(keep, compliances(factor, [Ws[k] for k in keep])):
                    if np.all(np.linalg.eigvalsh(C) > 0):
                        out_sites.append(int(block[k]))
                        out_K.append(np.linalg.inv(C))
            done += len(block)
            if progress is not None:
                progress(done, total)
        del problem, factor
    return {"sites": np.array(out_sites, dtype=np.int64), "K_per_pa": np.array(out_K), "size_mm": size_mm,
            "grasp_radius_m": radius, "seconds": time.perf_counter() - start}


def interpolate(mesh, sites: np.ndarray, K_sites: np.ndarray, sigma: float = FIELD_SIGMA, reach: float = FIELD_REACH) -> np.ndarray:
    """K at every surface vertex (n, 3, 3): Gaussian-weighted sites within `reach`, same
    hemisphere; the nearest site where none is in reach. (Rotating each site's tensor so its
    normal lies along the vertex's was tried and is worse: the folded surface's normals vary
    more than the tensors do.)"""
    v = mesh.vertices
    labels = mesh.labels if mesh.labels is not None else np.zeros(len(v), dtype=np.int64)
    out = np.zeros((len(v), 3, 3))
    for h in np.unique(labels):
        on = labels[sites] == h
        if not on.any():
            continue
        sv, sk = v[sites[on]], K_sites[on]
        tree = cKDTree(sv)
        verts = np.flatnonzero(labels == h)
        for i, near in zip(verts, tree.query_ball_point(v[verts], reach)):
            if near:
                d = np.linalg.norm(sv[near] - v[i], axis=1)
                w = np.exp(-((d / sigma) ** 2))
                out[i] = np.tensordot(w / w.sum(), sk[near], axes=1)
            else:
                out[i] = sk[tree.query(v[i])[1]]
    return out


def build_field(scene_path, out: Path = FIELD_FILE, size_mm: float = FIELD_SIZE_MM, progress=None) -> dict:
    """Solve the sites, interpolate, and write the field (float32, symmetric 6 entries per
    vertex) with what it was made from; atomic."""
    scene = scene_with(scene_path)
    res = site_stiffness(scene_path, size_mm, progress=progress)
    K = interpolate(scene.mesh, res["sites"], res["K_per_pa"])
    iu = np.triu_indices(3)
    out = save_npz(out, compressed=True, K_per_pa=K[:, iu[0], iu[1]].astype(np.float32), sites=res["sites"],
                        K_sites_per_pa=res["K_per_pa"][:, iu[0], iu[1]].astype(np.float32),
                        mesh_digest=mesh_digest(scene.mesh), size_mm=size_mm, grasp_radius_m=res["grasp_radius_m"],
                        law=json.dumps(scene.spec.material.law.params()), sigma_m=FIELD_SIGMA, reach_m=FIELD_REACH,
                        white_matter=json.dumps(white.params() if (white := scene.spec.material.white_matter) is not None else None),
                        source="analysis/verification/field_fit.py build_field: the tissue law's small-strain limit on P2 on fTetWild meshes of the "
                               "scene's hemispheres (the white matter's law inside the white surface where the scene names one), "
                               "area-mean grasp, per pascal of the grey law's shear modulus")
    return {"path": str(out), "sites": int(len(res["sites"])), "vertices": int(len(K)), "size_mm": size_mm,
            "seconds": res["seconds"]}


def fit_shape(scene_path, start_params, xs, formulation: str = "finite-strain", jobs: int | None = None) -> tuple:
    """The located stack's curve, which only shapes the force (the field sets its size).

    "small-strain": a one-layer stack, whose curve is a straight line, so F = E K(v) d exactly.
    "finite-strain": h1, alpha, q and x_c1 fitted (`sim.calibrate.fit`) so that the stack's
    force over its initial slope follows the mean finite-strain / small-strain force ratio of
    the calibration pulls (`sim.pulls.make_pulls`), both on the reference's finest mesh
    (the shipped solves), where that mesh followed the pull. Returns (params, report)."""
    if formulation == "small-strain":
        return dataclasses.replace(start_params, layers=1), {"formulation": formulation, "within_jnd": 1.0, "pulls": []}

    scene = scene_with(scene_path)
    law = scene.spec.material.law
    pulls = make_pulls(scene)
    fine = min(DEFAULT_SIZES_MM)
    # the reference's group, so that the finest mesh is read as far as it followed each pull (the
    # support's limit, docs/reference.md), not solved further on its own
    refs = pull_references(scene_path, pulls, xs, DEFAULT_SIZES_MM, jobs=jobs)["pulls"]
    ratios = {}
    for label in sorted({p.hemisphere for p in pulls}):
        verts, tris, _ = hemisphere_surface(scene.mesh, label)
        problem = build_problem(scene, label, mesh_hemisphere(verts, tris, fine * 1e-3))
        for p in (p for p in pulls if p.hemisphere == label):
            K = pull_stiffness(problem, law, *patch_area_points(scene.mesh, p.vertex, grasp_radius(scene)), regional=scene_regions(scene),
                               membrane=body_membrane(scene, law))
            small = np.linalg.norm(np.outer(xs, K @ np.asarray(p.direction)), axis=1)
            ratios[p.name] = np.linalg.norm(refs[p.name]["force_per_pa"][-1], axis=1) / small
    # the mean over the pulls whose solve reached each x (a solve that stopped has none beyond)
    stacked = np.array(list(ratios.values()))
    reached_by = np.isfinite(stacked).sum(axis=0)
    ratio = np.nansum(stacked, axis=0) / np.maximum(reached_by, 1)
    ok = reached_by > 0
    k0 = PlateSpring(start_params).force(1e-7) / 1e-7
    params, rep = fit(start_params, np.asarray(xs)[ok], k0 * ratio[ok] * np.asarray(xs)[ok])
    return params, rep | {"formulation": formulation, "finite_over_small_strain": ratio.tolist(),
                          "per_pull": {k: v.tolist() for k, v in ratios.items()}, "mesh_mm": fine,
                          "pulls": sorted(k for k, v in ratios.items() if np.isfinite(v).any()),
                          "no_reference": sorted(k for k, v in ratios.items() if not np.isfinite(v).any()),
                          "pulls_reaching": reached_by.tolist()}
