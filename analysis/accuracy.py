"""Model error against run time: the same pulls for every tissue model and setting, compared
with a nonlinear (neo-Hookean) FEM reference at the finest resolution (docs/accuracy.md).

Pulls: three grasp points (the scene's two hands and a frontal point), each pulled along two
tangent directions (lateral and anterior), the hand moving at 10 mm/s to `max_pull`; each
model runs its visual frames along the ramp (so the corotational FEM's per-frame iteration and
the mass-spring dynamics are what a user would feel) and is sampled at `samples` equally spaced
displacements. The reference solves each pull quasi-statically with one load step per sample.

Forces of every model are proportional to Young's modulus at a fixed displacement (the FEM
formulations exactly, the plate-spring stack exactly, the mass-spring in its static limit), so
the bench runs the brain scene at `young` (default 15 kPa, five times the scene's) to reach
forces beyond 1 N and the JND's 10% band; relative errors are those at the scene's modulus.
"""

from __future__ import annotations

import dataclasses
import json
import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from sim.calibrate import jnd
from sim.reference import Pull, make_pulls, reference_pull, scene_with, surface_part
from sim.scene import DEFAULT_SCENE

HANDSET_PARAMS = Path(__file__).resolve().parents[1] / "protocols" / "models" / "plate_spring_handset.toml"
PULL_SPEED = 0.010  # m/s, a careful surgical pull (the scene's: 12 mm in 1.2 s)


@dataclass(frozen=True)
class Setting:
    model: str  # plate_spring | fem | mass_spring
    setting: str  # the row label: continuous, calibrated, 4mm, corotational-6mm, ...
    options: tuple = ()  # (key, value) pairs for the model spec


@dataclass(frozen=True)
class AccuracyConfig:
    scene: Path = DEFAULT_SCENE
    young: float = 15000.0  # Pa, see the module docstring
    max_pull: float = 0.024  # m
    samples: int = 6
    reference_resolution: float = 0.003  # m: every pull solves here; 2 mm is 14-23% softer still (docs/accuracy.md)
    settings: tuple[Setting, ...] = field(default_factory=lambda: default_settings(False))
    handset: Path = HANDSET_PARAMS  # the uncalibrated plate-spring parameters
    quick: bool = False


def default_settings(quick: bool) -> tuple[Setting, ...]:
    ps = [Setting("plate_spring", "paper", (("variant", "paper"), ("params", "handset"))),
          Setting("plate_spring", "continuous", (("variant", "continuous"), ("params", "handset"))),
          Setting("plate_spring", "calibrated", (("variant", "continuous"), ("params", "scene")))]
    fem_res = (8, 6) if quick else (8, 6, 4, 3)
    corot_res = (8,) if quick else (6, 4)
    ms_res = (8,) if quick else (8, 6)
    lg_res = (8, 6) if quick else (8, 6, 4)
    fem = [Setting("fem", f"linear-{r}mm", (("formulation", "linear"), ("resolution", r / 1000))) for r in fem_res]
    fem += [Setting("fem", f"corotational-{r}mm", (("formulation", "corotational"), ("resolution", r / 1000))) for r in corot_res]
    ms = [Setting("mass_spring", f"{i}-{r}mm", (("integrator", i), ("resolution", r / 1000)))
          for i in ("explicit", "implicit") for r in ms_res]
    ms += [Setting("mass_spring", f"local-global-{r}mm", (("integrator", "local-global"), ("resolution", r / 1000))) for r in lg_res]
    return tuple(ps + fem + ms)


def quick_config(**kw) -> AccuracyConfig:
    """A smaller bench for CI and `make demo`: 6 mm reference, 3 samples, coarse settings."""
    return AccuracyConfig(**({"samples": 3, "reference_resolution": 0.006, "settings": default_settings(True), "quick": True} | kw))


def sample_displacements(cfg: AccuracyConfig) -> np.ndarray:
    return cfg.max_pull * np.arange(1, cfg.samples + 1) / cfg.samples


# -- a model on the same pulls -------------------------------------------------------------

def _build_model(scene, setting: Setting, handset: Path, e_ratio: float):
    from sim.models import model_module
    from sim.models.plate_spring import load_params
    from sim.scene import ModelSpec

    opts = dict(setting.options)
    base = scene.spec.models.get(setting.model)
    if setting.model == "plate_spring":
        scene_ps = scene.spec.models["plate_spring"].plate_spring
        params = load_params(handset) if opts["params"] == "handset" else scene_ps
        # the stack's modulus is the tissue's: scale it with the bench's modulus
        params = dataclasses.replace(params, E=params.E * e_ratio)
        spec = ModelSpec(name="plate_spring", variant=opts["variant"], plate_spring=params)
    else:
        spec = ModelSpec(name=setting.model, options=dict(base.options if base else {}) | opts)
    return model_module(setting.model).build(scene.mesh, spec, scene)


def model_pulls(scene_path, young: float, setting: Setting, pulls: list[Pull], xs, handset: Path = HANDSET_PARAMS,
                e_ratio: float = 1.0) -> dict:
    """Run every pull as a ramp of visual frames; sample force, grasp and surface displacement.
    `e_ratio` is `young` over the scene's own modulus (it scales the plate-spring stack's E)."""
    scene = scene_with(scene_path, young)
    xs = np.asarray(xs, dtype=np.float64)
    start = time.perf_counter()
    model = _build_model(scene, setting, handset, e_ratio)
    build_s = time.perf_counter() - start
    frame_hz = scene.spec.visual_rate_hz
    per_sample = max(1, round((xs[0]) / PULL_SPEED * frame_hz))
    n_frames = per_sample * len(xs)
    P, n = len(pulls), len(xs)
    force = np.zeros((P, n, 3))
    grasp = np.zeros((P, n, 3))
    surfaces = []
    frame_s: list[float] = []
    tick_s: list[float] = []
    unstable = False
    for p, pull in enumerate(pulls):
        if hasattr(model, "reset"):
            model.reset()  # mass-spring: back to rest (an empty frame would step the system)
        else:
            model.deformation([], [])  # drops the corotational FEM's state
        contact = model.grasp(pull.point, 0)
        hemi = surface_part(scene.mesh, pull.hemisphere)
        surf_p = np.zeros((n, len(hemi), 3), dtype=np.float32)
        direction = np.asarray(pull.direction)
        for f in range(1, n_frames + 1):
            d = direction * xs[-1] * f / n_frames
            t0 = time.perf_counter()
            surf = model.deformation([contact], [d])
            frame_s.append(time.perf_counter() - t0)
            if f % per_sample == 0:
                k = f // per_sample - 1
                force[p, k] = model.force(contact, tuple(float(c) for c in d))
                grasp[p, k] = surf[pull.vertex]
                surf_p[k] = surf[hemi]
        tick_s.append(_tick_time(model, contact, tuple(float(c) for c in direction * xs[-1])))
        unstable = unstable or bool(getattr(model, "unstable", False))
        surfaces.append(surf_p)
    return {"model": setting.model, "setting": setting.setting, "force": force, "grasp": grasp, "surface": surfaces,
            "frame_ms": float(np.median(frame_s) * 1e3), "frame_ms_p99": float(np.percentile(frame_s, 99) * 1e3),
            "tick_us": float(np.median(tick_s) * 1e6), "build_s": build_s, "unstable": unstable}


def _tick_time(model, contact, d, reps: int = 20000) -> float:
    """Median of 5 batches: the per-tick force call the servo makes (contact law, plain floats)."""
    law = contact.law
    batches = []
    for _ in range(5):
        t0 = time.perf_counter()
        for _ in range(reps // 5):
            law.force(d)
        batches.append((time.perf_counter() - t0) / (reps // 5))
    return float(np.median(batches))


# -- the bench -----------------------------------------------------------------------------

def _task(task):
    kind = task[0]
    if kind == "reference":
        _, scene_path, resolution, pull, xs = task
        return reference_pull(scene_path, resolution, pull, xs)
    _, scene_path, young, setting, pulls, xs, handset, e_ratio = task
    return model_pulls(scene_path, young, setting, pulls, xs, handset, e_ratio)


def run_accuracy(cfg: AccuracyConfig, jobs: int | None = None, scheduler: str | None = None, progress=None) -> dict:
    """Every setting and the reference on the same pulls; returns rows, per-sample errors, meta."""
    from analysis.sweep import run_tasks

    scene = scene_with(cfg.scene)
    pulls = make_pulls(scene)
    xs = sample_displacements(cfg)
    # the references (the slowest tasks) first, so the pool is not left waiting on one at the end
    tasks = [("reference", str(cfg.scene), cfg.reference_resolution, p, xs) for p in pulls]
    e_ratio = cfg.young / scene.spec.material.young
    tasks += [("model", str(cfg.scene), cfg.young, s, pulls, xs, cfg.handset, e_ratio) for s in cfg.settings]
    results = run_tasks(_task, tasks, jobs=jobs, scheduler=scheduler, progress=progress)
    refs, models = results[: len(pulls)], results[len(pulls):]
    rows, samples = compare(refs, models, pulls, xs, cfg.young)
    meta = {
        "synthetic": False,
        "young_pa": cfg.young, "scene_young_pa": scene.spec.material.young,
        "max_pull_m": cfg.max_pull, "samples_per_pull": cfg.samples, "pull_speed_m_per_s": PULL_SPEED,
        "pulls": [dataclasses.asdict(p) for p in pulls],
        "reference": {"model": "fem", "setting": f"neo-hookean-{cfg.reference_resolution * 1e3:g}mm",
                      "resolution_m": cfg.reference_resolution,
                      "converged": all(r["converged"] for r in refs),
                      "min_jacobian": min(r["min_jacobian"] for r in refs),
                      "nodes": max(r["nodes"] for r in refs),
                      "seconds": sum(r["seconds"] for r in refs)},
        "quick": cfg.quick,
    }
    return {"rows": rows, "samples": samples, "meta": meta}


def compare(refs: list[dict], models: list[dict], pulls: list[Pull], xs, young: float) -> tuple[list[dict], list[dict]]:
    rows, samples = [], []
    for m in models:
        errs, within, angle, gerr, srms = [], [], [], [], []
        for p, (pull, ref) in enumerate(zip(pulls, refs)):
            fr = np.asarray(ref["force_per_pa"]) * young
            for k, x in enumerate(xs):
                f, f_ref = m["force"][p, k], fr[k]
                mag, mag_ref = float(np.linalg.norm(f)), float(np.linalg.norm(f_ref))
                rel = abs(mag - mag_ref) / mag_ref
                ok = bool(abs(mag - mag_ref) <= jnd(np.array(mag_ref)) * mag_ref)
                cos = float(np.dot(f, f_ref) / (mag * mag_ref)) if mag > 0 else -1.0
                ang = math.degrees(math.acos(max(-1.0, min(1.0, cos))))
                ge = float(np.linalg.norm(m["grasp"][p, k] - ref["grasp"][k]))
                diff = m["surface"][p][k].astype(np.float64) - ref["surface"][k]
                sr = float(np.sqrt(np.mean(np.sum(diff**2, axis=1))))
                errs.append(rel)
                within.append(ok)
                angle.append(ang)
                gerr.append(ge)
                srms.append(sr)
                samples.append({"model": m["model"], "setting": m["setting"], "pull": pull.name, "displacement_mm": x * 1e3,
                                "force_n": mag, "reference_force_n": mag_ref, "force_error": rel, "within_jnd": ok,
                                "angle_deg": ang, "grasp_error_mm": ge * 1e3, "surface_rms_mm": sr * 1e3})
        rows.append({"model": m["model"], "setting": m["setting"],
                     "force_error": float(np.mean(errs)), "force_error_max": float(np.max(errs)),
                     "within_jnd": float(np.mean(within)), "angle_deg": float(np.mean(angle)),
                     "grasp_error_mm": float(np.mean(gerr) * 1e3), "surface_rms_mm": float(np.mean(srms) * 1e3),
                     "tick_us": m["tick_us"], "frame_ms": m["frame_ms"], "frame_ms_p99": m["frame_ms_p99"],
                     "build_s": m["build_s"], "unstable": m["unstable"]})
    return rows, samples


def pareto(rows: list[dict]) -> list[bool]:
    """Rows no other row beats on both force error and frame time."""
    out = []
    for r in rows:
        out.append(not any(o is not r and o["force_error"] <= r["force_error"] and o["frame_ms"] <= r["frame_ms"]
                           and (o["force_error"] < r["force_error"] or o["frame_ms"] < r["frame_ms"]) for o in rows))
    return out


COLUMNS = ("model", "setting", "force_error", "force_error_max", "within_jnd", "angle_deg", "grasp_error_mm",
           "surface_rms_mm", "tick_us", "frame_ms")


def markdown(result: dict) -> str:
    """The accuracy table as Markdown, with what it was measured against."""
    m = result["meta"]
    ref = m["reference"]
    lines = [f"Reference: {ref['setting']} ({ref['nodes']} nodes in the largest part, converged: {'yes' if ref['converged'] else 'NO'}); "
             f"{len(m['pulls'])} pulls to {m['max_pull_m'] * 1e3:g} mm at {m['pull_speed_m_per_s'] * 1e3:g} mm/s, "
             f"{m['samples_per_pull']} samples each; E = {m['young_pa'] / 1e3:g} kPa (scene: {m['scene_young_pa'] / 1e3:g} kPa)"
             + (" (quick bench)" if m["quick"] else "") + ".", "",
             "| model | setting | force error (mean / max) | within JND | direction error | grasp error | surface RMS error | tick | frame |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in result["rows"]:
        lines.append(f"| {r['model']} | {r['setting']} | {r['force_error']:.1%} / {r['force_error_max']:.1%} | {r['within_jnd']:.0%} | "
                     f"{r['angle_deg']:.1f} deg | {r['grasp_error_mm']:.2f} mm | {r['surface_rms_mm']:.2f} mm | "
                     f"{r['tick_us']:.2f} us | {r['frame_ms']:.3g} ms |")
    lines += ["", "Seed paper, deformation time per frame on its 2014 PC: plate-spring 14.69 ms, FEM 21.35 ms, mass-spring 23.08 ms."]
    return "\n".join(lines) + "\n"


def write_outputs(result: dict, out_dir) -> list[Path]:
    """accuracy.json, accuracy.csv, samples.csv, accuracy.md, pareto.png and .svg."""
    import pandas as pd

    from analysis.plots import pareto_plot

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    files = [out / "accuracy.json", out / "accuracy.csv", out / "samples.csv", out / "accuracy.md"]
    files[0].write_text(json.dumps(result, indent=2, default=float))
    pd.DataFrame(result["rows"]).to_csv(files[1], index=False)
    pd.DataFrame(result["samples"]).to_csv(files[2], index=False)
    files[3].write_text(markdown(result))
    for ext in ("png", "svg"):
        pareto_plot(result["rows"], out / f"pareto.{ext}", reference=result["meta"]["reference"]["setting"])
        files.append(out / f"pareto.{ext}")
    return files
