"""The brain's regions: grey matter between the pial and the white surface, white matter inside
the white surface (FreeSurfer's fsaverage5 white surfaces, `data/brain_white_fsaverage5.npz`,
hash-checked against `data/brain_white_fsaverage5.json`; made by scripts/make_white_asset.py).

A point is inside a closed surface when a ray from it crosses the surface an odd number of
times. The ray runs along +z; the triangles are binned by their xy bounding boxes, so each
point tests only the triangles over its own column (a few dozen of the 10 242 per hemisphere):
every quadrature point of the 4 mm mesh in about a second on one core, in NumPy and numba only
(the simulator does not import open3d; the tests check the labels against open3d's
occupancy). A generalized winding number would be robust to holes, but the white surfaces are
closed and manifold (the script checks), and it costs every triangle per point.
"""

from __future__ import annotations

import hashlib
import json

import numba
import numpy as np

from brainsim_assets import path as _asset
from sim.errors import MeshError
from sim.geometry.tetmesh import labelled_part

WHITE_SURFACE = _asset("data/brain_white_fsaverage5.npz")
WHITE_INFO = _asset("data/brain_white_fsaverage5.json")
BIN = 0.001  # m: the xy cell of the triangle bins (the surfaces' triangles are about 1-3 mm)
GREY, WHITE = 0, 1  # region codes of `point_regions`


def white_sha256() -> str:
    """The shipped white surfaces' SHA-256 as recorded (what a regional solve's key holds)."""
    try:
        return str(json.loads(WHITE_INFO.read_text())["sha256"])
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise MeshError(f"{WHITE_INFO}: not the white surfaces' record ({exc}); reinstall") from None


def white_surfaces() -> dict:
    """{hemisphere label: (vertices (n, 3) m, triangles (m, 3))} of the shipped white surfaces,
    checked against their recorded SHA-256."""
    want = white_sha256()
    try:
        data = WHITE_SURFACE.read_bytes()
    except OSError as exc:
        raise MeshError(f"{WHITE_SURFACE}: cannot read the white surfaces ({exc}); reinstall") from None
    have = hashlib.sha256(data).hexdigest()
    if have != want:
        raise MeshError(f"{WHITE_SURFACE}: SHA-256 {have[:12]}... differs from {WHITE_INFO.name}'s {want[:12]}...; "
                        "the file is damaged (reinstall, or rebuild it with scripts/make_white_asset.py)")
    with np.load(WHITE_SURFACE) as z:
        v, f, lab = z["vertices"].astype(np.float64), z["triangles"].astype(np.int64), z["hemisphere"]
    return {int(label): labelled_part(v, f, lab, label)[:2] for label in np.unique(lab)}


@numba.njit(cache=True)
def _bin_triangles(tv, x0, y0, nx, ny, cell):
    """CSR lists of the triangles whose xy bounding box touches each cell."""
    m = tv.shape[0]
    counts = np.zeros(nx * ny + 1, dtype=np.int64)
    lo = np.empty((m, 2), dtype=np.int64)
    hi = np.empty((m, 2), dtype=np.int64)
    for t in range(m):
        for d, o, n in ((0, x0, nx), (1, y0, ny)):
            a = min(tv[t, 0, d], tv[t, 1, d], tv[t, 2, d])
            b = max(tv[t, 0, d], tv[t, 1, d], tv[t, 2, d])
            lo[t, d] = max(0, min(n - 1, int((a - o) / cell)))
            hi[t, d] = max(0, min(n - 1, int((b - o) / cell)))
        for i in range(lo[t, 0], hi[t, 0] + 1):
            for j in range(lo[t, 1], hi[t, 1] + 1):
                counts[i * ny + j + 1] += 1
    start = np.cumsum(counts)
    fill = start[:-1].copy()
    items = np.empty(start[-1], dtype=np.int64)
    for t in range(m):
        for i in range(lo[t, 0], hi[t, 0] + 1):
            for j in range(lo[t, 1], hi[t, 1] + 1):
                c = i * ny + j
                items[fill[c]] = t
                fill[c] += 1
    return start, items


@numba.njit(cache=True, parallel=True)
def _parity(points, tv, start, items, x0, y0, nx, ny, cell, out):
    for p in numba.prange(points.shape[0]):
        px, py, pz = points[p, 0], points[p, 1], points[p, 2]
        i, j = int((px - x0) / cell), int((py - y0) / cell)
        if i < 0 or j < 0 or i >= nx or j >= ny:
            out[p] = False
            continue
        c = i * ny + j
        crossings = 0
        for k in range(start[c], start[c + 1]):
            t = items[k]
            ax, ay = tv[t, 0, 0] - px, tv[t, 0, 1] - py
            bx, by = tv[t, 1, 0] - px, tv[t, 1, 1] - py
            cx, cy = tv[t, 2, 0] - px, tv[t, 2, 1] - py
            # signed areas of the point with each edge: all one sign when the column passes through
            w0, w1, w2 = bx * cy - by * cx, cx * ay - cy * ax, ax * by - ay * bx
            if not ((w0 > 0.0 and w1 > 0.0 and w2 > 0.0) or (w0 < 0.0 and w1 < 0.0 and w2 < 0.0)):
                continue
            s = w0 + w1 + w2
            z = (w0 * tv[t, 0, 2] + w1 * tv[t, 1, 2] + w2 * tv[t, 2, 2]) / s
            if z > pz:
                crossings += 1
        out[p] = crossings % 2 == 1


def inside(vertices: np.ndarray, triangles: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(n,) bool: each point inside the closed surface (ray parity along +z)."""
    points = np.ascontiguousarray(np.atleast_2d(points), dtype=np.float64)
    tv = np.ascontiguousarray(np.asarray(vertices, dtype=np.float64)[np.asarray(triangles)])
    x0, y0 = float(tv[..., 0].min()), float(tv[..., 1].min())
    nx = int((tv[..., 0].max() - x0) / BIN) + 1
    ny = int((tv[..., 1].max() - y0) / BIN) + 1
    start, items = _bin_triangles(tv, x0, y0, nx, ny, BIN)
    out = np.zeros(len(points), dtype=np.bool_)
    _parity(points, tv, start, items, x0, y0, nx, ny, BIN, out)
    return out


def point_regions(points: np.ndarray, hemisphere: int, surfaces: dict | None = None) -> np.ndarray:
    """(n,) int8: `WHITE` where a point lies inside its hemisphere's white surface, else `GREY`."""
    v, f = (surfaces or white_surfaces())[int(hemisphere)]
    return np.where(inside(v, f, points), WHITE, GREY).astype(np.int8)


def quadrature_regions(nodes: np.ndarray, tets: np.ndarray, points: np.ndarray, hemisphere: int,
                       surfaces: dict | None = None) -> np.ndarray:
    """(m, q) int8: the region of each element's quadrature point, the points given in
    barycentric coordinates `points` (q, 4) of the straight tetrahedra (`p2.POINTS`, `p1.POINTS`)."""
    where = np.einsum("qa,mak->mqk", np.asarray(points, dtype=np.float64), np.asarray(nodes)[np.asarray(tets)])
    return point_regions(where.reshape(-1, 3), hemisphere, surfaces).reshape(where.shape[:2])
