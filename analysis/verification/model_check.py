"""`studyctl model check`: one model's scorecard before a person holds it.

- **Contract** (`sim.models.api`): it builds on the scene; grasps at the scene's hands return a
  contact on the surface; the force is three finite floats, zero at zero displacement, continuous
  along a pull (no step above `MAX_STEP_N` per 0.1 mm: a step a device renders as a knock, or a
  stiffness above any the Omni renders stably); the per-tick law a servo in another process
  evaluates pickles and agrees with ``force``; the deformation has one finite row per surface
  vertex; two hands at once. A failure is a violation, named, and the command exits non-zero.
- **Budgets** (`sim.models.api.BUDGETS`), measured on this machine: the per-tick force call
  (the law, timed call by call, 99th percentile), a visual frame's deformation along a pull, a
  grasp. Over budget is a violation.
- **Stability**: the quick sweep's cases for the model (`analysis.verification.stability`), their outcomes.
- **Accuracy**: the accuracy bench's row for the model against the tissue truth
  (`analysis.verification.accuracy`), raw and calibrated.
"""

from __future__ import annotations

import dataclasses
import math
import pickle
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from analysis.errors import Interrupted
from analysis.verification.accuracy import (
    AccuracyConfig,
    Setting,
    quick_config,
    run_accuracy,
    sample_displacements,
)
from analysis.verification.bench_pulls import TICK_TIMING_CALLS, hand_speed, pull_plan
from analysis.verification.stability import DURATION as STABILITY_DURATION
from analysis.verification.stability import make_cases, run_case
from analysis.verification.tissue_pulls import shipped_solve_seconds, unsolved
from analysis.verification.truth_in_time import bench_speeds
from sim.errors import SimError
from sim.models.api import API_VERSION, BUDGETS, REST, deformation_at, force_at, law_force_at
from sim.models.registry import info, model_class
from sim.pulls import make_pulls, scene_with, test_pulls
from sim.scene import ModelSpec, Scene, clamp_limit, load_scene

STEP_M = 1e-4  # the continuity check's step along a pull
MAX_STEP_N = 0.1  # N per STEP_M: 1000 N/m, above the Omni's 700 N/m stable stiffness
ZERO_N = 1e-6  # force at zero displacement
# a model that uses time is driven along the pull as a ramp at this speed (the order of the
# synthetic scripts' and a person's pulls), told the time and the velocity at every 1 ms tick
CONTRACT_SPEED_M_S = 0.01
TICK_S = 1e-3


class CheckError(SimError):
    """A model check that cannot run (the model does not load, its scene does not)."""


@dataclass(frozen=True)
class CheckConfig:
    scene: Path
    quick: bool = False
    contract_only: bool = False  # the contract and the budgets only (seconds): what a model's author iterates on
    force_calls: int = 20000
    frames: int = 36  # a 12 mm pull at 10 mm/s, 30 Hz


def _scene(name: str, scene_path: Path):
    """The scene running model `name`: the scene's configuration of it, else its declared defaults."""
    spec = load_scene(scene_path)
    spec = dataclasses.replace(spec, models={**spec.models, name: ModelSpec(name=name, options=spec.options_of(name))})
    return Scene(dataclasses.replace(spec, model=name))


def _vec(f) -> np.ndarray:
    out = np.asarray(tuple(f), dtype=np.float64)
    if out.shape != (3,):
        raise ValueError(f"returned {len(out)} values, not 3")
    return out


class _Contract:
    """The contract's checks, each recorded as (check, ok, detail)."""

    def __init__(self) -> None:
        self.rows: list[dict] = []

    def record(self, check: str, ok: bool | None, detail: str = "") -> bool | None:
        """ok None: the check was not run (a fault it depends on is reported on its own row)."""
        self.rows.append({"check": check, "ok": None if ok is None else bool(ok), "detail": detail})
        return ok

    def attempt(self, check: str, fn):
        """fn() -> (ok, detail, value); an exception is a failure naming it."""
        try:
            ok, detail, value = fn()
        except Exception as exc:  # a model may fail in any way: the scorecard names it
            self.record(check, False, f"raised {type(exc).__name__}: {exc}")
            return None
        self.record(check, ok, detail)
        return value if ok else None

    def attempt_if(self, skipped: str | None, check: str, fn):
        """`attempt`, or a row saying the check was not run and why."""
        if skipped is not None:
            self.record(check, None, f"skipped: {skipped}")
            return None
        return self.attempt(check, fn)


def _fault(row: dict, what: str, otherwise: str) -> str:
    """Why the checks after a failed `row` are not run: the exception it recorded, in its own
    words, or `otherwise` (what the check itself found wrong)."""
    return f"{what} {row['detail']}" if row["detail"].startswith("raised ") else otherwise


def contract(scene) -> tuple[list[dict], dict]:
    """The contract's checks on `scene`'s model; (rows, what the budgets reuse)."""
    c = _Contract()
    model = c.attempt("build", lambda: (True, type(scene.model).__name__, scene.model))
    if model is None:
        return c.rows, {}
    surface = model.surface_mesh()
    n = len(surface.vertices)
    hands = [scene.script(i) for i in range(len(scene.spec.hands))]
    starts = [np.asarray(h.start) for h in hands]
    pulls = [np.asarray(h.pull) for h in hands]
    if len(starts) == 1:  # a second place for two hands at once: the mirror across the midline
        starts.append(starts[0] * np.array([-1.0, 1.0, 1.0]))
        pulls.append(pulls[0] * np.array([-1.0, 1.0, 1.0]))

    def grasp(i):
        contact = model.grasp(tuple(float(x) for x in starts[i]), i)
        gap = float(np.linalg.norm(np.asarray(contact.point) - starts[i]))
        ok = 0 <= contact.vertex < n and all(math.isfinite(x) for x in contact.point) and gap < 0.01
        return ok, f"vertex {contact.vertex}, {gap * 1e3:.2f} mm from the asked point", contact

    contact = c.attempt("grasp", lambda: grasp(0))
    if contact is None:
        return c.rows, {"model": model}
    d_max = pulls[0]
    # a model that uses time: the pull is a ramp at CONTRACT_SPEED_M_S, its end reached at t_end
    v_pull = tuple(float(x) for x in d_max / np.linalg.norm(d_max) * CONTRACT_SPEED_M_S)
    t_end = float(np.linalg.norm(d_max)) / CONTRACT_SPEED_M_S

    def fresh():
        """Back to rest before each check of a model that uses time: its time runs forward from 0
        within a check (a model with a history must not see the clock go back)."""
        if model.uses_time:
            model.reset()

    def shape():
        fresh()
        f = np.asarray(tuple(force_at(model, contact, tuple(float(x) for x in d_max), v_pull, t_end)), dtype=np.float64)
        return f.shape == (3,), "three floats" if f.shape == (3,) else f"force has shape {f.shape}, must be (3,)", f

    # one fault, reported once: a check that needs a sound force (or deformation) is not run
    # when it is not, rather than failing again under its own name or passing on a wrong number
    force_wrong = None if c.attempt("force: three floats", shape) is not None else _fault(c.rows[-1], "the force", "the force's shape is wrong")

    def zero():
        fresh()
        f = _vec(force_at(model, contact, (0.0, 0.0, 0.0), REST, 0.0))
        return bool(np.all(np.isfinite(f)) and np.linalg.norm(f) <= ZERO_N), f"|f| = {np.linalg.norm(f):.3g} N at d = 0", f

    c.attempt_if(force_wrong, "zero force at zero displacement", zero)
    steps = max(2, int(round(np.linalg.norm(d_max) / STEP_M)))

    def along():
        fresh()
        if model.uses_time:  # every tick of the ramp, told its time and the velocity; judged every STEP_M
            per = max(1, round(STEP_M / (CONTRACT_SPEED_M_S * TICK_S)))
            f = np.array([_vec(force_at(model, contact, tuple(float(x) for x in d_max * j / (steps * per)), v_pull, t_end * j / (steps * per)))
                          for j in range(steps * per + 1)])[::per]
        else:
            f = np.array([_vec(model.force(contact, tuple(float(x) for x in d_max * k / steps))) for k in range(steps + 1)])
        if not np.all(np.isfinite(f)):
            k = int(np.argmax(~np.all(np.isfinite(f), axis=1)))
            return False, f"non-finite force at {np.linalg.norm(d_max) * k / steps * 1e3:.2f} mm", None
        jump = np.linalg.norm(np.diff(f, axis=0), axis=1)
        k = int(np.argmax(jump))
        return (jump[k] <= MAX_STEP_N, f"largest step {jump[k]:.3g} N over 0.1 mm (at {np.linalg.norm(d_max) * (k + 1) / steps * 1e3:.1f} mm); "
                f"allowed: {MAX_STEP_N:g} N", f)

    c.attempt_if(force_wrong, "finite, continuous force along the pull", along)
    if c.rows[-1]["ok"] is False and not c.rows[-1]["detail"].startswith("largest step"):  # a step is its own fault; a NaN spoils what follows
        force_wrong = _fault(c.rows[-1], "the force along the pull", "the force is not finite along the pull")
    has_law = contact.law is not None

    def law():
        fresh()
        sent = pickle.loads(pickle.dumps(model.law(contact)))
        if not has_law:  # the servo process evaluates a copy of the model itself: only the copy is checked
            return True, f"the model's {type(sent).__name__} copy pickles", sent
        if force_wrong is not None:
            return None, f"pickles; agreement with force not run: {force_wrong}", sent
        d = tuple(float(x) for x in d_max)
        a, b = _vec(force_at(model, contact, d, v_pull, t_end)), _vec(law_force_at(sent, d, v_pull, t_end))
        gap = float(np.linalg.norm(a - b))
        return gap <= 1e-9 * max(1.0, float(np.linalg.norm(a))), f"law of {type(sent).__name__}: {gap:.2g} N from force", sent

    c.attempt("per-tick law pickles and agrees with force" if has_law else "no per-tick law: the model's copy pickles", law)

    def deform():
        fresh()
        u = np.array(deformation_at(model, [contact], [tuple(float(x) for x in d_max)], [v_pull], t_end))  # a copy: models reuse their buffer
        rest = np.array(deformation_at(model, [], [], [], t_end))
        ok = u.shape == (n, 3) and rest.shape == (n, 3) and bool(np.all(np.isfinite(u)))
        if u.shape != (n, 3):
            return False, f"deformation has shape {u.shape}, must be ({n}, 3)", u
        return ok, f"shape {u.shape}, max {np.abs(u).max() * 1e3 if u.size else 0:.3g} mm", u

    deform_wrong = None
    if c.attempt("deformation: a finite row per surface vertex", deform) is None:
        deform_wrong = "the deformation's shape is wrong" if "has shape" in c.rows[-1]["detail"] else "the deformation is not finite"

    def two():
        fresh()
        other = model.grasp(tuple(float(x) for x in starts[1]), 1)
        ds = [tuple(float(x) for x in pulls[0] / 2), tuple(float(x) for x in pulls[1] / 2)]
        if model.uses_time:  # both hands half way along their ramps, at the contract's speed
            vs = [v_pull, tuple(float(x) for x in pulls[1] / np.linalg.norm(pulls[1]) * CONTRACT_SPEED_M_S)]
            fs = [_vec(f) for f in model.forces([contact, other], ds, velocities=vs, t=t_end / 2)]
        else:
            vs = None
            fs = [_vec(f) for f in model.forces([contact, other], ds)]
        u = np.asarray(deformation_at(model, [contact, other], ds, vs, t_end / 2))
        deformation_at(model, [], [], [], t_end / 2)
        if len(fs) != 2 or not all(np.all(np.isfinite(f)) for f in fs):
            return False, f"forces returned {len(fs)} forces, {sum(bool(np.all(np.isfinite(f))) for f in fs)} finite; must be 2 finite", None
        if u.shape != (n, 3) or not np.all(np.isfinite(u)):
            return False, f"deformation of shape {u.shape} for two contacts, must be ({n}, 3) and finite", None
        return True, f"forces {np.linalg.norm(fs[0]):.3g} N and {np.linalg.norm(fs[1]):.3g} N", None

    c.attempt_if(force_wrong or deform_wrong, "two hands at once", two)
    if type(model).scales_stiffness:
        c.attempt("stiffness scaling (the discrimination task)",
                  lambda: (True, type(model.with_stiffness(1.37)).__name__, None))
    model.reset()

    return c.rows, {"model": model, "contact": contact, "pull": d_max, "start": starts[0], "clamp": clamp_limit(scene)}


def _grasp_places(mesh, start, clamp: tuple[int, float], n: int = 5) -> list[tuple]:
    """`n` surface vertices spread over the surface 20 mm or more above the scene's clamp
    (`sim.scene.clamp_limit`: a patch there can move), none the contract's grasp: the same
    places on every run."""
    v = np.asarray(mesh.vertices)
    axis, height = clamp
    upper = np.flatnonzero(v[:, axis] >= height + 0.02)
    upper = upper[np.linalg.norm(v[upper] - start, axis=1) > 0.01]
    picks = upper[np.linspace(0, len(upper) - 1, n).astype(int)]
    return [tuple(float(x) for x in v[i]) for i in picks]


def budgets(parts: dict, cfg: CheckConfig) -> list[dict]:
    """The budgets measured on this machine (each call timed on its own). A call that raises
    here is a violation too (a row with `raised`)."""
    if "contact" not in parts:
        return []
    try:
        return _timed(parts, cfg)
    except Exception as exc:  # the contract held at one place, not at these: name it
        return [{"budget": "timing", "value": math.nan, "median": math.nan, "limit": math.nan, "ok": False,
                 "raised": f"{type(exc).__name__}: {exc}"}]


def _timed(parts: dict, cfg: CheckConfig) -> list[dict]:
    model, contact, pull, start = parts["model"], parts["contact"], parts["pull"], parts["start"]
    clock = time.perf_counter_ns
    law = model.law(contact)
    d = tuple(float(x) for x in pull)
    v = tuple(float(x) for x in pull / np.linalg.norm(pull) * CONTRACT_SPEED_M_S)
    t_end = float(np.linalg.norm(pull)) / CONTRACT_SPEED_M_S
    ticks = np.empty(cfg.force_calls)
    timed = bool(getattr(law, "uses_time", False))  # decided once: the timed call is the servo's own
    for k in range(cfg.force_calls):
        if timed:
            t0 = clock()
            law.force(d, v, t_end)
        else:
            t0 = clock()
            law.force(d)
        ticks[k] = clock() - t0
    frames, grasps = [], []
    model.reset()
    for k in range(1, cfg.frames + 1):
        t0 = clock()
        deformation_at(model, [contact], [tuple(float(x) for x in pull * k / cfg.frames)], [v], t_end * k / cfg.frames)
        frames.append(clock() - t0)
    model.reset()
    for point in _grasp_places(model.surface_mesh(), start, parts["clamp"]):  # places not grasped before: no model's cache helps
        t0 = clock()
        model.grasp(point, 0)
        grasps.append(clock() - t0)
    measured = {"force_us_p99": np.percentile(ticks, 99) / 1e3, "deformation_ms_p99": np.percentile(frames, 99) / 1e6,
                "grasp_ms_p99": np.percentile(grasps, 99) / 1e6}
    medians = {"force_us_p99": np.median(ticks) / 1e3, "deformation_ms_p99": np.median(frames) / 1e6, "grasp_ms_p99": np.median(grasps) / 1e6}
    return [{"budget": k, "value": float(measured[k]), "median": float(medians[k]), "limit": limit, "ok": bool(measured[k] <= limit)}
            for k, limit in BUDGETS.items()]


def stability(name: str, scene_path: Path, step=None) -> dict:
    """The quick stability sweep's cases of the model's rows; `step(k, n)` after each case."""
    cases = make_cases(quick=True, models=(name,))
    rows = []
    for c in cases:
        rows.append(run_case(c, scene_path))
        if step is not None:
            step(len(rows), len(cases))
    counts = {k: sum(1 for r in rows if r["outcome"] == k) for k in ("stable", "unstable", "refused")}
    safety = not any(r["nan_sent"] or r["over_limit_sent"] for r in rows)
    return {"cases": [{k: r[k] for k in ("model", "case", "outcome", "reason")} for r in rows], "counts": counts,
            "safety_held": safety}


def _accuracy_config(name: str, scene_path: Path, quick: bool) -> AccuracyConfig:
    setting = (Setting(name, "default"),)
    return quick_config(scene=scene_path, settings=setting) if quick else AccuracyConfig(scene=scene_path, settings=setting)


def accuracy(name: str, scene_path: Path, quick: bool, step=None) -> dict:
    """The accuracy bench's row for the model (raw and calibrated) against the tissue truth;
    `step(k, n)` after each reference solve and the model's pulls."""
    out = run_accuracy(_accuracy_config(name, scene_path, quick), jobs=1, progress=step)
    keep = ("setting", "speed", "speed_m_s", "calibration", "scale", "force_error", "within_jnd", "within_jnd_low", "within_jnd_high", "n_test",
            "extrapolated", "truth_undecided", "pulls_within", "frame_ms", "tick_us", "n_within_jnd", "withheld", "force_error_extrapolated")
    return {"rows": [{k: r.get(k) for k in keep if k in r} for r in out["rows"]], "reference": out["meta"]["reference"]["setting"],
            "quick": quick}


UNKNOWN_SOLVE_S = 60.0  # a reference solve of a size with no shipped record: a guess, said as one
# what a stability case costs beyond the model's own work (its scene, the servo loop), and the
# compiled servo ticks' first compile in a fresh install (how they were measured: docs/models.md)
CASE_OVERHEAD_S, FIRST_RUN_S = 0.08, 2.0


def estimate(name: str, cfg: CheckConfig, build_s: float, timed: list[dict]) -> dict:
    """Seconds the sweep and the bench will take, from this model's own measured costs (its
    build, a tick's and a frame's median from the budgets) times the work each stage does, plus
    the reference solves neither shipped nor cached (at the shipped solves' median time)."""
    med = {b["budget"]: b["median"] for b in timed}
    tick_s, frame_s = med.get("force_us_p99", 0.0) * 1e-6, med.get("deformation_ms_p99", 0.0) * 1e-3
    scene = scene_with(cfg.scene)
    hz = scene.spec.visual_rate_hz
    cases = make_cases(quick=True, models=(name,))
    case_s = CASE_OVERHEAD_S + build_s + STABILITY_DURATION * (1000.0 * tick_s + hz * frame_s)
    acfg = _accuracy_config(name, cfg.scene, cfg.quick)
    pulls = make_pulls(scene) + test_pulls(scene, acfg.test_places)
    xs = sample_displacements(acfg)
    uses_time = bool(model_class(name).uses_time)
    pulls_s = build_s
    for sp in bench_speeds(acfg.speeds):  # in frames, or in time from rest to the last hold (`bench_pulls`)
        _, frames, ticks_per_frame = pull_plan(xs, hz, scene.spec.servo_rate_hz, hand_speed(sp.speed_m_s, uses_time), sp.holds_s, uses_time)
        pulls_s += len(pulls) * (frames * (frame_s + ticks_per_frame * tick_s) + TICK_TIMING_CALLS * tick_s)
    todo = unsolved(cfg.scene, pulls, xs, acfg.reference_sizes_mm)
    per = shipped_solve_seconds()
    ref_s = sum(n * per.get(size, UNKNOWN_SOLVE_S) for size, n in todo.items())
    return {"stability_s": FIRST_RUN_S + len(cases) * case_s, "stability_cases": len(cases), "accuracy_s": pulls_s + ref_s,
            "reference_solves": int(sum(todo.values())), "reference_solves_s": ref_s, "pulls": len(pulls)}


class CheckInterrupted(Interrupted):
    """Stopped (Ctrl-C) during a check: `card` holds the stages that finished."""

    def __init__(self, card: dict, stage: str):
        super().__init__(f"interrupted during {stage}")
        self.card, self.stage = card, stage


class _Quiet:
    def start(self, key: str, title: str) -> None: ...
    def step(self, k: int, n: int) -> None: ...
    def end(self, key: str, seconds: float, result) -> None: ...
    def estimate(self, est: dict) -> None: ...


STAGES = {"contract": "contract", "budgets": "budgets (this machine)", "stability": "stability (quick sweep)",
          "accuracy": "accuracy against the tissue truth"}


def check_model(name: str, cfg: CheckConfig, progress=None) -> dict:
    """The scorecard of model `name` on `cfg.scene`. Raises CheckError when it cannot run, and
    CheckInterrupted (holding what finished) on Ctrl-C. `progress`: an object with `start(key,
    title)`, `step(k, n)`, `end(key, seconds, result)` (the stage's result) and `estimate(dict)`, told as the stages go."""
    try:
        cls = model_class(name)
        scene = _scene(name, cfg.scene)
    except SimError as exc:  # a model that does not load, or a scene it refuses
        raise CheckError(str(exc)) from None
    i = info(name)
    ui = progress or _Quiet()
    card = {"model": name, "class": i.target, "distribution": i.distribution, "version": i.version, "api_version": API_VERSION,
            "description": cls.description, "scene": str(cfg.scene), "machine_budgets": BUDGETS, "contract_only": cfg.contract_only,
            "contract": [], "budgets": [], "violations": [], "stage_seconds": {}}
    stage = "contract"

    def run(key, fn):
        nonlocal stage
        stage = key
        ui.start(key, STAGES[key])
        t0 = time.perf_counter()
        out = fn()
        card["stage_seconds"][key] = time.perf_counter() - t0
        ui.end(key, card["stage_seconds"][key], out)
        return out

    try:
        rows, parts = run("contract", lambda: contract(scene))
        card["contract"] = rows
        timed = run("budgets", lambda: budgets(parts, cfg))
        card["budgets"] = timed
        violations = [f"{r['check']}: {r['detail']}" for r in rows if r["ok"] is False]
        violations += [f"{b['budget']}: raised {b['raised']} while timed" if "raised" in b else
                       f"{b['budget']}: {b['value']:.3g} over the budget of {b['limit']:g}" for b in timed if not b["ok"]]
        card["violations"] = violations
        if violations:  # a model that breaks the contract is not swept nor benched: the violations come first
            card["stability"] = card["accuracy"] = None
            card["skipped"] = "the stability sweep and the accuracy bench run once the contract and the budgets hold"
            return card
        if cfg.contract_only:
            card["stability"] = card["accuracy"] = None
            card["skipped"] = "--contract: the stability sweep and the accuracy bench were not run"
            return card
        stage = "stability"  # the estimate is the sweep's first step: a Ctrl-C here keeps the contract and budgets
        try:
            est = estimate(name, cfg, card["stage_seconds"]["contract"], timed)
        except Exception:  # an estimate never stops a check: the stages report their own time
            est = None
        card["estimate"] = est
        if est is not None:
            ui.estimate(est)
        card["stability"] = run("stability", lambda: stability(name, cfg.scene, ui.step))
        card["accuracy"] = run("accuracy", lambda: accuracy(name, cfg.scene, cfg.quick, ui.step))
    except KeyboardInterrupt:
        card["interrupted"] = stage
        raise CheckInterrupted(card, STAGES[stage]) from None
    return card



