"""Plate-spring costs on the shipped brain: force per servo tick, deformation per frame.
`python -m bench plate_spring [--json]` (keys `plate_spring.*`)."""

from __future__ import annotations

import numpy as np

from analysis.verification.paper import deformation_ms
from bench.common import each_call, main_with_json, per_call, percentile_keys, report
from sim.scene import DEFAULT_SCENE as SCENE
from sim.scene import build_scene


def measure() -> dict:
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

    rows = {"tick_both_hands_batched_us": report("force, both hands, per servo tick (batched)", per_call(tick, 200_000), "us", target=10.0),
            "tick_both_hands_us": report("force, both hands, per servo tick (each)", each_call(tick, 50_000), "us", target=10.0)}
    dd = [[rng.uniform(-0.015, 0.015, 3) for _ in range(2)] for _ in range(64)]
    j = [0]

    def frame():
        model.deformation(contacts, dd[j[0] & 63])
        j[0] += 1

    rows["frame_two_hands_ms"] = report("deformation, whole brain, two hands, per frame", each_call(frame, 3000), "ms", target=1.0,
                                        reference=("paper (2014 PC)", deformation_ms()["plate_spring"]))
    rows["grasp_ms"] = report("grasp (nearest vertex + geodesic ring)", each_call(lambda: model.grasp(scene.spec.hands[0].start, 0), 200), "ms", target=50.0)
    return {"rows": rows, "located_over_paper_tick": located_tick(scene, disp)}


TARGETS = {"tick_both_hands_batched_us": 10.0, "tick_both_hands_us": 10.0, "frame_two_hands_ms": 1.0, "grasp_ms": 50.0}


def flat(result: dict) -> dict:
    keys = {}
    for name, row in result["rows"].items():
        keys |= percentile_keys(f"plate_spring.{name}", row, TARGETS[name])
    keys["plate_spring.frame_two_hands_ms_p50.ratio_to_paper"] = result["rows"]["frame_two_hands_ms"]["p50"] / deformation_ms()["plate_spring"]
    keys["plate_spring.located.tick_p50.ratio_to_paper_model"] = result["located_over_paper_tick"]
    keys["plate_spring.located.tick_p50.ratio_to_paper_model.target"] = 2.0
    return keys


def main() -> None:
    main_with_json(measure, flat)


def located_tick(scene, disp) -> float:
    """The location-aware model (issue 16's goal: a tick within 2x of the paper's model's)."""
    from analysis.verification.bench_pulls import LOCATED_PARAMS
    from sim.models.plate_spring import PlateSpringModel, load_params
    from sim.stiffness_field import FIELD_FILE, load_field

    paper = PlateSpringModel(scene.mesh, scene.spec.models["plate_spring"].options["params"], "continuous")
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
    ratio = out["located"]["p50"] / out["paper"]["p50"]
    print(f"located / paper tick, p50: {ratio:.2f}x (goal: at most 2x)")
    return float(ratio)


if __name__ == "__main__":
    main()
