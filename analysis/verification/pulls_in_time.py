"""The truth's pulls in time: the scene's brain grasped and pulled at a constant speed to the
bench's largest displacement, then held, its tissue the finite viscoelastic law of each region
(`sim.material.Viscoelastic`: the rheology files beside the hyperelastic ones), solved by
`newton.follow` (docs/viscoelastic.md). The force is recorded at every sample of the ramp and at
the hold's times; per pascal of the grey matter's equilibrium shear modulus (the law's force
scales with its moduli along any history, the times kept).
"""

from __future__ import annotations

import time

import numpy as np

from analysis.verification.tissue_pulls import Problem, grasp_matrix
from brainsim_assets import path as _asset
from sim.errors import ParameterError
from sim.geometry.regions import WHITE, quadrature_regions, white_surfaces
from sim.material import Viscoelastic, read_rheology
from sim.models.fem import ViscoelasticStrain, follow

GREY_RHEOLOGY = _asset("protocols/materials/human_cortex_rheology.toml")
WHITE_RHEOLOGY = _asset("protocols/materials/human_white_matter_rheology.toml")
HOLDS_S = (0.25, 0.5, 1.0, 2.0, 5.0)  # s after the ramp's end: a person's hold (about 1 s) and the relaxation beyond
MAX_DT_S = 0.1  # the longest time step (the implicit step is first order: docs/viscoelastic.md)


def shipped_rheology() -> tuple[Viscoelastic, Viscoelastic]:
    """(grey, white) of the shipped rheology files."""
    return read_rheology(GREY_RHEOLOGY)[0], read_rheology(WHITE_RHEOLOGY)[0]


def record_times(xs, speed: float, holds=HOLDS_S) -> tuple[np.ndarray, np.ndarray]:
    """(times s, displacements m) of a ramp at `speed` (m/s) through the samples `xs` (m), then
    held at the last for each of `holds` (s after the ramp's end)."""
    xs = np.asarray(xs, dtype=np.float64)
    if not speed > 0 or xs.ndim != 1 or np.any(np.diff(xs) <= 0) or xs[0] <= 0:
        raise ParameterError("a pull in time: a positive speed (m/s) and increasing positive samples (m)")
    ramp = xs / speed
    return np.concatenate([ramp, ramp[-1] + np.asarray(holds, dtype=np.float64)]), np.concatenate([xs, np.full(len(holds), xs[-1])])


def solve_pull_in_time(problem: Problem, grey: Viscoelastic, white: Viscoelastic | None, points, weights, direction, xs, speed: float,
                       holds=HOLDS_S, max_dt: float = MAX_DT_S) -> dict:
    """The pull along `direction` at `speed` through `xs`, then held (`record_times`), on the
    problem's hemisphere with `grey` (and `white` inside the white surface): the force holding the
    patch's mean displacement at each record per pascal of grey's equilibrium modulus
    ((records, 3), the force on the tissue; NaN from where the solve stopped) and the solve's
    account."""
    times, xs_all = record_times(xs, speed, holds)
    W = grasp_matrix(problem, points, weights)
    unit = 1.0 / grey.equilibrium.shear_modulus
    laws, law_of = grey.scaled(unit), None
    if white is not None:
        law_of = (quadrature_regions(problem.mesh.nodes, problem.mesh.tets, problem.space.element.POINTS, problem.label, white_surfaces())
                  == WHITE).astype(np.int64)
        laws = [grey.scaled(unit), white.scaled(unit)]
    t0 = time.perf_counter()
    system = ViscoelasticStrain(problem.space, laws, law_of=law_of)
    res = follow(system, W, times, np.asarray(direction, dtype=np.float64)[None, :] * xs_all[:, None], max_dt=max_dt)
    rep = res.report
    return {"times_s": times, "x_m": xs_all, "force_per_pa": res.forces, "converged": bool(rep.converged), "reason": rep.reason,
            "steps": int(rep.load_steps), "cut_steps": int(rep.cut_steps), "iterations": int(sum(rep.iterations)),
            "min_jacobian": float(rep.min_jacobian), "seconds": time.perf_counter() - t0, "free_dofs": int(len(problem.space.free)),
            "speed_m_s": float(speed), "max_dt_s": float(max_dt)}
