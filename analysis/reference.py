"""A converged reference for the accuracy bench: quadratic tetrahedra on the brain's body-fitted
meshes, refined three times, with Richardson extrapolation and Roache's grid convergence index.

- **Geometry**: the same body-fitted fTetWild meshes the simulator's FEM and mass-spring run
  on (`sim.tetmesh`: 8, 6 and 4 mm target edges, shipped in data/ with their hashes).
- **Elements**: the FEM core's quadratic (P2) tetrahedra (`sim.models.fem.LinearFem` with
  ``order=2``), small-strain linear elasticity, the scene's material and clamp (nodes at or
  below the highest clamped surface vertex, the plane of `sim.models.fem.fixed_nodes`).
- **Grasp**: the FEM core's constraint and condensation (`sim.models.fem.grasp`): the mean
  displacement of the surface *area* within the grasp radius (`sim.patch`), each quadrature
  point interpolated with its element's quadratic shape functions; the force holding the
  patch at ``d`` is ``(W K^-1 W^T)^-1 d``.
- **Nonlinear**: the FEM core's Newton solver (`sim.models.fem.neo_hookean_solve`) on P2.
- The accuracy bench's pulls and displacements (`analysis.accuracy`). Linear elasticity makes
  the force proportional to the displacement and to Young's modulus: one solve per pull (3
  right-hand sides) serves every sampled displacement and modulus.
- Richardson and the GCI: `analysis.convergence`.

The numbers are in docs/reference.md.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from analysis.convergence import GCI_FS3, GCI_FS_FALLBACK, converge
from sim.files import save_npz
from sim.jsonable import jsonable
from sim.mesh import patch_vertices
from sim.patch import patch_area_points
from sim.scene import DEFAULT_SCENE, clamp_limit, grasp_radius
from sim.tetmesh import (
    ENVELOPE_FRACTION,
    SHIPPED_MM,
    BodyMesh,
    enclosed_volume,
    hemisphere_surface,
    mesh_hemisphere,
    needs_meshing,
)

DEFAULT_SIZES_MM = SHIPPED_MM  # target edge lengths, coarse to fine: the shipped meshes
QUICK_SIZES_MM = (20.0, 16.0)
FORMULATIONS = ("linear", "neo-hookean")


# -- the P2 problem ---------------------------------------------------------------------------

@dataclass
class Problem:
    """One hemisphere at one mesh size: the factorised P2 stiffness and its grasp queries."""

    label: int
    mesh: BodyMesh
    fem: object  # sim.models.fem.LinearFem, order 2, Young's modulus 1 Pa
    fixed_nodes: int
    build_s: float
    factor_s: float = 0.0


def build_problem(scene, label: int, mesh: BodyMesh) -> Problem:
    """P2 linear elasticity (E = 1 Pa, the scene's Poisson ratio) on a body-fitted hemisphere
    mesh, clamped like the scene's FEM; factorised now."""
    from sim.models.fem import LinearFem

    start = time.perf_counter()
    axis, limit = clamp_limit(scene)
    fixed = mesh.nodes[:, axis] <= limit
    fem = LinearFem(mesh.nodes, mesh.tets, 1.0, scene.spec.material.poisson, fixed, order=2)
    problem = Problem(label=label, mesh=mesh, fem=fem, fixed_nodes=int(fixed.sum()), build_s=time.perf_counter() - start)
    _ = fem.factor
    problem.factor_s = fem.timings.factorisation_s
    return problem


def grasp_matrix(problem: Problem, points: np.ndarray, weights: np.ndarray | None = None):
    """W (3, n_free): the weighted mean displacement of `points` (weights sum to 1; default
    equal), each located in its containing or nearest tetrahedron and interpolated with the
    element's quadratic shape functions (`sim.models.fem.constraint_matrix`, as `FemModel.grasp`)."""
    from sim.models.fem import constraint_matrix
    from sim.volume import locate

    points = np.atleast_2d(points)
    weights = np.full(len(points), 1.0 / len(points)) if weights is None else np.asarray(weights, dtype=np.float64)
    tet, bary = locate(problem.mesh.nodes, problem.mesh.tets, points)
    return constraint_matrix(problem.fem, tet, bary, weights)


def pull_stiffness(problem: Problem, points: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
    """The condensed stiffness (3, 3) per pascal of Young's modulus: the force holding the
    patch's mean displacement at d is K d (N for E = 1 Pa and d in m)."""
    from sim.models.fem import condense

    return condense(problem.fem, grasp_matrix(problem, points, weights))[2]


# -- compressible neo-Hookean on P2 --------------------------------------------------------

def neo_hookean_pull(problem: Problem, points, weights, direction, xs, min_steps: int = 6, tol: float = 1e-6) -> dict:
    """Forces (per pascal, (len(xs), 3)) holding the patch at each x in `xs` (equal steps
    x_max k / n) along `direction`: one solve (`sim.models.fem.neo_hookean_solve` on P2), at
    least `min_steps` load steps in all."""
    from sim.models.fem import neo_hookean_solve

    xs = np.asarray(xs, dtype=np.float64)
    W = grasp_matrix(problem, points, weights)
    sub = max(1, math.ceil(min_steps / len(xs)))
    forces = np.full((len(xs), 3), np.nan)

    def on_step(step, u, lam_mult):
        if step % sub == 0:
            forces[step // sub - 1] = lam_mult

    t0 = time.perf_counter()
    _, _, rep = neo_hookean_solve(problem.fem, W, np.asarray(direction) * xs[-1], steps=sub * len(xs), tol=tol, max_iter=40, on_step=on_step)
    return {"force_per_pa": forces, "converged": rep.converged, "iterations": rep.iterations, "shifts": rep.shifts,
            "min_jacobian": rep.min_jacobian, "seconds": time.perf_counter() - t0}


NONLINEAR_CACHE_VERSION = 1


def _nonlinear_path(body: BodyMesh, scene, radius: float, pull, xs) -> Path:
    from sim.volume import cache_dir

    axis, limit = clamp_limit(scene)
    key = json.dumps([NONLINEAR_CACHE_VERSION, body.key, scene.spec.material.poisson, axis, round(limit, 9), radius,
                      pull.vertex, [round(c, 12) for c in pull.direction], [round(float(x), 9) for x in xs]])
    return cache_dir() / "reference" / f"neohookean-{hashlib.sha256(key.encode()).hexdigest()[:20]}.npz"


def _nonlinear_task(args) -> dict:
    """One neo-Hookean pull on one mesh (a worker process): cached on disk per pull."""
    scene_path, label, size_mm, pull, xs, radius = args
    from sim.reference import scene_with

    scene = scene_with(scene_path)
    verts, tris, _ = hemisphere_surface(scene.mesh, label)
    edge = size_mm * 1e-3
    body = mesh_hemisphere(verts, tris, edge)
    path = _nonlinear_path(body, scene, radius, pull, xs)
    if path.exists():
        with np.load(path) as z:
            return {k: (z[k] if z[k].ndim else z[k].item()) for k in z.files} | {"cached": True}
    problem = build_problem(scene, label, body)
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


# -- the reference ------------------------------------------------------------------------

@dataclass(frozen=True)
class ReferenceConfig:
    scene: Path = DEFAULT_SCENE
    sizes_mm: tuple[float, ...] = DEFAULT_SIZES_MM  # fTetWild target edge lengths
    young: float | None = None  # Pa; None: the scene's (forces are proportional to it)
    max_pull: float = 0.024  # m, the accuracy bench's (analysis.accuracy.AccuracyConfig)
    samples: int = 6
    pulls: tuple[str, ...] | None = None  # pull names to run; None: all of the bench's
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


def _selected_pulls(cfg: ReferenceConfig, scene) -> list:
    from sim.errors import ParameterError
    from sim.reference import make_pulls

    pulls = make_pulls(scene)
    if cfg.pulls is not None:
        unknown = set(cfg.pulls) - {p.name for p in pulls}
        if unknown:
            raise ParameterError(f"pulls: {', '.join(sorted(unknown))} not among {', '.join(p.name for p in pulls)}")
        pulls = [p for p in pulls if p.name in cfg.pulls]
    if cfg.formulation not in FORMULATIONS:
        raise ParameterError(f"formulation: {cfg.formulation!r}; allowed: {', '.join(FORMULATIONS)}")
    return pulls


def _patches(cfg: ReferenceConfig, mesh, pulls, radius: float) -> dict:
    """The grasp functional per pull: the mean displacement of the surface within the grasp
    radius ("area", converges) or of the surface vertices there ("vertices", does not)."""
    from sim.errors import ParameterError

    if cfg.functional not in ("area", "vertices"):
        raise ParameterError(f"functional: {cfg.functional!r}; allowed: area, vertices")
    if cfg.functional == "area":
        return {p.name: patch_area_points(mesh, p.vertex, radius) for p in pulls}
    return {p.name: (mesh.vertices[patch_vertices(mesh, p.vertex, radius)], None) for p in pulls}


def _solve_meshes(cfg: ReferenceConfig, scene, pulls, patches, xs, sizes, progress) -> tuple[dict, dict, list]:
    """Per pull, the force per pascal on each mesh (sizes, xs, 3) and the nonlinear solves' records; the meshes' rows."""
    mesh = scene.mesh
    labels = sorted({p.hemisphere for p in pulls})
    F: dict[str, list[np.ndarray]] = {p.name: [] for p in pulls}
    solves: dict[str, list[dict]] = {p.name: [] for p in pulls}
    made = _premesh(mesh, labels, sizes, cfg.threads, cfg.jobs)
    meshes, n_steps = [], len(labels) * len(sizes)
    for label in labels:
        verts, tris, _ = hemisphere_surface(mesh, label)
        surf_vol = enclosed_volume(verts, tris)
        for size in sizes:
            bm = mesh_hemisphere(verts, tris, size * 1e-3, threads=cfg.threads)
            prob = build_problem(scene, label, bm)
            t0 = time.perf_counter()
            for p in (p for p in pulls if p.hemisphere == label):
                if cfg.formulation == "neo-hookean":
                    r = neo_hookean_pull(prob, *patches[p.name], np.asarray(p.direction), xs)
                    F[p.name].append(r["force_per_pa"])
                    solves[p.name].append({k: r[k] for k in ("converged", "iterations", "shifts", "min_jacobian", "seconds")})
                else:  # linear: proportional to the displacement
                    F[p.name].append(np.outer(xs, pull_stiffness(prob, *patches[p.name]) @ np.asarray(p.direction)))
            meshes.append(bm.describe() | {"cached": bm.cached and (label, size) not in made, "hemisphere": int(label),
                                           "surface_volume_cm3": surf_vol * 1e6, "volume_error": bm.volume / surf_vol - 1.0,
                                           "p2_nodes": int(prob.fem.n_all), "free_dofs": int(len(prob.fem.free)),
                                           "fixed_corner_nodes": prob.fixed_nodes, "assembly_s": prob.build_s,
                                           "factor_s": prob.factor_s, "solve_s": time.perf_counter() - t0})
            del prob
            if progress is not None:
                progress(len(meshes), n_steps)
    return {k: np.stack(v) for k, v in F.items()}, solves, meshes


def _sample(pull, x: float, f: list, hs: list, sizes: list) -> dict:
    """One sample's convergence record and verdict from its forces on the meshes (coarse to fine)."""
    row = {"pull": pull.name, "displacement_mm": float(x) * 1e3, "forces_n": f, "h_mm": [h * 1e3 for h in hs], "target_edge_mm": sizes}
    if not all(math.isfinite(v) for v in f):  # a nonlinear solve that stopped early
        return row | {"status": "not solved", "order": math.nan, "order_used": math.nan, "fs": math.nan, "extrapolated": False,
                      "force_ext_n": math.nan, "gci": math.nan, "band_n": [math.nan, math.nan], "band_half_n": math.nan,
                      "band_rel": math.nan, "jnd_fraction": math.nan, "within_jnd_rel": False, "within_jnd_abs": False}
    conv = converge(f, hs)
    half = conv["gci"] * f[-1]
    return row | {"order": conv["p"], "order_used": conv["p_used"], "status": conv["status"], "R": conv["R"], "fs": conv["fs"],
                  "extrapolated": conv["extrapolated"], "force_ext_n": conv["f_ext"], "gci": conv["gci"],
                  "band_n": [f[-1] - half, f[-1] + half], "band_half_n": half} | jnd_verdict(f[-1], half)


def run_reference(cfg: ReferenceConfig, progress=None) -> dict:
    """Mesh, solve and extrapolate every pull; returns {"samples", "pulls", "meshes", "meta"}."""
    from analysis.accuracy import AccuracyConfig, sample_displacements
    from sim.reference import scene_with

    t_start = time.perf_counter()
    scene = scene_with(cfg.scene)
    young = float(cfg.young if cfg.young is not None else scene.spec.material.young)
    pulls = _selected_pulls(cfg, scene)
    xs = sample_displacements(AccuracyConfig(max_pull=cfg.max_pull, samples=cfg.samples))
    radius = grasp_radius(scene)
    sizes = sorted((float(s) for s in cfg.sizes_mm), reverse=True)  # coarse to fine
    patches = _patches(cfg, scene.mesh, pulls, radius)
    F, solves, meshes = _solve_meshes(cfg, scene, pulls, patches, xs, sizes, progress)
    h_of = {(m["hemisphere"], m["target_edge_mm"]): m["h_mm"] * 1e-3 for m in meshes}
    samples, pull_rows = [], []
    for p in pulls:
        hs = [h_of[(p.hemisphere, s)] for s in sizes]
        pull_rows.append({"pull": p.name, "hemisphere": p.hemisphere, "grasp_vertex": p.vertex, "patch_points": int(len(patches[p.name][0])),
                          "direction": list(p.direction), "h_mm": [h * 1e3 for h in hs], "force_per_pa": F[p.name].tolist(),
                          "solves": solves[p.name]})
        samples += [_sample(p, x, [float(np.linalg.norm(F[p.name][i, k])) * young for i in range(len(sizes))], hs, sizes)
                    for k, x in enumerate(xs)]
    meta = {"scene": str(cfg.scene), "young_pa": young, "scene_young_pa": scene.spec.material.young, "poisson": scene.spec.material.poisson,
            "element": "P2 (10-node tetrahedra)",
            "formulation": "compressible neo-Hookean" if cfg.formulation == "neo-hookean" else "small-strain linear elasticity",
            "mesher": "fTetWild (pytetwild), shipped meshes where the size is shipped", "envelope_fraction": ENVELOPE_FRACTION,
            "sizes_mm": sizes, "grasp_radius_m": radius, "functional": cfg.functional,
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
            if needs_meshing(verts, tris, s * 1e-3):
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

