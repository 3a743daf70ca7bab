"""Tetrahedral volume meshes and points embedded in them.

`VolumeMesh` holds a mesh of one or more components (the brain's two hemispheres, meshed on
their own so the volumes never merge across the midline; the body-fitted meshes of
`sim.geometry.tetmesh`). `embed` finds each surface vertex's containing (or nearest) tetrahedron and
its barycentric coordinates; `locate` does it for any points. (Structured box meshes for the
tests: `tests/helpers.grid_tets`.)
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.sparse import csr_matrix
from scipy.spatial import cKDTree

# Kuhn split of the unit cube (corner k has bits x=k&1, y=k>>1&1, z=k>>2&1): six tetrahedra
# sharing the diagonal 0-7, each positively oriented.


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


def tet_volumes(nodes: np.ndarray, tets: np.ndarray) -> np.ndarray:
    a, b, c, d = (nodes[tets[:, k]] for k in range(4))
    return np.einsum("ij,ij->i", np.cross(b - a, c - a), d - a) / 6.0


@dataclass(frozen=True, eq=False)
class Embedding:
    """Each surface vertex as barycentric coordinates in one tetrahedron.

    A vertex outside the volume (the body-fitted mesh's boundary lies within its envelope of
    the surface) takes the barycentric coordinates of the nearest tetrahedron, slightly
    outside [0, 1]: the element's field extended to it.
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


def centroid_tree(nodes: np.ndarray, tets: np.ndarray) -> cKDTree:
    """The k-d tree of the tetrahedra's centroids that `locate` searches: built once per mesh by
    a model that locates points again and again (a grasp), else built by each call."""
    return cKDTree(nodes[tets].mean(axis=1))


def locate(nodes: np.ndarray, tets: np.ndarray, points: np.ndarray, k: int = 32, tree: cKDTree | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Containing (or nearest) tetrahedron of each point and its barycentric coordinates: among
    the k tetrahedra with the nearest centroids, the one whose smallest barycentric coordinate
    is largest (>= 0: inside; the least negative is the nearest outside). `tree`: the mesh's
    `centroid_tree`, when the caller keeps one."""
    points = np.atleast_2d(np.asarray(points, dtype=np.float64))
    kk = min(k, len(tets))
    _, cand = (tree if tree is not None else centroid_tree(nodes, tets)).query(points, k=kk)
    cand = np.asarray(cand).reshape(len(points), kk)
    w = barycentric(nodes, tets[cand.ravel()], np.repeat(points, kk, axis=0)).reshape(len(points), kk, 4)
    pick = w.min(axis=2).argmax(axis=1)
    rows = np.arange(len(points))
    return cand[rows, pick], w[rows, pick]


def embed(volume: VolumeMesh, points: np.ndarray, labels: np.ndarray | None = None, k: int = 12) -> Embedding:
    """Barycentric embedding of `points` in the volume (each restricted to its component)."""
    tet_comp = volume.component[volume.tets[:, 0]]
    labels = np.zeros(len(points), dtype=np.int64) if labels is None else labels
    best_tet = np.empty(len(points), dtype=np.int64)
    best_w = np.empty((len(points), 4))
    for label in np.unique(labels):
        psel = np.flatnonzero(labels == label)
        tsel = np.flatnonzero(tet_comp == label)
        tet, best_w[psel] = locate(volume.nodes, volume.tets[tsel], points[psel], k)
        best_tet[psel] = tsel[tet]
    rows = np.repeat(np.arange(len(points)), 4)
    matrix = csr_matrix((best_w.ravel(), (rows, volume.tets[best_tet].ravel())), shape=(len(points), volume.n_nodes))
    return Embedding(tet=best_tet, weights=best_w, matrix=matrix)


def describe(volume: VolumeMesh) -> dict:
    return {"nodes": int(volume.n_nodes), "tets": int(len(volume.tets)), "resolution_mm": volume.resolution * 1e3}
