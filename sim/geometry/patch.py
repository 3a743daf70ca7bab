"""The grasp patch: the surface within the grasp radius of the grasped vertex, as an area.

A grasp holds the *mean displacement of the surface area* within the radius (same
hemisphere). This is a bounded functional (its dual is a uniform traction on a disc cut out
of the surface), so a model refined towards the continuum approaches a limit. The mean of the
few surface vertices inside the radius is not: in 3D elasticity the compliance of a point load
is unbounded, and a handful of vertices on the 3.1 mm fsaverage5 surface is close to that
(docs/reference.md: it falls with each refinement, with no sign of settling).

`patch_area_points` gives the quadrature (points and weights) for a reference that
interpolates its own field at the points, and for a model that moves the surface vertices
(`sim.models.fem.FemModel.grasp`); the tests fold the same quadrature onto the vertices
(`tests/helpers.patch_vertex_weights`) to check it.
"""

from __future__ import annotations

import numpy as np

SUBDIVISIONS = 16  # each triangle near the grasp is split into 16 x 16 for the quadrature
GRASP_RADIUS = 0.005  # m: the default patch, about the bite of a pair of tissue forceps
GRASP_REACH_M = 0.01  # a button press farther than this from the surface grasps nothing


def grasp_problem(mesh, point) -> str | None:
    """Why a grasp at `point` (m) grasps nothing: farther than `GRASP_REACH_M` from the surface
    (the message names the distance and the reach); None when it is within reach."""
    p = np.asarray(point, dtype=np.float64)
    dist = float(np.linalg.norm(mesh.vertices[mesh.nearest_vertex(p)] - p))
    if dist <= GRASP_REACH_M:
        return None
    return (f"{','.join(f'{x:g}' for x in point)} is {dist * 1e3:.4g} mm from the brain surface; "
            f"allowed: within {GRASP_REACH_M * 1e3:g} mm of it (the simulator's grasp reach)")


def _sub_triangle_centroids(n: int) -> np.ndarray:
    """Barycentric coordinates (s, 3) of the centroids of the n^2 similar sub-triangles."""
    bc = []
    for i in range(n):
        for j in range(n - i):
            bc.append(((i + 1 / 3) / n, (j + 1 / 3) / n))  # n(n+1)/2 upright
            if j < n - i - 1:
                bc.append(((i + 2 / 3) / n, (j + 2 / 3) / n))  # n(n-1)/2 inverted
    bc = np.array(bc)
    return np.column_stack([1.0 - bc.sum(axis=1), bc])


def _patch_quadrature(mesh, vertex: int, radius: float, subdivisions: int):
    """(triangles (t, 3), barycentric (q, 3), parent triangle row (q,), points (q, 3), weights (q,))."""
    mesh.prepare_queries()
    v = mesh.vertices
    tri = np.asarray(mesh.triangles, dtype=np.int64)
    centre = v[vertex]
    reach = radius + float(np.linalg.norm(v[tri[:, 1]] - v[tri[:, 0]], axis=1).max())
    near = np.zeros(len(v), dtype=bool)
    near[mesh._kdtree.query_ball_point(centre, reach)] = True
    sel = tri[near[tri].any(axis=1)]
    if mesh.labels is not None:
        sel = sel[np.all(mesh.labels[sel] == mesh.labels[vertex], axis=1)]
    lam = _sub_triangle_centroids(int(subdivisions))
    a, b, c = (v[sel[:, k]] for k in range(3))
    area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1) / subdivisions**2  # each sub-triangle's
    pts = lam[None, :, 0, None] * a[:, None] + lam[None, :, 1, None] * b[:, None] + lam[None, :, 2, None] * c[:, None]
    keep = np.linalg.norm(pts - centre, axis=2) <= radius
    parent, sub = np.nonzero(keep)
    w = area[parent]
    return sel, lam[sub], parent, pts[keep], w


def patch_area_points(mesh, vertex: int, radius: float, subdivisions: int = SUBDIVISIONS) -> tuple[np.ndarray, np.ndarray]:
    """Quadrature of the surface within `radius` of `vertex` (same hemisphere): (points (q, 3),
    weights (q,) summing to 1) for the mean displacement over that area.

    Each triangle of the surface near the vertex is split into subdivisions^2 similar
    triangles; those whose centroid lies within the radius are kept, each weighing its area
    (the midpoint rule on a disc cut out of the surface at 1/subdivisions of an edge)."""
    _, _, _, pts, w = _patch_quadrature(mesh, vertex, radius, subdivisions)
    if len(pts) == 0:
        return mesh.vertices[vertex][None, :], np.ones(1)
    return pts, w / w.sum()
