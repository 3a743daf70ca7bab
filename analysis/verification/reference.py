"""A converged reference for the accuracy bench and the observer's truth: the tissue's
finite-strain law (the scene's `[material]`: human cortex, one-term Ogden, sim/material.py) on
quadratic tetrahedra on the brain's body-fitted meshes, refined three times, with Richardson
extrapolation and Roache's grid convergence index.

- **The pulls** (geometry, elements, grasp, solves, the shipped data and the cache):
  analysis/verification/tissue_pulls.py.
- Richardson and the GCI: `analysis.verification.convergence`.

The numbers are in docs/reference.md.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from analysis.verification.convergence import GCI_FS3, GCI_FS_FALLBACK, converge
from analysis.verification.regions import scene_regions
from analysis.verification.tissue_pulls import (
    DEFAULT_SIZES_MM,
    QUICK_SIZES_MM,
    _premesh,
    body_membrane,
    build_problem,
    grasp_matrix,
    pull_references,
    pull_samples,
    small_strain_factor,
)
from analysis.verification.truth_band import rule_inputs
from sim.errors import ParameterError
from sim.geometry.mesh import patch_vertices
from sim.geometry.patch import patch_area_points
from sim.geometry.tetmesh import ENVELOPE_FRACTION, enclosed_volume, hemisphere_surface, mesh_hemisphere
from sim.perception import force_jnd
from sim.pulls import make_pulls, scene_with
from sim.scene import DEFAULT_SCENE, clamp_limit, grasp_radius

FORMULATIONS = ("finite-strain", "small-strain")


# -- the reference ------------------------------------------------------------------------

@dataclass(frozen=True)
class ReferenceConfig:
    scene: Path = DEFAULT_SCENE
    sizes_mm: tuple[float, ...] = DEFAULT_SIZES_MM  # fTetWild target edge lengths
    max_pull: float = 0.012  # m, the accuracy bench's (analysis.verification.accuracy.AccuracyConfig)
    samples: int = 24
    pulls: tuple[str, ...] | None = None  # pull names to run; None: all of the bench's calibration pulls
    formulation: str = "finite-strain"  # or "small-strain" (the law's small-strain limit: one linear solve per pull)
    functional: str = "area"  # the grasp: mean displacement of the surface area ("area") or of its vertices ("vertices", small strain)
    threads: int = 1  # fTetWild's threads per mesh (more gain nothing on this surface: docs/reference.md)
    jobs: int | None = None  # worker processes for meshing and solving (default: every core)
    quick: bool = False
    extra: dict = field(default_factory=dict)


def quick_config(**kw) -> ReferenceConfig:
    """Two coarse meshes (20 and 16 mm), the left hand's two pulls (one hemisphere), 2 samples
    (2 and 4 mm: where the finer mesh follows, docs/reference.md)."""
    return ReferenceConfig(**({"sizes_mm": QUICK_SIZES_MM, "samples": 2, "max_pull": 0.004, "pulls": ("left-lateral", "left-anterior"), "quick": True} | kw))


def jnd_verdict(force: float, band_half: float) -> dict:
    """Is the band narrower than the force JND? Relative: half-band / force below the JND
    fraction (10% at or above 0.5 N, 25% below, `sim.perception.force_jnd`); absolute: half-band below
    0.05 N (10% of 0.5 N)."""
    rel = band_half / force if force > 0 else math.inf
    frac = float(force_jnd(np.array(force)))
    return {"band_rel": rel, "jnd_fraction": frac, "within_jnd_rel": bool(rel < frac), "within_jnd_abs": bool(band_half < 0.05)}


def _selected_pulls(cfg: ReferenceConfig, scene) -> list:
    pulls = make_pulls(scene)
    if cfg.pulls is not None:
        unknown = set(cfg.pulls) - {p.name for p in pulls}
        if unknown:
            raise ParameterError(f"pulls: {', '.join(sorted(unknown))} not among {', '.join(p.name for p in pulls)}")
        pulls = [p for p in pulls if p.name in cfg.pulls]
    if cfg.formulation not in FORMULATIONS:
        raise ParameterError(f"formulation: {cfg.formulation!r}; allowed: {', '.join(FORMULATIONS)}")
    if cfg.functional not in ("area", "vertices"):
        raise ParameterError(f"functional: {cfg.functional!r}; allowed: area, vertices")
    if cfg.functional == "vertices" and cfg.formulation != "small-strain":
        raise ParameterError("functional: vertices is a small-strain demonstration (its force has no continuum limit); "
                             "use it with formulation small-strain")
    return pulls


def _patches(cfg: ReferenceConfig, mesh, pulls, radius: float) -> dict:
    """The grasp functional per pull: the mean displacement of the surface within the grasp
    radius ("area", converges) or of the surface vertices there ("vertices", does not)."""
    if cfg.functional == "area":
        return {p.name: patch_area_points(mesh, p.vertex, radius) for p in pulls}
    return {p.name: (mesh.vertices[patch_vertices(mesh, p.vertex, radius)], None) for p in pulls}


def _mesh_rows(scene, labels, sizes, made) -> tuple[list, dict]:
    """The meshes' rows (sizes, volumes, P2 dofs) and h by (hemisphere, size)."""
    rows, h_of = [], {}
    for label in labels:
        verts, tris, _ = hemisphere_surface(scene.mesh, label)
        surf_vol = enclosed_volume(verts, tris)
        for size in sizes:
            bm = mesh_hemisphere(verts, tris, size * 1e-3)
            prob = build_problem(scene, label, bm)
            h_of[(label, size)] = bm.h
            rows.append(bm.describe() | {"cached": bm.cached and (label, size) not in made, "hemisphere": int(label),
                                         "surface_volume_cm3": surf_vol * 1e6, "volume_error": bm.volume / surf_vol - 1.0,
                                         "p2_nodes": int(prob.space.n_all), "free_dofs": int(len(prob.space.free)),
                                         "fixed_corner_nodes": prob.fixed_nodes})
    return rows, h_of


def _small_strain(cfg, scene, pulls, patches, xs, sizes, progress) -> dict:
    """Per pull, the small-strain force per pascal of shear modulus on each mesh (sizes, xs, 3)."""
    law = scene.spec.material.law
    F: dict[str, list[np.ndarray]] = {p.name: [] for p in pulls}
    labels = sorted({p.hemisphere for p in pulls})
    done = 0
    for label in labels:
        verts, tris, _ = hemisphere_surface(scene.mesh, label)
        for size in sizes:
            prob = build_problem(scene, label, mesh_hemisphere(verts, tris, size * 1e-3))
            factor = small_strain_factor(prob, law, scene_regions(scene), body_membrane(scene, law))
            for p in (p for p in pulls if p.hemisphere == label):
                W = grasp_matrix(prob, *patches[p.name])
                C = W @ factor.solve(np.ascontiguousarray(W.T.toarray()))
                F[p.name].append(np.outer(xs, np.linalg.inv(0.5 * (C + C.T)) @ np.asarray(p.direction)))
            del prob, factor
            done += 1
            if progress is not None:
                progress(done, len(labels) * len(sizes))
    return {k: np.stack(v) for k, v in F.items()}


def _sample(pull, x: float, f: list, hs: list, sizes: list) -> dict:
    """One sample's convergence record and verdict from its forces on the meshes (coarse to fine)."""
    row = {"pull": pull.name, "displacement_mm": float(x) * 1e3, "forces_n": f, "h_mm": [h * 1e3 for h in hs], "target_edge_mm": sizes}
    if not all(math.isfinite(v) for v in f):  # a solve that stopped early, or a finer mesh that did not follow
        status = "coarsest mesh only" if math.isfinite(f[0]) else "not solved"
        return row | {"status": status, "order": math.nan, "order_used": math.nan, "fs": math.nan, "extrapolated": False,
                      "force_ext_n": math.nan, "gci": math.nan, "band_n": [math.nan, math.nan], "band_half_n": math.nan,
                      "band_rel": math.nan, "jnd_fraction": math.nan, "within_jnd_rel": False, "within_jnd_abs": False}
    conv = converge(f, hs)
    half = conv["gci"] * f[-1]
    return row | {"order": conv["p"], "order_used": conv["p_used"], "status": conv["status"], "R": conv["R"], "fs": conv["fs"],
                  "extrapolated": conv["extrapolated"], "force_ext_n": conv["f_ext"], "gci": conv["gci"],
                  "band_n": [f[-1] - half, f[-1] + half], "band_half_n": half} | jnd_verdict(f[-1], half)


def _support(sup, k: int) -> dict:
    """A sample's support over the meshes that reached it (the larger share and |J - 1|;
    analysis.verification.truth_band): NaN for the small-strain formulation, which has none."""
    keys = ("support_share_outside", "max_abs_j_minus_1", "marginal_share_outside", "max_abs_j_minus_1_fine")
    if sup is None:
        return dict.fromkeys(keys, math.nan)
    rule = rule_inputs(np.asarray(sup)[:, k])
    return {key: rule[key] for key in keys}


def run_reference(cfg: ReferenceConfig, progress=None) -> dict:
    """Mesh, solve and extrapolate every pull; returns {"samples", "pulls", "meshes", "meta"}."""
    t_start = time.perf_counter()
    scene = scene_with(cfg.scene)
    law = scene.spec.material.law
    mu = law.shear_modulus
    pulls = _selected_pulls(cfg, scene)
    xs = pull_samples(cfg.max_pull, cfg.samples)
    radius = grasp_radius(scene)
    sizes = sorted((float(s) for s in cfg.sizes_mm), reverse=True)  # coarse to fine
    patches = _patches(cfg, scene.mesh, pulls, radius)
    labels = sorted({p.hemisphere for p in pulls})
    made = _premesh(scene.mesh, labels, sizes, cfg.threads, cfg.jobs)
    solves: dict = {p.name: [] for p in pulls}
    support: dict = {}
    if cfg.formulation == "finite-strain":
        refs = pull_references(cfg.scene, pulls, xs, sizes, jobs=cfg.jobs, progress=progress)["pulls"]
        F = {name: r["force_per_pa"] for name, r in refs.items()}
        support = {name: r["support"] for name, r in refs.items()}
        solves = {name: r["solves"] for name, r in refs.items()}
    else:
        F = _small_strain(cfg, scene, pulls, patches, xs, sizes, progress)
    meshes, h_of = _mesh_rows(scene, labels, sizes, made)
    samples, pull_rows = [], []
    for p in pulls:
        hs = [h_of[(p.hemisphere, s)] for s in sizes]
        pull_rows.append({"pull": p.name, "hemisphere": p.hemisphere, "grasp_vertex": p.vertex, "patch_points": int(len(patches[p.name][0])),
                          "direction": list(p.direction), "h_mm": [h * 1e3 for h in hs], "force_per_pa": F[p.name].tolist(),
                          "solves": solves[p.name]})
        samples += [_sample(p, x, [float(np.linalg.norm(F[p.name][i, k])) * mu for i in range(len(sizes))], hs, sizes)
                    | _support(support.get(p.name), k) for k, x in enumerate(xs)]
    gcis = [s["gci"] for s in samples if math.isfinite(s["gci"])]
    meta = {"scene": str(cfg.scene), "law": law.params(), "law_text": law.describe(), "law_source": scene.spec.material.law_source,
            "shear_modulus_pa": mu, "element": "P2 (10-node tetrahedra), displacement-based",
            "formulation": (f"finite strain, {law.describe()}" if cfg.formulation == "finite-strain"
                            else f"the law's small-strain limit (mu {mu:.4g} Pa, Poisson {law.poisson:.3f})"),
            "mesher": "fTetWild (pytetwild), shipped meshes where the size is shipped", "envelope_fraction": ENVELOPE_FRACTION,
            "sizes_mm": sizes, "grasp_radius_m": radius, "functional": cfg.functional,
            "clamp": dict(zip(("axis", "height_m"), clamp_limit(scene))),
            "max_pull_m": cfg.max_pull, "samples_per_pull": cfg.samples, "quick": cfg.quick,
            "gci_fs": GCI_FS3 if len(sizes) == 3 else GCI_FS_FALLBACK,
            "gci_median": float(np.median(gcis)) if gcis else math.nan, "gci_max": float(np.max(gcis)) if gcis else math.nan,
            "seconds": time.perf_counter() - t_start}
    return {"samples": samples, "pulls": pull_rows, "meshes": meshes, "meta": meta}



