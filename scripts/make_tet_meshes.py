"""Make the shipped body-fitted meshes: data/brain_tets_<size>mm.npz and data/brain_tets.json.

fTetWild (pytetwild) meshes each hemisphere of data/brain_fsaverage5.npz at each of
sim.geometry.tetmesh.SHIPPED_MM and TEST_MM; fTetWild is not deterministic, so the meshes are made once
and shipped with their content hashes (the simulator refuses a file whose hash differs).

    .venv/bin/python scripts/make_tet_meshes.py [--fresh] [--jobs 2]

Without --fresh, meshes already shipped, then those in the cache ($BRAINSIM_CACHE/reference),
are kept: adding a size leaves the shipped ones (and every solve made on them) as they are.
"""

from __future__ import annotations

import argparse
import datetime
import hashlib
import json
from concurrent.futures import ProcessPoolExecutor
from importlib.metadata import version

import numpy as np

from sim.files import save_npz
from sim.geometry.mesh import BRAIN_MESH as MESH_FILE
from sim.geometry.tetmesh import (
    ENVELOPE_FRACTION,
    PROVENANCE,
    SHIPPED_MM,
    TEST_MM,
    _cache_path,
    _shipped,
    _tetwild,
    content_hash,
    enclosed_volume,
    hemisphere_surface,
    shipped_file,
    surface_digest,
)
from sim.geometry.volume import tet_volumes
from sim.pulls import scene_with
from sim.scene import DEFAULT_SCENE


def _mesh(args) -> tuple:
    label, size, fresh = args
    v, t, _ = hemisphere_surface(scene_with(DEFAULT_SCENE).mesh, label)
    edge, env = size * 1e-3, ENVELOPE_FRACTION * size * 1e-3
    if not fresh and (kept := _shipped(v, t, edge, env)) is not None:
        return label, size, kept.nodes, kept.tets, kept.seconds
    path = _cache_path(v, t, edge, env)
    if path.exists() and not fresh:
        with np.load(path) as z:
            return label, size, z["nodes"], z["tets"], float(z["seconds"])
    nodes, tets, seconds = _tetwild(v, t, edge, env, threads=1)
    save_npz(path, compressed=True, nodes=nodes, tets=tets, seconds=seconds)
    return label, size, nodes, tets, seconds


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--fresh", action="store_true", help="mesh again even where the cache holds a mesh")
    ap.add_argument("--jobs", type=int, default=2, help="meshes made at once (fTetWild uses about one core)")
    a = ap.parse_args()
    surface = scene_with(DEFAULT_SCENE).mesh
    labels = [int(x) for x in np.unique(surface.labels)]
    tasks = [(label, size, a.fresh) for size in sorted(SHIPPED_MM + TEST_MM) for label in labels]
    with ProcessPoolExecutor(max_workers=a.jobs) as pool:
        results = list(pool.map(_mesh, tasks))
    entries, arrays = [], {s: {} for s in SHIPPED_MM + TEST_MM}
    for label, size, nodes, tets, seconds in results:
        v, t, _ = hemisphere_surface(surface, label)
        vol = float(tet_volumes(nodes, tets).sum())
        arrays[size] |= {f"nodes_{label}": nodes, f"tets_{label}": tets.astype(np.int32)}
        entries.append({"file": shipped_file(size).name, "hemisphere": label, "target_edge_mm": size,
                        "envelope_mm": ENVELOPE_FRACTION * size, "nodes": int(len(nodes)), "tets": int(len(tets)),
                        "volume_cm3": vol * 1e6, "volume_error": vol / enclosed_volume(v, t) - 1.0, "mesh_s": seconds,
                        "surface_digest": surface_digest(v, t), "sha256": content_hash(nodes, tets)})
    for size, arr in arrays.items():
        if shipped_file(size).exists():
            with np.load(shipped_file(size)) as z:
                if set(z.files) == set(arr) and all(np.array_equal(z[k], arr[k]) for k in arr):
                    continue  # kept: the file as shipped
        save_npz(shipped_file(size), compressed=True, **arr)
    made = json.loads(PROVENANCE.read_text()).get("made") if PROVENANCE.exists() and not a.fresh else None
    today = datetime.date.today().isoformat()
    for e in entries:  # a size added later says when
        if made and e["target_edge_mm"] not in SHIPPED_MM:
            e["made"] = today
    prov = {"source_surface": MESH_FILE.name, "source_surface_sha256": hashlib.sha256(MESH_FILE.read_bytes()).hexdigest(),
            "mesher": f"fTetWild via pytetwild {version('pytetwild')}", "envelope_fraction": ENVELOPE_FRACTION,
            "parameters": "tetrahedralize(vertices_mm, triangles, edge_length_abs=size_mm, epsilon=envelope_mm / bbox_diagonal_mm, num_threads=1)",
            "made": made or today, "script": "scripts/make_tet_meshes.py",
            "meshes": sorted(entries, key=lambda e: (-e["target_edge_mm"], e["hemisphere"]))}
    PROVENANCE.write_text(json.dumps(prov, indent=2) + "\n")
    for e in prov["meshes"]:
        print(f"{e['file']} hemisphere {e['hemisphere']}: {e['nodes']} nodes, {e['tets']} tets, volume error {e['volume_error']:+.2%}")


if __name__ == "__main__":
    main()
