"""The truth a synthetic participant perceives: what measured brain tissue would push back with.

The observer (studyctl/synthetic/observer.py) judges every condition's rendered force against the force
the converged reference gives for the same hand motion and grasp: the tissue's finite-strain
law (human cortex, one-term Ogden, nearly incompressible; docs/material.md) on quadratic
tetrahedra on the shipped body-fitted meshes of 8, 6 and 4 mm, Richardson-extrapolated
(analysis/verification/reference.py). It is none of the study's models and nothing is calibrated against it.

The force is not proportional to the displacement, so the table holds, per hand of the scene,
the reference's **path**: the force f(s) and the condensed tangent stiffness K(s) along the
hand's pull at s = 0, 2, ..., 24 mm (the shipped solves), and per grasp place v near that
hand (the surface vertices within `TRUTH_RADIUS`) a **transfer** T(v) = K0(v) K0(c)^-1 of the
small-strain stiffnesses at v and at the hand's own vertex c. For a hand displacement d
grasped at v, with e the pull's direction and s = d.e:

    f(d) = T(v) [f(s) + K(s) (d - s e)]

f(s) a cubic Hermite interpolant of the recorded forces and their slopes K(s) e, K(s) linear
between records; below s = 0 the small-strain tangent, past the last record its tangent.
`studyctl calibrate truth` measures the transfer's error where it matters most (the place
farthest from each hand's vertex, solved directly) and stores it beside the table.

Forces are stored per pascal of the law's shear modulus (a law scaled in mu scales them).
The shipped table (`data/observer_truth.npz`) covers the shipped scenes' hands; another scene
or grasp place needs `studyctl calibrate truth`, which writes a table to the cache folder
that `load_truth` reads next to the shipped one.
"""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from analysis.errors import InputError
from analysis.verification.regions import scene_regions
from analysis.verification.solve_keys import body_key
from brainsim_assets import path as _asset
from sim.geometry.mesh import patch_vertices
from sim.geometry.volume import cache_dir
from sim.perception import force_jnd
from sim.scene import clamp_limit, grasp_radius
from sim.stiffness_field import mesh_digest

TRUTH_FILE = _asset("data/observer_truth.npz")
TRUTH_INFO = _asset("data/observer_truth.json")  # its SHA-256 and how it was made
TRUTH_RADIUS = 0.010  # m around each hand's start: the motor model's grasps land within a few mm
TRUTH_SIZES_MM = (8.0, 6.0, 4.0)  # the shipped body-fitted meshes (sim/geometry/tetmesh.py)
TRUTH_VERSION = 3  # 1: the linear P2 stiffness per pascal of Young's modulus; 3: records to 12 mm with the band


@dataclass(frozen=True)
class Truth:
    """The reference's force for any hand displacement at the table's grasp places."""

    vertices: np.ndarray  # (n,) surface vertex ids
    path: np.ndarray  # (n,) which path (hand) each vertex's grasp follows
    transfer: np.ndarray  # (n, 3, 3) T(v) = K0(v) K0(c)^-1
    s: np.ndarray  # (m,) m, the records along each path, from 0
    direction: np.ndarray  # (h, 3) each path's unit direction e
    force_per_pa: np.ndarray  # (h, m, 3) force on the tissue per pascal of shear modulus
    stiffness_per_pa: np.ndarray  # (h, m, 3, 3) dF/dd per pascal
    mu: float  # the scene's law's shear modulus, Pa
    digest: str  # the surface the table belongs to
    grasp_radius: float
    band_rel: np.ndarray | None = None  # (h, m) the truth's relative half-band where it is not decided, 0 where it is
    path_band: np.ndarray | None = None  # (h, m) the band everywhere (mesh and law)
    transfer_error: np.ndarray | None = None  # (h, m) the transfer's error at the path's farthest place
    path_vertex: np.ndarray | None = None  # (h,) each path's own grasp vertex
    path_decided: np.ndarray | None = None  # (h, m) whether the truth is decided at each record; None: where band_rel is 0

    def band(self, vertex: int, d) -> np.ndarray:
        """The truth's relative half-band for hand displacements d (k, 3), linear along the path
        between records, the last record's beyond: at a path's own vertex, where the truth is
        not decided (0 where it is); at any other place, everywhere, the path's band and the
        transfer's measured error root-sum-square (the transfer is exact only at rest)."""
        d = np.atleast_2d(np.asarray(d, dtype=np.float64))
        if self.band_rel is None:
            return np.zeros(len(d))
        h = int(self.path[self._row(vertex)])
        s = d @ self.direction[h]
        if self.path_vertex is None or int(vertex) == int(self.path_vertex[h]):
            return np.interp(s, self.s, self.band_rel[h])
        return np.hypot(np.interp(s, self.s, self.path_band[h]), np.interp(s, self.s, self.transfer_error[h]))

    def decided(self, vertex: int, d) -> np.ndarray:
        """Whether the truth is decided (analysis.verification.truth_band.decide) for hand
        displacements d (k, 3): along the path only between two decided records, never below its
        start (compression, which the reference did not solve) nor past its last record (the
        tangent's extrapolation); at a place off the path's own vertex also only where its band
        (`band`: the path's and the transfer's error) is narrower than the force JND there, the
        rule's own bar."""
        d = np.atleast_2d(np.asarray(d, dtype=np.float64))
        h = int(self.path[self._row(vertex)])
        if self.path_decided is not None:
            rec = np.asarray(self.path_decided[h], dtype=bool)
        else:
            rec = self.band_rel[h] == 0 if self.band_rel is not None else np.ones(len(self.s), dtype=bool)
        s = d @ self.direction[h]
        k = np.clip(np.searchsorted(self.s, s, side="right") - 1, 0, len(self.s) - 2)
        ok = (s >= self.s[0]) & (s <= self.s[-1]) & rec[k] & rec[k + 1]
        if self.path_vertex is not None and int(vertex) != int(self.path_vertex[h]):
            ok &= self.band(vertex, d) < force_jnd(np.linalg.norm(self.force(vertex, d), axis=1))
        return ok

    def _row(self, vertex: int) -> int:
        hit = np.flatnonzero(self.vertices == int(vertex))
        if not len(hit):
            raise InputError(f"observer truth: no reference for grasp vertex {int(vertex)}; compute it with "
                             "`studyctl calibrate truth --scene FILE --vertices ...` (docs/synthetic.md)")
        return int(hit[0])

    def force(self, vertex: int, d) -> np.ndarray:
        """The force (N, on the tissue; the hand feels minus it) for hand displacements d (k, 3)
        from the grasped vertex `vertex`."""
        i = self._row(vertex)
        h = int(self.path[i])
        d = np.atleast_2d(np.asarray(d, dtype=np.float64))
        e, s_rec = self.direction[h], self.s
        F, K = self.force_per_pa[h], self.stiffness_per_pa[h]
        s = d @ e
        sc = np.clip(s, 0.0, s_rec[-1])
        k = np.clip(np.searchsorted(s_rec, sc, side="right") - 1, 0, len(s_rec) - 2)
        s0, s1 = s_rec[k], s_rec[k + 1]
        L = s1 - s0
        t = ((sc - s0) / L)[:, None]
        g0, g1 = K[k] @ e, K[k + 1] @ e  # slopes dF/ds
        h00, h10, h01, h11 = 2 * t**3 - 3 * t**2 + 1, t**3 - 2 * t**2 + t, -2 * t**3 + 3 * t**2, t**3 - t**2
        on_path = h00 * F[k] + h10 * L[:, None] * g0 + h01 * F[k + 1] + h11 * L[:, None] * g1
        Kt = K[k] + (t[:, :, None]) * (K[k + 1] - K[k])  # the tangent between records
        off = d - sc[:, None] * e[None, :]  # beyond the path's ends the tangent carries the rest along e too
        f = on_path + np.einsum("kij,kj->ki", Kt, off)
        return self.mu * (f @ self.transfer[i].T)

    def K(self, vertex: int) -> np.ndarray:
        """The small-strain stiffness (N/m) at `vertex`: the force's slope at rest."""
        i = self._row(vertex)
        return self.mu * self.transfer[i] @ self.stiffness_per_pa[int(self.path[i]), 0]


def law_key(law) -> str:
    """The law up to its scale (the table is per pascal of shear modulus)."""
    mu = law.shear_modulus
    return json.dumps([law.law, [round(m / mu, 9) for m in law.mu], [round(a, 9) for a in law.alpha], round(law.bulk_ratio, 9)])


def truth_key(scene) -> dict:
    """What the table depends on: the surface, the clamp, the law's shape and the grasp radius
    (not its scale, the shear modulus: the forces scale with it)."""
    axis, limit = clamp_limit(scene)
    key = {"version": TRUTH_VERSION, "digest": mesh_digest(scene.mesh), "clamp_axis": int(axis), "clamp_height": float(limit),
           "law": law_key(scene.spec.material.law), "grasp_radius": grasp_radius(scene)}
    # a brain with white matter or a pia-arachnoid is another body: its own table (one material adds nothing, as
    # before); the membrane's spread moves the table's band; body_version 2: the small-strain transfer sees the body too
    body = body_key(scene, scene_regions(scene))
    if (pac := scene.spec.material.pia_arachnoid) is not None:
        body = body + [["pia-arachnoid spread", pac.mu_spread]]
    return key | ({"body": json.dumps(body), "body_version": 2} if body else {})


def user_truth_path(scene) -> Path:
    """Where `studyctl calibrate truth` puts a table for a scene the shipped one does not cover."""
    key = json.dumps(truth_key(scene), sort_keys=True)
    return cache_dir() / f"truth-{hashlib.sha256(key.encode()).hexdigest()[:20]}.npz"


def _check_shipped(path: Path) -> None:
    """The shipped table is the one its record describes (a damaged install is refused by name)."""
    if path.resolve() != TRUTH_FILE.resolve() or not TRUTH_INFO.exists():
        return
    want = json.loads(TRUTH_INFO.read_text())["sha256"]
    have = hashlib.sha256(path.read_bytes()).hexdigest()
    if have != want:
        raise InputError(f"{path}: SHA-256 {have[:12]}... differs from {TRUTH_INFO.name}'s {want[:12]}...; the file is damaged "
                         "(reinstall, or rebuild it with `studyctl calibrate truth --out data/observer_truth.npz --force`)")


def _read(path: Path, key: dict):
    """The table at `path` if it was made for `key`, else None (with why)."""
    _check_shipped(path)
    try:
        z = np.load(path, allow_pickle=False)
    except (OSError, ValueError) as exc:
        raise InputError(f"{path}: cannot read the observer truth table: {exc}") from None
    for name, want in key.items():
        if name not in z.files:
            return None, f"{name}: missing there (an older table)"
        have = z[name].item() if z[name].shape == () else z[name]
        same = have == want if isinstance(want, str) else math.isclose(float(have), float(want), rel_tol=1e-9, abs_tol=1e-12)
        if not same:
            return None, f"{name}: {have} there, {want} here"
    if "body" in z.files and "body" not in key:  # a table of a brain with regions, asked for by one material
        return None, f"body: {z['body'].item()} there, one material here"
    return z, ""


def load_truth(scene, path: Path | str | None = None) -> Truth:
    """The truth for this scene: `path`, else the shipped table and the one `calibrate truth`
    made for this scene (their grasp places together). A table made for another surface,
    clamp, law or grasp radius is refused by name."""
    key = truth_key(scene)
    paths = [Path(path)] if path is not None else [p for p in (TRUTH_FILE, user_truth_path(scene)) if p.exists()]
    parts, why = [], []
    for p in paths:
        z, reason = _read(p, key)
        if z is None:
            why.append(f"{p}: made for another scene ({reason})")
            continue
        parts.append({k: z[k] for k in ("vertices", "path", "transfer", "s", "direction", "force_per_pa", "stiffness_per_pa", "path_band_rel",
                                        "path_band", "transfer_error", "path_vertex")}
                     # an older table records no decision: decided where it gives no band
                     | {"path_decided": z["path_decided"] if "path_decided" in z.files else z["path_band_rel"] == 0})
    if not parts:
        raise InputError(("; ".join(why) or "no observer truth table") + "; make one with `studyctl calibrate truth --scene FILE`")
    s = parts[0]["s"]
    if any(len(q["s"]) != len(s) or not np.allclose(q["s"], s) for q in parts):
        raise InputError("observer truth: the shipped and the calibrated tables record their paths at different displacements; "
                         "make the scene's table again with `studyctl calibrate truth`")
    offsets = np.cumsum([0] + [len(q["direction"]) for q in parts[:-1]])
    return Truth(vertices=np.concatenate([q["vertices"] for q in parts]),
                 path=np.concatenate([q["path"] + o for q, o in zip(parts, offsets)]),
                 transfer=np.concatenate([q["transfer"] for q in parts]), s=s,
                 direction=np.concatenate([q["direction"] for q in parts]),
                 force_per_pa=np.concatenate([q["force_per_pa"] for q in parts]),
                 stiffness_per_pa=np.concatenate([q["stiffness_per_pa"] for q in parts]),
                 mu=float(scene.spec.material.law.shear_modulus), digest=key["digest"], grasp_radius=key["grasp_radius"],
                 band_rel=np.concatenate([q["path_band_rel"] for q in parts]), path_band=np.concatenate([q["path_band"] for q in parts]),
                 transfer_error=np.concatenate([q["transfer_error"] for q in parts]),
                 path_vertex=np.concatenate([q["path_vertex"] for q in parts]),
                 path_decided=np.concatenate([q["path_decided"] for q in parts]))


def hand_sets(scene, radius: float = TRUTH_RADIUS) -> dict:
    """{hand index: the surface vertices within `radius` of its grasp (same hemisphere)}."""
    mesh = scene.mesh
    return {k: patch_vertices(mesh, mesh.nearest_vertex(hand.script(mesh).start), radius) for k, hand in enumerate(scene.spec.hands)}
