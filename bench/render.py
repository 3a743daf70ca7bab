"""Offscreen rendering of the brain (open3d legacy OpenGL on EGL): ms per frame."""

from __future__ import annotations

import numpy as np

from bench.common import each_call, report
from sim.mesh import load_mesh


def main() -> None:
    from sim.render import BrainRenderer

    mesh = load_mesh()
    r = BrainRenderer(mesh, 640, 480)
    rng = np.random.default_rng(1)
    mags = rng.uniform(0, 1, mesh.n_vertices)
    hands = [(mesh.vertices[3386], np.array([-1.0, 0, 0])), (mesh.vertices[13629], np.array([1.0, 0, 0]))]
    r.render(mesh.vertices, mags, hands)  # warm-up
    report("render 640x480, brain + two hands", each_call(lambda: r.render(mesh.vertices, mags, hands), 30), "ms", target=33.0)
    r.close()


if __name__ == "__main__":
    main()
