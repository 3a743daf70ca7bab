"""The truth a synthetic participant perceives: the body-fitted P2 reference's grasp stiffness.

The observer (studyctl/observer.py) judges every condition's rendered force against the force
the converged reference gives for the same hand motion and grasp: linear elasticity on
quadratic tetrahedra on the shipped body-fitted meshes of 8, 6 and 4 mm (fTetWild), Richardson-
extrapolated (analysis/reference.py, docs/reference.md). It is none of the study's models and
nothing is calibrated against it (the located plate-spring's field is solved on the 8 mm mesh
alone, and is not a study condition).

Only grasp places are needed, so the truth is a table: the condensed stiffness per pascal
(3 x 3) at the surface vertices within `TRUTH_RADIUS` of the scene's hands, shipped in
`data/observer_truth.npz` (fTetWild is not deterministic: a rebuilt table differs by up to
about 1.5%, which is why it is shipped rather than rebuilt on each machine). Another scene or
another grasp place needs `studyctl calibrate truth` (about 3.5 minutes on 2 cores), which
writes a table to the cache folder that `load_truth` reads next to the shipped one.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from brainsim_assets import path as _asset
from studyctl.errors import InputError

TRUTH_FILE = _asset("data/observer_truth.npz")
TRUTH_RADIUS = 0.010  # m around each hand's start: the motor model's grasps land within a few mm
TRUTH_SIZES_MM = (8.0, 6.0, 4.0)  # the shipped body-fitted meshes (sim/tetmesh.py)


@dataclass(frozen=True)
class Truth:
    """K per pascal at surface vertices; `force` scales by the scene's Young's modulus."""

    vertices: np.ndarray  # (n,) surface vertex ids
    K_per_pa: np.ndarray  # (n, 3, 3)
    young: float  # the scene's modulus, Pa
    digest: str  # the surface the table belongs to
    grasp_radius: float

    def K(self, vertex: int) -> np.ndarray:
        hit = np.flatnonzero(self.vertices == int(vertex))
        if not len(hit):
            raise InputError(f"observer truth: no reference stiffness for grasp vertex {int(vertex)}; compute it with "
                             "`studyctl calibrate truth --scene FILE --vertices ...` (docs/synthetic.md)")
        return self.young * self.K_per_pa[hit[0]]


def truth_key(scene) -> dict:
    """What the table depends on: the surface, the clamp, Poisson's ratio and the grasp radius
    (not Young's modulus: linear elasticity scales with it)."""
    from sim.field import mesh_digest
    from sim.scene import clamp_limit, grasp_radius

    axis, limit = clamp_limit(scene)
    return {"digest": mesh_digest(scene.mesh), "clamp_axis": int(axis), "clamp_height": float(limit),
            "poisson": float(scene.spec.material.poisson),
            "grasp_radius": grasp_radius(scene)}


def user_truth_path(scene) -> Path:
    """Where `studyctl calibrate truth` puts a table for a scene the shipped one does not cover."""
    import hashlib
    import json

    from sim.volume import cache_dir

    key = json.dumps(truth_key(scene), sort_keys=True)
    return cache_dir() / f"truth-{hashlib.sha256(key.encode()).hexdigest()[:20]}.npz"


def _read(path: Path, key: dict):
    """The table at `path` if it was made for `key`, else None (with why)."""
    try:
        z = np.load(path, allow_pickle=False)
    except (OSError, ValueError) as exc:
        raise InputError(f"{path}: cannot read the observer truth table: {exc}") from None
    for name, want in key.items():
        have = z[name].item() if z[name].shape == () else z[name]
        same = have == want if isinstance(want, str) else math.isclose(float(have), float(want), rel_tol=1e-9, abs_tol=1e-12)
        if not same:
            return None, f"{name}: {have} there, {want} here"
    return z, ""


def load_truth(scene, path: Path | str | None = None) -> Truth:
    """The truth for this scene: `path`, else the shipped table and the one `calibrate truth`
    made for this scene (their grasp places together). A table made for another surface,
    clamp, Poisson's ratio or grasp radius is refused by name."""
    key = truth_key(scene)
    paths = [Path(path)] if path is not None else [p for p in (TRUTH_FILE, user_truth_path(scene)) if p.exists()]
    vertices, K, why = [], [], []
    for p in paths:
        z, reason = _read(p, key)
        if z is None:
            why.append(f"{p}: made for another scene ({reason})")
            continue
        vertices.append(z["vertices"])
        K.append(z["K_per_pa"])
    if not vertices:
        raise InputError(("; ".join(why) or "no observer truth table") + "; make one with `studyctl calibrate truth --scene FILE`")
    return Truth(vertices=np.concatenate(vertices), K_per_pa=np.concatenate(K), young=float(scene.spec.material.young),
                 digest=key["digest"], grasp_radius=key["grasp_radius"])


def hand_vertices(scene, radius: float = TRUTH_RADIUS) -> np.ndarray:
    """Surface vertices within `radius` of where each hand grasps (same hemisphere)."""
    from sim.mesh import patch_vertices

    mesh = scene.mesh
    out = [patch_vertices(mesh, mesh.nearest_vertex(hand.script(mesh).start), radius) for hand in scene.spec.hands]
    return np.unique(np.concatenate(out)) if out else np.zeros(0, dtype=np.int64)
