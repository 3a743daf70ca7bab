"""Reference solutions: quasi-static neo-Hookean FEM pulls on the scene's brain.

The accuracy bench (analysis/accuracy.py) compares every model with these, and the plate-spring
calibration (sim/calibrate.py) fits to them. A pull grasps a surface vertex and moves it along
a tangent direction; the solve takes one load step (or more) per sampled displacement and
records the force on the hand, the grasp point's displacement and the surface displacement of
the grasped hemisphere at each. Results are cached on disk: the 3 mm solve takes about a
minute and 1.5 GB per pull on a 2-core machine, the 2 mm one about 8 minutes and 5 GB.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

EXTRA_GRASPS = ((0.035, 0.015, 0.062),)  # frontal dorsal right hemisphere, beside the scene's hands
CACHE_VERSION = 1  # bump when the reference solution changes (not for solver settings that reach the same one)


@dataclass(frozen=True)
class Pull:
    name: str  # e.g. "left-lateral"
    vertex: int
    point: tuple[float, float, float]
    direction: tuple[float, float, float]  # unit vector in the tangent plane
    hemisphere: int

# -- the pulls -----------------------------------------------------------------------------

def _tangent(normal: np.ndarray, d: np.ndarray) -> np.ndarray:
    t = d - np.dot(d, normal) * normal
    return t / np.linalg.norm(t)


def make_pulls(scene) -> list[Pull]:
    """Each hand's grasp point and one frontal point, pulled laterally and anteriorly."""
    mesh = scene.mesh
    points = [h.start for h in scene.spec.hands] + list(EXTRA_GRASPS)
    names = [h.name for h in scene.spec.hands] + [f"extra{i + 1}" for i in range(len(EXTRA_GRASPS))]
    out = []
    for name, p in zip(names, points):
        v = mesh.nearest_vertex(p)
        x = mesh.vertices[v]
        n = mesh.vertex_normals[v]
        hemi = int(mesh.labels[v]) if mesh.labels is not None else 0
        for dname, d in (("lateral", np.array([math.copysign(1.0, x[0]), 0.0, 0.0])), ("anterior", np.array([0.0, 1.0, 0.0]))):
            t = _tangent(n, d)
            out.append(Pull(f"{name}-{dname}", int(v), tuple(float(c) for c in x), tuple(float(c) for c in t), hemi))
    return out


TEST_PLACES = 6  # held-out grasp places (half per hemisphere), two directions each
TEST_MIN_DISTANCE = 0.020  # m from every calibration grasp point
TEST_MIN_HEIGHT = 0.015  # m above the clamp plane: the patch must be free to move
ICO4_VERTICES = 2562  # the first 2562 vertices of each fsaverage5 hemisphere are its ico4 subset


def test_pulls(scene, places: int = TEST_PLACES) -> list[Pull]:
    """Held-out pulls for the accuracy bench: `places` grasp places, half on each hemisphere,
    each pulled along two tangent directions (anterior, and across: the normal x anterior).

    Deterministic: farthest-point sampling over the surface vertices that a surgeon can reach
    (outward normal not facing the other hemisphere or downwards), at least
    TEST_MIN_HEIGHT above the clamp plane and TEST_MIN_DISTANCE from every calibration grasp
    point (`make_pulls`), starting from those points. Vertices of the ico4 subset, where the
    location-aware plate-spring's field is sampled (`analysis.field`), are excluded, so no
    test place is a field site."""
    from sim.scene import clamp_limit

    mesh = scene.mesh
    v, n = mesh.vertices, mesh.vertex_normals
    labels = mesh.labels if mesh.labels is not None else np.zeros(len(v), dtype=np.int64)
    axis, limit = clamp_limit(scene)
    calib = np.array([p.point for p in make_pulls(scene)])
    dist = np.min(np.linalg.norm(v[:, None, :] - calib[None], axis=2), axis=1)
    centre_x = 0.5 * (v[labels == 0, 0].mean() + v[labels == 1, 0].mean()) if labels.max() > 0 else v[:, 0].mean()
    outward = np.sign(v[:, 0] - centre_x)
    facing_medial = (n[:, 0] * outward) < -0.5
    local = np.arange(len(v)) - np.array([np.flatnonzero(labels == lab)[0] for lab in labels])  # index within the hemisphere
    ok = ((v[:, axis] >= limit + TEST_MIN_HEIGHT) & (dist >= TEST_MIN_DISTANCE) & ~facing_medial & (n[:, 2] > -0.3)
          & (local >= ICO4_VERTICES))
    chosen: list[int] = []
    for k in range(places):
        lab = k % 2 if labels.max() > 0 else 0
        cand = np.flatnonzero(ok & (labels == lab))
        anchors = np.vstack([calib] + [v[c][None] for c in chosen])
        d = np.min(np.linalg.norm(v[cand][:, None, :] - anchors[None], axis=2), axis=1)
        chosen.append(int(cand[np.argmax(d)]))
    out = []
    for k, vid in enumerate(chosen):
        x, normal = v[vid], n[vid]
        ant = _tangent(normal, np.array([0.0, 1.0, 0.0]))
        across = np.cross(normal, ant)
        across /= np.linalg.norm(across)
        hemi = int(labels[vid])
        for dname, t in (("anterior", ant), ("across", across)):
            out.append(Pull(f"test{k + 1}-{dname}", vid, tuple(float(c) for c in x), tuple(float(c) for c in t), hemi))
    return out


def hand_pulls(scene) -> list[Pull]:
    """The scene's own scripted pulls (the calibration's reference curve)."""
    mesh = scene.mesh
    out = []
    for h in scene.spec.hands:
        script = h.script(mesh)
        v = mesh.nearest_vertex(h.start)
        d = np.asarray(script.pull) / np.linalg.norm(script.pull)
        hemi = int(mesh.labels[v]) if mesh.labels is not None else 0
        out.append(Pull(f"{h.name}-scripted", int(v), tuple(float(c) for c in mesh.vertices[v]), tuple(float(c) for c in d), hemi))
    return out


def scene_with(path, young: float | None = None):
    """The scene at `path`, with Young's modulus replaced if given."""
    from sim.scene import Scene, load_scene

    spec = load_scene(path)
    if young is not None:
        spec = dataclasses.replace(spec, material=dataclasses.replace(spec.material, young=float(young)))
    return Scene(spec)


def surface_part(mesh, label: int) -> np.ndarray:
    """Surface vertices of one hemisphere (where a pull's displacement is compared)."""
    return np.flatnonzero(mesh.labels == label) if mesh.labels is not None else np.arange(len(mesh.vertices))


# -- the reference: neo-Hookean FEM --------------------------------------------------------

def _reference_key(scene, resolution: float, pull: Pull, xs: np.ndarray, grasp_radius: float) -> str:
    mesh_hash = hashlib.sha256(Path(scene.spec.mesh_path).read_bytes()).hexdigest()[:16]
    s = scene.spec
    key = json.dumps([CACHE_VERSION, mesh_hash, s.material.poisson, s.fixed.axis, s.fixed.from_bottom, resolution,
                      grasp_radius, pull.vertex, [round(c, 12) for c in pull.direction], [round(x, 9) for x in xs]])
    return hashlib.sha256(key.encode()).hexdigest()[:20]


def reference_pull(scene_path, resolution: float, pull: Pull, xs, use_cache: bool = True) -> dict:
    """Neo-Hookean pull, one load step per displacement in `xs` (equally spaced from xs[0]).

    Forces are returned per pascal of Young's modulus (the neo-Hookean energy is proportional to
    E at a fixed Poisson ratio, so the force at a given displacement is too): multiply by E.
    Cached on disk (the 3 mm solve takes about a minute per pull, the 2 mm one about 8).
    """
    from sim.errors import ParameterError
    from sim.models.fem import FemModel, NewtonReport, SingularSystemError, fixed_nodes, neo_hookean_solve
    from sim.scene import AXES, grasp_radius
    from sim.volume import cache_dir, voxel_volume

    scene = scene_with(scene_path, young=1.0)
    xs = np.asarray(xs, dtype=np.float64)
    if len(xs) == 0 or not np.allclose(xs, xs[-1] * np.arange(1, len(xs) + 1) / len(xs)):
        raise ParameterError("displacements: the reference needs equal steps from 0 (x_max * k / n)")
    radius = grasp_radius(scene)
    path = cache_dir() / "accuracy" / f"reference-{_reference_key(scene, resolution, pull, xs, radius)}.npz"
    if use_cache and path.exists():
        with np.load(path) as z:
            return {k: (z[k] if z[k].ndim else z[k].item()) for k in z.files}
    mesh = scene.mesh
    start = time.perf_counter()
    volume = voxel_volume(mesh, resolution)
    fixed = fixed_nodes(volume, mesh, scene.fixed_mask, AXES[scene.spec.fixed.axis])
    model = FemModel(mesh, volume, 1.0, scene.spec.material.poisson, fixed, grasp_radius=radius)
    contact = model.grasp(pull.point, 0)
    part = model.parts[contact.data.part]
    hemi = surface_part(mesh, pull.hemisphere)
    n = len(xs)
    force = np.zeros((n, 3))
    grasp = np.zeros((n, 3))
    surface = np.zeros((n, len(hemi), 3), dtype=np.float32)
    u_full = np.zeros((volume.n_nodes, 3))
    target = np.asarray(pull.direction) * xs[-1]
    iterations = 0
    # at least 6 load steps for the largest pull (4 mm each), each to a relative residual of
    # 1e-6 (five orders below the JND; near a buckling load the tangent is indefinite and the
    # shifted Newton steps converge only linearly); where that fails, halve the steps
    for sub in (max(1, math.ceil(6 / n)) * m for m in (1, 2, 4)):

        def on_step(step, u_part, lam_mult, sub=sub):
            if step % sub:
                return
            k = step // sub - 1
            force[k] = -lam_mult  # the hand feels minus the force that holds the tissue
            u_full[model.part_nodes[contact.data.part]] = u_part
            surf = model.embedding.matrix @ u_full
            grasp[k] = surf[pull.vertex]
            surface[k] = surf[hemi]

        try:
            _, _, rep = neo_hookean_solve(part, contact.data.W, target, steps=n * sub, on_step=on_step, tol=1e-6, max_iter=60)
        except SingularSystemError:  # a Newton iterate went where no shift helps: smaller load steps
            rep = NewtonReport(load_steps=n * sub, converged=False, min_jacobian=math.nan)
        iterations += int(sum(rep.iterations))
        if rep.converged:
            break
    out = {"force_per_pa": force, "grasp": grasp, "surface": surface, "converged": bool(rep.converged),
           "min_jacobian": float(rep.min_jacobian), "iterations": iterations, "load_steps": n * sub,
           "nodes": int(len(part.nodes)), "seconds": time.perf_counter() - start}
    if use_cache and rep.converged:
        from sim.files import save_npz

        save_npz(path, **out)
    return out


