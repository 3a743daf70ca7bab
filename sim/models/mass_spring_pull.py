"""One held pull of the mass-spring system (`studyctl model mass-spring`): grasp, hold the hand
displaced, step the system with a chosen integrator and report stability and cost."""

from __future__ import annotations

import time

import numpy as np

from sim.errors import ParameterError
from sim.geometry.tetmesh import body_volume
from sim.models.base import pull_problem
from sim.models.fem import fixed_nodes
from sim.models.mass_spring import MassSpringModel, StabilityError, from_tets
from sim.scene import AXES


def hold_pull(scene, integrator: str, dt: float, steps: int, resolution: float | None = None, substep: bool = False,
              grasp=None, displacement=None) -> dict:
    """Grasp the scene's brain (default: its first hand's start), hold the hand displaced (default:
    that hand's scripted pull) and step the mass-spring system `steps` times."""
    opts = scene.spec.options_of("mass_spring")
    resolution = opts["resolution"] if resolution is None else resolution
    if not 0.003 <= resolution <= 0.008:
        raise ParameterError(f"resolution: {resolution * 1e3:g} mm is out of range; allowed: 3..8 mm")
    if not (isinstance(steps, int) and steps >= 1):
        raise ParameterError(f"steps: {steps!r} is out of range; allowed: an integer >= 1")
    hand = scene.spec.hands[0]
    if grasp is None:
        grasp = hand.start
    if displacement is None:
        displacement = np.asarray(hand.script(scene.mesh).pull)
    if (problem := pull_problem(displacement)) is not None:
        raise ParameterError(f"displacement: {problem}")
    mesh = scene.mesh
    volume = body_volume(mesh, resolution)
    material = scene.spec.material
    fixed = fixed_nodes(volume, mesh, scene.fixed_mask, AXES[scene.spec.fixed.axis])
    system = from_tets(volume.nodes, volume.tets, material.young, material.density, fixed=fixed, damping=opts["damping"])
    model = MassSpringModel(mesh, volume, system, integrator=integrator, dt=dt, coupling=opts["coupling"],
                            grasp_radius=opts["grasp_radius"], substep=True, iterations=opts["iterations"])
    contact = model.grasp(grasp, 0)
    d = np.asarray(displacement, dtype=np.float64)
    system.set_anchors([(contact.data.nodes, model.coupling, contact.data.anchor + d)])
    crit_rest = None
    crit = system.critical_dt()
    error = None
    times = []
    for _ in range(steps):
        start = time.perf_counter()
        try:
            system.step(dt, integrator, substep=substep, iterations=opts["iterations"])
        except StabilityError as exc:
            error = str(exc)
            break
        times.append(time.perf_counter() - start)
        if system.unstable:
            break
    if error is not None:
        raise StabilityError(error)
    u = system.x - system.rest_positions
    patch = system.x[contact.data.nodes].mean(axis=0) - contact.data.anchor
    force = -model.coupling * (d - patch)  # on the hand
    finite = bool(np.all(np.isfinite(u)))
    system.set_anchors([])
    crit_rest = system.critical_dt()
    return {
        "integrator": integrator,
        "dt": dt,
        "steps": len(times),
        "substep": substep,
        "critical_dt": crit,
        "critical_dt_without_coupling": crit_rest,
        "stable": (not system.unstable) and finite,
        "unstable_at": system.unstable_at,
        "max_displacement": float(np.linalg.norm(u, axis=1).max()) if finite else None,
        "grasp_displacement": patch.tolist() if finite else None,
        "force_on_hand_n": force.tolist() if finite else None,
        "energy": system.energy() if finite else None,
        "ms_per_step": float(np.median(times) * 1e3) if times else None,
        "nodes": int(system.n),
        "springs": int(len(system.springs)),
    }
