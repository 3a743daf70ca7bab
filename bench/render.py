"""Offscreen rendering of the brain (the participant view's renderer, open3d's classic OpenGL
on EGL, no window): ms per 640x480 frame. `python -m bench render [--json]` (keys `render.*`)."""

from __future__ import annotations

import numpy as np

from bench.common import each_call, main_with_json, percentile_keys, report
from sim.mesh import load_mesh

TARGET_MS = 33.0  # a 30 Hz visual frame


def measure() -> dict:
    from sim.view import HandState, ParticipantView

    mesh = load_mesh()
    r = ParticipantView(mesh, width=640, height=480, visible=False)
    rng = np.random.default_rng(1)
    mags = rng.uniform(0, 1, mesh.n_vertices)
    hands = [HandState(tuple(mesh.vertices[3386])), HandState(tuple(mesh.vertices[13629]))]
    u = np.zeros_like(mesh.vertices)

    def frame():
        r.draw(u, hands, heat01=mags)
        r.image()

    frame()  # warm-up
    row = report("render 640x480, brain + two hands", each_call(frame, 30), "ms", target=TARGET_MS)
    r.close()
    return row


def main() -> None:
    main_with_json(measure, lambda row: percentile_keys("render.frame_ms", row, TARGET_MS))


if __name__ == "__main__":
    main()
