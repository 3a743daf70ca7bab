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

import numpy as np
import open3d as o3d
from make_brain_asset import closed, read_hemisphere
from nilearn.datasets import data as nilearn_data

from sim.geometry.tetmesh import enclosed_volume, labelled_part

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "data" / "brain_white_fsaverage5.npz"
INFO = ROOT / "data" / "brain_white_fsaverage5.json"
PIAL = ROOT / "data" / "brain_fsaverage5.npz"
SOURCE = Path(nilearn_data.__file__).parent / "fsaverage5"


def _raycaster(v: np.ndarray, f: np.ndarray):
    """open3d's ray-casting scene of a closed surface: occupancy and distance of points."""
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(v.astype(np.float32)), o3d.core.Tensor(f.astype(np.uint32)))
    return scene


def main() -> int:
    with np.load(PIAL) as z:
        pial_v, pial_f, pial_lab = z["vertices"], z["triangles"].astype(np.int64), z["hemisphere"]
    vertices, triangles, labels, record = [], [], [], {}
    offset = 0
    for label, hemi in enumerate(("left", "right")):
        path = SOURCE / f"white_{hemi}.gii.gz"
        v, f, fix, checks = read_hemisphere(path)  # as the pial asset: mm -> m, the same relaxation
        pv, pf, _ = labelled_part(pial_v, pial_f, pial_lab, label)
        pial = _raycaster(pv, pf)
        outside = ~pial.compute_occupancy(o3d.core.Tensor(v.astype(np.float32)), nsamples=3).numpy().astype(bool)
        depth = pial.compute_distance(o3d.core.Tensor(v[outside].astype(np.float32))).numpy()
        vol_w, vol_p = enclosed_volume(v, f), enclosed_volume(pv, pf)
        digest = hashlib.sha256(path.read_bytes()).hexdigest()[:16]
        record[hemi] = {"vertices": len(v), "triangles": len(f), "source_sha256_prefix": digest, "fix": fix, **checks,
                        "white_vertices_outside_pial": int(outside.sum()), "share_outside_pial": float(outside.mean()),
                        "outside_max_mm": float(depth.max() * 1e3) if len(depth) else 0.0,
                        "white_volume_cm3": vol_w * 1e6, "pial_volume_cm3": vol_p * 1e6, "white_over_pial": vol_w / vol_p}
        print(f"{hemi}: {record[hemi]}")
        if not closed(checks):
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
