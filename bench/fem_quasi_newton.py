"""A method tried for a real-time finite-strain FEM (issue 44), measured: the tissue's law on
P1 with nodal pressures (`sim.models.fem.nodal_pressure`, 8 mm), advanced along the accuracy
bench's ramp one visual frame at a time by a quasi-Newton method that never refactorises.

Each frame: the grasp moves to its new place through the rest tangent's response (the
condensed constraint, as the corotational frame does), then `iterations` L-BFGS steps on the
energy with the constraint held. L-BFGS keeps `memory` pairs across frames; its initial
inverse is the rest tangent's factor, projected onto W du = 0 (Liu, Bouaziz and Kavan 2017
use the rest factor the same way for hyperelastic projective dynamics). An Armijo line search
halves a step that does not decrease the energy. The force is the multiplier of the last
gradient. Judged against the same element solved to convergence (`newton.hold`) at the
bench's sample displacements, so what is measured is the frame iteration's error, not the
element's. `python -m bench fem_quasi_newton [--json]` (about 5 min on 2 cores); not in the
default run.
"""

from __future__ import annotations

import time

import numpy as np

from bench.common import main_with_json

SETTINGS = ((2, 8), (1, 16))  # (iterations a frame, L-BFGS memory)
PULLS = ("test1-across", "left-lateral")  # a held-out pull and a calibration pull
MAX_HALVINGS = 10


def _frames(system, factor, W, U, Ci, direction, xs, per_sample: int, iterations: int, memory: int) -> dict:
    free = system.free
    u = np.zeros(3 * system.space.n_all)
    pairs: list = []

    def precond(g):
        z = factor.solve(g)
        lam = Ci @ (W @ z)
        return z - U @ lam, lam

    def precond_project(r):
        return r - U @ (Ci @ (W @ r))

    forces, frame_s, evals, failed, drift = [], [], 0, 0, 0.0
    n = per_sample * len(xs)
    for f in range(1, n + 1):
        t0 = time.perf_counter()
        d = direction * xs[-1] * f / n
        moved = u.copy()
        moved[free] += U @ (Ci @ (d - W @ u[free]))
        st = system.evaluate(moved, tangent=False)
        evals += 1
        if np.isfinite(st["energy"]):
            u = moved
        else:  # the rest response inverted an element: stay, and let the iterations move it
            st = system.evaluate(u, tangent=False)
            evals += 1
        g = st["f"][free]
        for _ in range(iterations):
            q, coef = g.copy(), []
            for s, y, rho in reversed(pairs):  # L-BFGS two-loop recursion
                a = rho * (s @ q)
                coef.append(a)
                q -= a * y
            r, _ = precond(q)
            for (s, y, rho), a in zip(pairs, reversed(coef)):
                r += s * (a - rho * (y @ r))
            # back onto W du = 0: the recursion's corrections carry each earlier step's round-off
            # off the constraint and amplify it step after step (on some machines, with some
            # BLAS, the grasp had drifted by millimetres within a frame); the projector removes it
            p = -precond_project(r)
            slope = float(g @ p)
            if slope >= 0:  # not a descent direction: drop the history
                pairs.clear()
                p = -precond(g)[0]
                slope = float(g @ p)
            alpha = 1.0
            for _ in range(MAX_HALVINGS):
                trial = u.copy()
                trial[free] += alpha * p
                sn = system.evaluate(trial, tangent=False)
                evals += 1
                if np.isfinite(sn["energy"]) and sn["energy"] <= st["energy"] + 1e-4 * alpha * slope + 1e-12 * abs(st["energy"]):
                    break
                alpha *= 0.5
            else:
                failed += 1
                break
            gn = sn["f"][free]
            s, y = alpha * p, gn - g
            if s @ y > 1e-12 * np.linalg.norm(s) * np.linalg.norm(y):
                pairs = (pairs + [(s, y, 1.0 / float(s @ y))])[-memory:]
            u, st, g = trial, sn, gn
        lam = precond(g)[1]
        frame_s.append(time.perf_counter() - t0)
        drift = max(drift, float(np.linalg.norm(W @ u[free] - d)))
        if f % per_sample == 0:
            forces.append(float(np.linalg.norm(lam)))
    return {"forces": forces, "frame_ms_p50": float(np.percentile(frame_s, 50) * 1e3), "frame_ms_p99": float(np.percentile(frame_s, 99) * 1e3),
            "evaluations_per_frame": evals / n, "line_search_failures": failed,
            "constraint_drift_m": drift}


def measure() -> dict:
    from analysis.verification.accuracy import AccuracyConfig, sample_displacements
    from analysis.verification.bench_pulls import frames_per_sample
    from sim.linalg import Factor
    from sim.models.api import BUDGETS
    from sim.models.fem.newton import hold
    from sim.models.fem.nodal_pressure import NodalPressure
    from sim.models.registry import model_class
    from sim.pulls import make_pulls, scene_with, test_pulls

    cfg = AccuracyConfig()
    scene = scene_with(cfg.scene)
    pulls = {p.name: p for p in make_pulls(scene) + test_pulls(scene, cfg.test_places)}
    xs = sample_displacements(cfg)
    per_sample = frames_per_sample(xs, scene.spec.visual_rate_hz)
    # the model only supplies the 8 mm hemisphere and the grasp's constraint
    model = model_class("fem").build(scene.mesh, scene.spec.options_of("fem") | {"formulation": "linear", "resolution": 0.008, "order": 1}, scene)
    out = {"budget_ms": BUDGETS["deformation_ms_p99"], "samples_mm": [float(x * 1e3) for x in xs], "pulls": {}}
    for name in PULLS:
        pull = pulls[name]
        contact = model.grasp(pull.point, 0)
        system = NodalPressure(model.parts[contact.data.part], scene.spec.material.law)
        factor = Factor(system.evaluate(np.zeros(3 * system.space.n_all))["K"])  # the rest tangent
        W = contact.data.W.tocsr()
        U = factor.solve(np.ascontiguousarray(W.T.toarray()))
        Ci = np.linalg.inv(W @ U)
        direction = np.asarray(pull.direction)
        static = np.linalg.norm(hold(system, W, direction * xs[-1], fractions=xs / xs[-1], first_step=0.1).forces, axis=1)
        row = {"static_n": static.tolist(), "settings": {}}
        for iterations, memory in SETTINGS:
            r = _frames(system, factor, W, U, Ci, direction, xs, per_sample, iterations, memory)
            err = np.asarray(r["forces"]) / static - 1.0
            r["error"] = err.tolist()
            row["settings"][f"{iterations}it-m{memory}"] = r
            print(f"fem_quasi_newton {name}, {iterations} iteration(s) a frame, memory {memory}: frame p50 {r['frame_ms_p50']:.0f} ms, "
                  f"p99 {r['frame_ms_p99']:.0f} ms ({r['frame_ms_p99'] / out['budget_ms']:.1f}x the {out['budget_ms']:g} ms budget), "
                  f"{r['evaluations_per_frame']:.1f} energy evaluations a frame; force against the converged element: "
                  + ", ".join(f"{x:g} mm {e:+.0%}" for x, e in zip(out["samples_mm"], err)), flush=True)
        out["pulls"][name] = row
    return out


def flat(out: dict) -> dict:
    keys = {"fem_quasi_newton.budget_ms": out["budget_ms"]}
    for name, row in out["pulls"].items():
        for setting, r in row["settings"].items():
            k = f"fem_quasi_newton.{name}.{setting}"
            keys |= {f"{k}.frame_ms_p50": r["frame_ms_p50"], f"{k}.frame_ms_p99": r["frame_ms_p99"],
                     f"{k}.frame_ms_p99.ratio_to_budget": r["frame_ms_p99"] / out["budget_ms"],
                     f"{k}.evaluations_per_frame": r["evaluations_per_frame"], f"{k}.max_abs_error": float(np.max(np.abs(r["error"])))}
    return keys


def main() -> None:
    main_with_json(measure, flat)


if __name__ == "__main__":
    main()
