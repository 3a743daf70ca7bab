"""Tetrahedral volume meshes of a closed surface, and the surface embedded in them.

Voxel-tetrahedral meshing: the surface's bounding box is covered by a grid of spacing h; a
cell is kept when its centre is inside the surface (open3d's ``RaycastingScene`` occupancy
query), which keeps the volume right (1.00 L for the brain at 4 mm; keeping every cell that
touches the surface would add 40% at 4 mm, the cortex being folded); every kept cell becomes six tetrahedra around its main diagonal (the Kuhn
split, which is conforming between neighbouring cells). Each labelled component of the
surface (the two hemispheres) is meshed on its own, so the volumes never merge across the
midline where the pial surfaces touch.

The occupancy query imports open3d, which loads its rendering module with it; so that a
headless scene never does that, the query runs in a child process and its result is cached
on disk (``$BRAINSIM_CACHE`` or ``~/.cache/brainsim``), keyed by the surface's content and h.
"""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sim.errors import MeshError

# Kuhn split of the unit cube (corner k has bits x=k&1, y=k>>1&1, z=k>>2&1): six tetrahedra
# sharing the diagonal 0-7, each positively oriented.
_CORNERS = np.array([[(k >> 0) & 1, (k >> 1) & 1, (k >> 2) & 1] for k in range(8)])
MESHER_VERSION = 3  # part of the cache key: bump when the occupancy rule changes
_KUHN = np.array([[0, 1, 3, 7], [0, 3, 2, 7], [0, 2, 6, 7], [0, 6, 4, 7], [0, 4, 5, 7], [0, 5, 1, 7]])


@dataclass(frozen=True, eq=False)
class VolumeMesh:
    nodes: np.ndarray  # (n, 3) m
    tets: np.ndarray  # (m, 4) int, positively oriented
    resolution: float  # grid spacing, m
    component: np.ndarray  # (n,) label of the surface component each node belongs to

    @property
    def n_nodes(self) -> int:
        return len(self.nodes)


def cache_dir() -> Path:
    root = os.environ.get("BRAINSIM_CACHE") or Path.home() / ".cache" / "brainsim"
    return Path(root)


def grid_tets(inside: np.ndarray, origin: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray]:
    """Nodes and Kuhn tetrahedra of the kept cells of a grid. `inside`: (nx, ny, nz) bool."""
    cells = np.argwhere(inside)  # (c, 3) cell indices
    if len(cells) == 0:
        return np.zeros((0, 3)), np.zeros((0, 4), dtype=np.int64)
    corners = cells[:, None, :] + _CORNERS[None, :, :]  # (c, 8, 3) grid-node indices
    dims = np.array(inside.shape) + 1
    flat = np.ravel_multi_index(corners.reshape(-1, 3).T, dims).reshape(-1, 8)
    used, inverse = np.unique(flat, return_inverse=True)
    local = inverse.reshape(-1, 8)
    ijk = np.stack(np.unravel_index(used, dims), axis=1)
    nodes = origin + ijk * h
    tets = local[:, _KUHN].reshape(-1, 4)
    return nodes, tets


def tet_volumes(nodes: np.ndarray, tets: np.ndarray) -> np.ndarray:
    a, b, c, d = (nodes[tets[:, k]] for k in range(4))
    return np.einsum("ij,ij->i", np.cross(b - a, c - a), d - a) / 6.0


def _occupancy_child(surface_npz: str, h: float, out_npz: str) -> None:
    """Runs in a child process: occupancy of cell centres per component, with open3d."""
    import open3d as o3d

    data = np.load(surface_npz)
    vertices, triangles = data["vertices"], data["triangles"]
    labels = data["labels"] if "labels" in data else np.zeros(len(vertices), dtype=np.int64)
    result = {}
    for label in np.unique(labels):
        vsel = np.flatnonzero(labels == label)
        remap = -np.ones(len(vertices), dtype=np.int64)
        remap[vsel] = np.arange(len(vsel))
        tri = remap[triangles[np.all(np.isin(triangles, vsel), axis=1)]]
        v = vertices[vsel]
        lo, hi = v.min(axis=0) - h, v.max(axis=0) + h
        shape = np.ceil((hi - lo) / h).astype(int)
        scene = o3d.t.geometry.RaycastingScene()
        scene.add_triangles(o3d.core.Tensor(v.astype(np.float32)), o3d.core.Tensor(tri.astype(np.uint32)))
        idx = np.stack(np.meshgrid(*[np.arange(s) for s in shape], indexing="ij"), axis=-1).reshape(-1, 3)
        centres = scene.compute_occupancy(o3d.core.Tensor((lo + (idx + 0.5) * h).astype(np.float32)), nsamples=3).numpy()
        inside = centres.reshape(shape).astype(bool)
        result[f"inside_{label}"] = inside
        result[f"origin_{label}"] = lo
    np.savez_compressed(out_npz, **result)


def voxel_volume(surface, resolution: float, use_cache: bool = True) -> VolumeMesh:
    """Tetrahedral mesh of `surface` (a `sim.mesh.SurfaceMesh`) at grid spacing `resolution` (m)."""
    if not (0.5e-3 <= resolution <= 0.05):
        raise MeshError(f"resolution: {resolution * 1e3:g} mm is out of range; allowed: 0.5..50 mm")
    labels = surface.labels if surface.labels is not None else np.zeros(surface.n_vertices, dtype=np.int64)
    digest = hashlib.sha256()
    for a in (surface.vertices, surface.triangles, labels):
        digest.update(np.ascontiguousarray(a).tobytes())
    digest.update(repr((round(resolution, 9), MESHER_VERSION)).encode())
    key = digest.hexdigest()[:20]
    cache = cache_dir() / f"occupancy-{key}.npz"
    if not (use_cache and cache.exists()):
        cache.parent.mkdir(parents=True, exist_ok=True)
        src = cache.with_suffix(".surface.npz")
        np.savez(src, vertices=surface.vertices, triangles=surface.triangles, labels=labels)
        tmp = cache.with_suffix(f".{os.getpid()}.tmp.npz")
        code = "import sys; from sim.volume import _occupancy_child as f; f(sys.argv[1], float(sys.argv[2]), sys.argv[3])"
        proc = subprocess.run([sys.executable, "-c", code, str(src), repr(resolution), str(tmp)], capture_output=True, text=True)
        src.unlink(missing_ok=True)
        if proc.returncode != 0:
            tail = proc.stderr.strip().splitlines()[-1:] or ["no output"]
            raise MeshError(f"volume meshing failed: {tail[0]}")
        os.replace(tmp, cache)  # atomic: a concurrent reader sees all or nothing
    data = np.load(cache)
    all_nodes, all_tets, comp = [], [], []
    offset = 0
    for label in np.unique(labels):
        nodes, tets = grid_tets(data[f"inside_{label}"], data[f"origin_{label}"], resolution)
        all_nodes.append(nodes)
        all_tets.append(tets + offset)
        comp.append(np.full(len(nodes), label))
        offset += len(nodes)
    nodes = np.concatenate(all_nodes)
    tets = np.concatenate(all_tets)
    if len(tets) == 0:
        raise MeshError(f"resolution: {resolution * 1e3:g} mm leaves no cell inside the surface; use a finer grid")
    return VolumeMesh(nodes=nodes, tets=tets, resolution=resolution, component=np.concatenate(comp))


@dataclass(frozen=True, eq=False)
class Embedding:
    """Each surface vertex as barycentric coordinates in one tetrahedron.

    About half of the brain's surface vertices lie outside the voxel volume (within half a
    cell of it); they take the barycentric coordinates of the nearest tetrahedron, slightly
    outside [0, 1], i.e. the element's linear field extended to them.
    """

    tet: np.ndarray  # (s,) containing (or nearest) tetrahedron
    weights: np.ndarray  # (s, 4), sum to 1; slightly outside [0, 1] for vertices outside the volume
    matrix: object  # scipy.sparse CSR (s, n_nodes): surface = matrix @ nodal values

    def outside(self) -> np.ndarray:
        return self.weights.min(axis=1) < -1e-9


def barycentric(nodes: np.ndarray, tets: np.ndarray, points: np.ndarray) -> np.ndarray:
    a = nodes[tets[:, 0]]
    T = np.stack([nodes[tets[:, k]] - a for k in (1, 2, 3)], axis=2)  # (s, 3, 3)
    lam = np.linalg.solve(T, (points - a)[..., None])[..., 0]
    return np.column_stack((1.0 - lam.sum(axis=1), lam))


def embed(volume: VolumeMesh, points: np.ndarray, labels: np.ndarray | None = None, k: int = 12) -> Embedding:
    """Barycentric embedding of `points` in the volume (restricted to the point's component)."""
    from scipy.sparse import csr_matrix
    from scipy.spatial import cKDTree

    centroids = volume.nodes[volume.tets].mean(axis=1)
    tet_comp = volume.component[volume.tets[:, 0]]
    labels = np.zeros(len(points), dtype=np.int64) if labels is None else labels
    best_tet = np.empty(len(points), dtype=np.int64)
    best_w = np.empty((len(points), 4))
    for label in np.unique(labels):
        psel = np.flatnonzero(labels == label)
        tsel = np.flatnonzero(tet_comp == label)
        tree = cKDTree(centroids[tsel])
        kk = min(k, len(tsel))
        _, cand = tree.query(points[psel], k=kk)
        cand = tsel[cand.reshape(len(psel), kk)]
        w = barycentric(volume.nodes, volume.tets[cand.ravel()], np.repeat(points[psel], kk, axis=0)).reshape(len(psel), kk, 4)
        score = w.min(axis=2)  # >= 0 inside; the least negative is the nearest outside
        pick = score.argmax(axis=1)
        best_tet[psel] = cand[np.arange(len(psel)), pick]
        best_w[psel] = w[np.arange(len(psel)), pick]
    rows = np.repeat(np.arange(len(points)), 4)
    matrix = csr_matrix((best_w.ravel(), (rows, volume.tets[best_tet].ravel())), shape=(len(points), volume.n_nodes))
    return Embedding(tet=best_tet, weights=best_w, matrix=matrix)


def describe(volume: VolumeMesh) -> dict:
    return {"nodes": int(volume.n_nodes), "tets": int(len(volume.tets)), "resolution_mm": volume.resolution * 1e3}


if __name__ == "__main__":  # pragma: no cover - debugging aid
    from sim.mesh import load_mesh

    vm = voxel_volume(load_mesh(), float(sys.argv[1]) if len(sys.argv) > 1 else 0.004)
    print(json.dumps(describe(vm)))
