"""The participant view's frame: the brain deforming (positions and normals written every frame),
two instruments, a force arrow and the text, at 1280x720, in a real window (Xvfb is started if
there is no display) and offscreen (EGL), with one Mesa rasteriser thread unless LP_NUM_THREADS
says otherwise. Prints frame-time percentiles (draw, swap and wait until shown) and frames per
second against the targets (frame p50 <= 33 ms, 30 fps).
Usage: python -m bench render [--json]  (keys `render.window.*`, `render.offscreen.*`)
"""

from __future__ import annotations

import os
import time

import numpy as np

from bench.common import main_with_json, percentile_keys, report, xvfb_display

TARGET_MS = 33.0  # a 30 Hz frame
TARGET_FPS = 30.0
SIZE = (1280, 720)
FRAMES = 120


def _frames(visible: bool) -> dict:
    from sim.geometry.mesh import load_mesh
    from sim.view.window import HandState, ParticipantView

    mesh = load_mesh()
    view = ParticipantView(mesh, width=SIZE[0], height=SIZE[1], visible=visible, show_force=True)
    view.set_text(top="Condition B (2 of 3) - trial 1 of 3", bottom="Pull the brain freely: grasp it with the left or right stylus")
    rng = np.random.default_rng(1)
    wave = rng.normal(0.0, 1.0, mesh.vertices.shape) * 1e-3
    left, right = mesh.vertices[3386], mesh.vertices[13629]
    times = np.empty(FRAMES)
    for k in range(FRAMES + 5):
        s = np.sin(k / 9.0)
        hands = [HandState(tuple(left + [-0.01 * s, 0.0, 0.005]), (-0.5 * s, 0.0, 0.1), 3386), HandState(tuple(right + [0.0, 0.004 * s, 0.0]))]
        view.set_text(center=f"{(FRAMES - k) // 30 + 1} s")
        start = time.perf_counter()
        view.draw(wave * s, hands)
        if k >= 5:  # the first frames build the font atlases and compile the normals pass
            times[k - 5] = time.perf_counter() - start
    stats = view.stats()
    view.close()
    return {"times": times, "renderer": stats["renderer"], "prepare_ms_p50": stats["prepare_ms"]["p50"],
            "fps": FRAMES / float(times.sum())}


def measure() -> dict:
    os.environ.setdefault("LP_NUM_THREADS", "1")  # the condition: one rasteriser thread (the servo keeps a core)
    print(f"participant view {SIZE[0]}x{SIZE[1]}: the 41k-triangle brain deforming, two forceps, a force arrow, text; "
          f"LP_NUM_THREADS={os.environ['LP_NUM_THREADS']}")
    xvfb = xvfb_display()
    out = {}
    try:
        for case, visible in (("window", True), ("offscreen", False)):
            r = _frames(visible)
            row = report(f"{case} frame (draw, swap, finish)", r["times"], "ms", target=TARGET_MS)
            print(f"{'':<44} {r['fps']:.1f} fps (target {TARGET_FPS:g}: {r['fps'] / TARGET_FPS:.2f}x); own CPU work p50 "
                  f"{r['prepare_ms_p50']:.2f} ms; renderer: {r['renderer']}")
            out[case] = row | {"fps": r["fps"], "renderer": r["renderer"], "prepare_ms_p50": r["prepare_ms_p50"]}
    finally:
        if xvfb is not None:
            xvfb.terminate()
    return out


def flat(result: dict) -> dict:
    keys = {"render.size": f"{SIZE[0]}x{SIZE[1]}", "render.lp_num_threads": os.environ.get("LP_NUM_THREADS")}
    for case, row in result.items():
        keys |= percentile_keys(f"render.{case}.frame_ms", row, TARGET_MS)
        keys |= {f"render.{case}.fps": row["fps"], f"render.{case}.fps.ratio_to_target": row["fps"] / TARGET_FPS,
                 f"render.{case}.frame_ms_p50.ratio_to_target": row["p50"] / TARGET_MS, f"render.{case}.renderer": row["renderer"]}
    return keys


def main() -> None:
    main_with_json(measure, flat)


if __name__ == "__main__":
    main()
