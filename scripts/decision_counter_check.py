"""Counter-check solves for the truth's decision rule (docs/reference.md, "Decided"): does the
marginal share of energy outside the data's stretches bound what a law wrong there does to the force?

For each pull (8 mm mesh, the scene's law): the path to `--upto` mm, recording at every 0.5 mm
the force and the support with the marginal share m = dE_out/dE (`sim.models.fem.finite_strain.support`).
At the records whose m is nearest each of `--near`, the pull is solved again to that record

- with the law wrong by a factor of two at the points outside the data at that state (their
  quadrature weights, so their whole energy, times 2 and times 1/2): to first order the force
  moves by +m and -m/2;
- with each of the ensemble's laws that bound the chosen one beyond the data
  (`analysis.verification.truth_band.edge_fits`) and the two-term Ogden fit,

and the relative force change is printed beside m.

    .venv/bin/python scripts/decision_counter_check.py [--pulls left-lateral,test4-across] [--near 0.25,0.4] [--upto 6] [--json FILE]
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from analysis.verification.tissue_pulls import build_problem, grasp_matrix, truth_range
from analysis.verification.truth_band import ensemble
from sim.geometry.patch import patch_area_points
from sim.geometry.tetmesh import hemisphere_surface, mesh_hemisphere
from sim.models.fem import FiniteStrain, hold
from sim.models.fem.finite_strain import point_states, support
from sim.pulls import make_pulls, scene_with, test_pulls
from sim.scene import DEFAULT_SCENE, grasp_radius

FACTORS = (2.0, 0.5)  # the law wrong by a factor of two outside the data, either way


def _force(system, W, direction, x) -> float:
    """The force along the pull holding the patch at x (N per unit of the law's scale), or NaN."""
    res = hold(system, W, direction * x, fractions=(1.0,), first_step=0.1)
    return float(res.forces[-1] @ direction) if res.report.converged else float("nan")


def _moving_set(xs, force, share) -> np.ndarray:
    """d(E_out)/dE with E_out counted at each state's own outside points (the set moving with the
    state), by central differences over the neighbouring records, E the path integral of the
    force (trapezoids from rest): what the marginal share is when points crossing the data's edge
    bring their whole energy with them (a law whose energy jumps there). NaN at the ends."""
    x = np.concatenate([[0.0], xs])
    f = np.concatenate([[0.0], force])
    E = np.cumsum(np.concatenate([[0.0], 0.5 * (f[1:] + f[:-1]) * np.diff(x)]))[1:]
    out = np.full(len(xs), np.nan)
    out[1:-1] = (share[2:] * E[2:] - share[:-2] * E[:-2]) / (E[2:] - E[:-2])
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pulls", default="left-lateral,test4-across,right-lateral,test9-across")
    ap.add_argument("--near", default="0.25,0.4", help="marginal shares to counter-check near, per pull")
    ap.add_argument("--upto", type=float, default=6.0, help="mm")
    ap.add_argument("--size", type=float, default=8.0, help="mesh, mm")
    ap.add_argument("--json", default=None)
    args = ap.parse_args()
    scene = scene_with(DEFAULT_SCENE)
    law = scene.spec.material.law
    rng = truth_range(scene)
    members = [m for m in ensemble(scene.spec.material.law_source, law) if "beyond the data" in m["name"] or m["name"] == "ogden-2 fit"]
    wanted = args.pulls.split(",")
    pulls = [p for p in make_pulls(scene) + test_pulls(scene) if p.name in wanted]
    near = [float(v) for v in args.near.split(",")]
    xs = 0.0005 * np.arange(1, int(round(args.upto / 0.5)) + 1)
    rows = []
    print("| pull | x (mm) | force (N) | energy share | marginal share m | x2 outside (first order +m) | x1/2 outside (first order -m/2) | "
          + " | ".join(m["name"] for m in members) + " |", flush=True)
    for p in pulls:
        t0 = time.perf_counter()
        verts, tris, _ = hemisphere_surface(scene.mesh, p.hemisphere)
        problem = build_problem(scene, p.hemisphere, mesh_hemisphere(verts, tris, args.size * 1e-3))
        W = grasp_matrix(problem, *patch_area_points(scene.mesh, p.vertex, grasp_radius(scene)))
        d = np.asarray(p.direction, dtype=np.float64)
        system = FiniteStrain(problem.space, law)
        path = hold(system, W, d * xs[-1], fractions=xs / xs[-1], first_step=0.05, keep_states=True, sensitivity=True)
        sup = [support(system, u, rng, du) for u, du in zip(path.states, path.sensitivities)]
        m = np.array([s["marginal_share_outside"] for s in sup])
        moving = _moving_set(xs, path.forces @ d, np.array([s["energy_share_outside"] for s in sup]))
        print(f"{p.name}: " + ", ".join(f"{x * 1e3:g} mm m {v:.3f} (moving set {q:.3f}) share {s['energy_share_outside']:.3f} "
                                       f"|J-1| {s['max_abs_j_minus_1']:.3f} fine {s['max_abs_j_minus_1_fine']:.3f}"
                                       for x, v, q, s in zip(xs, m, moving, sup)), flush=True)
        picks = sorted({int(np.nanargmin(np.abs(m - v))) for v in near})
        for i in picks:
            x, f0 = xs[i], float(path.forces[i] @ d)
            st = point_states(system, path.states[i])
            outside = (st["stretches"].min(axis=-1) < rng[0]) | (st["stretches"].max(axis=-1) > rng[1])
            changes = []
            for factor in FACTORS:
                wrong = FiniteStrain(problem.space, law)
                wrong.wq = np.where(outside, factor, 1.0) * wrong.wq  # the law times `factor` at those points
                changes.append(_force(wrong, W, d, x) / f0 - 1.0)
            for mem in members:
                changes.append(_force(FiniteStrain(problem.space, mem["law"]), W, d, x) / f0 - 1.0)
            row = {"pull": p.name, "x_mm": x * 1e3, "force_n": f0, "energy_share": sup[i]["energy_share_outside"], "marginal_share": float(m[i]),
                   "moving_set_share": float(moving[i]),
                   "energy_rate_over_force": sup[i]["energy_rate"] / f0, "max_abs_j_minus_1": sup[i]["max_abs_j_minus_1"],
                   "max_abs_j_minus_1_fine": sup[i]["max_abs_j_minus_1_fine"], "factor_2": changes[0], "factor_half": changes[1],
                   "members": {mem["name"]: c for mem, c in zip(members, changes[2:])}}
            rows.append(row)
            print(f"| {p.name} | {x * 1e3:g} | {f0:.4f} | {row['energy_share']:.3f} | {m[i]:.3f} | {changes[0]:+.3f} | {changes[1]:+.3f} | "
                  + " | ".join(f"{c:+.3f}" for c in changes[2:]) + f" |  ({time.perf_counter() - t0:.0f} s)", flush=True)
    if args.json:
        with open(args.json, "w") as fh:
            json.dump({"rows": rows, "members": [m["name"] for m in members]}, fh, indent=1)


if __name__ == "__main__":
    main()
