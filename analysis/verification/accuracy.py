"""Model error against run time, fairly: every model on the same pulls at the scene's own
modulus, against a converged reference, calibrated with the same budget and judged on pulls
it was not calibrated on (docs/accuracy.md).

- **Pulls.** Calibration: the three grasp points of `sim.pulls.make_pulls` (the scene's two
  hands and a frontal point) x two tangent directions. Test (held out): `sim.pulls.test_pulls`,
  six places away from those (three per hemisphere) x two directions. The hand moves at 10 mm/s;
  each model runs its visual frames along the ramp (so the corotational FEM's per-frame
  iteration and the mass-spring's dynamics are what a user would feel) and is sampled at
  `samples` equal displacements.
- **Reference** (`analysis.verification.reference.pull_references`): the tissue's finite-strain law (human
  cortex, one-term Ogden, nearly incompressible; docs/material.md) on P2 tetrahedra on the
  shipped fTetWild meshes of each hemisphere at three sizes, the area-mean grasp
  (`sim.geometry.patch`), each pull followed by Newton from rest; Richardson extrapolation of the force
  magnitude with the GCI band (`combined_sample`). Solved once and shipped
  (data/reference_pulls.npz), hash-checked.
- **Calibration budget.** Every model gets one stiffness scale s, fitted on the calibration
  pulls (the geometric mean of reference over model force: least squares in log force), and
  is reported raw (s = 1) and calibrated; s multiplies the force, as scaling the modulus would
  (exactly for the FEM and the plate-spring stack; the mass-spring's hand coupling does not scale).
- **Verdicts** per test sample: within the JND (10% at or above 0.5 N, 25% below, of the
  reference) as a point estimate; and against the reference's band: `within` when the whole
  band is within the JND of the model's force, `outside` when none of it is, else `undecided`.
  Fractions carry Wilson 95% intervals. Samples of one pull are correlated (a linear model's
  are one number times the displacement), so `pulls_within` counts whole pulls too.
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.optimize import brentq

from analysis.statistics.stats import wilson
from analysis.verification.bench_pulls import HANDSET_PARAMS, model_pulls, pull_speed
from analysis.verification.pulls_in_time import record_times
from analysis.verification.regions import membrane_meta, regions_meta
from analysis.verification.tissue_pulls import (
    DEFAULT_SIZES_MM,
    ReferenceDataError,
    pull_samples,
    reached,
)
from analysis.verification.truth_band import (
    DEVICE_LIMIT_N,
    MARGINAL_LIMIT,
    MAX_J_DEVIATION,
    combine,
    decide,
    truth_samples,
)
from analysis.verification.truth_in_time import QUASI_STATIC, SPEED_NAMES, bench_speeds, truth_in_time
from sim.errors import SceneError
from sim.models.api import BUDGETS
from sim.models.mass_spring import OMNI_MAX_STIFFNESS
from sim.models.registry import installed, plugins
from sim.perception import force_jnd
from sim.pulls import TEST_PLACES, Pull, make_pulls, scene_with, test_pulls
from sim.scene import DEFAULT_SCENE, load_scene
from sim.sweep import run_tasks

DECIDED_RULE = (f"decided: reference at most {DEVICE_LIMIT_N:g} N, a marginal share dE_out/dE (the force's share from quadrature points "
                f"outside the data's principal stretches) at most {MARGINAL_LIMIT:g} x the JND fraction at that force (25% below 0.5 N, 10% above), "
                f"|J - 1| at most {MAX_J_DEVIATION:g} at the nodes and a 64-point rule, and the band "
                "(mesh GCI and the ensemble's law spread, root-sum-square) narrower than the JND")


@dataclass(frozen=True)
class Setting:
    model: str  # plate_spring | fem | mass_spring
    setting: str  # the row label: continuous, calibrated, 4mm, corotational-6mm, ...
    options: tuple = ()  # (key, value) pairs for the model spec


@dataclass(frozen=True)
class AccuracyConfig:
    scene: Path = DEFAULT_SCENE
    young: float | None = None  # Pa, the linear models' modulus; None: the scene's. Another value scales the whole brain:
    # the law's mu by the same ratio (its forces scale exactly), so the reference and every model move together
    max_pull: float = 0.012  # m: the scenes' scripted pulls; beyond, no truth is decided (docs/reference.md)
    samples: int = 24  # every 0.5 mm: the shipped solves' records
    reference_sizes_mm: tuple[float, ...] = (8.0, 6.0, 4.0)  # the reference's meshes: the shipped body-fitted ones (sim/geometry/tetmesh.py)
    test_places: int = TEST_PLACES
    settings: tuple[Setting, ...] = field(default_factory=lambda: default_settings(False))
    handset: Path = HANDSET_PARAMS  # the uncalibrated plate-spring parameters
    quick: bool = False
    speeds: tuple[str, ...] = SPEED_NAMES  # `truth_in_time.bench_speeds`: the truth and the pulls at each


def default_settings(quick: bool) -> tuple[Setting, ...]:
    ps = [Setting("plate_spring", "paper", (("variant", "paper"), ("params", "handset"))),
          Setting("plate_spring", "continuous", (("variant", "continuous"), ("params", "handset"))),
          Setting("plate_spring", "scene-fit", (("variant", "continuous"), ("params", "scene"))),
          Setting("plate_spring", "located", (("variant", "located"), ("params", "located")))]
    # every FEM row names its element; the P2 rows stop at 6 mm: the reference's finest mesh (4 mm)
    # with P2 is the reference itself. linear-p2-8mm is the scene's FEM (protocols/scenes/brain_pull.toml).
    fem_res = (8, 6) if quick else (8, 6, 4)
    corot_res = (8,) if quick else (8, 6)
    ms_res = () if quick else (8,)  # the implicit step is slow on the body-fitted mesh (docs/accuracy.md)
    lg_res = (8, 6) if quick else (8, 6, 4)
    fem = [Setting("fem", f"linear-{r}mm", (("formulation", "linear"), ("resolution", r / 1000), ("order", 1))) for r in fem_res]
    fem += [Setting("fem", f"linear-p2-{r}mm", (("formulation", "linear"), ("resolution", r / 1000), ("order", 2))) for r in (8, 6)[: 1 if quick else 2]]
    fem += [Setting("fem", f"corotational-{r}mm", (("formulation", "corotational"), ("resolution", r / 1000), ("order", 1))) for r in corot_res]
    # the explicit integrator: its critical step on the body-fitted mesh is short (the small
    # elements by the folded surface: the step and the sub-steps a frame in docs/fem.md)
    ms = [Setting("mass_spring", f"explicit-{r}mm", (("integrator", "explicit"), ("resolution", r / 1000))) for r in ms_res]
    ms += [Setting("mass_spring", f"implicit-{r}mm", (("integrator", "implicit"), ("resolution", r / 1000))) for r in ms_res]
    ms += [Setting("mass_spring", f"local-global-{r}mm", (("integrator", "local-global"), ("resolution", r / 1000))) for r in lg_res]
    if not quick:  # the discrimination protocol's mass-spring (protocols/stiffness_jnd.toml): 3 iterations a frame
        ms.append(Setting("mass_spring", "local-global-8mm-3it", (("integrator", "local-global"), ("resolution", 0.008), ("iterations", 3))))
    return tuple(ps + fem + ms + plugin_settings())


def plugin_settings() -> list[Setting]:
    """A row for every installed model outside brainsim (a lab's own): as the scene configures
    it, else with its declared defaults."""
    models, _ = installed()
    return [Setting(name, "default") for name in plugins(models) if plugin_problem(name) is None]


def plugin_problem(name: str, scene_path=DEFAULT_SCENE) -> str | None:
    """Why the benches leave a lab's model out of their default rows, or None: it has an
    option without a default and the scene does not configure it."""
    try:
        load_scene(scene_path).options_of(name)
    except SceneError as exc:
        return str(exc)
    return None


def quick_config(**kw) -> AccuracyConfig:
    """A smaller bench for CI and `make demo`: 20 and 16 mm reference meshes, 6 samples (every
    2 mm), two test places, coarse settings."""
    return AccuracyConfig(**({"samples": 6, "reference_sizes_mm": (20.0, 16.0), "test_places": 2,
                              "settings": default_settings(True), "quick": True} | kw))


def sample_displacements(cfg: AccuracyConfig) -> np.ndarray:
    return pull_samples(cfg.max_pull, cfg.samples)


# -- the reference -------------------------------------------------------------------------

def reference_samples(truth: dict, pulls: list[Pull]) -> list[list[dict]]:
    """Per pull and sample: the truth (`analysis.verification.truth_band.truth_samples`): the reference force
    (N, vector on the tissue), its magnitude, band and support, and whether it is decided."""
    return [truth["pulls"][p.name] for p in pulls]


def calibration_curve(scene_path, xs, jobs: int | None = None, progress=None) -> tuple:
    """The converged reference's force magnitude (N, the scene's law) on the bench's calibration
    pulls (`make_pulls`), at displacements `xs`: (displacements, forces, how), the pulls'
    curves concatenated. What `calibrate plate-spring` fits to."""
    scene = scene_with(scene_path)
    pulls = make_pulls(scene)
    xs = np.asarray(xs, dtype=np.float64)
    truth = truth_samples(scene_path, pulls, xs, DEFAULT_SIZES_MM, jobs=jobs, progress=progress)
    law = scene.spec.material.law
    rows = reference_samples(truth, pulls)
    forces = np.array([[c["force_n"] for c in row] for row in rows]).ravel()
    ok = np.array([[c["decided"] for c in row] for row in rows]).ravel()
    if not ok.any():
        raise ReferenceDataError("calibration curve: the truth is decided at no sample of the calibration pulls")
    white = scene.spec.material.white_matter
    body = law.describe() + (f" as grey matter, {white.describe()} as white matter inside FreeSurfer's white surface" if white else "")
    how = (f"the converged reference ({body}, finite strain on P2 on the body-fitted "
           f"{', '.join(f'{s:g}' for s in DEFAULT_SIZES_MM)} mm meshes, Richardson-extrapolated; "
           f"the accuracy bench's {len(pulls)} calibration pulls, at the {int(ok.sum())} of {ok.size} samples where the truth is "
           f"decided: {_not_decided_words([c for row in rows for c in row])})")
    return np.tile(xs, len(pulls))[ok], forces[ok], how


def _not_decided_words(cells: list[dict]) -> str:
    """"n extrapolated, m undecided, k without a reference" over samples."""
    ext = sum(c["truth"] == "extrapolated" for c in cells)
    und = sum(c["truth"] == "undecided" and math.isfinite(c["force_n"]) for c in cells)
    none = sum(not math.isfinite(c["force_n"]) for c in cells)
    return f"{ext} extrapolated, {und} undecided, {none} without a reference"


# -- the bench -----------------------------------------------------------------------------

def _task(task):
    _, scene_path, young, setting, pulls, xs, handset, e_ratio, speed = task
    return model_pulls(scene_path, young, setting, pulls, xs, handset, e_ratio, speed.speed_m_s, speed.holds_s) | {"speed": speed.name}


def run_accuracy(cfg: AccuracyConfig, jobs: int | None = None, scheduler: str | None = None, progress=None) -> dict:
    """The reference, then every setting, on the calibration and test pulls; returns rows
    (raw and calibrated per setting), per-sample verdicts and meta."""
    scene = scene_with(cfg.scene)
    young = float(cfg.young if cfg.young is not None else scene.spec.material.young)
    e_ratio = young / scene.spec.material.young
    law = scene.spec.material.law.scaled(e_ratio)
    calib, test = make_pulls(scene), test_pulls(scene, cfg.test_places)
    pulls = calib + test
    xs = sample_displacements(cfg)
    speeds = bench_speeds(cfg.speeds)
    n_tasks = len(cfg.settings) * len(speeds)

    def ref_progress(k, n):
        if progress is not None:
            progress(k, n + n_tasks)

    start = time.perf_counter()
    truth = truth_samples(cfg.scene, pulls, xs, cfg.reference_sizes_mm, jobs=jobs, progress=ref_progress)
    refs = truth["refs"]
    ref_s = time.perf_counter() - start
    if e_ratio != 1.0:  # a stiffer or softer brain of the same shape: every force scales with mu
        truth = _scaled(truth, e_ratio)
    ref = reference_samples(truth, pulls)
    n_ref = len(pulls) * len(cfg.reference_sizes_mm)

    def model_progress(k, n):
        if progress is not None:
            progress(n_ref + k, n_ref + n)

    tasks = [("model", str(cfg.scene), young, s, pulls, xs, cfg.handset, e_ratio, sp) for sp in speeds for s in cfg.settings]
    models = run_tasks(_task, tasks, jobs=jobs, scheduler=scheduler, progress=model_progress)
    rows, samples, in_time, scales = [], [], {}, None
    for sp in sorted(speeds, key=lambda sp: sp.speed_m_s is not None):  # quasi-static first: its scale serves every speed
        cells, columns = ref, xs
        if sp.speed_m_s is not None:  # the viscoelastic truth on the timeless truth's coarsest mesh
            timed, in_time[sp.name] = truth_in_time(cfg.scene, scene, truth, pulls, xs, sp, max(cfg.reference_sizes_mm), e_ratio)
            cells = [timed[p.name] for p in pulls]
            columns = record_times(xs, sp.speed_m_s, sp.holds_s)[1]
        r, smp = compare(cells, [m for m in models if m["speed"] == sp.name], pulls, len(calib), columns, sp.name, scales)
        if sp.name == QUASI_STATIC:
            scales = {(x["model"], x["setting"]): x["scale"] for x in r if x["calibration"] == "calibrated"}
        rows += r
        samples += smp
    flat = [c for row in ref for c in row]
    solved = [c for c in flat if math.isfinite(c["force_n"]) and math.isfinite(c["band_rel"])]
    if not solved:
        raise ReferenceDataError("accuracy bench: no reference solve reached any sample")
    solves = [s for r in refs["pulls"].values() for s in r["solves"]]

    coupling = float(scene.spec.options_of("mass_spring")["coupling"])
    meta = {
        "synthetic": False,
        # what a mass-spring's hand coupling alone allows: an exact tissue behind the scene's
        # coupling and behind the stiffest an Omni renders stably at 1 kHz
        "coupling_bound": {"scene_n_per_m": coupling, "scene": coupling_bound(ref, len(calib), xs, coupling),
                           "omni_max_n_per_m": OMNI_MAX_STIFFNESS, "omni_max": coupling_bound(ref, len(calib), xs, OMNI_MAX_STIFFNESS)},
        "young_pa": young, "scene_young_pa": scene.spec.material.young,
        "max_pull_m": cfg.max_pull, "samples_per_pull": cfg.samples, "pull_speed_m_per_s": pull_speed(xs, scene.spec.visual_rate_hz),
        "speeds": [{"speed": sp.name, "speed_m_s": sp.speed_m_s, "holds_s": list(sp.holds_s)} for sp in speeds],
        "calibration_pulls": [dataclasses.asdict(p) for p in calib],
        "test_pulls": [dataclasses.asdict(p) for p in test],
        "reference": {
            "setting": f"{law.law}-p2-bodyfitted-{'/'.join(f'{x:g}' for x in refs['sizes_mm'])}mm",
            "element": "P2 (10-node tetrahedra)", "mesher": "fTetWild (pytetwild)", "grasp": "area mean (sim/geometry/patch.py)",
            "formulation": f"finite strain, {law.describe()}, Richardson", "law": law.params(),
            "law_source": scene.spec.material.law_source, "sizes_mm": refs["sizes_mm"],
            "band_rel_max": float(max(c["band_rel"] for c in solved)), "band_rel_median": float(np.median([c["band_rel"] for c in solved])),
            "band_half_n_max": float(max(c["band_half_n"] for c in solved)),
            "ensemble": truth["ensemble"], "decided_rule": DECIDED_RULE,
            "samples": {"decided": sum(c["decided"] for c in flat), "extrapolated": sum(c["truth"] == "extrapolated" for c in flat),
                        "undecided": sum(c["truth"] == "undecided" and math.isfinite(c["force_n"]) for c in flat),
                        "no_reference": sum(not math.isfinite(c["force_n"]) for c in flat)},
            "test_decided": sum(c["decided"] for row in ref[len(calib):] for c in row),
            "max_abs_j_minus_1_decided": max((c["max_abs_j_minus_1"] for c in flat if c["decided"]), default=math.nan),
            # the finer rule's |J - 1| where the solves recorded it (NaN before: those samples decided on the Gauss points)
            "max_abs_j_minus_1_fine_decided": max((c["max_abs_j_minus_1_fine"] for c in flat
                                                   if c["decided"] and math.isfinite(c.get("max_abs_j_minus_1_fine", math.nan))), default=math.nan),
            "decided_on": {m: sum(c["decided"] and c.get("decided_on") == m for c in flat) for m in sorted({c.get("decided_on") for c in flat if c.get("decided_on")})},
            "regions": regions_meta(scene), "pia_arachnoid": membrane_meta(scene, truth.get("membrane_members", [])), "contrast": truth.get("contrast", []),
            # how many decided samples stay decided with the literature's regional contrast in the band (None: one material)
            "decided_with_contrast": sum(bool(c.get("decided_with_contrast")) for c in flat if c["decided"]) if truth.get("contrast") else None,
            "support_share_decided_max": max((c["support_share_outside"] for c in flat if c["decided"]), default=math.nan),
            "decided_share_max": max((c["decided_share"] for c in flat if c["decided"]), default=math.nan),
            "statuses": {s: sum(c["status"] == s for c in flat) for s in sorted({c["status"] for c in flat})},
            "converged": all(s["converged"] for s in solves),
            # samples past where a mesh's solve stopped have no reference: left out of every row
            "no_reference": _no_reference(ref, pulls, xs, refs["pulls"]),
            "min_jacobian": min((s["min_jacobian"] for s in solves if "min_jacobian" in s), default=math.nan),
            "solves_stored": sum(bool(s.get("cached")) for s in solves), "solves": len(solves), "seconds": ref_s,
            "in_time": in_time,
        },
        "quick": cfg.quick,
    }
    return {"rows": rows, "best": class_best(rows, quick=cfg.quick), "samples": samples, "by_displacement": breakdown(samples, "displacement_mm"),
            "by_force_band": breakdown(samples, "force_band"), "meta": meta}


def _no_reference(ref: list[list[dict]], pulls: list[Pull], xs, refs: dict) -> list[dict]:
    """The pulls with samples that have no reference force at all (the coarsest mesh's solve
    stopped before them): how many, the last x reached (mm) and why (`tissue_pulls.reached`)."""
    out = []
    for p, row in zip(pulls, ref):
        ok = np.array([math.isfinite(c["force_n"]) for c in row])
        if not ok.all():
            out.append({"pull": p.name, "samples": int((~ok).sum()), "reached_mm": float(np.asarray(xs)[ok].max() * 1e3) if ok.any() else 0.0,
                        "why": reached(refs)[p.name][1] or "no reference solve reached it"})
    return out


def _scaled(truth: dict, ratio: float) -> dict:
    """The truth of a brain `ratio` times as stiff (forces scale with mu; bands and support do not)."""
    pulls = {}
    for name, rows in truth["pulls"].items():
        out = []
        for c in rows:
            f = c["force_n"] * ratio
            ok, verdict_, why = decide(f, c["band_rel"], c["decided_share"], c["decided_j"], c["decided_on"])
            contrast = c.get("decided_with_contrast")
            if contrast is not None:
                contrast = decide(f, combine(c["band_rel"], c["contrast_band_rel"]), c["decided_share"], c["decided_j"], c["decided_on"])[0]
            out.append(c | {"force": np.asarray(c["force"]) * ratio, "force_n": f, "band_half_n": c["band_half_n"] * ratio,
                            "forces_n": [x * ratio for x in c["forces_n"]]}
                       | {k: [x * ratio for x in c.get(k, [])] for k in ("law_forces_n", "membrane_forces_n", "contrast_forces_n")}
                       | {"decided": ok, "truth": verdict_, "reason": why, "decided_with_contrast": contrast})
        pulls[name] = out
    return truth | {"pulls": pulls}


FORCE_BANDS = ((0.0, 0.1, "below 0.1 N"), (0.1, 0.5, "0.1-0.5 N"), (0.5, math.inf, "above 0.5 N"))


def force_band(force_n: float) -> str:
    return next(label for lo, hi, label in FORCE_BANDS if lo <= force_n < hi)


def breakdown(samples: list[dict], by: str) -> list[dict]:
    """Held-out samples per model, speed, calibration and group (`displacement_mm` or `force_band`):
    decided, within the JND among them (with a Wilson interval), extrapolated and undecided. Per
    displacement, the ramp's samples only (a hold's are at the last displacement, later)."""
    groups: dict = {}
    for c in samples:
        if c["set"] != "test" or (by == "displacement_mm" and c.get("hold_s", 0.0) > 0):
            continue
        g = c[by] if by != "force_band" else force_band(c["reference_force_n"])
        groups.setdefault((c["model"], c["setting"], c.get("speed", QUASI_STATIC), c["calibration"], g), []).append(c)
    out = []
    for (model, setting, speed, calibration, g), cs in groups.items():
        dec = [c for c in cs if c["decided"]]
        k = sum(c["within_jnd"] for c in dec)
        lo, hi = wilson(k, len(dec)) if dec else (math.nan, math.nan)
        out.append({"model": model, "setting": setting, "speed": speed, "calibration": calibration, by: g, "decided": len(dec), "within": k,
                    "within_jnd": k / len(dec) if dec else math.nan, "within_jnd_low": lo, "within_jnd_high": hi,
                    "extrapolated": sum(c["verdict"] == "extrapolated" for c in cs), "undecided": sum(not c["decided"] and c["verdict"] == "undecided" for c in cs)})
    return out


def _angle(f, g) -> float:
    nf, ng = float(np.linalg.norm(f)), float(np.linalg.norm(g))
    if nf == 0 or ng == 0:
        return 180.0
    return math.degrees(math.acos(max(-1.0, min(1.0, float(np.dot(f, g)) / (nf * ng)))))


def verdict(force: float, reference: float, half_band: float) -> str:
    """Within the JND for every reference value in its band, for none, or undecided."""
    e, tol = abs(force - reference), float(force_jnd(np.array(reference))) * reference
    return "within" if e + half_band <= tol else "outside" if e - half_band > tol else "undecided"


def calibration_scale(model_mags: np.ndarray, ref_mags: np.ndarray) -> float:
    """One stiffness scale: exp(mean log(reference / model)) over the calibration samples."""
    ok = (model_mags > 0) & np.isfinite(model_mags) & np.isfinite(ref_mags)
    return float(np.exp(np.mean(np.log(ref_mags[ok] / model_mags[ok])))) if ok.any() else math.nan


def compare(ref: list[list[dict]], models: list[dict], pulls: list[Pull], n_calib: int, xs, speed: str = QUASI_STATIC,
            scales: dict | None = None) -> tuple[list[dict], list[dict]]:
    """Rows (per setting: raw and calibrated) judged on the test pulls (pulls[n_calib:]) at the
    samples where the truth is decided, and every sample (the others carry the truth's verdict,
    `extrapolated` or `undecided`, and its reason). The calibration scale is fitted on the
    calibration pulls' decided samples, or given per (model, setting) in `scales` (the quasi-static
    one, used at every speed). `xs`: each sample's displacement (m); `speed` the truth's
    speed (`truth_in_time.SPEED_NAMES`); each sample carries it, the model's pull speed and the
    time it was reached (`bench_pulls.model_pulls`' `times_s`), and the cell's `hold_s`."""
    rows, samples = [], []
    R = np.array([[c["force_n"] for c in row] for row in ref])  # (P, n)
    H = np.array([[c["band_half_n"] for c in row] for row in ref])
    D = np.array([[c["decided"] for c in row] for row in ref], dtype=bool)
    for m in models:
        v = m.get("speed_m_s")
        F = np.asarray(m["force"])
        mags = np.linalg.norm(F, axis=2)
        calib = D[:n_calib]
        scale = (scales or {}).get((m["model"], m["setting"]), calibration_scale(mags[:n_calib][calib], R[:n_calib][calib]))
        for calibration, s in (("raw", 1.0), ("calibrated", scale)):
            errs, within, verdicts, angles, calib_errs, beyond = [], [], [], [], [], []
            counts = {"extrapolated": 0, "truth_undecided": 0, "no_reference": 0}
            pulls_within = pulls_judged = 0
            for p, pull in enumerate(pulls):
                test = p >= n_calib
                all_in, judged = True, 0
                for k, x in enumerate(xs):
                    f = s * mags[p, k]
                    r = R[p, k]
                    cell = ref[p][k]
                    if not math.isfinite(r):  # no reference here (its solve stopped, or none shipped): not judged
                        counts["no_reference"] += int(test)
                        continue
                    rel = abs(f - r) / r
                    ok = bool(abs(f - r) <= float(force_jnd(np.array(r))) * r)
                    verdict_ = verdict(f, r, H[p, k]) if D[p, k] else cell["truth"]
                    ang = _angle(-F[p, k], cell["force"])  # the reference is the force on the tissue
                    samples.append({"model": m["model"], "setting": m["setting"], "calibration": calibration, "set": "test" if test else "calibration",
                                    "speed": speed, "speed_m_s": v, "hold_s": float(cell.get("hold_s", 0.0)),
                                    "time_s": float(m["times_s"][k]) if "times_s" in m else math.nan,
                                    "pull": pull.name, "displacement_mm": round(float(x) * 1e3, 6), "force_n": f, "reference_force_n": r,
                                    "reference_half_band_n": float(H[p, k]), "mesh_band_rel": cell["mesh_band_rel"], "law_band_rel": cell["law_band_rel"],
                                    "support_share_outside": cell["support_share_outside"], "max_abs_j_minus_1": cell["max_abs_j_minus_1"],
                                    **{name: cell.get(name, math.nan) for name in ("marginal_share_outside", "max_abs_j_minus_1_fine", "decided_share", "contrast_band_rel")},
                                    "decided_with_contrast": cell.get("decided_with_contrast"),
                                    "decided_on": cell.get("decided_on", ""),
                                    "decided": bool(D[p, k]), "reason": cell["reason"],
                                    **{name: cell.get(name, math.nan) for name in ("rate_share_outside", "strain_rate_per_s", "static_force_n", "mesh_correction")},
                                    "left_by": cell.get("left_by", ""),
                                    "force_error": rel, "within_jnd": ok, "verdict": verdict_, "angle_deg": ang})
                    if not D[p, k]:
                        if test:
                            counts["extrapolated" if verdict_ == "extrapolated" else "truth_undecided"] += 1
                            if verdict_ == "extrapolated":
                                beyond.append(rel)
                        continue
                    if test:
                        errs.append(rel)
                        within.append(ok)
                        verdicts.append(verdict_)
                        angles.append(ang)
                        all_in = all_in and ok
                        judged += 1
                    else:
                        calib_errs.append(rel)
                pulls_within += int(test and judged > 0 and all_in)  # a pull with no decided sample is not judged
                pulls_judged += int(test and judged > 0)
            n = len(within)
            lo, hi = wilson(int(sum(within)), n) if n else (math.nan, math.nan)
            rows.append({"model": m["model"], "setting": m["setting"], "speed": speed, "speed_m_s": v, "calibration": calibration, "scale": s,
                         "force_error": nan_mean(errs), "force_error_max": float(np.max(errs)) if errs else math.nan,
                         "within_jnd": nan_mean(within), "within_jnd_low": lo, "within_jnd_high": hi, "n_test": n,
                         "n_within_jnd": int(sum(within)), "withheld": too_few(n),
                         "within": verdicts.count("within"), "outside": verdicts.count("outside"), "undecided": verdicts.count("undecided"),
                         "extrapolated": counts["extrapolated"], "truth_undecided": counts["truth_undecided"], "no_reference": counts["no_reference"],
                         "pulls_within": pulls_within, "n_test_pulls": pulls_judged,
                         "angle_deg": nan_mean(angles), "angle_deg_max": float(np.max(angles)) if angles else math.nan,
                         "calibration_error": nan_mean(calib_errs),
                         # against the truth where it rests beyond its data (a prediction, not a verdict)
                         "force_error_extrapolated": nan_mean(beyond),
                         "tick_us": m["tick_us"], "frame_ms": m["frame_ms"], "frame_ms_p99": m["frame_ms_p99"],
                         "build_s": m["build_s"], "unstable_pulls": int(m["unstable"])})
    return rows, samples


def nan_mean(values) -> float:
    return float(np.mean(values)) if len(values) else math.nan


def coupling_bound(ref: list[list[dict]], n_calib: int, xs, stiffness: float) -> float:
    """The fraction of held-out samples within the JND that a tissue model exact in every other
    respect reaches behind a virtual coupling of `stiffness` N/m (how the mass-spring renders:
    the hand at d pulls the patch through a spring, so the patch lags by F / k): F solves
    F = F_ref(d - F / k) along the pull, F_ref interpolated linearly from rest between the
    reference's samples (above a convex curve, so the bound is if anything optimistic)."""
    within = []
    for row in ref[n_calib:]:
        mags = np.array([c["force_n"] for c in row])
        known = np.isfinite(mags)
        decided = known & np.array([bool(c.get("decided", True)) for c in row])  # rated where the truth is decided
        x = np.concatenate([[0.0], np.asarray(xs, dtype=np.float64)[known]])
        f = np.concatenate([[0.0], mags[known]])
        for d, r in zip(np.asarray(xs)[decided], mags[decided]):
            F = brentq(lambda F, d=d, x=x, f=f: F - float(np.interp(d - F / stiffness, x, f)), 0.0, stiffness * d)
            within.append(abs(F - r) <= float(force_jnd(np.array(r))) * r)
    return float(np.mean(within)) if within else math.nan


TARGET_WITHIN = 0.80  # a class follows the tissue when one configuration is within the JND on 80% of held-out samples
# The fewest decided held-out samples a rate, a verdict or "meets target" is given from: 39 is the
# smallest n at which every Wilson 95% interval, whatever the count, is at most RATE_HALF_WIDTH
# either side, narrow enough that a rate at the 80% target and one at chance (50%) cannot share
# an interval. Below it a row shows its counts only (the quick bench's rows are, at its two
# default test places).
MIN_DECIDED = 39
RATE_HALF_WIDTH = 0.15
# The quick bench gives no verdict whatever its samples (`--test-places 20` gives rows past
# MIN_DECIDED): its truth is two coarse meshes, whose agreement need not mean convergence, and it
# runs only the cheaper settings, so a "no" would not be the class's either.
QUICK_REASON = "a coarse reference and the cheaper settings give no verdict, whatever the decided samples"
QUICK_NOTE = f"quick bench: a smoke run that decides nothing ({QUICK_REASON})"


def too_few(n: int) -> str | None:
    """Why a rate over `n` decided samples is withheld, or None."""
    return f"too few decided samples ({n} < {MIN_DECIDED})" if n < MIN_DECIDED else None


def class_best(rows: list[dict], frame_budget_ms: float | None = None, quick: bool = False) -> list[dict]:
    """Each class (model) at its best at each speed, raw and calibrated: the configuration with the most
    held-out samples within the JND among those whose frame keeps the contract's budget (p99,
    `sim.models.api.BUDGETS`), that gave up no pull and that have at least `MIN_DECIDED` decided
    samples; ties go to the lower force error, then the faster frame. A class with no such
    configuration gets a row with `setting` None and the reason, and `meets_target` None where
    every configuration had too few decided samples (no verdict either way). `meets_target`:
    within on at least `TARGET_WITHIN` of the samples; None for every class of a `quick` bench
    (`QUICK_REASON` in `why`)."""
    budget = float(BUDGETS["deformation_ms_p99"] if frame_budget_ms is None else frame_budget_ms)
    out = []
    for model, speed, calibration in dict.fromkeys((r["model"], r.get("speed", QUASI_STATIC), c) for r in rows for c in ("raw", "calibrated")):
        cands = [r for r in rows if r["model"] == model and r.get("speed", QUASI_STATIC) == speed and r["calibration"] == calibration]
        if not cands:
            continue
        left = {r["setting"]: ("gave up on a pull" if r["unstable_pulls"] else f"frame p99 {r['frame_ms_p99']:.3g} ms over the {budget:g} ms budget")
                for r in cands if r["unstable_pulls"] or not r["frame_ms_p99"] <= budget}
        few = {r["setting"]: why for r in cands if r["setting"] not in left and (why := too_few(r["n_test"]))}
        ok = [r for r in cands if r["setting"] not in left and r["setting"] not in few]
        base = {"model": model, "speed": speed, "calibration": calibration, "frame_budget_ms": budget, "left_out": left | few}
        if all(too_few(r["n_test"]) for r in cands):  # no rate can be given: no verdict, not a "no"
            most = max(r["n_test"] for r in cands)
            out.append(base | {"setting": None, "meets_target": None, "why": f"too few decided samples in every configuration ({most} < {MIN_DECIDED})"})
            continue
        if not ok:
            out.append(base | {"setting": None, "meets_target": False, "why": "no configuration keeps the budget without giving up a pull"
                               + (f" and has at least {MIN_DECIDED} decided samples" if few else "")})
            continue
        best = max(ok, key=lambda r: (r["within_jnd"], -r["force_error"], -r["frame_ms"]))
        out.append(base | {k: best[k] for k in ("setting", "scale", "within_jnd", "within_jnd_low", "within_jnd_high", "force_error",
                                                "n_test", "n_within_jnd", "pulls_within", "n_test_pulls", "frame_ms", "frame_ms_p99")}
                   | {"meets_target": bool(best["within_jnd"] >= TARGET_WITHIN), "why": ""})
    if quick:
        return [b | {"meets_target": None, "why": "; ".join(filter(None, (b["why"], f"quick bench: {QUICK_REASON}")))} for b in out]
    return out
