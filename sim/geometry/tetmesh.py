"""The brain's body-fitted tetrahedral meshes: one geometry for the FEM, the mass-spring and the
reference.

Each hemisphere's closed pial surface is meshed with fTetWild (`pytetwild`, MPL-2.0) at a
target edge length; the mesh boundary follows the surface within an envelope of
ENVELOPE_FRACTION x the edge length, so geometry and field refine together. fTetWild is not
deterministic (two runs give meshes a few % apart in node count), so the meshes at the
simulator's resolutions (SHIPPED_MM), and the coarse ones the test suite's small reference
solves use (TEST_MM), are made once and shipped in `data/` with their provenance and content
hash (`data/brain_tets.json`, `scripts/make_tet_meshes.py`). Any other
size, or another surface, is meshed on first use and cached on disk
(``$BRAINSIM_CACHE/reference``): fTetWild is slow (docs/fem.md).
"""

from __future__ import annotations

import hashlib
import importlib.util
import json
import sys
import time
import types
from dataclasses import dataclass

import numpy as np

from brainsim_assets import path as _asset
from sim.errors import MeshError
from sim.files import save_npz
from sim.geometry.volume import VolumeMesh, cache_dir, tet_volumes

MESHER_VERSION = 1  # part of the mesh cache key: bump when the meshing rule changes
ENVELOPE_FRACTION = 0.1  # fTetWild's envelope (max distance of the mesh boundary from the surface) = this x edge length
SHIPPED_MM = (8.0, 6.0, 4.0)  # target edge lengths shipped in data/ (the simulator's resolutions)
TEST_MM = (20.0, 16.0)  # also shipped: the tests' small reference solves (a fresh machine's `make test` runs no fTetWild)
PROVENANCE = _asset("data/brain_tets.json")


def shipped_file(size_mm: float):
    return _asset(f"data/brain_tets_{size_mm:g}mm.npz")


def _pytetwild():
    """pytetwild's `tetrahedralize`. Its package imports PyVista on import only to register a
    `.tetwild` accessor on PyVista meshes (0.4.2); where PyVista is not installed, that module is stubbed
    (the accessor is not used here, and PyVista's VTK is a 100 MB dependency)."""
    if importlib.util.find_spec("pyvista") is None:
        sys.modules.setdefault("pytetwild._accessor", types.ModuleType("pytetwild._accessor"))
    try:
        from pytetwild import tetrahedralize  # lazy: only to mesh a size not shipped; it loads PyVista where installed
    except ImportError as exc:  # pragma: no cover - a dependency in pyproject.toml
        raise MeshError(f"body-fitted meshing needs pytetwild (pip install 'pytetwild>=0.4'): {exc}") from None
    return tetrahedralize


def hemisphere_surface(mesh, label: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One labelled component of a surface: (vertices (k, 3), triangles (t, 3) local, global vertex ids)."""
    if mesh.labels is None:
        ids = np.arange(mesh.n_vertices)
        return mesh.vertices, np.asarray(mesh.triangles, dtype=np.int64), ids
    return labelled_part(mesh.vertices, mesh.triangles, mesh.labels, label)


def labelled_part(vertices: np.ndarray, triangles: np.ndarray, labels: np.ndarray, label: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The vertices labelled `label` and the triangles among them, renumbered: (vertices (k, 3),
    triangles (t, 3) local, global vertex ids)."""
    ids = np.flatnonzero(labels == label)
    local = -np.ones(len(vertices), dtype=np.int64)
    local[ids] = np.arange(len(ids))
    tri = triangles[np.all(labels[triangles] == label, axis=1)]
    return vertices[ids], local[tri], ids


def enclosed_volume(vertices: np.ndarray, triangles: np.ndarray) -> float:
    """Volume enclosed by a closed, outward-oriented triangle surface (divergence theorem)."""
    a, b, c = (vertices[triangles[:, k]] for k in range(3))
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


@dataclass(frozen=True, eq=False)
class BodyMesh:
    """One hemisphere's body-fitted mesh."""

    nodes: np.ndarray  # (n, 3) m
    tets: np.ndarray  # (m, 4), positively oriented
    edge_length: float  # fTetWild's target edge length, m
    envelope: float  # fTetWild's envelope, m
    seconds: float  # the meshing time (as recorded, when shipped or cached)
    source: str = "meshed"  # "shipped" (data/), "cache" or "meshed"

    @property
    def cached(self) -> bool:
        """Read back, not meshed now."""
        return self.source != "meshed"

    @property
    def volume(self) -> float:
        return float(tet_volumes(self.nodes, self.tets).sum())

    @property
    def key(self) -> str:
        """Identifies this mesh (its content hash): fTetWild's meshes differ run to run."""
        return content_hash(self.nodes, self.tets)[:20]

    @property
    def h(self) -> float:
        """Characteristic element size (V / n_tets)^(1/3), m: the refinement measure."""
        return (self.volume / len(self.tets)) ** (1.0 / 3.0)

    def describe(self) -> dict:
        v = tet_volumes(self.nodes, self.tets)
        return {"target_edge_mm": self.edge_length * 1e3, "envelope_mm": self.envelope * 1e3, "nodes": int(len(self.nodes)),
                "tets": int(len(self.tets)), "h_mm": self.h * 1e3, "volume_cm3": float(v.sum() * 1e6),
                "min_tet_volume_mm3": float(v.min() * 1e9), "mesh_s": self.seconds, "cached": self.cached, "source": self.source}


def content_hash(nodes: np.ndarray, tets: np.ndarray) -> str:
    """sha256 of the mesh itself (float64 nodes, int32 tets), not of its file's bytes."""
    h = hashlib.sha256()
    h.update(np.ascontiguousarray(nodes, dtype="<f8").tobytes())
    h.update(np.ascontiguousarray(tets, dtype="<i4").tobytes())
    return h.hexdigest()


def surface_digest(vertices: np.ndarray, triangles: np.ndarray) -> str:
    digest = hashlib.sha256()
    digest.update((np.ascontiguousarray(vertices, dtype=np.float64) * 1e3).tobytes())
    digest.update(np.ascontiguousarray(triangles, dtype=np.int32).tobytes())
    return digest.hexdigest()[:20]


def _cache_path(vertices, triangles, edge_length: float, envelope: float):
    key = hashlib.sha256((surface_digest(vertices, triangles) + repr((round(edge_length, 9), round(envelope, 9), MESHER_VERSION))).encode())
    return cache_dir() / "reference" / f"tetwild-{key.hexdigest()[:20]}.npz"


def _shipped(vertices, triangles, edge_length: float, envelope: float) -> BodyMesh | None:
    """The shipped mesh of this hemisphere surface and size, if there is one; checked against its hash."""
    if not PROVENANCE.exists() or abs(envelope - ENVELOPE_FRACTION * edge_length) > 1e-12:
        return None
    prov = json.loads(PROVENANCE.read_text())
    entry = next((m for m in prov["meshes"] if abs(m["target_edge_mm"] - edge_length * 1e3) < 1e-9
                  and m["surface_digest"] == surface_digest(vertices, triangles)), None)
    if entry is None:
        return None
    path = _asset(f"data/{entry['file']}")
    with np.load(path) as z:
        nodes, tets = z[f"nodes_{entry['hemisphere']}"], z[f"tets_{entry['hemisphere']}"].astype(np.int64)
    if content_hash(nodes, tets) != entry["sha256"]:
        raise MeshError(f"{path}: hemisphere {entry['hemisphere']}: content hash differs from data/brain_tets.json; the file is damaged")
    return BodyMesh(nodes, tets, edge_length, envelope, float(entry["mesh_s"]), source="shipped")


def _tetwild(vertices: np.ndarray, triangles: np.ndarray, edge_length: float, envelope: float, threads: int) -> tuple:
    """fTetWild in millimetres; (nodes m, positively oriented tets, seconds)."""
    v_mm = np.ascontiguousarray(vertices, dtype=np.float64) * 1e3
    diag = float(np.linalg.norm(v_mm.max(axis=0) - v_mm.min(axis=0)))
    start = time.perf_counter()
    nodes, tets = _pytetwild()(v_mm, np.ascontiguousarray(triangles, dtype=np.int32), edge_length_abs=edge_length * 1e3,
                               epsilon=envelope * 1e3 / diag, num_threads=threads)
    seconds = time.perf_counter() - start
    nodes, tets = np.asarray(nodes, dtype=np.float64) * 1e-3, np.asarray(tets, dtype=np.int64)
    if len(tets) == 0:
        raise MeshError("fTetWild returned no tetrahedra")
    flip = tet_volumes(nodes, tets) < 0  # fTetWild's orientation is the opposite of ours
    tets[flip] = tets[flip][:, [0, 2, 1, 3]]
    used = np.unique(tets)
    if len(used) < len(nodes):  # drop unreferenced nodes (none expected)
        remap = -np.ones(len(nodes), dtype=np.int64)
        remap[used] = np.arange(len(used))
        nodes, tets = nodes[used], remap[tets]
    if np.any(np.abs(tet_volumes(nodes, tets)) <= 0):
        raise MeshError("fTetWild returned a degenerate tetrahedron")
    return nodes, tets, seconds


def mesh_hemisphere(vertices: np.ndarray, triangles: np.ndarray, edge_length: float, envelope: float | None = None,
                    threads: int = 1, use_cache: bool = True) -> BodyMesh:
    """Body-fitted tetrahedral mesh of a closed surface (metres): the shipped one, else the
    cached one, else fTetWild's (then cached).

    `edge_length`: target edge length (m); `envelope`: the largest distance of the mesh's
    boundary from the surface (m, default ENVELOPE_FRACTION x edge_length); `threads`: fTetWild's
    (0 = every core; more than one gains nothing on this surface: docs/reference.md). fTetWild refines near the surface
    as far as the envelope needs (the pial surface is folded), so the node count is not
    V / edge^3.
    """
    if not (0.5e-3 <= edge_length <= 0.05):
        raise MeshError(f"edge_length: {edge_length * 1e3:g} mm is out of range; allowed: 0.5..50 mm")
    envelope = ENVELOPE_FRACTION * edge_length if envelope is None else float(envelope)
    if use_cache and (shipped := _shipped(vertices, triangles, edge_length, envelope)) is not None:
        return shipped
    path = _cache_path(vertices, triangles, edge_length, envelope)
    if use_cache and path.exists():
        with np.load(path) as z:
            return BodyMesh(z["nodes"], z["tets"], edge_length, envelope, float(z["seconds"]), source="cache")
    nodes, tets, seconds = _tetwild(vertices, triangles, edge_length, envelope, threads)
    if use_cache:
        save_npz(path, compressed=True, nodes=nodes, tets=tets, seconds=seconds)
    return BodyMesh(nodes, tets, edge_length, envelope, seconds)


def needs_meshing(vertices: np.ndarray, triangles: np.ndarray, edge_length: float) -> bool:
    """Neither shipped nor cached: `mesh_hemisphere` would run fTetWild."""
    env = ENVELOPE_FRACTION * edge_length
    return _shipped(vertices, triangles, edge_length, env) is None and not _cache_path(vertices, triangles, edge_length, env).exists()


def body_volume(surface, resolution: float) -> VolumeMesh:
    """Both hemispheres' body-fitted meshes at target edge `resolution` (m) as one volume,
    nodes grouped by hemisphere (`component`)."""
    labels = np.unique(surface.labels) if surface.labels is not None else np.array([0])
    nodes, tets, comp, offset = [], [], [], 0
    for label in labels:
        v, t, _ = hemisphere_surface(surface, int(label))
        bm = mesh_hemisphere(v, t, resolution)
        nodes.append(bm.nodes)
        tets.append(bm.tets + offset)
        comp.append(np.full(len(bm.nodes), label))
        offset += len(bm.nodes)
    return VolumeMesh(nodes=np.concatenate(nodes), tets=np.concatenate(tets), resolution=resolution, component=np.concatenate(comp))
