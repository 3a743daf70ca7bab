"""The servo loop under load: 10 s, two hands, each model, frames drawn live.

For every model, the scene runs in real time twice: with the servo in a thread of this
process and in its own process (the default), while this process draws every visual frame
with open3d. Prints tick-interval percentiles, deadline misses and compute percentiles.
Usage: python -m bench servo [SECONDS]
"""

from __future__ import annotations

import sys

import numpy as np

from sim.run import run_scene
from sim.scene import DEFAULT_SCENE, build_scene


def _drawer(renderer, mesh, state):
    def draw(visual):
        u = visual.last
        if u is None:
            return
        mag = np.linalg.norm(u, axis=1)
        hands = [(np.asarray(h.position), np.array([1.0, 0.0, 0.0])) for h in visual.hands]
        renderer.render(mesh.vertices + u, mag / max(float(mag.max()), 1e-3), hands)
        state["frames"] += 1

    return draw


def main(seconds: float | None = None) -> None:
    if seconds is None:
        seconds = float(sys.argv[2]) if len(sys.argv) > 2 and sys.argv[1] == "servo" else 10.0
    from sim.render import BrainRenderer

    renderer = None
    print(f"{seconds:g} s per run, two simulated hands, every visual frame drawn live (640x480)")
    print(f"{'model':<13} {'servo':<8} {'ticks':>6} {'p50 us':>8} {'p99 us':>8} {'p99.9 us':>9} {'max us':>9} {'misses':>7} "
          f"{'compute p50/p99 us':>19} {'streaks':>7} {'frames':>7} {'deform p99 ms':>13}")
    import tempfile
    from pathlib import Path

    root = DEFAULT_SCENE.parents[2]
    text = DEFAULT_SCENE.read_text().replace('"../../data/', f'"{root}/data/').replace('"../models/', f'"{root}/protocols/models/')
    # hold the pull for the whole run, so the tissue deforms and frames are drawn throughout
    text = text.replace("pull_time = 1.2", f"pull_time = {seconds / 2:g}").replace("release_at = 2.6", f"release_at = {seconds - 0.2:g}")
    tmp = Path(tempfile.mkdtemp()) / "bench_scene.toml"
    tmp.write_text(text)
    for model in ("plate_spring", "fem", "mass_spring"):
        for servo in ("thread", "process"):
            scene = build_scene(tmp, model)
            if renderer is None:
                renderer = BrainRenderer(scene.mesh, 640, 480)
            state = {"frames": 0}

            draw = _drawer(renderer, scene.mesh, state)

            r = run_scene(scene, duration=seconds, time_scale=1.0, servo=servo, render=draw)
            s = r.stats()
            iv, tc = s["tick_interval_us"], s["tick_compute_us"]
            print(f"{model:<13} {servo:<8} {s['ticks']:>6} {iv['p50']:>8.0f} {iv['p99']:>8.0f} {iv['p99.9']:>9.0f} {iv['max']:>9.0f} "
                  f"{s['deadline_misses']:>7} {tc['p50']:>9.0f}/{tc['p99']:<9.0f} {s['events'].get('deadline_streak', 0):>7} {state['frames']:>7} "
                  f"{s['deformation_ms']['p99']:>13.2f}")


if __name__ == "__main__":
    main()
