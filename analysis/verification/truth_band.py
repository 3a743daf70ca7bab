"""Where the tissue truth is decided: the law's ensemble, each sample's band and support, and
the rule that says whether a sample can judge a model (docs/reference.md).

- **Ensemble.** The data do not fix one law beyond their stretches, so the truth is a family:
  the scene's law (chosen on every loading mode), the best fit of every other law family that
  passes `ACCEPT` on the same data (uniaxial RMS error, worst shear error over strains 0.1-0.2),
  and the corners of the chosen law's 95% parameter box. Forces scale with mu at fixed
  exponents, so only the distinct shapes are solved (`shapes`), on the coarsest mesh.
- **Band.** Per sample: the mesh half-band (GCI, `tissue_pulls.combined_sample`) and the law
  half-band (the largest distance of an ensemble member's force from the chosen law's, relative)
  combined root-sum-square as independent parts (ASME V&V 20-2009's combination of numerical and
  input uncertainty).
- **Support.** Per sample: the share of the state's stored energy at quadrature points whose
  principal stretches leave the data's range, and the largest |J - 1| (the larger over the meshes).
- **Decided** (`decide`): a reference below the device's force limit, support share at most the
  JND fraction at that force (a law wrong by a factor of two where no one measured moves the force
  by about that share, the state changing to second order only: so by less than a JND), |J - 1| at
  most `MAX_J_DEVIATION`, and a band narrower than the JND. Otherwise `extrapolated` (support) or
  `undecided` (band, or an ensemble member not solved there), with the reason.
"""

from __future__ import annotations

import itertools
import json
import math

import numpy as np

from analysis.verification.material_fit import (
    MaterialDataError,
    fit_material,
    law_errors,
    law_of,
    material_data,
    read_curve,
)
from analysis.verification.tissue_pulls import SHIPPED_PULLS_INFO, combined_sample, law_shape_key, pull_references
from sim.hyperelastic import Hyperelastic
from sim.perception import force_jnd
from sim.pulls import scene_with

ACCEPT = {"rms_rel_uniaxial": 0.10, "shear_worst_rel": 0.20}  # a law fits the data "about as well" (the bar the chosen law met)
DEVICE_LIMIT_N = 3.3  # the PHANTOM Omni's largest force (docs/hardware.md): no sample above it is judged
MAX_J_DEVIATION = 0.05  # a nearly incompressible law: |J - 1| beyond this is not the tissue the data measured


def ensemble(material_path, law: Hyperelastic) -> list[dict]:
    """The truth's laws: {name, role, law, rms_rel_uniaxial, shear_worst_rel, passes} for the
    chosen `law` (the material file's), each other family's best fit that passes `ACCEPT`, and
    the corners of the chosen family's 95% parameter box (fitted on the material's own data)."""
    paths, region = material_data(material_path)
    curves = [read_curve(p, region) for p in paths]
    fit = fit_material(paths, region, bulk_ratio=law.bulk_ratio)
    family = "ogden-2" if law.law == "ogden" and len(law.mu) == 2 else law.law

    def member(name, role, member_law):
        err = law_errors(member_law, curves)
        ok = all(not (err[k] > v) for k, v in ACCEPT.items())  # NaN (a mode without data) passes
        return {"name": name, "role": role, "law": member_law, **err, "passes": bool(ok)}

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
    return out


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


def decide(force_n: float, band_rel: float, share_outside: float, max_j_dev: float) -> tuple[bool, str, str]:
    """(decided, the truth's verdict when not decided: "extrapolated" or "undecided", reason)."""
    if not math.isfinite(force_n):
        return False, "undecided", "no reference force"
    tol = float(force_jnd(np.array(force_n)))
    if force_n > DEVICE_LIMIT_N:
        return False, "extrapolated", f"reference {force_n:.2f} N above the device's {DEVICE_LIMIT_N:g} N"
    if not math.isfinite(share_outside):
        return False, "undecided", "the law names no data, so where its states rest on measurements is unknown"
    if not (share_outside <= tol):
        return False, "extrapolated", f"{share_outside:.0%} of the energy outside the data's stretches (at most {tol:.0%}, the JND here)"
    if not (max_j_dev <= MAX_J_DEVIATION):
        return False, "extrapolated", f"|J - 1| up to {max_j_dev:.3f} (at most {MAX_J_DEVIATION:g})"
    if not math.isfinite(band_rel):
        return False, "undecided", "no band (an ensemble law or a finer mesh was not solved here)"
    if not (band_rel < tol):
        return False, "undecided", f"band +-{band_rel:.0%} not narrower than the JND {tol:.0%}"
    return True, "", ""


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
            band = combine(mesh_rel, law_rel)
            sup = np.asarray(r["support"])[:, k]  # (meshes, 4)
            reached = np.isfinite(sup[:, 0])
            share = float(np.max(sup[reached, 0])) if reached.any() else math.nan
            jdev = float(np.max(sup[reached, 1])) if reached.any() else math.nan
            ok, truth, why = decide(c["force_n"], band, share, jdev)
            rows.append(c | {"mesh_band_rel": mesh_rel, "law_band_rel": law_rel, "band_rel": band, "band_half_n": band * c["force_n"],
                             "law_forces_n": coarse, "support_share_outside": share, "max_abs_j_minus_1": jdev,
                             "stretch_min": float(np.min(sup[reached, 2])) if reached.any() else math.nan,
                             "stretch_max": float(np.max(sup[reached, 3])) if reached.any() else math.nan,
                             "decided": ok, "truth": truth, "reason": why})
        out[p.name] = rows
    return {"pulls": out, "ensemble": members_json(members), "refs": refs}


def members_json(members: list[dict]) -> list[dict]:
    return [{"name": m["name"], "role": m["role"], "law": m["law"].params(), "rms_rel_uniaxial": m["rms_rel_uniaxial"],
             "shear_worst_rel": m["shear_worst_rel"], "passes": m["passes"]} for m in members]
