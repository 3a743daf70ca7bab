"""Write data/brain_white_fsaverage5.npz (and its .json record) from FreeSurfer's fsaverage5
white surfaces: the grey/white interface, inside which the brain's white matter lies
(sim/geometry/regions.py).

Dev-time only, like scripts/make_brain_asset.py (nilearn ships the surfaces, nibabel reads
them, open3d checks them): `.venv/bin/python scripts/make_white_asset.py`. The same transform
as the pial surfaces (millimetres to metres, FreeSurfer's RAS axes, nothing moved: the scene
uses the pial asset's coordinates as they are). Checks each hemisphere is watertight and
manifold, reports how many white vertices lie outside the shipped pial hemisphere (open3d's
occupancy) and the volumes each encloses.
"""

from __future__ import annotations

import hashlib
import json
import sys
from pathlib import Path

import nibabel as nib
import numpy as np
import open3d as o3d
from make_brain_asset import remove_self_intersections
from nilearn.datasets import data as nilearn_data

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "data" / "brain_white_fsaverage5.npz"
INFO = ROOT / "data" / "brain_white_fsaverage5.json"
PIAL = ROOT / "data" / "brain_fsaverage5.npz"
SOURCE = Path(nilearn_data.__file__).parent / "fsaverage5"


def _volume(v: np.ndarray, f: np.ndarray) -> float:
    """Enclosed volume by the divergence theorem (m^3)."""
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


def _occupancy(v: np.ndarray, f: np.ndarray, points: np.ndarray) -> np.ndarray:
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(v.astype(np.float32)), o3d.core.Tensor(f.astype(np.uint32)))
    return scene.compute_occupancy(o3d.core.Tensor(points.astype(np.float32)), nsamples=3).numpy().astype(bool)


def _depth(v: np.ndarray, f: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Each point's distance to the surface (m)."""
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(v.astype(np.float32)), o3d.core.Tensor(f.astype(np.uint32)))
    return scene.compute_distance(o3d.core.Tensor(points.astype(np.float32))).numpy()


def main() -> int:
    with np.load(PIAL) as z:
        pial_v, pial_f, pial_lab = z["vertices"], z["triangles"].astype(np.int64), z["hemisphere"]
    vertices, triangles, labels, record = [], [], [], {}
    offset = 0
    for label, hemi in enumerate(("left", "right")):
        path = SOURCE / f"white_{hemi}.gii.gz"
        gii = nib.load(path)
        v = gii.darrays[0].data.astype(np.float64) / 1000.0  # mm -> m, as the pial asset
        f = gii.darrays[1].data.astype(np.int64)
        v, fix = remove_self_intersections(v, f)  # the pial asset's relaxation, for the same reason
        mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(v), o3d.utility.Vector3iVector(f.astype(np.int32)))
        checks = {"watertight": mesh.is_watertight(), "edge_manifold": mesh.is_edge_manifold(),
                  "vertex_manifold": mesh.is_vertex_manifold(), "self_intersecting": mesh.is_self_intersecting()}
        keep = np.flatnonzero(pial_lab == label)
        index = np.full(len(pial_v), -1)
        index[keep] = np.arange(len(keep))
        pv, pf = pial_v[keep], index[pial_f[np.all(pial_lab[pial_f] == label, axis=1)]]
        outside = ~_occupancy(pv, pf, v)
        depth = _depth(pv, pf, v[outside])
        vol_w, vol_p = _volume(v, f), _volume(pv, pf)
        digest = hashlib.sha256(path.read_bytes()).hexdigest()[:16]
        record[hemi] = {"vertices": len(v), "triangles": len(f), "source_sha256_prefix": digest, "fix": fix, **checks,
                        "white_vertices_outside_pial": int(outside.sum()), "share_outside_pial": float(outside.mean()),
                        "outside_max_mm": float(depth.max() * 1e3) if len(depth) else 0.0,
                        "white_volume_cm3": vol_w * 1e6, "pial_volume_cm3": vol_p * 1e6, "white_over_pial": vol_w / vol_p}
        print(f"{hemi}: {record[hemi]}")
        if not (checks["watertight"] and checks["edge_manifold"] and checks["vertex_manifold"]):
            print(f"error: {hemi} white surface is not watertight and manifold", file=sys.stderr)
            return 1
        vertices.append(v)
        triangles.append(f + offset)
        labels.append(np.full(len(v), label, dtype=np.uint8))
        offset += len(v)
    np.savez_compressed(OUT, vertices=np.concatenate(vertices), triangles=np.concatenate(triangles).astype(np.int32),
                        hemisphere=np.concatenate(labels), units=np.array("m"),
                        source=np.array("FreeSurfer fsaverage5 white surfaces (lh, rh) as shipped in nilearn"))
    info = {"file": OUT.name, "sha256": hashlib.sha256(OUT.read_bytes()).hexdigest(),
            "source": "FreeSurfer fsaverage5 white_left.gii.gz, white_right.gii.gz (nilearn/datasets/data/fsaverage5/)",
            "transform": "millimetres to metres, RAS axes, as data/brain_fsaverage5.npz", "hemispheres": record}
    INFO.write_text(json.dumps(info, indent=1) + "\n")
    print(f"wrote {OUT.relative_to(ROOT)} ({OUT.stat().st_size} bytes) and {INFO.relative_to(ROOT)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
