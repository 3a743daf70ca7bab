"""The view's vertex normals, compiled (numba): the window recomputes them every frame as the
tissue deforms (a headless scene computes its mesh's normals once, in NumPy:
`sim.geometry.mesh.vertex_normals`)."""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True, fastmath=False)
def vertex_normals(x, triangles):
    """Unit vertex normals of a triangle surface, each the area-weighted mean of its faces'
    normals: one pass over the triangles, then one over the vertices (compiled because the view
    recomputes them every frame; against NumPy: docs/participant.md)."""
    n = np.zeros((x.shape[0], 3))
    for t in range(triangles.shape[0]):
        a, b, c = triangles[t, 0], triangles[t, 1], triangles[t, 2]
        e0 = x[b, 0] - x[a, 0]
        e1 = x[b, 1] - x[a, 1]
        e2 = x[b, 2] - x[a, 2]
        f0 = x[c, 0] - x[a, 0]
        f1 = x[c, 1] - x[a, 1]
        f2 = x[c, 2] - x[a, 2]
        c0 = e1 * f2 - e2 * f1  # |cross| is twice the area: area weighting for free
        c1 = e2 * f0 - e0 * f2
        c2 = e0 * f1 - e1 * f0
        for v in (a, b, c):
            n[v, 0] += c0
            n[v, 1] += c1
            n[v, 2] += c2
    out = np.empty((x.shape[0], 3))
    for v in range(x.shape[0]):
        s = np.sqrt(n[v, 0] ** 2 + n[v, 1] ** 2 + n[v, 2] ** 2)
        s = 1.0 / s if s > 0.0 else 0.0
        out[v, 0] = n[v, 0] * s
        out[v, 1] = n[v, 1] * s
        out[v, 2] = n[v, 2] * s
    return out
