"""Where the tissue truth is decided: the law's ensemble, each sample's band and support, and
the rule that says whether a sample can judge a model (docs/reference.md).

- **Ensemble.** The data do not fix one law beyond their stretches, so the truth is a family:
  the scene's law (chosen on every loading mode), the best fit of every other law family that
  passes `ACCEPT` on the same data (uniaxial RMS error, worst shear error over strains 0.1-0.2),
  the corners of the chosen law's 95% parameter box, and two laws that bound the chosen one
  beyond the data (`edge_fits`): the one-term fits with the exponent held at the least and the
  most stiffening value that still passes `ACCEPT`: one stiffens less than the chosen law beyond
  the data's stretches, one more (their stresses there: docs/reference.md). Forces scale with mu at fixed exponents, so only the
  distinct shapes are solved (`shapes`), on the coarsest mesh. A member is a record with its
  `kind` ("law" here); a regional or membrane variant is a member of another kind.
- **Band.** Per sample: the mesh half-band (GCI, `tissue_pulls.combined_sample`) and the law
  half-band (the largest distance of an ensemble member's force from the chosen law's, relative)
  combined root-sum-square as independent parts (ASME V&V 20-2009's combination of numerical and
  input uncertainty).
- **Support.** Per sample: the share of the state's stored energy at quadrature points whose
  principal stretches leave the data's range, the marginal share dE_out/dE (the share of the
  force, dE/dd, those points give, the set fixed at the state), and the largest |J - 1| at the
  Gauss points and at the nodes and a 64-point rule (the larger over the meshes).
- **Decided** (`decide`): a reference below the device's force limit; a marginal share at most
  `MARGINAL_LIMIT` x the JND fraction at that force (a law wrong by a factor of two where no one
  measured moves the force by about +m or -m/2 to first order; solved, by 0.63-0.76 m at the
  shares near the limit, the softening's second order included: docs/reference.md), so by less
  than a JND; |J - 1| at most `MAX_J_DEVIATION` at the finer rule; and a band narrower than the
  JND. Otherwise `extrapolated` (support) or `undecided` (band, or an ensemble member not solved
  there), with the reason. A solve stored before the marginal share was recorded is decided on
  the energy share and the Gauss points' |J - 1|, the rule before.
"""

from __future__ import annotations

import dataclasses
import itertools
import json
import math

import numpy as np

from analysis.verification.material_fit import (
    MaterialDataError,
    fit_material,
    fitted_range,
    law_errors,
    law_of,
    material_data,
    read_curve,
    shear_stress,
)
from analysis.verification.regions import contrast_members, scene_regions
from analysis.verification.tissue_pulls import (
    SHIPPED_PULLS_INFO,
    SUPPORT_FIELDS,
    combined_sample,
    law_shape_key,
    pull_references,
)
from sim.hyperelastic import Hyperelastic, ogden, uniaxial
from sim.perception import force_jnd
from sim.pulls import scene_with

ACCEPT = {"rms_rel_uniaxial": 0.10, "shear_worst_rel": 0.20}  # a law fits the data "about as well" (the bar the chosen law met)
DEVICE_LIMIT_N = 3.3  # the PHANTOM Omni's largest force (docs/hardware.md): no sample above it is judged
BEYOND_STRETCHES = (1.2, 1.3, 0.8, 0.7)  # where a member's uniaxial stress is shown beside the chosen law's
EDGE_STEP = 0.05  # the exponent's step in `edge_fits`' scan
MARGINAL, ENERGY = "marginal share", "energy share (a solve made before the marginal share was recorded)"
MARGINAL_LIMIT = 1.0  # of the JND fraction: the largest marginal share a decided sample may have (docs/reference.md)
MAX_J_DEVIATION = 0.05  # a nearly incompressible law: |J - 1| beyond this is not the tissue the data measured


def ensemble(material_path, law: Hyperelastic) -> list[dict]:
    """The truth's laws: {name, role, kind, law, rms_rel_uniaxial, shear_worst_rel, passes,
    beyond_data} for the chosen `law` (the material file's), each other family's best fit that
    passes `ACCEPT`, the corners of the chosen family's 95% parameter box (fitted on the
    material's own data), and `edge_fits`' softer and stiffer laws."""
    paths, region = material_data(material_path)
    curves = [read_curve(p, region) for p in paths]
    fit = fit_material(paths, region, bulk_ratio=law.bulk_ratio)
    family = "ogden-2" if law.law == "ogden" and len(law.mu) == 2 else law.law

    def member(name, role, member_law):
        err = law_errors(member_law, curves)
        ok = all(not (err[k] > v) for k, v in ACCEPT.items())  # NaN (a mode without data) passes
        return {"name": name, "role": role, "kind": "law", "law": member_law, **err, "passes": bool(ok),
                "beyond_data": beyond_data(member_law, law)}

    out = [member("chosen", f"the scene's law ({family}, chosen by AICc on every mode)", law)]
    for f in fit["laws"]:
        if f["law"] == family:
            continue
        m = member(f"{f['law']} fit", f"the best {f['law']} fit to the same data", law_of(f))
        if m["passes"]:
            out.append(m)
    mine = next((f for f in fit["laws"] if f["law"] == family), None)
    if mine is not None:
        names = list(mine["ci95"])
        for corner in itertools.product(*(mine["ci95"][n] for n in names)):
            params = dict(zip(names, corner))
            label = ", ".join(f"{n} {v:.4g}" for n, v in params.items())
            out.append(member(f"corner ({label})", "a corner of the chosen law's 95% parameter box", law_of(mine | {"parameters": params})))
    for name, role, edge in edge_fits(curves, law):
        out.append(member(name, role, edge))
    return out


def _unit_fit(curves, alpha: float, bulk_ratio: float) -> Hyperelastic:
    """The one-term Ogden law of exponent `alpha` whose mu fits `curves` best (least squares,
    each file's residuals over its data's RMS, as `fit_material` weighs them): the stress is mu
    times the unit law's at a fixed exponent and kappa / mu, so mu is one linear solve."""
    unit = ogden([1.0], [alpha], bulk_ratio)
    a = np.concatenate([(shear_stress(unit, c.x) if c.mode == "shear" else uniaxial(unit, c.x)[0]) / np.sqrt(np.mean(c.stress**2))
                        for c in curves])
    b = np.concatenate([c.stress / np.sqrt(np.mean(c.stress**2)) for c in curves])
    return unit.scaled(float(a @ b / (a @ a)))


def _passes(law: Hyperelastic, curves) -> bool:
    err = law_errors(law, curves)
    return all(not (err[k] > v) for k, v in ACCEPT.items())


def edge_fits(curves, law: Hyperelastic) -> list[tuple[str, str, Hyperelastic]]:
    """Two laws that fit `curves` as well as the bar asks and bound `law` (a one-term Ogden)
    beyond the data: the one-term Ogden fit (mu by least squares) with its exponent moved from
    the chosen one, in `EDGE_STEP`s, towards zero (less stiffening: softer beyond the data's
    stretches, in tension and compression) and away from it (stiffer), each to the last value
    that passes `ACCEPT`. [] for another law."""
    if law.law != "ogden" or len(law.alpha) != 1:
        return []
    a0 = law.alpha[0]
    out = []
    for sign, name, role in ((1.0, "softer beyond the data", "the one-term fit of the least stiffening exponent that passes the bar"),
                             (-1.0, "stiffer beyond the data", "the one-term fit of the most stiffening exponent that passes the bar")):
        towards_zero = sign * (-1.0 if a0 > 0 else 1.0)
        best, k = None, 1
        while True:
            a = a0 + towards_zero * EDGE_STEP * k
            if a * a0 <= 0 or abs(a) > 60.0:
                break
            trial = _unit_fit(curves, a, law.bulk_ratio)
            if not _passes(trial, curves):
                break
            best, k = trial, k + 1
        if best is not None:
            out.append((f"{name} (alpha {best.alpha[0]:.4g})", role, best))
    return out


def beyond_data(member: Hyperelastic, chosen: Hyperelastic) -> dict:
    """The member's uniaxial nominal stress (Pa) at `BEYOND_STRETCHES`, beyond the data, its
    ratio to the chosen law's there, and the ratio of their tangents dP/dl (central differences)."""
    lam, h = np.asarray(BEYOND_STRETCHES), 1e-6
    mine, theirs = uniaxial(member, lam)[0], uniaxial(chosen, lam)[0]

    def tangent(law):
        return (uniaxial(law, lam + h)[0] - uniaxial(law, lam - h)[0]) / (2.0 * h)

    slope = tangent(member) / tangent(chosen)
    return {f"{x:g}": {"stress_pa": float(p), "ratio": float(p / q), "tangent_ratio": float(t)} for x, p, q, t in zip(lam, mine, theirs, slope)}


def shapes(members: list[dict]) -> list[Hyperelastic]:
    """The distinct law shapes (up to the scale of mu) of the ensemble, the chosen law's first,
    each at unit shear modulus: what is solved."""
    out: dict = {}
    for m in members:  # the solves' own key of a law up to its scale (analysis.verification.tissue_pulls)
        out.setdefault(json.dumps(law_shape_key(m["law"])), m["law"].scaled(1.0 / m["law"].shear_modulus))
    return list(out.values())


def shape_index(members: list[dict]) -> list[int]:
    """For each member, the index of its shape in `shapes(members)`."""
    keys = [json.dumps(law_shape_key(u)) for u in shapes(members)]
    return [keys.index(json.dumps(law_shape_key(m["law"]))) for m in members]


def law_spread(forces_by_member: np.ndarray) -> float:
    """The law half-band (relative): the largest distance of a member's force magnitude from the
    chosen law's (member 0) over it; NaN when a member has no force there."""
    f = np.asarray(forces_by_member, dtype=np.float64)
    if not np.all(np.isfinite(f)) or f[0] <= 0:
        return math.nan
    return float(np.max(np.abs(f - f[0])) / f[0])


def combine(mesh_rel: float, law_rel: float) -> float:
    """Root-sum-square of the independent parts (NaN if either is unknown)."""
    return float(math.hypot(mesh_rel, law_rel))


def decide(force_n: float, band_rel: float, share_outside: float, max_j_dev: float, measure: str = MARGINAL) -> tuple[bool, str, str]:
    """(decided, the truth's verdict when not decided: "extrapolated" or "undecided", reason).
    `share_outside` is the marginal share dE_out/dE (`measure` MARGINAL), or for a solve made
    before it was recorded the energy share E_out/E (`measure` ENERGY, the rule before it);
    `max_j_dev` the largest |J - 1| at the finer rule where recorded."""
    if not math.isfinite(force_n):
        return False, "undecided", "no reference force"
    tol = float(force_jnd(np.array(force_n)))
    if force_n > DEVICE_LIMIT_N:
        return False, "extrapolated", f"reference {force_n:.2f} N above the device's {DEVICE_LIMIT_N:g} N"
    if not math.isfinite(share_outside):
        return False, "undecided", "the law names no data, so where its states rest on measurements is unknown"
    limit = tol * (MARGINAL_LIMIT if measure == MARGINAL else 1.0)
    if not (share_outside <= limit):
        what = "the force (dE_out/dE)" if measure == MARGINAL else "the energy"
        return False, "extrapolated", f"{share_outside:.0%} of {what} from outside the data's stretches (at most {limit:.0%} here)"
    if not (max_j_dev <= MAX_J_DEVIATION):
        return False, "extrapolated", f"|J - 1| up to {max_j_dev:.3f} (at most {MAX_J_DEVIATION:g})"
    if not math.isfinite(band_rel):
        return False, "undecided", "no band (an ensemble law or a finer mesh was not solved here)"
    if not (band_rel < tol):
        return False, "undecided", f"band +-{band_rel:.0%} not narrower than the JND {tol:.0%}"
    return True, "", ""


def rule_inputs(sup: np.ndarray) -> dict:
    """What `decide` reads of a sample's support (`tissue_pulls.SUPPORT_FIELDS`, (meshes, fields),
    NaN where a mesh did not reach it), the larger over the meshes that reached it: the marginal
    share where every such mesh recorded it, else the energy share (a solve made before the
    marginal share was); |J - 1| at the nodes and the 64-point rule where recorded, else at the
    Gauss points."""
    sup = np.atleast_2d(np.asarray(sup, dtype=np.float64))
    reached = np.isfinite(sup[:, 0])
    if not reached.any():
        return {"support_share_outside": math.nan, "marginal_share_outside": math.nan, "max_abs_j_minus_1": math.nan,
                "max_abs_j_minus_1_fine": math.nan, "decided_on": MARGINAL, "decided_share": math.nan, "decided_j": math.nan}
    col = {name: sup[reached, i] for i, name in enumerate(SUPPORT_FIELDS)}
    top = {name: float(np.max(v)) if np.all(np.isfinite(v)) else math.nan for name, v in col.items()}
    marginal = math.isfinite(top["marginal_share_outside"])
    fine = math.isfinite(top["max_abs_j_minus_1_fine"])
    return {"support_share_outside": top["energy_share_outside"], "marginal_share_outside": top["marginal_share_outside"],
            "max_abs_j_minus_1": top["max_abs_j_minus_1"], "max_abs_j_minus_1_fine": top["max_abs_j_minus_1_fine"],
            "decided_on": MARGINAL if marginal else ENERGY,
            "decided_share": top["marginal_share_outside"] if marginal else top["energy_share_outside"],
            "decided_j": max(top["max_abs_j_minus_1_fine"], top["max_abs_j_minus_1"]) if fine else top["max_abs_j_minus_1"]}


# -- the truth at every sample -------------------------------------------------------------------

def _shipped_record() -> dict | None:
    """data/reference_pulls.json (the shipped solves' record, with their ensemble), or None."""
    try:
        return json.loads(SHIPPED_PULLS_INFO.read_text())
    except (OSError, ValueError):
        return None


def scene_ensemble(scene) -> list[dict]:
    """The ensemble of the scene's law: fitted on its material's data (a few seconds); a law
    without data (an inline `[material]`) is its own ensemble, with no spread to show."""
    law = scene.spec.material.law
    source = scene.spec.material.law_source
    shipped = _shipped_record()
    if shipped and shipped.get("ensemble") and Hyperelastic.from_params(shipped["law"]) == law:
        # the shipped solves' ensemble: the same fit, recorded when they were made (no refit)
        return [e | {"law": Hyperelastic.from_params(e["law"])} for e in shipped["ensemble"]]
    try:
        return ensemble(source, law) if source else [_alone(law)]
    except MaterialDataError:
        return [_alone(law)]


def _alone(law: Hyperelastic) -> dict:
    return {"name": "chosen", "role": "the scene's law (no data named: no ensemble)", "law": law,
            "rms_rel_uniaxial": math.nan, "shear_worst_rel": math.nan, "passes": True}


def truth_samples(scene_path, pulls, xs, sizes_mm, jobs: int | None = None, progress=None, stiffness_for=()) -> dict:
    """The truth at every sample of every pull: {"pulls": {name: [sample per x]}, "ensemble":
    members (JSON-ready), "refs": the chosen law's `pull_references`}. Each sample: the
    reference force (vector on the tissue, N) and magnitude, the band and its parts (mesh GCI,
    law spread, combined), the support (energy share outside the data's stretches, largest
    |J - 1|, over the meshes that reached it), and `decided` with the truth's own verdict and
    reason when not (`decide`). A sample the finer meshes did not follow has the coarsest mesh's
    force and no mesh band."""
    scene = scene_with(scene_path)
    law = scene.spec.material.law
    members = scene_ensemble(scene)
    idx = shape_index(members)
    shp = shapes(members)
    xs = np.asarray(xs, dtype=np.float64)
    sizes = sorted((float(s) for s in sizes_mm), reverse=True)
    refs = pull_references(scene_path, pulls, xs, sizes, jobs=jobs, progress=progress, stiffness_for=stiffness_for)
    upto = {p.name: refs["pulls"][p.name]["follow_m"] for p in pulls}
    # each other shape on the coarsest mesh, as far as the finer meshes follow
    per_shape = [refs["pulls"]] + [pull_references(scene_path, pulls, xs, (sizes[0],), jobs=jobs, law=s, upto=upto)["pulls"] for s in shp[1:]]
    contrast = scene_contrast(scene)
    per_contrast = [pull_references(scene_path, pulls, xs, (sizes[0],), jobs=jobs, law=c["law"], upto=upto)["pulls"] for c in contrast]
    pac = scene_pac_spread(scene)
    per_pac = [pull_references(scene_path, pulls, xs, (sizes[0],), jobs=jobs, law=m["law"], upto=upto)["pulls"] for m in pac]
    mu = law.shear_modulus
    out = {}
    for p in pulls:
        r = refs["pulls"][p.name]
        rows = []
        for k in range(len(xs)):
            c = combined_sample(r["force_per_pa"][:, k] * mu, r["h_m"])
            mesh_rel = c["band_rel"]
            if not math.isfinite(c["force_n"]) and np.all(np.isfinite(r["force_per_pa"][0, k])):
                # the finer meshes did not follow this far: the coarsest mesh's force, no mesh band
                vec = r["force_per_pa"][0, k] * mu
                c = c | {"force": vec, "force_n": float(np.linalg.norm(vec)), "status": "coarsest mesh only"}
                mesh_rel = math.nan
            coarse = [float(np.linalg.norm(per_shape[i][p.name]["force_per_pa"][0, k])) * m["law"].shear_modulus
                      for m, i in zip(members, idx)]
            law_rel = law_spread(coarse) if len(members) > 1 else 0.0
            # the pia-arachnoid's measured spread (the chosen law under it): another independent input, in the band
            membrane = [float(np.linalg.norm(pm[p.name]["force_per_pa"][0, k])) * mu for pm in per_pac]
            membrane_rel = law_spread([coarse[0]] + membrane) if membrane else 0.0
            band = combine(combine(mesh_rel, law_rel), membrane_rel)
            sup = np.asarray(r["support"])[:, k]  # (meshes, SUPPORT_FIELDS)
            reached = np.isfinite(sup[:, 0])
            rule = rule_inputs(sup)
            ok, truth, why = decide(c["force_n"], band, rule["decided_share"], rule["decided_j"], rule["decided_on"])
            # the literature's regional contrast: reported, and what it would leave decided (docs/reference.md, Regions)
            others = [float(np.linalg.norm(pc[p.name]["force_per_pa"][0, k])) * mu for pc in per_contrast]
            contrast_rel = law_spread([coarse[0]] + others) if others else math.nan  # NaN: no contrast solved (one material)
            with_contrast = decide(c["force_n"], combine(band, contrast_rel), rule["decided_share"], rule["decided_j"], rule["decided_on"])[0] if others else None
            rows.append(c | rule | {"mesh_band_rel": mesh_rel, "law_band_rel": law_rel, "band_rel": band, "band_half_n": band * c["force_n"],
                             "law_forces_n": coarse, "membrane_band_rel": membrane_rel, "membrane_forces_n": membrane, "contrast_band_rel": contrast_rel, "contrast_forces_n": others,
                             "decided_with_contrast": with_contrast,
                             "stretch_min": float(np.min(sup[reached, 2])) if reached.any() else math.nan,
                             "stretch_max": float(np.max(sup[reached, 3])) if reached.any() else math.nan,
                             "decided": ok, "truth": truth, "reason": why})
        out[p.name] = rows
    return {"pulls": out, "ensemble": members_json(members), "membrane_members": pac_json(pac), "contrast": contrast_json(contrast), "refs": refs}


def scene_contrast(scene) -> list[dict]:
    """The regional contrasts the literature spans, other than the scene's own and those resting
    on an assumed ratio (`regions.contrast_members`): solved on the coarsest mesh and reported with every sample, outside the
    band that decides (docs/reference.md, Regions, says why); [] for a brain of one material."""
    material = scene.spec.material
    if material.white_matter is None:
        return []
    grey_range = fitted_range(material.law_source)[0] if material.law_source else None
    # measured ratios and bounds only: the Jin-direction member's ratio is an assumption (not solved)
    return [m | {"kind": "contrast"} for m in contrast_members(material.law, grey_range) if not m["chosen"] and not m.get("assumed")]


def scene_pac_spread(scene) -> list[dict]:
    """The pia-arachnoid's measured spread as members of the band: the scene's body with the
    membrane's mu at (1 - s) and (1 + s) times its own (`MembraneLaw.mu_spread`), the chosen law
    under it; [] without a pia-arachnoid or a spread."""
    pac = scene.spec.material.pia_arachnoid
    if pac is None or pac.mu_spread == 0.0:
        return []
    body = scene_regions(scene)
    return [{"name": f"pia-arachnoid {name}", "role": "the pia-arachnoid's measured spread", "kind": "membrane",
             "law": dataclasses.replace(body, pac_scale=scale), "pac_scale": scale}
            for name, scale in (("low", 1.0 - pac.mu_spread), ("high", 1.0 + pac.mu_spread))]


def pac_json(pac: list[dict]) -> list[dict]:
    return [{"name": m["name"], "role": m["role"], "kind": "membrane", "pac_scale": m["pac_scale"]} for m in pac]


def contrast_json(contrast: list[dict]) -> list[dict]:
    return [{"name": m["name"], "kind": "contrast", "source": m["source"], "grey": m["law"].grey.params(),
             "white": m["law"].white.params() if m["law"].white is not None else None} for m in contrast]


def members_json(members: list[dict]) -> list[dict]:
    return [{"name": m["name"], "role": m["role"], "kind": m.get("kind", "law"), "law": m["law"].params(), "rms_rel_uniaxial": m["rms_rel_uniaxial"],
             "shear_worst_rel": m["shear_worst_rel"], "passes": m["passes"]} | ({"beyond_data": m["beyond_data"]} if "beyond_data" in m else {})
            for m in members]
