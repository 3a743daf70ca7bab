"""Timing helpers: percentiles of per-call times, printed with ratios to targets."""

from __future__ import annotations

import time

import numpy as np


def per_call(fn, calls: int, batch: int = 100) -> np.ndarray:
    """Seconds per call, measured over batches of `batch` calls (amortises the clock's cost)."""
    out = np.empty(calls // batch)
    clock = time.perf_counter
    for b in range(len(out)):
        start = clock()
        for _ in range(batch):
            fn()
        out[b] = (clock() - start) / batch
    return out


def each_call(fn, calls: int) -> np.ndarray:
    out = np.empty(calls)
    clock = time.perf_counter
    for k in range(calls):
        start = clock()
        fn()
        out[k] = clock() - start
    return out


def report(name: str, seconds: np.ndarray, unit: str, target: float | None = None, reference: tuple[str, float] | None = None) -> dict:
    scale = {"us": 1e6, "ms": 1e3}[unit]
    v = seconds * scale
    p50, p95, p99 = np.percentile(v, [50, 95, 99])
    line = f"{name:<44} p50 {p50:9.3f} {unit}  p95 {p95:9.3f}  p99 {p99:9.3f}  max {v.max():9.3f}"
    if target is not None:
        line += f"  | target {target:g} {unit}: p99 is {target / p99:6.1f}x under" if p99 < target else f"  | target {target:g} {unit}: MISSED ({p99 / target:.1f}x over)"
    if reference is not None:
        line += f"  | {reference[0]} {reference[1]:g} {unit} = {reference[1] / p50:.0f}x p50"
    print(line)
    return {"name": name, "unit": unit, "p50": p50, "p95": p95, "p99": p99, "max": float(v.max())}


def main_with_json(measure, flat) -> None:
    """Run `measure()` (prints its lines, returns a dict). With `--json` on the command line its
    lines are swallowed and only `flat(result)`, a dict of stable keys, is printed as JSON."""
    import contextlib
    import io
    import json
    import sys

    as_json = "--json" in sys.argv[1:]
    with contextlib.redirect_stdout(io.StringIO()) if as_json else contextlib.nullcontext():
        result = measure()
    if as_json:
        print(json.dumps(flat(result), indent=2))


def percentile_keys(prefix: str, row: dict, target: float | None = None) -> dict:
    """`prefix_p50`, `_p95`, `_p99`, `_max` of a `report` row, and `prefix.target` with the p99's ratio to it."""
    out = {f"{prefix}_{k}": float(row[k]) for k in ("p50", "p95", "p99", "max")}
    if target is not None:
        out[f"{prefix}.target"] = target
        out[f"{prefix}_p99.ratio_to_target"] = float(row["p99"]) / target
    return out


def start_xvfb(screen: str = "1600x900x24", *args: str):
    """An Xvfb server on a free display number (it reports the number it took): (process, ":N")."""
    import os
    import shutil
    import subprocess

    xvfb = shutil.which("Xvfb")
    if xvfb is None:
        raise FileNotFoundError("Xvfb is not installed (make test installs the xvfb package)")
    r, w = os.pipe()
    proc = subprocess.Popen([xvfb, "-displayfd", str(w), "-screen", "0", screen, "-nolisten", "tcp", *args], pass_fds=(w,),
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    os.close(w)
    with os.fdopen(r) as fh:
        return proc, ":" + fh.readline().strip()


def xvfb_display():
    """A virtual X display for a window when there is none: DISPLAY is set for this process and
    its children. Returns the Xvfb process to terminate, or None if a display was there already."""
    import os
    import sys

    if os.environ.get("DISPLAY"):
        return None
    try:
        proc, os.environ["DISPLAY"] = start_xvfb()
    except FileNotFoundError as exc:
        sys.exit(f"bench: no DISPLAY and {exc}")
    return proc


def scene_budgets(model: str, frames: int = 36, force_calls: int = 20000) -> dict:
    """The shipped scene's configuration of `model` against the model contract's budgets
    (`sim.models.api.BUDGETS`): both hands grasp where the study's do and pull 12 mm over
    `frames` visual frames (the study's pull at 10 mm/s, 30 Hz), each frame timed; the law's
    force call timed `force_calls` times at the pull's end. Returns stable keys (p50, p99 and
    the budgets with the p99's ratio to them) and prints one line each."""
    from sim.models.api import BUDGETS
    from sim.scene import DEFAULT_SCENE, Scene, load_scene

    scene = Scene(load_scene(DEFAULT_SCENE), model=model)
    m = scene.model
    m.reset()
    scripts = [scene.script(i) for i in range(len(scene.spec.hands))]
    contacts = [m.grasp(s.start, i) for i, s in enumerate(scripts)]
    pulls = [np.asarray(s.pull, dtype=np.float64) for s in scripts]
    times = []
    for k in range(1, frames + 1):
        d = [tuple(float(c) for c in p * k / frames) for p in pulls]
        start = time.perf_counter()
        m.deformation(contacts, d)
        times.append(time.perf_counter() - start)
    frame_s = np.asarray(times)
    law = m.law(contacts[0])
    end = tuple(float(c) for c in pulls[0])
    force_s = each_call(lambda: law.force(end), force_calls)
    frame = report(f"{model} (scene configuration) frame", frame_s, "ms", BUDGETS["deformation_ms_p99"])
    force = report(f"{model} (scene configuration) force call", force_s, "us", BUDGETS["force_us_p99"])
    return {"options": {k: (str(v) if not isinstance(v, (int, float, str, bool, type(None))) else v) for k, v in scene.model_spec.options.items()},
            **percentile_keys("frame_ms", frame, BUDGETS["deformation_ms_p99"]), **percentile_keys("force_us", force, BUDGETS["force_us_p99"])}
