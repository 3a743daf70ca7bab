"""Plate-spring costs on the shipped brain: force per servo tick, deformation per frame."""

from __future__ import annotations

import numpy as np

from bench.common import each_call, per_call, report
from sim.scene import DEFAULT_SCENE as SCENE
from sim.scene import build_scene


def main() -> None:
    scene = build_scene(SCENE)
    model = scene.model
    mesh = scene.mesh
    rng = np.random.default_rng(0)
    contacts = [model.grasp(h.start, i) for i, h in enumerate(scene.spec.hands)]
    print(f"plate-spring ({model.stack.variant}, {model.stack.params.layers} layers) on {mesh.n_vertices} vertices; "
          f"outer ring {model.radii[-1] * 1e3:.1f} mm, {sum(len(c.data.vertices) for c in contacts)} vertices in the two rings")
    disp = [tuple(float(x) for x in rng.uniform(-0.02, 0.02, 3)) for _ in range(1024)]
    k = [0]

    def tick():
        d = disp[k[0] & 1023]
        k[0] += 1
        model.force(contacts[0], d)
        model.force(contacts[1], d)

    report("force, both hands, per servo tick (batched)", per_call(tick, 200_000), "us", target=10.0)
    report("force, both hands, per servo tick (each)", each_call(tick, 50_000), "us", target=10.0)
    dd = [[rng.uniform(-0.015, 0.015, 3) for _ in range(2)] for _ in range(64)]
    j = [0]

    def frame():
        model.deformation(contacts, dd[j[0] & 63])
        j[0] += 1

    report("deformation, whole brain, two hands, per frame", each_call(frame, 3000), "ms", target=1.0,
           reference=("paper (2014 PC)", 14.69))
    report("grasp (nearest vertex + geodesic ring)", each_call(lambda: model.grasp(scene.spec.hands[0].start, 0), 200), "ms", target=50.0)
    located_tick(scene, disp)


def located_tick(scene, disp) -> None:
    """The location-aware model (issue 16's goal: a tick within 2x of the paper's model's)."""
    from analysis.accuracy import LOCATED_PARAMS
    from analysis.field import FIELD_FILE, load_field
    from sim.models.plate_spring import PlateSpringModel, load_params

    paper = PlateSpringModel(scene.mesh, scene.spec.models["plate_spring"].plate_spring, "continuous")
    located = PlateSpringModel(scene.mesh, load_params(LOCATED_PARAMS), "located", load_field(FIELD_FILE, scene.mesh))
    laws = {name: [m.grasp(h.start, i).law for i, h in enumerate(scene.spec.hands)] for name, m in (("paper", paper), ("located", located))}
    out = {}
    for name, (a, b) in laws.items():
        k = [0]

        def tick(a=a, b=b, k=k):
            d = disp[k[0] & 1023]
            k[0] += 1
            a.force(d)
            b.force(d)

        out[name] = report(f"law, both hands, per tick ({name})", per_call(tick, 200_000), "us", target=10.0)
    print(f"located / paper tick, p50: {out['located']['p50'] / out['paper']['p50']:.2f}x (goal: at most 2x)")


if __name__ == "__main__":
    main()
