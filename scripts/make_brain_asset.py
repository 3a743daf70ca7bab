"""Regenerate data/brain_fsaverage5.npz from FreeSurfer's fsaverage5 pial surfaces.

Dev-time only: needs nilearn (which ships the surfaces) and nibabel; run with
`.venv/bin/python scripts/make_brain_asset.py`. The run-time code reads the .npz with NumPy.

Steps: read both pial hemispheres (millimetres, RAS), convert to metres, remove the few
self-intersections FreeSurfer's right pial surface has (a local Laplacian relaxation of the
offending triangles' vertices, reported), check each hemisphere is watertight and manifold with
open3d, and write vertices, triangles and a per-vertex hemisphere label.
"""

from __future__ import annotations

import hashlib
import sys
from pathlib import Path

import nibabel as nib
import numpy as np
import open3d as o3d
from nilearn.datasets import data as nilearn_data

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "data" / "brain_fsaverage5.npz"
SOURCE = Path(nilearn_data.__file__).parent / "fsaverage5"


def _o3d_mesh(v: np.ndarray, f: np.ndarray) -> o3d.geometry.TriangleMesh:
    return o3d.geometry.TriangleMesh(
        o3d.utility.Vector3dVector(v), o3d.utility.Vector3iVector(f.astype(np.int32))
    )


def _neighbours(f: np.ndarray, n: int) -> list[set[int]]:
    nb: list[set[int]] = [set() for _ in range(n)]
    for a, b, c in f:
        nb[a] |= {b, c}
        nb[b] |= {a, c}
        nb[c] |= {a, b}
    return nb


def remove_self_intersections(v: np.ndarray, f: np.ndarray, max_rounds: int = 50) -> tuple[np.ndarray, dict]:
    """Relax the vertices of self-intersecting triangles toward their neighbours' mean."""
    v = v.copy()
    nb = _neighbours(f, len(v))
    moved: set[int] = set()
    rounds = 0
    original = v.copy()
    for rounds in range(1, max_rounds + 1):
        pairs = np.asarray(_o3d_mesh(v, f).get_self_intersecting_triangles())
        if len(pairs) == 0:
            rounds -= 1
            break
        verts = np.unique(f[pairs.ravel()])
        for i in verts:
            v[i] = 0.5 * v[i] + 0.5 * v[list(nb[i])].mean(axis=0)
        moved |= set(int(i) for i in verts)
    else:
        raise RuntimeError("self-intersections remain after relaxation")
    shift = np.linalg.norm(v - original, axis=1)
    return v, {"rounds": rounds, "vertices_moved": len(moved), "max_shift_m": float(shift.max())}


def read_hemisphere(path: Path) -> tuple[np.ndarray, np.ndarray, dict, dict]:
    """A FreeSurfer surface file's vertices (mm -> m, RAS) and triangles, its self-intersections
    relaxed (what was moved) and open3d's checks of the result."""
    gii = nib.load(path)
    v = gii.darrays[0].data.astype(np.float64) / 1000.0  # mm -> m
    f = gii.darrays[1].data.astype(np.int64)
    v, fix = remove_self_intersections(v, f)
    mesh = _o3d_mesh(v, f)
    checks = {
        "watertight": mesh.is_watertight(),
        "edge_manifold": mesh.is_edge_manifold(),
        "vertex_manifold": mesh.is_vertex_manifold(),
        "self_intersecting": mesh.is_self_intersecting(),
    }
    return v, f, fix, checks


def closed(checks: dict) -> bool:
    """A surface that bounds a volume: watertight and manifold."""
    return bool(checks["watertight"] and checks["edge_manifold"] and checks["vertex_manifold"])


def main() -> int:
    vertices, triangles, labels = [], [], []
    offset = 0
    for label, hemi in enumerate(("left", "right")):
        path = SOURCE / f"pial_{hemi}.gii.gz"
        v, f, fix, checks = read_hemisphere(path)
        digest = hashlib.sha256(path.read_bytes()).hexdigest()[:16]
        print(f"{hemi}: {len(v)} vertices, {len(f)} triangles, sha256 {digest}, fix {fix}, {checks}")
        if not closed(checks):
            print(f"error: {hemi} hemisphere is not watertight and manifold", file=sys.stderr)
            return 1
        vertices.append(v)
        triangles.append(f + offset)
        labels.append(np.full(len(v), label, dtype=np.uint8))
        offset += len(v)
    np.savez_compressed(
        OUT,
        vertices=np.concatenate(vertices),
        triangles=np.concatenate(triangles).astype(np.int32),
        hemisphere=np.concatenate(labels),
        units=np.array("m"),
        source=np.array("FreeSurfer fsaverage5 pial surfaces (lh, rh) as shipped in nilearn"),
    )
    print(f"wrote {OUT.relative_to(ROOT)} ({OUT.stat().st_size} bytes)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
