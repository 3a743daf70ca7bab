"""The tissue's finite-strain pulls, which the converged reference (analysis/verification/reference.py)
and the observer's truth (analysis/verification/truth_table.py) are made of: the tissue's law (the scene's
`[material]`, sim/material.py) on quadratic tetrahedra on the brain's body-fitted meshes, each
pull solved by Newton, read from the shipped solves or from the cache.

- **Geometry**: the body-fitted fTetWild meshes the simulator's FEM and mass-spring run on
  (`sim.geometry.tetmesh`: 8, 6 and 4 mm target edges, shipped in data/ with their hashes).
- **Elements**: P2 (10-node) tetrahedra, displacement-based, the law nearly incompressible
  (kappa = 50 mu): `sim.models.fem.FiniteStrain` (docs/material.md says why P2 and not the
  P2/P0 mean-dilatation element), the scene's clamp (nodes at or below the highest clamped
  surface vertex, the plane of `sim.models.fem.fixed_nodes`).
- **Grasp**: the FEM core's constraint (`sim.models.fem.grasp`): the mean displacement of the
  surface *area* within the grasp radius (`sim.geometry.patch`), each quadrature point interpolated
  with its element's quadratic shape functions.
- **Solve**: each pull is followed from rest to its largest displacement by the FEM core's
  Newton solver (`sim.models.fem.hold`), recording the force holding the patch (and, for the
  observer's pulls, the condensed tangent stiffness) at every sampled displacement. Forces are
  stored per pascal of the law's shear modulus: a law scaled in mu gives forces scaled alike.
- **Shipped**: the solves of the shipped scene's pulls on the shipped meshes are in
  `data/reference_pulls.npz` (made by `scripts/make_reference_pulls.py`, hash-checked against
  `data/reference_pulls.json`); any other pull, mesh or law is solved and cached on disk.
"""

from __future__ import annotations

import json
import math
import multiprocessing
import os
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from analysis.verification.convergence import converge
from analysis.verification.material_fit import fitted_range
from analysis.verification.regions import regional_system, scene_regions
from analysis.verification.solve_keys import (  # noqa: F401 - the keys' home; read here by their old names too
    KEY_DECIMALS,
    LAW_DIGITS,
    SOLVER_VERSION,
    ReferenceDataError,
    key_digits,
    key_number,
    keyed_solves,
    law_shape_key,
    pull_key,
    pull_key_inputs,
)
from brainsim_assets import path as _asset
from sim.errors import ParameterError
from sim.files import save_npz
from sim.geometry.patch import patch_area_points
from sim.geometry.tetmesh import SHIPPED_MM, BodyMesh, hemisphere_surface, mesh_hemisphere, needs_meshing
from sim.geometry.volume import cache_dir, locate
from sim.linalg import Factor
from sim.models.fem import FiniteStrain, TetSpace, constraint_matrix, hold
from sim.models.fem.finite_strain import support
from sim.models.fem.membrane import WithMembrane
from sim.pulls import scene_with
from sim.scene import clamp_limit, grasp_radius

DEFAULT_SIZES_MM = SHIPPED_MM  # target edge lengths, coarse to fine: the shipped meshes
QUICK_SIZES_MM = (20.0, 16.0)
SHIPPED_PULLS = _asset("data/reference_pulls.npz")
SHIPPED_PULLS_INFO = _asset("data/reference_pulls.json")
RECORD_XS = 0.0005 * np.arange(1, 25)  # m: where the shipped solves record (0.5, 1.0, ..., 12 mm)
# the finer meshes and the ensemble's laws follow a pull only while the coarsest mesh's state has at
# most this share of its energy outside the data's stretches: beyond, no sample can be decided (a decided
# sample has at most the JND fraction at its force, 25% at most; analysis.verification.truth_band.decide)
FOLLOW_SHARE = 0.25
# a solve made before the last two were recorded has the first four; the rest read NaN (`stored_solve`)
SUPPORT_FIELDS = ("energy_share_outside", "max_abs_j_minus_1", "principal_stretch_min", "principal_stretch_max",
                  "marginal_share_outside", "max_abs_j_minus_1_fine")


# -- the P2 problem ---------------------------------------------------------------------------

@dataclass
class Problem:
    """One hemisphere at one mesh size: the P2 space with the scene's clamp."""

    label: int
    mesh: BodyMesh
    space: object  # sim.models.fem.TetSpace, order 2
    fixed_nodes: int
    build_s: float


def build_problem(scene, label: int, mesh: BodyMesh) -> Problem:
    """P2 tetrahedra on a body-fitted hemisphere mesh, clamped like the scene's FEM."""
    start = time.perf_counter()
    axis, limit = clamp_limit(scene)
    fixed = mesh.nodes[:, axis] <= limit
    space = TetSpace(mesh.nodes, mesh.tets, fixed, order=2)
    return Problem(label=label, mesh=mesh, space=space, fixed_nodes=int(fixed.sum()), build_s=time.perf_counter() - start)


def grasp_matrix(problem: Problem, points: np.ndarray, weights: np.ndarray | None = None):
    """W (3, n_free): the weighted mean displacement of `points` (weights sum to 1; default
    equal), each located in its containing or nearest tetrahedron and interpolated with the
    element's quadratic shape functions (`sim.models.fem.constraint_matrix`, as `FemModel.grasp`)."""
    points = np.atleast_2d(points)
    weights = np.full(len(points), 1.0 / len(points)) if weights is None else np.asarray(weights, dtype=np.float64)
    tet, bary = locate(problem.mesh.nodes, problem.mesh.tets, points)
    return constraint_matrix(problem.space, tet, bary, weights)


def small_strain_factor(problem: Problem, law, regional=None, membrane=None):
    """The factorised tangent of `law` at rest on the problem (its small-strain limit: linear
    elasticity with mu and lambda = kappa - 2 mu / 3), per pascal of the law's shear modulus;
    with `regional` (`regions.RegionalLaw`, `law` its grey), the white matter's inside the white
    surface, and with `membrane` (`body_membrane`) the pia-arachnoid's at rest on the surface, as
    the finite-strain solves have them."""
    return Factor(body_system(problem, law, regional, membrane)[1].evaluate(np.zeros(3 * problem.space.n_all))["K"])


def body_system(problem: Problem, law, regional=None, membrane=None):
    """(the body, the body with its membrane) per pascal of `law`'s mu: regional laws, `WithMembrane` where there is one."""
    unit = law.scaled(1.0 / law.shear_modulus)
    laws, law_of = regional_system(problem.space, problem.mesh, problem.label, regional, unit) if regional else (unit, None)
    body = FiniteStrain(problem.space, laws, mean_dilatation=False, law_of=law_of)
    return body, body if membrane is None else WithMembrane(body, membrane.scaled(1.0 / law.shear_modulus))


def pull_stiffness(problem: Problem, law, points: np.ndarray, weights: np.ndarray | None = None, regional=None,
                   membrane=None) -> np.ndarray:
    """The small-strain condensed stiffness (3, 3) per pascal of shear modulus: the force
    holding the patch's mean displacement at a small d is mu K d (`regional`, `membrane`: as
    `small_strain_factor`)."""
    W = grasp_matrix(problem, points, weights)
    C = W @ small_strain_factor(problem, law, regional, membrane).solve(np.ascontiguousarray(W.T.toarray()))
    return np.linalg.inv(0.5 * (C + C.T))


# -- finite-strain pulls, shipped or solved and cached ---------------------------------------

# A solve's key is a hash of its inputs, so a number must be written the same on every machine:
# rounded to a stated precision, then any zero (-0.0, or a value that rounds to zero) written 0.0.
def entry_keys(entries, scene, laws: dict, pulls: dict) -> list[str]:
    """Each shipped entry's key (data/reference_pulls.json `entries`) from its inputs: its pull
    (`pulls`, by name), the body-fitted mesh of the pull's hemisphere at the entry's size, its law
    (`laws`, by shape: a law, or a regional contrast's `RegionalLaw`). Who calls it chooses where the laws and pulls come from: the rekeying
    script from the record, the test from this machine's own computation."""
    radius, rng = grasp_radius(scene), truth_range(scene)
    bodies: dict = {}
    out = []
    for e in entries:
        pull = pulls[e["pull"]]
        where = (pull.hemisphere, float(e["size_mm"]))
        if where not in bodies:
            verts, tris, _ = hemisphere_surface(scene.mesh, pull.hemisphere)
            bodies[where] = mesh_hemisphere(verts, tris, where[1] * 1e-3)
        regional = scene_regions(scene, laws[e["shape"]])  # a law (the scene's white matter kept) or a whole regional variant
        out.append(pull_key(bodies[where], scene, regional.grey, radius, pull, rng, regional))
    return out


_SHIPPED: dict | None = None


def shipped_solves() -> dict:
    """The shipped solves by key ({key: {"xs", "force_per_pa", "stiffness_per_pa"?, "meta"}}): `keyed_solves`."""
    global _SHIPPED
    if _SHIPPED is None:
        _SHIPPED = keyed_solves(SHIPPED_PULLS, SHIPPED_PULLS_INFO, "scripts/make_reference_pulls.py")
    return _SHIPPED


def _cache_file(key: str) -> Path:
    return cache_dir() / "reference" / f"pull-{key}.npz"


def _covers(entry: dict, xs: np.ndarray, stiffness: bool) -> np.ndarray | None:
    """Indices of `xs` in the entry's records, if it has them all (and its stiffness, if asked)."""
    have = np.asarray(entry["xs"])
    idx = np.array([int(np.argmin(np.abs(have - x))) for x in xs])
    if not all(abs(have[i] - x) <= 1e-9 for i, x in zip(idx, xs)):
        return None
    if "support" not in entry:
        return None
    if stiffness:  # recorded wherever the solve reached (a solve that stopped has no records beyond)
        reached_at = np.isfinite(np.asarray(entry["force_per_pa"])[idx]).all(axis=1)
        if "stiffness_per_pa" not in entry or not np.all(np.isfinite(np.asarray(entry["stiffness_per_pa"])[idx][reached_at])):
            return None
    return idx


def stored_solve(key: str, xs, stiffness: bool = False) -> dict | None:
    """A solve of `key` recording at every x of `xs`: shipped, else cached; None if neither."""
    xs = np.asarray(xs, dtype=np.float64)
    candidates = [shipped_solves().get(key)]
    path = _cache_file(key)
    if path.exists():
        with np.load(path, allow_pickle=False) as z:
            candidates.append({k: (json.loads(str(z[k])) if k == "meta" else z[k]) for k in z.files})
    for entry in candidates:
        if entry is None:
            continue
        idx = _covers(entry, xs, stiffness)
        if idx is not None:
            sup = np.asarray(entry["support"])[idx]
            sup = np.hstack([sup, np.full((len(idx), len(SUPPORT_FIELDS) - sup.shape[1]), np.nan)])
            out = {"force_per_pa": np.asarray(entry["force_per_pa"])[idx], "support": sup, **entry["meta"]}
            if "stiffness_per_pa" in entry:
                out["stiffness_per_pa"] = np.asarray(entry["stiffness_per_pa"])[idx]
            if not out.get("converged") and np.isfinite(out["force_per_pa"]).all():
                # a longer pull that stopped beyond every record asked: those records are
                # converged states, whichever request solved it first
                out |= {"converged": True, "reason": f"stored solve stopped at {out.get('reached_mm')} mm "
                                                     f"({out.get('reason')}), beyond every record asked"}
            return out
    return None


def solve_pull(problem: Problem, law, points, weights, direction, xs, stiffness: bool = False, stretch_range=None, regional=None,
               membrane=None, marginal: bool = True) -> dict:
    """Follow the pull (the patch's mean displacement along `direction`) to max(xs), recording
    the force holding it (per pascal of shear modulus, (len(xs), 3), the force on the tissue),
    its support (`support`, (len(xs), 6): `SUPPORT_FIELDS` of `sim.models.fem.finite_strain.support`
    for the principal stretches `stretch_range`, NaN without one) and, with `stiffness`, the
    condensed tangent (len(xs), 3, 3) at each x. `regional` (`regions.RegionalLaw`): the white
    matter's law inside the white surface, `stretch_range` then one range per law; `membrane`: a
    `MembraneLaw` on the surface (the support stays the body's). `marginal`: record the marginal
    share (one more factorisation per record; only the scene's own law's solves decide, so the
    ensemble's other laws go without: NaN there)."""
    xs = np.asarray(xs, dtype=np.float64)
    if xs.ndim != 1 or len(xs) == 0 or not np.all(np.isfinite(xs)) or np.any(xs <= 0) or np.any(np.diff(xs) <= 0):
        raise ParameterError("displacements: an increasing list of positive lengths (m)")
    W = grasp_matrix(problem, points, weights)
    t0 = time.perf_counter()
    system, whole = body_system(problem, law, regional, membrane)
    res = hold(whole, W, np.asarray(direction) * xs[-1], fractions=xs / xs[-1],
               first_step=min(0.25, 2.0 * xs[0] / xs[-1]), stiffness=stiffness, keep_states=stretch_range is not None,
               sensitivity=marginal and stretch_range is not None)
    rep = res.report
    sup = np.full((len(xs), len(SUPPORT_FIELDS)), np.nan)
    for i, u in enumerate(res.states):  # the states of the records reached, in order
        s = support(system, u, stretch_range, res.sensitivities[i] if res.sensitivities else None)
        sup[i] = [s[k] for k in SUPPORT_FIELDS]
    out = {"force_per_pa": res.forces, "support": sup, "converged": bool(rep.converged), "reason": rep.reason,
           "iterations": int(sum(rep.iterations)), "load_steps": int(rep.load_steps), "cut_steps": int(rep.cut_steps),
           "factorisations": int(rep.tangent_updates), "gmres_iterations": int(rep.linear_iterations), "shifts": int(rep.shifts),
           "min_jacobian": float(rep.min_jacobian), "reached_mm": float(res.fraction_done * xs[-1] * 1e3), "seconds": time.perf_counter() - t0, "free_dofs": int(len(problem.space.free))}
    if stiffness:
        out["stiffness_per_pa"] = res.stiffness
    return out


def pull_samples(max_pull: float, samples: int) -> np.ndarray:
    """Where a pull is sampled: `samples` equal steps to `max_pull` (m), rest excluded."""
    return max_pull * np.arange(1, samples + 1) / samples


def reached(refs: dict) -> dict:
    """Per pull, which records every mesh's solve reached (bool per x), and why the others
    have no reference (the first solve that stopped: its mesh, where and why; "" if none)."""
    out = {}
    for name, r in refs.items():
        ok = np.isfinite(np.asarray(r["force_per_pa"])).all(axis=(0, 2))
        why = ""
        for s in r["solves"]:
            if not s["converged"]:
                why = f"the {s['size_mm']:g} mm mesh's solve stopped at {s.get('reached_mm', math.nan):.1f} mm ({s.get('reason') or 'no convergence'})"
                break
        out[name] = (ok, why)
    return out


def no_reference(refs: dict, xs) -> list[dict]:
    """The pulls with samples that have no reference: how many, the last x every mesh reached
    (mm, 0 if none) and why."""
    return [{"pull": name, "samples": int((~m).sum()), "reached_mm": float(np.asarray(xs)[m].max() * 1e3) if m.any() else 0.0, "why": why}
            for name, (m, why) in reached(refs).items() if not m.all()]


def describe_no_reference(gone: list[dict]) -> str:
    """`no_reference`'s list in words: "all of P (why); Q beyond 8 mm (why)"."""
    return "; ".join((f"{g['pull']} beyond {g['reached_mm']:g} mm" if g["reached_mm"] > 0 else f"all of {g['pull']}") + f" ({g['why']})"
                     for g in gone)


def require_converged(refs: dict, what: str) -> None:
    """Refuse to build on a reference solve that stopped (naming the pull, the mesh and why)."""
    for name, r in refs.items():
        for s in r["solves"]:
            if not s["converged"]:
                raise ReferenceDataError(f"{what}: the reference solve of pull {name} on the {s['size_mm']:g} mm mesh stopped "
                                         f"({s.get('reason') or 'no convergence'}); every sample needs it")


def _pull_task(args) -> dict:
    """One pull on one mesh (a worker process): shipped, cached, or solved and cached."""
    scene_path, label, size_mm, pull, xs, stiffness, upto, finer, law = args

    scene = scene_with(scene_path)
    given, regional = law, scene_regions(scene, law)
    law, radius, rng = regional.grey, grasp_radius(scene), truth_range(scene)
    verts, tris, _ = hemisphere_surface(scene.mesh, label)
    body = mesh_hemisphere(verts, tris, size_mm * 1e-3)
    key = pull_key(body, scene, law, radius, pull, rng, regional)
    found = _stored(key, xs, stiffness, finer, upto)
    if found is not None:
        return found | {"cached": True, "key": key, "h_m": body.h}
    asked = xs <= upto + 1e-12
    nothing = {"force_per_pa": np.full((len(xs), 3), np.nan), "support": np.full((len(xs), len(SUPPORT_FIELDS)), np.nan),
               "converged": False, "cached": False, "key": key, "h_m": body.h, "reached_mm": 0.0}
    if finer == "skip" and not asked.all():
        return nothing | {"skipped": True, "reason": f"not solved: the coarsest mesh's solve stopped after its {upto * 1e3:g} mm record, "
                                                     "and the finer ones were not run"}
    if not asked.any():
        return nothing | {"reason": "not solved: the coarsest mesh's solve stopped, or its state left the data, before the first sample"}
    problem = build_problem(scene, label, body)
    r = solve_pull(problem, law, *patch_area_points(scene.mesh, pull.vertex, radius), np.asarray(pull.direction), xs[asked], stiffness,
                   regional.ranges(), regional, body_membrane(scene, law, regional.pac_scale),
                   marginal=given is None)
    if not asked.all():  # followed only as far as asked: no records beyond
        for name in ("force_per_pa", "stiffness_per_pa", "support"):
            if name in r:
                part = np.asarray(r[name])
                r[name] = np.concatenate([part, np.full((len(xs) - len(part),) + part.shape[1:], np.nan)])
        r["followed_mm"] = float(upto * 1e3)
    meta = {k: v for k, v in r.items() if k not in ("force_per_pa", "stiffness_per_pa", "support")}
    if r["converged"] or np.isfinite(np.asarray(r["force_per_pa"])).all(axis=1).any():
        # a solve that stopped is kept too: its records up to where it stopped are converged
        # states, and solving it again would stop at the same place
        _cache(key, np.asarray(xs, dtype=np.float64), r["force_per_pa"], r.get("stiffness_per_pa"), r["support"], meta)
    return r | {"cached": False, "key": key, "h_m": body.h}


def body_membrane(scene, law, pac_scale: float = 1.0):
    """The scene's pia-arachnoid for a solve of `law` as the grey matter: scaled along with it (a
    member's forces scale with its mu), and by `pac_scale` (a member of its measured spread);
    None without one."""
    pac = scene.spec.material.pia_arachnoid
    return pac.scaled(law.shear_modulus / scene.spec.material.law.shear_modulus * pac_scale) if pac is not None else None


def truth_range(scene) -> tuple[float, float] | None:
    """The principal stretches the scene's law was fitted to (`analysis.verification.material_fit.fitted_range`),
    None when its material names no data."""
    source = scene.spec.material.law_source
    return fitted_range(source)[0] if source else None


def _cache(key: str, xs, force, stiffness, sup, meta: dict) -> None:
    """Keep a solve in the cache, merged with the records of an earlier one of the same pull
    (a stiffness is NaN where a solve did not record it)."""
    path = _cache_file(key)
    stiff = np.full((len(xs), 3, 3), np.nan) if stiffness is None else np.asarray(stiffness)
    sup = np.asarray(sup)
    if path.exists():
        with np.load(path, allow_pickle=False) as z:
            old_xs, old_f = z["xs"], z["force_per_pa"]
            old_k = z["stiffness_per_pa"] if "stiffness_per_pa" in z.files else np.full((len(old_xs), 3, 3), np.nan)
            old_s = z["support"] if "support" in z.files else np.full((len(old_xs), 0), np.nan)
        old_s = np.hstack([old_s, np.full((len(old_xs), len(SUPPORT_FIELDS) - old_s.shape[1]), np.nan)])  # fields it predates
        keep = np.array([np.min(np.abs(xs - x)) > 1e-9 for x in old_xs], dtype=bool)
        xs, force, stiff, sup = (np.concatenate([xs, old_xs[keep]]), np.concatenate([force, old_f[keep]]),
                                 np.concatenate([stiff, old_k[keep]]), np.concatenate([sup, old_s[keep]]))
    order = np.argsort(xs)
    save_npz(path, xs=xs[order], force_per_pa=np.asarray(force)[order], stiffness_per_pa=stiff[order], support=sup[order],
             meta=np.asarray(json.dumps(meta)))


def pull_references(scene_path, pulls, xs, sizes_mm=DEFAULT_SIZES_MM, jobs: int | None = None, progress=None,
                    stiffness_for=(), finer: str = "stored", law=None, upto: dict | None = None) -> dict:
    """The finite-strain reference of every pull in `pulls` on every mesh size: per pull
    ``{"h_m": [coarse..fine], "force_per_pa": (sizes, n, 3), "stiffness_per_pa": (sizes, n, 3, 3)
    or None, "solves": [per size]}``, plus ``"sizes_mm"``. Pulls named in `stiffness_for`
    record the condensed tangent too. Solves run in worker processes (`jobs`, default every
    core): the coarsest mesh first, then the finer ones, largest first; where the coarsest
    mesh's solve stopped, the finer ones follow the pull only as far as it got (a sample needs
    every mesh, and the last steps before a solve stops are the slowest). `finer` says what to do
    there: "stored" (a stored skip stands, otherwise solve), "solve", or "skip" (record a skip:
    a solve near where the coarse one stopped can take an hour on the 4 mm mesh). Beyond where the
    coarsest mesh's state has more than `FOLLOW_SHARE` of its energy outside the data's stretches
    the finer meshes do not follow either (no sample is decided there), except on the pulls in
    `stiffness_for` (the observer's paths); each pull's `follow_m` says how far (m). `law`:
    another law than the scene's (the truth's ensemble); `upto`: per pull, the last displacement
    to solve on every mesh (m)."""
    scene = scene_with(scene_path)
    xs = np.asarray(xs, dtype=np.float64)
    sizes = sorted((float(x) for x in sizes_mm), reverse=True)
    labels = sorted({p.hemisphere for p in pulls})
    _premesh(scene.mesh, labels, sizes, 1, jobs)
    n_all = len(sizes) * len(pulls)
    given = upto or {}
    first = [(str(scene_path), p.hemisphere, sizes[0], p, xs, p.name in stiffness_for, given.get(p.name, xs[-1]), finer, law) for p in pulls]
    coarse = _run(first, jobs, (lambda k, n: progress(k, n_all)) if progress else None)
    follow, mode = {}, {}
    for p, r in zip(pulls, coarse):
        follow[p.name] = follow_to(xs, r, p.name in stiffness_for)
        # "skip" is for pulls whose coarsest solve stopped; one cut short by its support is followed
        stopped = not np.isfinite(np.asarray(r["force_per_pa"])).all()
        mode[p.name] = finer if finer != "skip" or stopped else "stored"
    rest = [(str(scene_path), p.hemisphere, s, p, xs, p.name in stiffness_for, follow[p.name], mode[p.name], law)
            for s in sorted(sizes[1:]) for p in pulls]
    tasks = first + rest
    results = coarse + _run(rest, jobs, (lambda k, n: progress(len(first) + k, n_all)) if progress else None)
    out = {p.name: {"h_m": [0.0] * len(sizes), "force_per_pa": [None] * len(sizes), "stiffness_per_pa": [None] * len(sizes),
                    "support": [None] * len(sizes), "solves": [None] * len(sizes), "follow_m": follow[p.name]} for p in pulls}
    for (_, _, s, p, *_), r in zip(tasks, results):
        i = sizes.index(s)
        row = out[p.name]
        row["h_m"][i] = r["h_m"]
        row["force_per_pa"][i] = np.asarray(r["force_per_pa"])
        row["stiffness_per_pa"][i] = r.get("stiffness_per_pa")
        row["support"][i] = np.asarray(r["support"])
        row["solves"][i] = {k: v for k, v in r.items() if k not in ("force_per_pa", "stiffness_per_pa", "support")} | {"size_mm": s}
    for row in out.values():
        row["force_per_pa"] = np.stack(row["force_per_pa"])
        row["support"] = np.stack(row["support"])
        row["stiffness_per_pa"] = np.stack(row["stiffness_per_pa"]) if all(k is not None for k in row["stiffness_per_pa"]) else None
    return {"pulls": out, "sizes_mm": sizes}


def follow_to(xs, coarse: dict, whole: bool) -> float:
    """How far the finer meshes follow a pull (m): as far as the coarsest mesh's solve reached
    and, unless `whole`, while its state's share outside the data's stretches, the one the truth
    decides on (the marginal share where recorded, else the energy share), is at most `FOLLOW_SHARE`
    (a state beyond the solve's reach, NaN, counts as outside; a law whose data are unknown has
    no support at all and is followed as far as it goes)."""
    ok = np.isfinite(np.asarray(coarse["force_per_pa"])).all(axis=1)
    sup = np.asarray(coarse["support"])
    share = sup[:, 4] if sup.shape[1] > 4 and np.isfinite(sup[ok, 4]).all() else sup[:, 0]
    if not whole and np.isfinite(share[ok]).any():  # a law without data (no stretch range, NaN) is followed as far as it goes
        inside = np.cumprod(share <= FOLLOW_SHARE).astype(bool)  # stop at the first state outside
        ok = ok & inside
    return float(np.asarray(xs)[ok].max()) if ok.any() else 0.0


def _run(tasks: list, jobs: int | None, progress) -> list:
    """`_pull_task` over `tasks`, in order: stored ones here, the rest in worker processes."""
    results: list = [None] * len(tasks)
    todo = []
    seen: dict = {}
    for i, t in enumerate(tasks):
        r = _stored_task(t, seen)
        if r is not None:
            results[i] = r
        else:
            todo.append(i)
    done = len(tasks) - len(todo)
    if progress is not None:
        progress(done, len(tasks))
    jobs = max(1, min(jobs or os.cpu_count() or 1, len(todo) or 1))
    order = sorted(todo, key=lambda i: tasks[i][2])  # the finest (slowest) meshes first
    if jobs == 1:
        for i in order:
            results[i] = _pull_task(tasks[i])
            done += 1
            if progress is not None:
                progress(done, len(tasks))
    elif order:
        with ProcessPoolExecutor(max_workers=jobs, mp_context=multiprocessing.get_context("spawn")) as pool:
            futures = {pool.submit(_pull_task, tasks[i]): i for i in order}
            for f in as_completed(futures):
                results[futures[f]] = f.result()
                done += 1
                if progress is not None:
                    progress(done, len(tasks))
    return results


def _stored_task(task, seen: dict) -> dict | None:
    """`_pull_task`'s answer when it is shipped or cached (no worker needed); `seen` keeps the
    scene and the meshes read for earlier tasks."""
    scene_path, label, size_mm, pull, xs, stiffness, upto, finer, law = task

    if scene_path not in seen:
        seen[scene_path] = scene_with(scene_path)
    scene = seen[scene_path]
    if (scene_path, label, size_mm) not in seen:
        verts, tris, _ = hemisphere_surface(scene.mesh, label)
        seen[(scene_path, label, size_mm)] = None if needs_meshing(verts, tris, size_mm * 1e-3) else mesh_hemisphere(verts, tris, size_mm * 1e-3)
    body = seen[(scene_path, label, size_mm)]
    if body is None:
        return None
    if ("range", scene_path) not in seen:
        seen[("range", scene_path)] = truth_range(scene)
    regional = scene_regions(scene, law)
    key = pull_key(body, scene, regional.grey, grasp_radius(scene), pull, seen[("range", scene_path)], regional)
    found = _stored(key, xs, stiffness, finer, upto)
    return None if found is None else found | {"cached": True, "key": key, "h_m": body.h}


def unsolved(scene_path, pulls, xs, sizes_mm, law=None) -> dict:
    """The solves `pull_references` would have to run for these pulls and sizes (neither
    shipped nor cached), with the scene's law or `law` (followed, as `truth_samples` asks, as far as the
    scene's law's finer meshes follow): {size_mm: count}. `_stored_task` for each: reads the meshes and the
    stores, solves nothing and meshes nothing (a pull on a mesh not yet made counts as unsolved)."""
    xs = np.asarray(xs, dtype=np.float64)
    seen: dict = {}
    sizes = sorted((float(s) for s in sizes_mm), reverse=True)
    # the scene's law on the coarsest mesh sets how far the finer meshes, and the ensemble's laws, follow
    coarse = {p.name: _stored_task((str(scene_path), p.hemisphere, sizes[0], p, xs, False, xs[-1], "stored", None), seen) for p in pulls}
    follow = {name: follow_to(xs, c, False) for name, c in coarse.items() if c is not None}
    out = {}
    for i, size in enumerate(sizes):
        out[size] = 0
        for p in pulls:
            if law is None and i == 0:
                found = coarse[p.name]
            else:
                found = _stored_task((str(scene_path), p.hemisphere, size, p, xs, False, follow.get(p.name, xs[-1]), "stored", law), seen)
            out[size] += found is None
    return {float(s): out[float(s)] for s in sizes_mm}


def shipped_solve_seconds() -> dict:
    """The median time of a shipped solve per mesh size (s, on the machine that made them):
    what an unsolved one costs, roughly."""
    try:
        entries = json.loads(SHIPPED_PULLS_INFO.read_text())["entries"]
    except (OSError, ValueError, KeyError):
        return {}
    by: dict = {}
    for e in entries:
        if e.get("seconds"):
            by.setdefault(float(e["size_mm"]), []).append(float(e["seconds"]))
    return {k: float(np.median(v)) for k, v in by.items()}


def _stored(key: str, xs, stiffness: bool, finer: str, upto: float | None = None) -> dict | None:
    """`stored_solve`, except a stored skip when the finer solves are asked for ("solve"), and a
    solve followed only part of the way when it is asked to go further (`upto`, m)."""
    found = stored_solve(key, xs, stiffness)
    if found is None or (finer == "solve" and found.get("skipped")):
        return None
    if upto is not None and found.get("followed_mm") is not None and found["followed_mm"] < upto * 1e3 - 1e-6:
        return None
    return found


def combined_sample(forces, hs) -> dict:
    """The reference at one sample from its force vectors on the meshes (coarse to fine):
    Richardson on the magnitudes (`converge`), the finest mesh's vector scaled to the
    extrapolated magnitude. Returns the force vector, its magnitude, the GCI half-band (N,
    relative to the magnitude) and the convergence record; NaN and "not solved" where a mesh's
    solve did not reach the sample (no reference)."""
    mags = [float(np.linalg.norm(f)) for f in forces]
    if not all(math.isfinite(m) for m in mags):
        return {"force": np.full(3, math.nan), "force_n": math.nan, "band_rel": math.nan, "band_half_n": math.nan,
                "status": "not solved", "order": math.nan, "extrapolated": False, "forces_n": mags}
    conv = converge(mags, hs)
    finest = mags[int(np.argmin(hs))]
    vec = np.asarray(forces[int(np.argmin(hs))], dtype=np.float64) * (conv["f_ext"] / finest if finest > 0 else 1.0)
    mag = float(np.linalg.norm(vec))
    return {"force": vec, "force_n": mag, "band_rel": conv["gci"], "band_half_n": conv["gci"] * mag, "status": conv["status"],
            "order": conv["p"], "extrapolated": conv["extrapolated"], "forces_n": mags}


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

    with ProcessPoolExecutor(max_workers=min(jobs, len(tasks)), mp_context=multiprocessing.get_context("spawn")) as pool:
        list(pool.map(_mesh_task, tasks))
    return made
