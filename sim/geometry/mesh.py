"""Surface meshes: loading the shipped brain, normals, nearest vertex, geodesic rings.

Only NumPy and SciPy here: a headless scene must not import open3d (importing open3d loads its
rendering module).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np

from brainsim_assets import path as _asset
from sim.errors import InputFileError, MeshError
from sim.files import MESH_MAX_BYTES, check_input

BRAIN_MESH = _asset("data/brain_fsaverage5.npz")


@dataclass(frozen=True, eq=False)
class SurfaceMesh:
    """A triangle surface in metres; ``labels`` marks components (0/1 = left/right hemisphere)."""

    vertices: np.ndarray  # (n, 3) float64
    triangles: np.ndarray  # (m, 3) int32
    labels: np.ndarray | None = None

    @property
    def n_vertices(self) -> int:
        return len(self.vertices)

    @cached_property
    def vertex_normals(self) -> np.ndarray:
        return vertex_normals(self.vertices, self.triangles)

    @cached_property
    def edges(self) -> np.ndarray:
        """Unique undirected edges, (e, 2) with i < j."""
        t = self.triangles
        e = np.concatenate((t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]))
        e.sort(axis=1)
        return np.unique(e, axis=0)

    @cached_property
    def _graph(self):
        e = self.edges
        w = np.linalg.norm(self.vertices[e[:, 0]] - self.vertices[e[:, 1]], axis=1)
        n = self.n_vertices
        g = _scipy().sparse.coo_matrix((np.concatenate((w, w)), (np.concatenate((e[:, 0], e[:, 1])), np.concatenate((e[:, 1], e[:, 0])))), shape=(n, n))
        return g.tocsr()

    @cached_property
    def _kdtree(self):
        return point_tree(self.vertices)

    def prepare_queries(self) -> None:
        """Build the nearest-vertex tree, edge graph and normals ahead of the first grasp.

        Also imports SciPy's graph module now: an import inside a run holds the interpreter
        lock for tens of milliseconds, which the servo thread would feel.
        """
        _scipy()
        _ = self._kdtree, self._graph, self.vertex_normals

    @property
    def queries_prepared(self) -> bool:
        """Whether `prepare_queries` has run: a grasp then builds nothing."""
        return "_kdtree" in self.__dict__ and "_graph" in self.__dict__

    def nearest_vertex(self, point) -> int:
        _, i = self._kdtree.query(np.asarray(point, dtype=np.float64))
        return int(i)

    def geodesic_within(self, vertex: int, radius: float) -> tuple[np.ndarray, np.ndarray]:
        """Vertices whose edge-path distance from `vertex` is at most `radius`, and the distances.

        Edge paths overestimate true geodesics (by how much: docs/plate_spring.md); they never
        cross a sulcus or the gap between hemispheres, which straight-line distance would.
        """
        d = _scipy().sparse.csgraph.dijkstra(self._graph, directed=False, indices=vertex, limit=radius)
        idx = np.flatnonzero(np.isfinite(d))
        return idx, d[idx]

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        return self.vertices.min(axis=0), self.vertices.max(axis=0)


def point_tree(points: np.ndarray):
    """A k-d tree of `points` (SciPy's cKDTree) for nearest-point queries."""
    return _scipy().spatial.cKDTree(points)


def _scipy():
    """SciPy with its sparse graphs and k-d trees, loaded at a surface's first query: every scene
    reader (`protocol validate`, `status`, `--help`) imports this module and never queries."""
    import scipy.sparse.csgraph  # lazy: scipy, only for a surface's queries (every scene reader imports this module)

    return scipy  # its subpackages load on first use (scipy.spatial: `point_tree`)


def vertex_normals(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Area-weighted vertex normals (unit length). NumPy: once per mesh, so that a headless
    scene never imports numba; the view's per-frame pass is compiled (`sim.view.normals`)."""
    v0, v1, v2 = (vertices[triangles[:, k]] for k in range(3))
    fn = np.cross(v1 - v0, v2 - v0)  # length = 2 * area
    n = np.zeros_like(vertices)
    for k in range(3):
        for c in range(3):
            n[:, c] += np.bincount(triangles[:, k], weights=fn[:, c], minlength=len(vertices))
    norm = np.linalg.norm(n, axis=1, keepdims=True)
    return n / np.where(norm > 0, norm, 1.0)


def patch_vertices(mesh, vertex: int, radius: float) -> np.ndarray:
    """Surface vertices within `radius` of `vertex`, same hemisphere (the grasp by vertex mean,
    before the area mean of `sim.geometry.patch`: the reference's `--functional vertices` shows why it
    cannot converge)."""
    mesh.prepare_queries()
    patch = np.asarray(mesh._kdtree.query_ball_point(mesh.vertices[vertex], radius), dtype=np.int64)
    if mesh.labels is not None:
        patch = patch[mesh.labels[patch] == mesh.labels[vertex]]
    return patch if len(patch) else np.array([vertex], dtype=np.int64)


def load_mesh(path: str | Path = BRAIN_MESH) -> SurfaceMesh:
    """Load a surface saved as .npz with ``vertices`` (metres) and ``triangles``."""
    path = Path(path)
    try:
        check_input(path, MESH_MAX_BYTES)
    except InputFileError as exc:
        raise MeshError(str(exc)) from None
    try:
        with np.load(path) as data:
            vertices = np.asarray(data["vertices"], dtype=np.float64)
            triangles = np.asarray(data["triangles"], dtype=np.int32)
            labels = np.asarray(data["hemisphere"]) if "hemisphere" in data else None
    except FileNotFoundError:
        raise MeshError(f"{path}: mesh file not found") from None
    except (OSError, ValueError, KeyError) as exc:
        raise MeshError(f"{path}: not a mesh file with 'vertices' and 'triangles' ({exc})") from None
    if vertices.ndim != 2 or vertices.shape[1] != 3 or triangles.ndim != 2 or triangles.shape[1] != 3:
        raise MeshError(f"{path}: vertices must be (n, 3) and triangles (m, 3)")
    if len(triangles) and (triangles.min() < 0 or triangles.max() >= len(vertices)):
        raise MeshError(f"{path}: triangles index vertices out of range 0..{len(vertices) - 1}")
    if not np.all(np.isfinite(vertices)):
        raise MeshError(f"{path}: vertices contain NaN or infinity")
    return SurfaceMesh(vertices, triangles, labels)
