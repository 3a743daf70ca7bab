"""The pulls every model and the reference are measured on: a pull grasps a surface vertex and
moves it along a tangent direction. `make_pulls` gives the accuracy bench's calibration pulls
(the scene's hands and a frontal point), `test_pulls` its held-out ones, `hand_pulls` the
scene's scripted ones. The reference solutions themselves are analysis/verification/reference.py's."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from sim.scene import Scene, clamp_limit, load_scene

EXTRA_GRASPS = ((0.035, 0.015, 0.062),)  # frontal dorsal right hemisphere, beside the scene's hands


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


TEST_PLACES = 10  # held-out grasp places (half per hemisphere), two directions each: 20 pulls, enough decided samples
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
    location-aware plate-spring's field is sampled (`analysis.verification.field_fit`), are excluded, so no
    test place is a field site."""
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
    spec = load_scene(path)
    if young is not None:
        spec = dataclasses.replace(spec, material=dataclasses.replace(spec.material, young=float(young)))
    return Scene(spec)
