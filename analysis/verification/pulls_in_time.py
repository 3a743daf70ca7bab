"""The truth's pulls in time: the scene's brain grasped and pulled at a constant speed to the
bench's largest displacement, then held, its tissue the finite viscoelastic law of each region
(`sim.material.Viscoelastic`: the shipped rheology files, whatever hyperelastic law the scene
names; white matter where the scene has it; no pia-arachnoid yet), solved by
`newton.follow` (docs/viscoelastic.md). The force is recorded at every sample of the ramp and at
the hold's times; per pascal of the grey matter's equilibrium shear modulus (the law's force
scales with its moduli along any history, the times kept).
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from analysis.verification.solve_keys import keyed_solves, pull_in_time_key
from analysis.verification.tissue_pulls import Problem, build_problem, grasp_matrix
from brainsim_assets import path as _asset
from sim.errors import ParameterError
from sim.files import save_npz
from sim.geometry.patch import patch_area_points
from sim.geometry.regions import WHITE, quadrature_regions, white_surfaces
from sim.geometry.tetmesh import hemisphere_surface, mesh_hemisphere
from sim.geometry.volume import cache_dir
from sim.material import Viscoelastic, read_rheology
from sim.models.fem import ViscoelasticStrain, follow
from sim.models.fem.finite_strain import point_states, stress_power
from sim.pulls import scene_with
from sim.scene import grasp_radius

GREY_RHEOLOGY = _asset("protocols/materials/human_cortex_rheology.toml")
WHITE_RHEOLOGY = _asset("protocols/materials/human_white_matter_rheology.toml")
HOLDS_S = (0.25, 0.5, 1.0, 2.0)  # s after the ramp's end: a person's hold (0.9 to 1.3 s, data/pull_speeds.json) and beyond
MAX_DT_S = 0.1  # the longest time step (the implicit step is first order: docs/viscoelastic.md)
# each step's Newton residual: its force moves the recorded forces by 1e-5 of themselves (against
# 1e-8's, measured), far below the first-order step's 0.4%, for a quarter fewer iterations
FOLLOW_TOL = 1e-4
SHIPPED = _asset("data/reference_pulls_in_time.npz")
PARTS = ("times_s", "x_m", "force_per_pa", "rate_share_outside", "strain_rate_per_s")  # a solve's arrays, per record
SHIPPED_INFO = _asset("data/reference_pulls_in_time.json")


def shipped_rheology() -> tuple[Viscoelastic, Viscoelastic]:
    """(grey, white) of the shipped rheology files."""
    return read_rheology(GREY_RHEOLOGY)[0], read_rheology(WHITE_RHEOLOGY)[0]


def data_rates(white: bool = True) -> tuple[float, ...]:
    """(grey, white), or (grey,) without `white`: the fastest strain rate (1/s) the shipped rheology's data were measured at,
    the upper end of the 95% interval of the tests' rate `calibrate rheology` fitted (a uniaxial
    ramp's axial rate: its equivalent Hencky rate; a shear ramp's is 1/sqrt(3) of it)."""
    return tuple(float(read_rheology(f)[1]["ci95_rate_per_s"][1]) for f in ((GREY_RHEOLOGY, WHITE_RHEOLOGY) if white else (GREY_RHEOLOGY,)))


def _hencky(s: dict) -> np.ndarray:
    lam, N = s["stretches"], s["directions"]
    return np.einsum("mqai,mqi,mqbi->mqab", N, np.log(lam), N)


def rate_support(system, states, times, rate_limit) -> tuple[np.ndarray, np.ndarray]:
    """Per record (the states at `times`, from rest at t = 0): the share of the equilibrium
    stress's power P : dF between the record and the one before at quadrature points straining
    faster than `rate_limit` (1/s, one per law: the data's fastest; the equivalent Hencky rate
    sqrt(2/3) |dE| / dt), carried as the largest so far (a force remembers its history for about
    tau), and the power-weighted median rate (1/s). The marginal share of the stretch rule (`finite_strain.support`), in rate."""
    limit = np.asarray(rate_limit, dtype=np.float64).reshape(-1)[np.minimum(system.law_of, np.size(rate_limit) - 1)]
    share, median = np.full(len(times), np.nan), np.full(len(times), np.nan)
    u_prev, E_prev, t_prev, worst = np.zeros_like(states[0]) if states else None, 0.0, 0.0, 0.0
    for k, u in enumerate(states):
        s = point_states(system, u)
        E = _hencky(s)
        rate = np.sqrt(2.0 / 3.0) * np.linalg.norm(E - E_prev, axis=(-2, -1)) / (times[k] - t_prev)
        power = np.abs(stress_power(system, s, u - u_prev)) * s["weights"]
        total = float(np.sum(power))
        if total > 0:
            worst = max(worst, float(np.sum(power[rate > limit]) / total))
            order = np.argsort(rate, axis=None)
            cum = np.cumsum(power.ravel()[order])
            median[k] = float(rate.ravel()[order][np.searchsorted(cum, 0.5 * total)])
        share[k] = worst
        u_prev, E_prev, t_prev = u, E, times[k]
    return share, median


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
    res = follow(system, W, times, np.asarray(direction, dtype=np.float64)[None, :] * xs_all[:, None], max_dt=max_dt, tol=FOLLOW_TOL,
                 keep_states=True)
    rep = res.report
    share, rate = np.full(len(times), np.nan), np.full(len(times), np.nan)
    share[: len(res.states)], rate[: len(res.states)] = rate_support(system, res.states, times[: len(res.states)],
                                                                     data_rates(white is not None))
    return {"times_s": times, "x_m": xs_all, "force_per_pa": res.forces, "rate_share_outside": share, "strain_rate_per_s": rate,
            "converged": bool(rep.converged), "reason": rep.reason,
            "steps": int(rep.load_steps), "cut_steps": int(rep.cut_steps), "iterations": int(sum(rep.iterations)),
            "min_jacobian": float(rep.min_jacobian), "seconds": time.perf_counter() - t0, "free_dofs": int(len(problem.space.free)),
            "speed_m_s": float(speed), "max_dt_s": float(max_dt)}


def reached(solve: dict) -> tuple[float, float]:
    """How far a pull in time got: the displacement (mm) and time from rest (s) of its last record
    with a force (a hold's records share the ramp's end, so the time says how far into it); (0, 0)
    if none."""
    done = np.flatnonzero(np.isfinite(np.asarray(solve["force_per_pa"])).all(axis=1))
    return (float(np.asarray(solve["x_m"])[done[-1]] * 1e3), float(np.asarray(solve["times_s"])[done[-1]])) if len(done) else (0.0, 0.0)


def stopped(solve: dict) -> bool:
    """Whether a pull in time stopped before its last record (its records say so, whatever its account)."""
    return not np.isfinite(np.asarray(solve["force_per_pa"])).all()


# -- stored, or solved and cached -----------------------------------------------------------------

def _cache_file(key: str) -> Path:
    return cache_dir() / "reference" / f"pull-time-{key}.npz"


def stored_pull_in_time(key: str) -> dict | None:
    """A pull in time of `key`: shipped (hash-checked), else cached; None if neither."""
    found = shipped_pulls_in_time().get(key)
    if found is None and _cache_file(key).exists():
        with np.load(_cache_file(key), allow_pickle=False) as z:
            found = {k: (json.loads(str(z[k])) if k == "meta" else z[k]) for k in z.files}
    return found


def _task_parts(args):
    scene_path, pull, size_mm, speed, xs, holds, max_dt = args
    scene = scene_with(scene_path)
    if scene.spec.material.pia_arachnoid is not None:
        raise ParameterError(f"{scene_path}: material.pia_arachnoid: the pulls in time have no membrane yet; "
                             "allowed: a scene without one (the shipped brain_pull.toml)")
    grey, white = shipped_rheology()
    if scene.spec.material.white_matter is None:
        white = None
    verts, tris, _ = hemisphere_surface(scene.mesh, pull.hemisphere)
    body = mesh_hemisphere(verts, tris, size_mm * 1e-3)
    radius = grasp_radius(scene)
    return scene, grey, white, body, radius, pull_in_time_key(body, scene, grey, white, radius, pull, speed, xs, holds, max_dt)


def pull_in_time_key_of(args) -> str:
    """The key of `pull_in_time_task`'s `args`."""
    return _task_parts(args)[-1]


def pull_in_time_task(args) -> dict:
    """One pull in time on one mesh (a worker process): stored, or solved and cached. `args`:
    (scene path, pull, mesh size mm, speed m/s, samples m, holds s, largest step s)."""
    _, pull, size_mm, speed, xs, holds, max_dt = args
    scene, grey, white, body, radius, key = _task_parts(args)
    found = stored_pull_in_time(key)
    if found is not None:
        return {"key": key, "cached": True, "pull": pull.name, "size_mm": size_mm, "speed_m_s": speed} | found
    r = solve_pull_in_time(build_problem(scene, pull.hemisphere, body), grey, white, *patch_area_points(scene.mesh, pull.vertex, radius),
                           np.asarray(pull.direction), xs, speed, holds, max_dt)
    meta = {k: v for k, v in r.items() if k not in PARTS} | {"pull": pull.name, "size_mm": size_mm}
    save_npz(_cache_file(key), **{k: r[k] for k in PARTS}, meta=np.asarray(json.dumps(meta)))
    return {"key": key, "cached": False, "pull": pull.name, "size_mm": size_mm, "speed_m_s": speed} | {k: r[k] for k in PARTS} | {"meta": meta}


_SHIPPED: dict | None = None


def shipped_pulls_in_time() -> dict:
    """The shipped pulls in time by key (`data/reference_pulls_in_time.npz`), checked against the
    SHA-256 its record holds; {} while none are shipped."""
    global _SHIPPED
    if _SHIPPED is None:
        _SHIPPED = keyed_solves(SHIPPED, SHIPPED_INFO, "scripts/make_pulls_in_time.py")
    return _SHIPPED
