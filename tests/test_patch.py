"""The grasp patch's area mean (sim/geometry/patch.py) against closed forms on a flat grid."""

import numpy as np
import pytest

from sim.geometry.mesh import SurfaceMesh
from sim.geometry.patch import patch_area_points
from tests.helpers import patch_vertex_weights


@pytest.fixture(scope="module")
def plane():
    # a flat 40 x 40 mm grid of right triangles, 2 mm cells, in z = 0
    n = 21
    xs = np.linspace(-0.02, 0.02, n)
    gx, gy = np.meshgrid(xs, xs, indexing="ij")
    v = np.column_stack([gx.ravel(), gy.ravel(), np.zeros(n * n)])
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    tri = np.concatenate([np.column_stack([a, b, c]), np.column_stack([a, c, d])]).astype(np.int32)
    return SurfaceMesh(v, tri)


def test_area_points_cover_a_disc(plane):
    centre = int(np.argmin(np.linalg.norm(plane.vertices, axis=1)))
    pts, w = patch_area_points(plane, centre, 0.005, subdivisions=32)
    assert w.sum() == pytest.approx(1.0)
    assert np.all(np.linalg.norm(pts, axis=1) <= 0.005)
    # the mean of x^2 + y^2 over a disc of radius R is R^2 / 2 (midpoint rule, 1/32 of a 2 mm edge)
    assert w @ np.sum(pts[:, :2] ** 2, axis=1) == pytest.approx(0.005**2 / 2, rel=0.02)


def test_vertex_weights_give_the_area_mean_of_the_drawn_surface(plane):
    centre = int(np.argmin(np.linalg.norm(plane.vertices, axis=1)))
    ids, w = patch_vertex_weights(plane, centre, 0.005)
    assert w.sum() == pytest.approx(1.0)
    assert np.all(w > 0)
    # a linear field is reproduced exactly: the mean of x over a centred disc is 0, of 1 + 3x + 2y is 1
    f = 1 + 3 * plane.vertices[:, 0] + 2 * plane.vertices[:, 1]
    assert w @ f[ids] == pytest.approx(1.0, abs=1e-3 * 0.005 * 5)
    # vertices outside the radius whose triangles reach into it get a share; more than the 21 inside
    inside = np.sum(np.linalg.norm(plane.vertices, axis=1) <= 0.005)
    assert len(ids) > inside
    # and the share falls off with distance: the centre vertex weighs more than a rim vertex
    r = np.linalg.norm(plane.vertices[ids], axis=1)
    assert w[np.argmin(r)] > w[np.argmax(r)]
