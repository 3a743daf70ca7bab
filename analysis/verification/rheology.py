"""The viscoelastic truth's law (`sim.material.Viscoelastic`) against the measured curves beneath it: its
loading curves along the source tests' paths (uniaxial tension and compression with free lateral
faces to stretch 1.1 and 0.9, simple shear to 0.2), each a constant-rate ramp from rest lasting
`ramp_s`, solved on a homogeneous cube by the project's FEM (`newton.follow`), and their errors on
the curves (Budday et al. 2017, Acta Biomaterialia 48). The quasi-static curves were measured at
a finite rate, so the law matches them at the ramp time of those tests, not at rest: this is where
the published moduli and times meet the hyperelastic truth (docs/viscoelastic.md).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import scipy.sparse as sp
from scipy.optimize import least_squares
from scipy.stats import t as student_t

from analysis.verification.material_fit import Curve, read_curve
from sim.hyperelastic import ogden
from sim.material import Branch, Viscoelastic
from sim.models.fem import TetSpace, ViscoelasticStrain, follow


def _cube_uniaxial():
    """A unit P1 cube (6 tetrahedra), the face x = 0 sliding, rigid motions held at three corners;
    the face x = 1 moved along x (W's rows)."""
    nodes = np.array([[i, j, k] for i in (0, 1) for j in (0, 1) for k in (0, 1)], dtype=np.float64)
    tets = np.array([[0, 4, 6, 7], [0, 4, 5, 7], [0, 1, 5, 7], [0, 1, 3, 7], [0, 2, 3, 7], [0, 2, 6, 7]])
    e = nodes[tets[:, 1:]] - nodes[tets[:, :1]]
    flip = np.linalg.det(e) < 0
    tets[flip] = tets[flip][:, [0, 2, 1, 3]]  # every tetrahedron positively oriented
    fixed = np.zeros((8, 3), bool)
    fixed[nodes[:, 0] == 0, 0] = True
    fixed[0] = True
    fixed[2, 2] = True  # (0, 1, 0)
    fixed[1, 1] = True  # (0, 0, 1)
    space = TetSpace(nodes, tets, fixed, 1)
    col = -np.ones(3 * space.n_all, dtype=np.int64)
    col[space.free] = np.arange(len(space.free))
    top = np.flatnonzero(nodes[:, 0] == 1)
    rows = col[3 * top]
    return space, sp.csr_matrix((np.ones(len(rows)), (np.arange(len(rows)), rows)), shape=(len(rows), len(space.free)))


def uniaxial_ramp(law: Viscoelastic, stretches, ramp_s: float, steps: int = 200) -> np.ndarray:
    """Nominal stress (Pa) at each of `stretches` (all on one side of 1) along a constant-rate ramp
    from rest to the farthest of them in `ramp_s` s, lateral faces free; NaN past a failed solve."""
    x = np.asarray(stretches, dtype=np.float64)
    end = x[np.argmax(np.abs(x - 1.0))]
    times = np.arange(1, steps + 1) * ramp_s / steps
    space, W = _cube_uniaxial()
    res = follow(ViscoelasticStrain(space, law), W, times, [np.full(W.shape[0], (end - 1.0) * t / ramp_s) for t in times], tol=1e-10)
    path = np.concatenate([[0.0], res.forces.sum(axis=1)])  # the face's reference area is 1 m^2
    along = np.concatenate([[1.0], 1.0 + (end - 1.0) * times / ramp_s])
    order = np.argsort(along)
    return np.interp(x, along[order], path[order])


def shear_ramp(law: Viscoelastic, gammas, ramp_s: float, steps: int = 200) -> np.ndarray:
    """Shear stress P_12 (Pa) at each of `gammas` (one sign) along a constant-rate simple-shear ramp
    from rest to the largest in `ramp_s` s: F prescribed (J = 1), so every point is the cube's."""
    g = np.asarray(gammas, dtype=np.float64)
    end = g[np.argmax(np.abs(g))]
    space, _ = _cube_uniaxial()
    X = space.all_nodes
    system = ViscoelasticStrain(space, law)
    dt = ramp_s / steps
    path = [0.0]
    for k in range(1, steps + 1):
        F = np.eye(3)
        F[0, 1] = end * k / steps
        u = ((F - np.eye(3)) @ X.T).T.ravel()
        system.step(dt)
        f = system.evaluate(u, tangent=False)["f"].reshape(-1, 3)
        system.commit(u)
        path.append(float((f.T @ X)[0, 1]))  # P = sum_a f_a X_a / V, V = 1
    along = end * np.arange(steps + 1) / steps
    order = np.argsort(along)
    return np.interp(g, along[order], np.asarray(path)[order])


def _sides(c: Curve):
    """The curve's branches loaded from rest: (mask, end) per side of the unloaded point."""
    rest = 0.0 if c.mode == "shear" else 1.0
    for side in (c.x < rest, c.x > rest):
        if side.any():
            yield side, float(c.x[side][np.argmax(np.abs(c.x[side] - rest))]) - rest


def ramp_prediction(law: Viscoelastic, c: Curve, rate: float, steps: int = 200) -> np.ndarray:
    """The law's stress at each of the curve's points, every side loaded from rest at `rate` (1/s:
    stretch - 1, or shear strain, per second); 0 at the unloaded point."""
    pred = np.zeros_like(c.stress)
    for side, extent in _sides(c):
        ramp = (shear_ramp if c.mode == "shear" else uniaxial_ramp)
        pred[side] = ramp(law, c.x[side], abs(extent) / rate, steps)
    return pred


def fit_rheology(paths, region: str, mu_inf: float, mu_1: float, tau_1: float, kappa: float, alpha_start: float,
                 steps: int = 100, final_steps: int = 400, progress=None) -> dict:
    """The exponent alpha (both branches': fitted apart, the branch's is not identified, its 95%
    interval spanning +-100, since at the tests' rates the branch has mostly relaxed) and the tests'
    loading rate (one strain rate for every mode) that fit the law of published moduli `mu_inf`,
    `mu_1` (Pa), time `tau_1` (s) and bulk modulus `kappa` to `region`'s curves in the data files,
    each file's residuals over its data's RMS (as `material_fit.fit_law`): least squares from
    `alpha_start` and 1/300 s; errors per mode with `final_steps` steps a ramp."""
    curves = [read_curve(p, region) for p in paths]
    weights = [1.0 / float(np.sqrt(np.mean(c.stress**2))) for c in curves]

    def law_of(x):
        return Viscoelastic(ogden([mu_inf], [x[0]], kappa / mu_inf), (Branch(mu_1, float(x[0]), tau_1),))

    def residual(x, n=steps):
        law = law_of(x)
        return np.concatenate([(ramp_prediction(law, c, 10.0 ** x[1], n) - c.stress) * w for c, w in zip(curves, weights)])

    if progress:
        progress(0, 1)
    best = least_squares(residual, [alpha_start, math.log10(1.0 / 300.0)], bounds=([-60.0, -4.0], [-0.5, 0.0]),
                         x_scale=[10.0, 1.0], diff_step=1e-4)
    law, rate = law_of(best.x), 10.0 ** best.x[1]
    res = residual(best.x, final_steps)
    n, k = len(res), 2
    rss = max(float(np.sum(res**2)), 1e-300)
    try:
        half = student_t.ppf(0.975, n - k) * np.sqrt(np.clip(np.diag(np.linalg.inv(best.jac.T @ best.jac) * rss / (n - k)), 0.0, None))
    except np.linalg.LinAlgError:
        half = np.full(k, np.inf)
    errors = {}
    for c in curves:
        pred = ramp_prediction(law, c, rate, final_steps)
        for mode in np.unique(c.modes()):
            m = c.modes() == mode
            errors[str(mode)] = float(np.sqrt(np.mean((pred[m] - c.stress[m]) ** 2)) / np.sqrt(np.mean(c.stress[m] ** 2)))
    ramps = {("shear" if c.mode == "shear" else "tension" if e > 0 else "compression"): abs(e) / rate for c in curves for _, e in _sides(c)}
    return {"law": law, "alpha": float(best.x[0]), "rate_per_s": rate,
            "ci95": {"alpha": [float(best.x[0] - half[0]), float(best.x[0] + half[0])],
                     "rate_per_s": [10.0 ** (best.x[1] - half[1]), 10.0 ** (best.x[1] + half[1])]},
            "ramp_s": ramps, "rms_rel": errors, "converged": bool(best.success), "points": n,
            "published": {"mu_inf": mu_inf, "mu_1": mu_1, "tau_1": tau_1}, "bulk_modulus": kappa}


def rheology_provenance(rep: dict, paths, region: str, source: str, command: str) -> dict:
    """A rheology file's [provenance]: the data files and their SHA-256, the published source, the
    fitted exponent and rate with their intervals, each mode's error, the command."""
    curves = [read_curve(p, region) for p in paths]
    return {"data": [Path(c.path).name for c in curves], "sha256": [c.sha256 for c in curves], "region": region,
            "source": source, "fit": "published mu_inf, mu_1, tau_1 and kappa kept; one alpha for both branches and the tests' strain "
            "rate fitted (constant-rate ramps from rest, uniaxial with free lateral faces and simple shear, FEM cube), each file's "
            "residuals over its data's RMS", "alpha": rep["alpha"], "ci95_alpha": rep["ci95"]["alpha"],
            "rate_per_s": rep["rate_per_s"], "ci95_rate_per_s": rep["ci95"]["rate_per_s"],
            **{f"ramp_s_{m}": t for m, t in rep["ramp_s"].items()}, **{f"rms_rel_{m}": e for m, e in rep["rms_rel"].items()},
            "command": command}
