"""The participant's camera: a pinhole looking along -front with `up`, placed so the brain at
rest fills the view's height (or its width, where the window is narrow), refitted whenever the
window changes size.

Two conventions, one camera: `K`, `R`, `t` (x right, y down the image, z forward; pixel (u, v)
from the top left corner, as the mouse reports it) for picking and for tests that project a
vertex; `view_matrix` and `projection` for OpenGL (column vectors, y up, depth -1..1).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

FOVY_DEG = 30.0  # a narrow lens: little perspective distortion, as through a surgical microscope
FILL = 0.92  # the share of the view's height (or width) the brain fills at zoom 1


@dataclass(frozen=True)
class Camera:
    eye: np.ndarray  # (3,) metres
    R: np.ndarray  # (3, 3) rows: right, down, forward
    width: int
    height: int
    fovy_deg: float  # vertical field of view
    near: float
    far: float

    @property
    def t(self) -> np.ndarray:
        return -self.R @ self.eye

    @property
    def focal(self) -> float:
        """Focal length in pixels (square pixels)."""
        return 0.5 * self.height / math.tan(math.radians(self.fovy_deg) / 2.0)

    @property
    def K(self) -> np.ndarray:
        f = self.focal
        return np.array([[f, 0.0, self.width / 2.0], [0.0, f, self.height / 2.0], [0.0, 0.0, 1.0]])

    def project(self, points) -> np.ndarray:
        """(n, 3) points -> (n, 3): pixel u, v (continuous: pixel (i, j) spans [i, i + 1)) and depth."""
        c = np.atleast_2d(np.asarray(points, dtype=np.float64)) @ self.R.T + self.t
        uv = c[:, :2] / c[:, 2:3] * self.focal + [self.width / 2.0, self.height / 2.0]
        return np.column_stack([uv, c[:, 2]])

    def ray(self, u: float, v: float) -> np.ndarray:
        d = self.R.T @ np.linalg.solve(self.K, [u, v, 1.0])
        return d / np.linalg.norm(d)

    def at_depth(self, u: float, v: float, depth: float) -> np.ndarray:
        """The point at camera depth `depth` under pixel (u, v)."""
        return self.R.T @ (depth * np.linalg.solve(self.K, [u, v, 1.0]) - self.t)

    def depth(self, p) -> float:
        return float((self.R @ np.asarray(p, dtype=np.float64) + self.t)[2])

    def view_matrix(self) -> np.ndarray:
        M = np.eye(4)
        M[:3, :3] = self.R * np.array([[1.0], [-1.0], [-1.0]])  # OpenGL: y up, looking down -z
        M[:3, 3] = -M[:3, :3] @ self.eye
        return M

    def projection(self) -> np.ndarray:
        f = 1.0 / math.tan(math.radians(self.fovy_deg) / 2.0)
        n, fa = self.near, self.far
        P = np.zeros((4, 4))
        P[0, 0] = f * self.height / self.width
        P[1, 1] = f
        P[2, 2] = (fa + n) / (n - fa)
        P[2, 3] = 2.0 * fa * n / (n - fa)
        P[3, 2] = -1.0
        return P


def orientation(front, up) -> np.ndarray:
    """Rows right, down, forward of a camera looking along -front with `up` on the screen."""
    forward = -np.asarray(front, dtype=np.float64)
    forward /= np.linalg.norm(forward)
    right = np.cross(forward, np.asarray(up, dtype=np.float64))
    right /= np.linalg.norm(right)
    return np.stack([right, np.cross(forward, right), forward])


def fit(vertices, front, up, width: int, height: int, zoom: float = 1.0) -> Camera:
    """The camera that shows `vertices` (the brain at rest) centred, filling FILL of the view's
    height or of its width, whichever is tighter; `zoom` magnifies about the centre (a narrower
    field of view from the same place)."""
    X = np.asarray(vertices, dtype=np.float64)
    R = orientation(front, up)
    lo, hi = X.min(axis=0), X.max(axis=0)
    centre = (lo + hi) / 2.0
    tan_y = math.tan(math.radians(FOVY_DEG) / 2.0)
    tan_x = tan_y * width / height
    q = (X - centre) @ R.T  # camera axes, origin at the centre
    eye = centre
    for _ in range(3):  # distance that fits, then centre the image of the extents; converges in two
        d = max(float(np.max(np.abs(q[:, 1]) / (FILL * tan_y) - q[:, 2])), float(np.max(np.abs(q[:, 0]) / (FILL * tan_x) - q[:, 2])))
        z = q[:, 2] + d
        sx, sy = q[:, 0] / z, q[:, 1] / z
        shift = np.array([(sx.min() + sx.max()) / 2.0, (sy.min() + sy.max()) / 2.0]) * d
        q[:, :2] -= shift
        centre = centre + R[:2].T @ shift
        eye = centre - d * R[2]
    radius = float(np.linalg.norm(hi - lo)) / 2.0
    fovy = 2.0 * math.degrees(math.atan(tan_y / zoom))
    return Camera(eye=eye, R=R, width=int(width), height=int(height), fovy_deg=fovy, near=max(d - 4.0 * radius, 0.02 * d), far=d + 4.0 * radius)


def ray_hit(origin, direction, vertices: np.ndarray, triangles: np.ndarray) -> float:
    """Distance along the ray to the nearest triangle it crosses (Moller-Trumbore, every
    triangle at once: a few ms for the brain, once per click), or inf."""
    o, d = np.asarray(origin, dtype=np.float64), np.asarray(direction, dtype=np.float64)
    v0 = vertices[triangles[:, 0]]
    e1, e2 = vertices[triangles[:, 1]] - v0, vertices[triangles[:, 2]] - v0
    p = np.cross(d, e2)
    det = np.einsum("ij,ij->i", e1, p)
    ok = np.abs(det) > 1e-18
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    s = o - v0
    a = np.einsum("ij,ij->i", s, p) * inv
    q = np.cross(s, e1)
    b = (q @ d) * inv
    t = np.einsum("ij,ij->i", e2, q) * inv
    hit = ok & (a >= 0.0) & (b >= 0.0) & (a + b <= 1.0) & (t > 0.0)
    return float(t[hit].min()) if hit.any() else math.inf
