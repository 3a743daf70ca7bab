"""The shipped brain surface: fsaverage5, both hemispheres, metres, watertight and manifold."""

import numpy as np
import pytest

from sim.errors import MeshError
from sim.geometry.mesh import BRAIN_MESH, load_mesh, vertex_normals
from tests.helpers import icosphere


@pytest.fixture(scope="module")
def brain():
    return load_mesh(BRAIN_MESH)


def _directed_edges(tri):
    return np.concatenate((tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]))


def test_two_hemispheres_of_fsaverage5_size(brain):
    assert brain.n_vertices == 2 * 10242
    assert len(brain.triangles) == 2 * 20480
    for h in (0, 1):
        verts = np.flatnonzero(brain.labels == h)
        assert len(verts) == 10242
        tri = brain.triangles[np.isin(brain.triangles[:, 0], verts)]
        assert len(tri) == 20480  # no triangle spans hemispheres
        assert np.isin(tri, verts).all()


def test_units_are_metres(brain):
    lo, hi = brain.bounds()
    extent = hi - lo
    # an adult brain is about 14 x 17 x 12 cm; in millimetres these would be ~1000x larger
    assert np.all(extent > 0.09)
    assert np.all(extent < 0.2)


def test_watertight_and_manifold_numpy(brain):
    # closed, consistently oriented 2-manifold: every directed edge once, and its reverse once
    e = _directed_edges(brain.triangles.astype(np.int64))
    key = e[:, 0] * brain.n_vertices + e[:, 1]
    rev = e[:, 1] * brain.n_vertices + e[:, 0]
    assert len(np.unique(key)) == len(key)
    assert np.isin(rev, key).all()
    # Euler characteristic of two spheres
    n_edges = len(key) // 2
    assert brain.n_vertices - n_edges + len(brain.triangles) == 4


def test_watertight_according_to_open3d(brain):
    o3d = pytest.importorskip("open3d")
    for h in (0, 1):
        verts = np.flatnonzero(brain.labels == h)
        tri = brain.triangles[np.isin(brain.triangles[:, 0], verts)] - verts[0]
        m = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(brain.vertices[verts]), o3d.utility.Vector3iVector(tri))
        assert m.is_watertight()
        assert m.is_edge_manifold()
        assert m.is_vertex_manifold()
        assert not m.is_self_intersecting()


def test_normals_point_outwards(brain):
    n = vertex_normals(brain.vertices, brain.triangles)
    for h in (0, 1):
        sel = brain.labels == h
        c = brain.vertices[sel].mean(axis=0)
        assert np.mean(np.sum((brain.vertices[sel] - c) * n[sel], axis=1) > 0) > 0.7  # folded cortex: most, not all


def test_geodesic_rings_on_a_sphere():
    s = icosphere(radius=0.05, subdivisions=4)
    v = s.nearest_vertex((0, 0, 0.05))
    idx, d = s.geodesic_within(v, 0.02)
    # edge paths are at least the straight-line distance and within 20% of the great circle (grid paths zigzag)
    p = s.vertices[idx] / 0.05
    arc = 0.05 * np.arccos(np.clip(p @ (s.vertices[v] / 0.05), -1, 1))
    chord = np.linalg.norm(s.vertices[idx] - s.vertices[v], axis=1)
    assert np.all(d >= chord - 1e-12)
    assert np.all(d <= 1.2 * arc + 1e-9)
    assert 0.0 in d
    assert d.max() <= 0.02


def test_bad_mesh_files(tmp_path):
    with pytest.raises(MeshError, match="not found"):
        load_mesh(tmp_path / "missing.npz")
    np.savez(tmp_path / "bad.npz", vertices=np.zeros((3, 3)))
    with pytest.raises(MeshError, match="'vertices' and 'triangles'"):
        load_mesh(tmp_path / "bad.npz")
    np.savez(tmp_path / "idx.npz", vertices=np.zeros((3, 3)), triangles=np.array([[0, 1, 5]]))
    with pytest.raises(MeshError, match="out of range"):
        load_mesh(tmp_path / "idx.npz")
