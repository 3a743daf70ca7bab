"""What a nonlinear FEM condition would need: the tissue's law solved statically (Newton to
convergence at every sample, no frame budget) on the accuracy bench's pulls, judged against
the reference like the bench's rows, and the cost of one Newton iteration beside the frame
budget. `python -m bench fem_static [--json]` (keys `fem_static.<element>.*`; about 15 min
on 2 cores, most of it the nodal-pressure solves).

Elements, on the shipped 8 mm body-fitted meshes:
- `p1-8mm`: linear tetrahedra, displacement-based (locks at kappa = 50 mu);
- `p1-nodal-pressure-8mm`: linear tetrahedra with averaged nodal volumes
  (`sim.models.fem.nodal_pressure`);
- `p2-8mm`: quadratic tetrahedra, read from the shipped reference solves. This is one of the
  three meshes the reference is extrapolated from, so its score measures the reference's own
  discretisation error, not an independent model.
"""

from __future__ import annotations

import math
import time

import numpy as np

from bench.common import main_with_json

SIZE_MM = 8.0


def _score(ref_mag: np.ndarray, mag: np.ndarray, n_calib: int) -> dict:
    """Within the JND and mean error on the test pulls, raw and with the bench's one scale."""
    from analysis.verification.accuracy import calibration_scale
    from sim.perception import force_jnd

    scale = calibration_scale(mag[:n_calib].ravel(), ref_mag[:n_calib].ravel())
    out = {"scale": scale}
    r = ref_mag[n_calib:]
    judged = np.isfinite(r) & np.isfinite(mag[n_calib:])
    for name, s in (("raw", 1.0), ("calibrated", scale)):
        err = np.abs(s * mag[n_calib:] - r)[judged] / r[judged]
        out[name] = {"within_jnd": float(np.mean(err <= force_jnd(r[judged]))), "force_error": float(np.mean(err)), "n": int(judged.sum())}
    return out


def _iteration_cost(space, system) -> dict:
    """ms of one Newton iteration's parts: forces, tangent, factorisation, solve. At a smooth 2%
    strain (at rest the law's eigen-solver ends at once and the passes look 3x cheaper)."""
    from sim.linalg import Factor

    X = np.asarray(space.all_nodes, dtype=np.float64)
    A = 0.02 * np.array([[1.0, 0.3, -0.2], [0.1, -0.5, 0.4], [-0.3, 0.2, 0.6]])
    u = ((X - X.mean(axis=0)) @ A.T).ravel()
    system.evaluate(u, tangent=True)  # compile and warm
    t0 = time.perf_counter()
    system.evaluate(u, tangent=False)
    t1 = time.perf_counter()
    K = system.evaluate(u, tangent=True)["K"]
    t2 = time.perf_counter()
    F = Factor(K)
    t3 = time.perf_counter()
    F.solve(np.ones(K.shape[0]))
    t4 = time.perf_counter()
    return {"forces_ms": (t1 - t0) * 1e3, "tangent_ms": (t2 - t1) * 1e3, "factor_ms": (t3 - t2) * 1e3, "solve_ms": (t4 - t3) * 1e3,
            "free_dofs": int(len(space.free))}


def measure() -> dict:
    from analysis.verification.accuracy import AccuracyConfig, reference_samples, sample_displacements
    from analysis.verification.truth_band import truth_samples
    from sim.geometry.patch import patch_area_points
    from sim.geometry.tetmesh import hemisphere_surface, mesh_hemisphere
    from sim.geometry.volume import locate
    from sim.models.api import BUDGETS
    from sim.models.fem import FiniteStrain, TetSpace, constraint_matrix, hold
    from sim.models.fem.nodal_pressure import NodalPressure
    from sim.pulls import make_pulls, scene_with, test_pulls
    from sim.scene import clamp_limit, grasp_radius

    cfg = AccuracyConfig()
    scene = scene_with(cfg.scene)
    law = scene.spec.material.law
    mu = law.shear_modulus
    unit = law.scaled(1.0 / mu)
    calib, test = make_pulls(scene), test_pulls(scene, cfg.test_places)
    pulls = calib + test
    xs = sample_displacements(cfg)
    truth = truth_samples(cfg.scene, pulls, xs, cfg.reference_sizes_mm)
    refs = truth["refs"]
    ref = reference_samples(truth, pulls)
    # judged where the truth is decided (analysis.verification.truth_band), as the accuracy bench does
    ref_mag = np.array([[c["force_n"] if c["decided"] else math.nan for c in row] for row in ref])
    sizes = list(refs["sizes_mm"])
    radius = grasp_radius(scene)
    axis, limit = clamp_limit(scene)
    budget = BUDGETS["deformation_ms_p99"]
    out = {"budget_ms": budget, "samples": int(np.isfinite(ref_mag[len(calib):]).sum()), "elements": {}}
    p2 = np.array([[np.linalg.norm(refs["pulls"][p.name]["force_per_pa"][sizes.index(SIZE_MM)][k]) * mu for k in range(len(xs))] for p in pulls])
    out["elements"]["p2-8mm"] = _score(ref_mag, p2, len(calib)) | {"note": "one of the reference's own meshes"}
    print(f"fem_static: {out['samples']} held-out samples where the truth is decided; frame budget {budget:g} ms (p99)")
    for name, make in (("p1-8mm", lambda s: FiniteStrain(s, unit, mean_dilatation=False)), ("p1-nodal-pressure-8mm", lambda s: NodalPressure(s, unit))):
        mag = np.full((len(pulls), len(xs)), math.nan)
        spaces: dict = {}
        t0 = time.perf_counter()
        stopped = 0
        for j, pull in enumerate(pulls):
            if pull.hemisphere not in spaces:
                verts, tris, _ = hemisphere_surface(scene.mesh, pull.hemisphere)
                body = mesh_hemisphere(verts, tris, SIZE_MM * 1e-3)
                space = TetSpace(body.nodes, body.tets, body.nodes[:, axis] <= limit, order=1)
                spaces[pull.hemisphere] = (body, space, make(space))
            body, space, system = spaces[pull.hemisphere]
            points, weights = patch_area_points(scene.mesh, pull.vertex, radius)
            tet, bary = locate(body.nodes, body.tets, np.atleast_2d(points))
            W = constraint_matrix(space, tet, bary, weights)
            held = hold(system, W, np.asarray(pull.direction) * xs[-1], fractions=xs / xs[-1], first_step=min(0.25, 2 * xs[0] / xs[-1]))
            stopped += int(not held.report.converged)
            mag[j] = np.linalg.norm(held.forces, axis=1) * mu  # NaN where a solve stopped
        _, space, system = spaces[min(spaces)]
        row = _score(ref_mag, mag, len(calib)) | {"solve_s": time.perf_counter() - t0, "stopped_pulls": stopped,
                                                   "iteration": _iteration_cost(space, system)}
        out["elements"][name] = row
    body = spaces[min(spaces)][0]
    p2_space = TetSpace(body.nodes, body.tets, body.nodes[:, axis] <= limit, order=2)
    out["elements"]["p2-8mm"]["iteration"] = _iteration_cost(p2_space, FiniteStrain(p2_space, unit, mean_dilatation=False))
    for name, row in out["elements"].items():
        it = row["iteration"]
        newton = it["forces_ms"] + it["tangent_ms"] + it["factor_ms"] + it["solve_ms"]
        row["newton_iteration_ms"] = newton
        print(f"  {name:24s} raw {row['raw']['within_jnd']:4.0%} within JND (error {row['raw']['force_error']:6.1%}), "
              f"calibrated x{row['scale']:.3g} {row['calibrated']['within_jnd']:4.0%} (error {row['calibrated']['force_error']:6.1%}); "
              f"one Newton iteration {newton:7.1f} ms = {newton / budget:5.1f} x the frame budget (forces {it['forces_ms']:.1f}, "
              f"tangent {it['tangent_ms']:.1f}, factor {it['factor_ms']:.1f}, solve {it['solve_ms']:.1f} ms; {it['free_dofs']} unknowns)"
              + (f"; {row['stopped_pulls']} solves stopped" if row.get("stopped_pulls") else "") + (f" [{row['note']}]" if "note" in row else ""))
    return out


def flat(out: dict) -> dict:
    keys = {"fem_static.budget_ms": out["budget_ms"]}
    for name, row in out["elements"].items():
        for cal in ("raw", "calibrated"):
            keys[f"fem_static.{name}.{cal}.within_jnd"] = row[cal]["within_jnd"]
            keys[f"fem_static.{name}.{cal}.force_error"] = row[cal]["force_error"]
        keys[f"fem_static.{name}.scale"] = row["scale"]
        keys[f"fem_static.{name}.newton_iteration_ms"] = row["newton_iteration_ms"]
        keys[f"fem_static.{name}.newton_iteration.ratio_to_budget"] = row["newton_iteration_ms"] / out["budget_ms"]
    return keys


def main() -> None:
    main_with_json(measure, flat)


if __name__ == "__main__":
    main()
