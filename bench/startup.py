"""What a scene costs to start: time and imported modules, one-hand plate-spring headless
against two-hand FEM with rendering (each in a fresh interpreter), and the first grasp after the
model's build (one-time work is the build's: `first_grasp_ms`, against the 250 ms grasp budget).
`python -m bench startup [--json]` (keys `startup.<case>.*`)."""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
from pathlib import Path

from bench.common import main_with_json
from sim.scene import DEFAULT_SCENE

CHILD = r"""
import json, resource, sys, time
t0 = time.perf_counter()
from sim.scene import build_scene
from sim.run import run_scene
scene = build_scene(sys.argv[1])
model = scene.model
t_ready = time.perf_counter() - t0
g0 = time.perf_counter()
model.grasp(scene.script(0).start, 0)  # the first grasp after the build: its one-time work belongs to the build
first_grasp_ms = (time.perf_counter() - g0) * 1e3
r = run_scene(scene, duration=0.2, time_scale=0, snapshots=scene.spec.renderer.kind == "offscreen")
if scene.spec.renderer.kind == "offscreen":
    from sim.view.window import ParticipantView
    ParticipantView(scene.mesh, width=320, height=240, visible=False).draw(None, [])
total = time.perf_counter() - t0
mods = sorted(sys.modules)
watch = ["open3d", "moderngl", "glfw", "sim.view.pictures", "sim.models.fem", "sim.models.mass_spring", "sim.models.plate_spring",
         "sksparse.cholmod", "cholespy", "scipy.sparse.linalg", "matplotlib", "sim.devices.simulated"]
print(json.dumps({"ready_s": t_ready, "first_grasp_ms": first_grasp_ms, "total_s": total, "modules": len(mods),
                  "loaded": {w: w in sys.modules for w in watch},
                  "max_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}))
"""


def _scene(text: str, tmp: Path, name: str) -> Path:
    root = DEFAULT_SCENE.parents[2]
    for rel, where in (('"../../data/', "data"), ('"../models/', "protocols/models"), ('"../materials/', "protocols/materials")):
        text = text.replace(rel, f'"{root}/{where}/')  # the scene's relative paths, from the temporary folder
    path = tmp / name
    path.write_text(text)
    return path


CASES = {"one-hand plate-spring, headless": "plate_spring_one_hand_headless", "two-hand FEM, rendering": "fem_two_hands_rendering"}


def measure() -> dict:
    base = DEFAULT_SCENE.read_text()
    results = {}
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        one = base.replace('kind = "offscreen"', 'kind = "none"')
        one = one[: one.rindex("[[hands]]")]
        fem = base.replace('name = "plate_spring"               #', 'name = "fem"  #')
        cases = {"one-hand plate-spring, headless": _scene(one, tmp, "one.toml"), "two-hand FEM, rendering": _scene(fem, tmp, "fem.toml")}
        for label, path in cases.items():
            out = subprocess.run([sys.executable, "-c", CHILD, str(path)], capture_output=True, text=True, check=True)
            r = json.loads(out.stdout.strip().splitlines()[-1])
            loaded = ", ".join(k for k, v in r["loaded"].items() if v)
            print(f"{label:<34} ready {r['ready_s']:6.2f} s, first grasp {r['first_grasp_ms']:5.0f} ms (budget 250), total {r['total_s']:6.2f} s, {r['modules']:5d} modules, "
                  f"max RSS {r['max_rss_mb']:6.0f} MB; loaded: {loaded}")
            results[CASES[label]] = r
    return results


def flat(results: dict) -> dict:
    return {f"startup.{case}.{k}": r[k] for case, r in results.items() for k in ("ready_s", "first_grasp_ms", "total_s", "modules", "max_rss_mb")}


def main() -> None:
    main_with_json(measure, flat)


if __name__ == "__main__":
    main()
