"""Offscreen rendering of the brain (the participant view's renderer, open3d's classic OpenGL
on EGL, no window): ms per 640x480 frame."""

from __future__ import annotations

import numpy as np

from bench.common import each_call, report
from sim.mesh import load_mesh


def main() -> None:
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
    report("render 640x480, brain + two hands", each_call(frame, 30), "ms", target=33.0)
    r.close()


if __name__ == "__main__":
    main()
