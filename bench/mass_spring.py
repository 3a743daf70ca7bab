"""Mass-spring on the brain at 4 mm: ms per step for each integrator; local/global iterations
to reach 1% of the implicit (backward Euler) solution of a step."""

from __future__ import annotations

import time

import numpy as np

from sim.models.fem import fixed_nodes
from sim.models.mass_spring import from_tets
from sim.scene import AXES, DEFAULT_SCENE, build_scene
from sim.volume import voxel_volume


def _system(scene, resolution=0.004):
    mesh = scene.mesh
    volume = voxel_volume(mesh, resolution)
    m = scene.spec.material
    fixed = fixed_nodes(volume, mesh, scene.fixed_mask, AXES[scene.spec.fixed.axis])
    return from_tets(volume.nodes, volume.tets, m.young, m.density, fixed=fixed, damping=5.0)


def main() -> None:
    scene = build_scene(DEFAULT_SCENE)
    base = _system(scene)
    grasp = scene.mesh.vertices[scene.mesh.nearest_vertex(scene.spec.hands[0].start)]
    patch = np.flatnonzero((np.linalg.norm(base.rest_positions - grasp, axis=1) < 0.006) & ~base.fixed)
    target = base.rest_positions[patch].mean(axis=0) + np.array([-0.012, 0.0, 0.0])
    base.set_anchors([(patch, 300.0, target)])
    crit = base.critical_dt()
    print(f"brain at 4 mm: {base.n} nodes, {len(base.springs)} springs, {len(base.free)} free nodes; "
          f"critical_dt {crit * 1e3:.3f} ms with a 300 N/m coupling")
    start_state = base.state()
    for integrator, dt, steps in (("explicit", 0.5 * crit, 200), ("implicit", 1 / 60, 10), ("local-global", 1 / 60, 20)):
        base.set_state(start_state)
        base.step(dt, integrator)  # warm-up: factorisations, caches
        times = []
        for _ in range(steps):
            start = time.perf_counter()
            base.step(dt, integrator)
            times.append(time.perf_counter() - start)
        t = np.array(times) * 1e3
        per_frame = np.median(t) * (1 / 60) / dt
        print(f"  {integrator:<13} dt {dt * 1e3:7.3f} ms: p50 {np.median(t):8.3f} ms per step, p95 {np.percentile(t, 95):8.3f}; "
              f"{per_frame:8.1f} ms per 1/60 s of simulated time")
    # convergence of local/global towards the backward-Euler step it approximates
    base.set_state(start_state)
    for _ in range(10):
        base.step(1 / 60, "local-global")  # a state in the middle of the pull
    s0 = base.state()
    base.step(1 / 60, "local-global", iterations=2000)  # converged: the exact backward-Euler step
    ref = base.x.copy()
    base.set_state(s0)
    base.step(1 / 60, "implicit")
    moved = np.linalg.norm(ref - s0[0])
    print(f"  one Newton step (implicit) vs the converged backward-Euler step: {np.linalg.norm(base.x - ref) / moved:.2%} of the step")
    for it in (1, 2, 5, 10, 20, 50, 100, 200, 500, 1000):
        base.set_state(s0)
        base.step(1 / 60, "local-global", iterations=it)
        err = np.linalg.norm(base.x - ref) / moved
        print(f"  local/global, {it:4d} iterations: {err:.2%} of the step")
        if err < 0.01:
            print(f"  -> {it} iterations reach 1% of the implicit solution")
            break


if __name__ == "__main__":
    main()
