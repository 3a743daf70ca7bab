"""Numerical stability of every model on stiff and extreme cases (docs/accuracy.md).

Each case changes one thing in the brain scene (Young's modulus, Poisson's ratio, the model's
time step, a spring stiffness, a plate-spring parameter, the pull distance, a sudden hand jump),
builds the model and runs one simulated hand through the real servo loop in lockstep: grasp,
pull, hold. The case ends as

- `refused`: the model would not build, with its one-line reason (parameters out of bounds, an
  explicit step above the critical one, a coupling stiffer than the device renders);
- `unstable`: the model reported instability, threw, sent a non-finite force into the safety
  layer, or the rendered force chattered (a limit cycle: the contact is stiffer than a 1 kHz
  loop can render on the Omni), with the time it was first seen;
- `stable` otherwise.

Whatever the outcome, the forces the servo sent to the device are checked: `nan_sent` and
`over_limit_sent` must both be false for every case (the safety layer's promise).
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass

import numpy as np

from analysis.verification.accuracy import plugin_problem
from sim.errors import SimError
from sim.models.plate_spring import PlateSpringParams
from sim.models.registry import installed, model_class, plugins
from sim.run import run_scene
from sim.scene import DEFAULT_SCENE, ModelSpec, Scene, load_scene
from sim.servo.loop import ServoLoop
from sim.sweep import run_tasks

# (row label, model name, options, plate-spring variant)
MODELS = (
    ("plate_spring/continuous", "plate_spring", {}, "continuous"),
    ("plate_spring/paper", "plate_spring", {}, "paper"),
    ("fem/linear", "fem", {"formulation": "linear"}, None),
    ("fem/corotational", "fem", {"formulation": "corotational", "order": 1}, None),
    ("mass_spring/explicit", "mass_spring", {"integrator": "explicit"}, None),
    ("mass_spring/implicit", "mass_spring", {"integrator": "implicit"}, None),
    ("mass_spring/local-global", "mass_spring", {"integrator": "local-global"}, None),
)
RESOLUTION = 0.008  # m: the coarsest mesh; stability depends on stiffness and step, and 8 mm keeps a case to seconds
DURATION = 0.4  # s per case: grasp at 20 ms, pull over 250 ms, hold
PULL = 0.012  # m, the scene's pull
# the servo's chatter monitor: this many force reversals within the window make a limit cycle
CHATTER_REVERSALS, CHATTER_WINDOW_S = ServoLoop.chatter_reversals, ServoLoop.chatter_window_s
NEAR_CHATTER = CHATTER_REVERSALS // 2  # a stable case that reached this many is listed as marginal


@dataclass(frozen=True)
class Case:
    model: str  # row label, e.g. "mass_spring/explicit"
    case: str  # column label, e.g. "E=1e+09Pa"
    family: str  # young | poisson | dt | stiffness | alpha | q | layers | pull | jump
    value: float


def _families(quick: bool) -> dict[str, tuple]:
    if quick:
        return {"young": (1.0, 1e9), "poisson": (0.4999,), "dt": (0.05,), "stiffness": (1e6,),
                "alpha": (2.5,), "q": (1.6,), "layers": (60,), "pull": (0.2,), "jump": (0.05,), "glitch": (0.05,)}
    return {"young": (1.0, 1e3, 3e3, 1e5, 1e7, 1e9), "poisson": (0.3, 0.45, 0.49, 0.499, 0.4999),
            "dt": (1e-4, 1e-3, 0.01, 1 / 30, 0.05), "stiffness": (100.0, 700.0, 1e4, 1e6),
            "alpha": (1.0, 2.0, 2.5), "q": (1.0, 1.5, 1.6), "layers": (1, 6, 40, 60),
            "pull": (0.012, 0.05, 0.2), "jump": (0.05,), "glitch": (0.05,)}


def _label(family: str, v: float) -> str:
    return {"young": f"E={v:g}Pa", "poisson": f"nu={v:g}", "dt": f"dt={v * 1e3:.3g}ms", "stiffness": f"k={v:g}N/m",
            "alpha": f"alpha={v:g}", "q": f"q={v:g}", "layers": f"layers={int(v)}", "pull": f"pull={v * 1e3:g}mm",
            "jump": f"jump={v * 1e2:g}cm", "glitch": f"glitch={v * 1e2:g}cm"}[family]


def model_rows(extra: tuple[str, ...] = ()) -> tuple:
    """`MODELS` and a row for every installed model outside brainsim (a lab's own), as the
    scene configures it or with its declared defaults, and for each name of `extra` (a
    "package.module:Class") that has none."""
    models, _ = installed()
    names = [n for n in plugins(models) if plugin_problem(n) is None]
    names += [n for n in extra if n not in names and all(m[1] != n for m in MODELS)]
    return MODELS + tuple((f"{name}/default", name, {}, None) for name in names)


def applies(model: str, family: str) -> bool:
    if family in ("alpha", "q", "layers"):
        return model.startswith("plate_spring/")
    if family == "stiffness":  # the mass-spring's springs: the hand coupling (tissue springs follow E)
        return model.startswith("mass_spring/")
    if family in ("young", "poisson") and not any(model.startswith(f"{m}/") for m in ("plate_spring", "fem", "mass_spring")):
        return family in model_class(model.rsplit("/", 1)[0]).material_keys  # a lab's model: the material it reads
    return True


def make_cases(quick: bool = False, models: tuple[str, ...] | None = None) -> list[Case]:
    """The sweep's cases: every row's (of `models` only, when given)."""
    out = []
    for label, name, *_ in model_rows(tuple(models or ())):
        if models is not None and name not in models:
            continue
        for family, values in _families(quick).items():
            if applies(label, family):
                out += [Case(label, _label(family, v), family, float(v)) for v in values]
    return out


def _scene_for(case: Case, scene_path):
    spec = load_scene(scene_path)
    _, name, options, variant = next(m for m in model_rows((case.model.rsplit("/", 1)[0],)) if m[0] == case.model)
    material = spec.material
    if case.family == "young":
        material = dataclasses.replace(material, young=case.value)
    elif case.family == "poisson":
        material = dataclasses.replace(material, poisson=case.value)
    opts = spec.options_of(name) | dict(options)
    if name in ("fem", "mass_spring"):
        opts["resolution"] = RESOLUTION
    visual_hz = spec.visual_rate_hz
    if case.family == "dt":
        if name == "mass_spring":
            opts["dt"] = case.value
        else:  # the other models have no time step of their own: their frame period is it
            visual_hz = 1.0 / case.value
    if case.family == "stiffness":
        opts["coupling"] = case.value
    if name == "plate_spring":
        params = opts["params"]
        if case.family in ("alpha", "q", "layers"):
            # through the constructor, so out-of-bounds values meet the same checks as a file's
            values = dataclasses.asdict(params) | {case.family: int(case.value) if case.family == "layers" else case.value}
            params = PlateSpringParams(**values)
        if case.family == "young":
            params = dataclasses.replace(params, E=case.value)
        opts |= {"variant": variant, "params": params, "field": None}
    model_spec = ModelSpec(name=name, options=opts)
    hand = spec.hands[0]
    hand = dataclasses.replace(hand, device="simulated", distance=case.value if case.family == "pull" else PULL,
                               grasp_at=0.02, pull_start=0.05, pull_time=0.25, release_at=DURATION + 1.0)
    spec = dataclasses.replace(spec, material=material, models={name: model_spec}, model=name, hands=(hand,),
                               visual_rate_hz=visual_hz, renderer=dataclasses.replace(spec.renderer, kind="none"))
    scene = Scene(spec)
    if case.family in ("jump", "glitch"):
        script = hand.script(scene.mesh)
        d = np.asarray(script.pull) / np.linalg.norm(script.pull)
        scene.operators = [dataclasses.replace(script, jump_at=0.3, jump=tuple(float(c) for c in d * case.value),
                                               glitch=case.family == "glitch")]
    return scene


def run_case(case: Case, scene_path=DEFAULT_SCENE) -> dict:
    """Build and run one case; never raises for what the case does to the model."""
    out = {"model": case.model, "case": case.case, "family": case.family, "value": case.value,
           "outcome": "stable", "reason": "", "detected_at_s": None, "nan_sent": False, "over_limit_sent": False,
           "max_force_n": 0.0, "peak_reversals": 0, "events": {}, "wall_s": 0.0}
    start = time.perf_counter()
    try:
        scene = _scene_for(case, scene_path)
        scene.model  # noqa: B018 - build now: a refusal is an outcome, not a crash
    except SimError as exc:
        out.update(outcome="refused", reason=str(exc), wall_s=time.perf_counter() - start)
        return out
    except Exception as exc:  # a bug or a numerical failure the model did not catch: show it
        out.update(outcome="unstable", reason=f"crash while building: {type(exc).__name__}: {exc}", detected_at_s=0.0,
                   wall_s=time.perf_counter() - start)
        return out
    try:
        result = run_scene(scene, duration=DURATION, time_scale=0.0)
    except Exception as exc:  # the loop itself must never crash: if it does, the sweep says so
        out.update(outcome="unstable", reason=f"crash in the loop: {type(exc).__name__}: {exc}", wall_s=time.perf_counter() - start)
        return out
    out["wall_s"] = time.perf_counter() - start
    return out | classify(result, peak=3.3)


def peak_reversals(times, forces, window: float = CHATTER_WINDOW_S) -> int:
    """Most force reversals (the servo's definition, `sim.servo.loop.ServoLoop._chatter`) within any
    `window` seconds, ends included, in one hand's sent forces (n, 3): how close a run came
    to the chatter monitor's limit."""
    f = np.asarray(forces, dtype=np.float64)
    x, y, z = f[:, 0], f[:, 1], f[:, 2]
    # the servo's sums, term by term in its order, so that each comparison comes out the same
    strong = x * x + y * y + z * z > 0.0025
    apart = x[:-1] * x[1:] + y[:-1] * y[1:] + z[:-1] * z[1:] < 0.0
    at = np.asarray(times)[1:][apart & strong[1:] & strong[:-1]]
    if not len(at):
        return 0
    return int(np.max(np.arange(1, len(at) + 1) - np.searchsorted(at, at - window, side="left")))


def classify(result, peak: float) -> dict:
    """Outcome of a run from its events and the forces the servo sent.

    Chatter is what the servo's monitor flagged (`force_chatter`), nothing else: one definition.
    `peak_reversals` is the margin to it (its limit is `CHATTER_REVERSALS`; a flagged run
    reaches it with the withheld force). A stable run within a few reversals of the limit is
    marginal: whether it chatters can turn on the last bits of the arithmetic (docs/accuracy.md).
    """
    forces = result.forces.reshape(len(result.forces), -1, 3)
    mag = np.linalg.norm(forces, axis=2)
    out = {"nan_sent": bool(not np.all(np.isfinite(forces))),
           "over_limit_sent": bool(np.nanmax(mag, initial=0.0) > peak * (1 + 1e-9)),
           "max_force_n": float(np.nanmax(mag, initial=0.0)),
           "events": {k: sum(1 for e in result.events if e.kind == k) for k in sorted({e.kind for e in result.events})}}
    chattered = out["events"].get("force_chatter", 0) > 0
    out["peak_reversals"] = CHATTER_REVERSALS if chattered else max(
        (peak_reversals(result.times, forces[:, k]) for k in range(forces.shape[1])), default=0)
    bad = [e for e in result.events if e.kind in ("model_unstable", "model_fault", "nan_force", "force_chatter")]
    diag = result.model_diagnostics or {}
    if bad:
        e = bad[0]
        reason = e.detail or e.kind
        if e.kind == "force_chatter":
            reason = f"{e.detail.split(';')[0]} (contact too stiff for the device at 1 kHz); grasp dropped"
        return out | {"outcome": "unstable", "reason": reason, "detected_at_s": float(e.t)}
    if diag.get("unstable"):
        return out | {"outcome": "unstable", "reason": "model reported instability", "detected_at_s": diag.get("unstable_at")}
    if out["nan_sent"] or out["over_limit_sent"]:
        return out | {"outcome": "unstable", "reason": "unsafe force sent", "detected_at_s": None}
    return out | {"outcome": "stable", "reason": "", "detected_at_s": None}


def run_stability(quick: bool = False, scene_path=DEFAULT_SCENE, jobs: int | None = None, scheduler: str | None = None,
                  progress=None, cases: list[Case] | None = None) -> dict:
    """Run the sweep (or the given `cases`) on local processes or a Dask cluster."""
    cases = make_cases(quick) if cases is None else cases
    results = run_tasks(_task, [(c, str(scene_path)) for c in cases], jobs=jobs, scheduler=scheduler, progress=progress)
    counts = {k: sum(r["outcome"] == k for r in results) for k in ("stable", "refused", "unstable")}
    return {"cases": results, "meta": {"quick": quick, "resolution_m": RESOLUTION, "duration_s": DURATION,
                                        "counts": counts, "nan_sent": sum(r["nan_sent"] for r in results),
                                        "over_limit_sent": sum(r["over_limit_sent"] for r in results)}}


def _task(task):
    case, scene_path = task
    return run_case(case, scene_path)


def outcome_grid(cases: list[dict]):
    """(rows, columns, matrix of outcome codes: 0 stable, 1 refused, 2 unstable, nan n/a)."""
    rows = list(dict.fromkeys(c["model"] for c in cases))
    cols = list(dict.fromkeys(c["case"] for c in cases))
    code = {"stable": 0, "refused": 1, "unstable": 2}
    grid = np.full((len(rows), len(cols)), math.nan)
    for c in cases:
        grid[rows.index(c["model"]), cols.index(c["case"])] = code[c["outcome"]]
    return rows, cols, grid



