"""Meshes the participant view draws besides the brain: the forceps each hand holds, and the
arrow that shows a force.

Why a forceps and not a block "hand": the participant grasps and pulls tissue, and what a
surgeon recognises at once, and aims with, is the instrument's tips. So the hand is drawn as
thumb (tissue) forceps whose jaws meet at the haptic point and open with the grip.

Pure NumPy (no GL, no open3d), so the geometry is testable headless and any renderer can take
it. Every mesh is a `Shape` in metres: triangles counter-clockwise seen from outside, so
(v1 - v0) x (v2 - v0) points outward, as the normals do. Flat parts (the blades, the hinge's
flat sides, the arrow's discs) have their own vertices per face so lit edges stay crisp; round
parts (the hinge's rounded end, the arrow's shaft and cone) share vertices with smooth normals.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

# ---------------------------------------------------------------------------------------------
# the mesh type


@dataclass(frozen=True, eq=False)
class Shape:
    """A triangle mesh: vertices (n, 3) float32 in metres, unit normals (n, 3) float32,
    triangles (m, 3) int32 counter-clockwise seen from outside. The arrays are read-only copies."""

    vertices: np.ndarray
    normals: np.ndarray
    triangles: np.ndarray

    def __post_init__(self) -> None:
        v = np.array(self.vertices, dtype=np.float32).reshape(-1, 3)
        n = np.array(self.normals, dtype=np.float32).reshape(-1, 3)
        t = np.array(self.triangles, dtype=np.int32).reshape(-1, 3)
        if len(n) != len(v):
            raise ValueError(f"{len(v)} vertices but {len(n)} normals")
        if t.size and (t.min() < 0 or t.max() >= len(v)):
            raise ValueError("triangle index out of range")
        for name, a in (("vertices", v), ("normals", n), ("triangles", t)):
            a.flags.writeable = False  # frozen means frozen: a renderer may cache uploads by identity
            object.__setattr__(self, name, a)

    @property
    def n_vertices(self) -> int:
        return len(self.vertices)

    @property
    def n_triangles(self) -> int:
        return len(self.triangles)

    @staticmethod
    def empty() -> Shape:
        return Shape(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 3)))


def concat(*shapes: Shape) -> Shape:
    """One mesh from several (their vertices are not merged)."""
    if not shapes:
        return Shape.empty()
    offsets = np.cumsum([0] + [s.n_vertices for s in shapes[:-1]])
    return Shape(
        np.concatenate([s.vertices for s in shapes]),
        np.concatenate([s.normals for s in shapes]),
        np.concatenate([s.triangles + o for s, o in zip(shapes, offsets)]),
    )


def transform(shape: Shape, R: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The shape placed in the scene: (vertices @ R.T + t, normals @ R.T), both float32.

    R must be a rotation: normals are rotated with it, not with the inverse transpose."""
    R = np.asarray(R, dtype=np.float64)
    t = np.asarray(t, dtype=np.float64).reshape(3)
    if R.shape != (3, 3):
        raise ValueError(f"R must be 3x3, got {R.shape}")
    v = shape.vertices @ R.T + t
    n = shape.normals @ R.T
    return v.astype(np.float32), n.astype(np.float32)


def frame(axis: np.ndarray, side: np.ndarray) -> np.ndarray:
    """The rotation [x y z] (as columns) with z the unit `axis` and y the unit part of `side`
    orthogonal to it, x = y cross z: e.g. a forceps' axis and its opening direction in the scene.

    Raises ValueError for a zero or non-finite axis, or a side (nearly) parallel to the axis."""
    a = np.asarray(axis, dtype=np.float64).reshape(3)
    s = np.asarray(side, dtype=np.float64).reshape(3)
    if not (np.all(np.isfinite(a)) and np.all(np.isfinite(s))):
        raise ValueError("axis and side must be finite")
    na = np.linalg.norm(a)
    if na == 0.0:
        raise ValueError("axis is zero")
    z = a / na
    y = s - (s @ z) * z
    ny = np.linalg.norm(y)
    # relative test: a side within ~1e-6 rad of the axis has no usable direction left
    if ny <= 1e-6 * max(np.linalg.norm(s), np.finfo(float).tiny):
        raise ValueError("side is zero or parallel to axis")
    y /= ny
    return np.column_stack((np.cross(y, z), y, z))


# ---------------------------------------------------------------------------------------------
# building blocks


def _flat(polygons: list[np.ndarray]) -> Shape:
    """Convex planar polygons (each (k, 3), counter-clockwise seen from outside), each with its
    own vertices and face normal: crisp edges under flat lighting."""
    verts, norms, tris = [], [], []
    base = 0
    for p in polygons:
        p = np.asarray(p, dtype=np.float64)
        # Newell's normal: robust for any planar polygon, exact direction for a flat one
        nrm = np.cross(p, np.roll(p, -1, axis=0)).sum(axis=0)
        nrm /= np.linalg.norm(nrm)
        k = len(p)
        verts.append(p)
        norms.append(np.repeat(nrm[None], k, axis=0))
        tris.append([(base, base + i, base + i + 1) for i in range(1, k - 1)])  # a fan: convex
        base += k
    return Shape(np.concatenate(verts), np.concatenate(norms), np.concatenate(tris))


def _mirror_y(shape: Shape) -> Shape:
    """The mirror image across y = 0 (a mirror reverses winding, so the triangles are flipped)."""
    m = np.array([1.0, -1.0, 1.0], dtype=np.float32)
    return Shape(shape.vertices * m, shape.normals * m, shape.triangles[:, ::-1])


def _rotation_x(phi: float) -> np.ndarray:
    c, s = math.cos(phi), math.sin(phi)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def _placed(shape: Shape, R: np.ndarray, t: np.ndarray) -> Shape:
    return Shape(*transform(shape, R, t), shape.triangles)


def _ring(radius: float, z: float, sides: int) -> np.ndarray:
    a = 2.0 * np.pi * np.arange(sides) / sides
    return np.column_stack((radius * np.cos(a), radius * np.sin(a), np.full(sides, z)))


# ---------------------------------------------------------------------------------------------
# the forceps: two tapered blades joined at a hinge block, tips at the origin, handle along +z

TIP_THICKNESS = 0.0010  # y, at the tip
TIP_WIDTH = 0.0016  # x, at the tip
ROOT_THICKNESS = 0.0022  # y, at the hinge
ROOT_WIDTH = 0.0050  # x, at the hinge
ROOT_Z = 0.075  # where the blades reach the hinge (and turn about)
BLADE_END_Z = 0.078  # the blades run on inside the hinge block so no seam shows
PIVOT_Y = 0.0025  # each blade's root centre, +-y
JAW_LENGTH = 0.008  # the last 8 mm run parallel: closed jaws meet along a length, not at a point
GRIP = (0.035, 0.055)  # the flat finger grip, a little wider
GRIP_EXTRA = 0.0010
GRIP_RAMP = 0.002
HINGE_Z = (0.072, 0.087)
HINGE_HALF_Y = 0.0038
HINGE_HALF_X = 0.0027
HINGE_RADII = (0.0008, 0.0030)  # corner radii at the blade end and at the rounded butt end
HINGE_ARC = 5  # segments per rounded corner
MAX_GAP = 0.0056  # jaw gap (between the gripping faces) fully open; tip centres 1 mm more apart
FORCEPS_LENGTH = HINGE_Z[1]


def _lerp(a: float, b: float, f: float) -> float:
    return a + (b - a) * f


def _blade_section(z: float) -> tuple[float, float, float]:
    """(centre y, thickness, width) of the +y blade, closed, at height z."""
    f = min(max(z / ROOT_Z, 0.0), 1.0)
    thickness = _lerp(TIP_THICKNESS, ROOT_THICKNESS, f)
    width = _lerp(TIP_WIDTH, ROOT_WIDTH, f)
    # the grip: ramps up over GRIP_RAMP into a plateau, so the fingers' place is seen
    lo, hi = GRIP
    g = min(max((z - (lo - GRIP_RAMP)) / GRIP_RAMP, 0.0), 1.0) * min(max(((hi + GRIP_RAMP) - z) / GRIP_RAMP, 0.0), 1.0)
    width += GRIP_EXTRA * g
    # gripping (inner) face: flat on y = 0 along the jaw, then straight out to the root
    root_inner = PIVOT_Y - ROOT_THICKNESS / 2
    inner = root_inner * min(max((z - JAW_LENGTH) / (ROOT_Z - JAW_LENGTH), 0.0), 1.0)
    return inner + thickness / 2, thickness, width


def _blade_closed() -> Shape:
    """The +y blade, closed: a sweep of axis-aligned rectangles (every side quad is a planar
    trapezoid), capped at both ends."""
    lo, hi = GRIP
    zs = [0.0, JAW_LENGTH, lo - GRIP_RAMP, lo, hi, hi + GRIP_RAMP, ROOT_Z, BLADE_END_Z]
    sections = []
    for z in zs:
        y, t, w = _blade_section(z)
        # counter-clockwise seen from +z
        sections.append(np.array([[-w / 2, y - t / 2, z], [w / 2, y - t / 2, z], [w / 2, y + t / 2, z], [-w / 2, y + t / 2, z]]))
    polys = [sections[0][::-1], sections[-1]]  # tip cap faces -z, root cap +z
    for a, b in zip(sections[:-1], sections[1:]):
        for j in range(4):
            k = (j + 1) % 4
            polys.append(np.array([a[j], a[k], b[k], b[j]]))
    return _flat(polys)


def _blade_angle(opening: float) -> float:
    """The turn about the root (x axis) that puts the +y blade's jaw point at y = gap / 2:
    exact, so the gap grows linearly with `opening`."""
    # jaw point relative to the pivot: (y, z) = (-a, -L); turned by phi its y is
    # -a cos(phi) + L sin(phi) = rho sin(phi - delta)
    a, length = PIVOT_Y, ROOT_Z
    rho = math.hypot(a, length)
    delta = math.atan2(a, length)
    return delta + math.asin((opening * MAX_GAP / 2 - a) / rho)


def _check_opening(opening: float) -> float:
    opening = float(opening)
    if not math.isfinite(opening):
        raise ValueError(f"opening must be finite, got {opening}")
    return min(max(opening, 0.0), 1.0)  # a grip sensor may overshoot a little: the jaws stop


def _blade_pose(opening: float) -> tuple[np.ndarray, np.ndarray]:
    R = _rotation_x(_blade_angle(opening))
    pivot = np.array([0.0, PIVOT_Y, ROOT_Z])
    return R, pivot - R @ pivot


def _hinge_profile() -> tuple[np.ndarray, np.ndarray]:
    """The hinge block's outline in the (y, z) plane, counter-clockwise seen from +x: a rectangle
    with small corners at the blade end and large ones at the butt. Returns points and normals."""
    z0, z1 = HINGE_Z
    rb, rt = HINGE_RADII
    hy = HINGE_HALF_Y
    corners = [  # centre, radius, start angle: counter-clockwise from the bottom right
        ((hy - rb, z0 + rb), rb, -0.5 * np.pi),
        ((hy - rt, z1 - rt), rt, 0.0),
        ((-hy + rt, z1 - rt), rt, 0.5 * np.pi),
        ((-hy + rb, z0 + rb), rb, np.pi),
    ]
    pts, nrm = [], []
    for (cy, cz), r, a0 in corners:
        a = a0 + 0.5 * np.pi * np.arange(HINGE_ARC + 1) / HINGE_ARC
        pts.append(np.column_stack((cy + r * np.cos(a), cz + r * np.sin(a))))
        nrm.append(np.column_stack((np.cos(a), np.sin(a))))
    return np.concatenate(pts), np.concatenate(nrm)


def _hinge() -> Shape:
    """The joined end both blades spring from: the rounded outline extruded along x; smooth
    normals round the outline, flat faces at x = +-HINGE_HALF_X."""
    p, n = _hinge_profile()
    k = len(p)
    hx = HINGE_HALF_X

    def at(x: float) -> np.ndarray:
        return np.column_stack((np.full(k, x), p))

    side_v = np.concatenate((at(-hx), at(hx)))
    side_n = np.concatenate([np.column_stack((np.zeros(k), n))] * 2)
    i = np.arange(k)
    j = (i + 1) % k
    # quad (i at -x, i+1 at -x, i+1 at +x, i at +x): outward for a counter-clockwise outline
    side_t = np.concatenate((np.column_stack((i, j, j + k)), np.column_stack((i, j + k, i + k))))
    side = Shape(side_v, side_n, side_t)

    def cap(x: float, sign: float) -> Shape:
        # a fan from the centre: a convex outline, and no sliver triangles along the flat sides
        centre = np.array([[x, 0.0, 0.5 * sum(HINGE_Z)]])
        v = np.concatenate((centre, at(x)))
        t = np.column_stack((np.zeros(k, dtype=int), i + 1, j + 1))
        return Shape(v, np.tile([sign, 0.0, 0.0], (k + 1, 1)), t if sign > 0 else t[:, ::-1])

    return concat(side, cap(hx, 1.0), cap(-hx, -1.0))


def forceps_parts(opening: float) -> tuple[Shape, Shape, Shape]:
    """The forceps as its three closed pieces: (+y blade, -y blade, hinge). See `forceps`."""
    opening = _check_opening(opening)
    blade = _placed(_blade_closed(), *_blade_pose(opening))
    return blade, _mirror_y(blade), _hinge()


def forceps(opening: float) -> Shape:
    """Thumb (tissue) forceps in their own frame, metres: the jaws meet at the origin when
    closed, the axis runs from the tips along +z to the butt at z = FORCEPS_LENGTH, and the jaws
    open along +-y. `opening` 0 is closed, 1 fully open (jaw gap MAX_GAP); values outside
    [0, 1] are clipped. Each blade turns about its own root at the hinge, so only the tips part."""
    return concat(*forceps_parts(opening))


# ---------------------------------------------------------------------------------------------
# the force arrow


def arrow(
    length: float,
    shaft_radius: float = 0.0016,
    head_radius: float = 0.0035,
    head_length: float = 0.010,
    sides: int = 16,
) -> Shape:
    """An arrow from the origin along +z, `length` long: a capped cylinder shaft and a cone head.

    Shorter than 2.5 head lengths, the whole arrow is scaled down (head 0.4 * length, radii in
    proportion) so a small force still reads as an arrow, not as a flat cone. `length <= 0`
    gives an empty Shape."""
    length = float(length)
    if not math.isfinite(length):
        raise ValueError(f"length must be finite, got {length}")
    if sides < 3:
        raise ValueError(f"sides must be at least 3, got {sides}")
    if not 0.0 < shaft_radius < head_radius or head_length <= 0.0:
        raise ValueError("need 0 < shaft_radius < head_radius and head_length > 0")
    if length <= 0.0:
        return Shape.empty()
    if length < 2.5 * head_length:
        scale = length / (2.5 * head_length)
        shaft_radius, head_radius, head_length = shaft_radius * scale, head_radius * scale, 0.4 * length
    z_head = length - head_length
    i = np.arange(sides)
    j = (i + 1) % sides
    # one ring computation per circle, so the pieces' shared vertices are bit-identical
    base, neck, collar = _ring(shaft_radius, 0.0, sides), _ring(shaft_radius, z_head, sides), _ring(head_radius, z_head, sides)
    down = np.tile([0.0, 0.0, -1.0], (2 * sides, 1))

    # the base disc, facing -z: a fan from its centre
    disc = Shape(np.concatenate(([[0.0, 0.0, 0.0]], base)), down[: sides + 1], np.column_stack((np.zeros(sides, int), j + 1, i + 1)))
    # the shaft's side, smooth
    radial = np.column_stack((np.cos(2 * np.pi * i / sides), np.sin(2 * np.pi * i / sides), np.zeros(sides)))
    shaft = Shape(np.concatenate((base, neck)), np.concatenate((radial, radial)),
                  np.concatenate((np.column_stack((i, j, j + sides)), np.column_stack((i, j + sides, i + sides)))))
    # the underside of the head, facing -z: the ring between shaft and cone
    under = Shape(np.concatenate((neck, collar)), down,
                  np.concatenate((np.column_stack((i, j, j + sides)), np.column_stack((i, j + sides, i + sides)))))
    return concat(disc, shaft, under, _cone(collar, head_radius, head_length, length))


def _cone(ring: np.ndarray, radius: float, height: float, apex_z: float) -> Shape:
    """A cone's side from `ring` up to the apex, smooth: the apex is repeated per side with the
    normal of the middle of its facet, since one normal there cannot suit every facet."""
    sides = len(ring)
    i = np.arange(sides)
    slope = radius / height

    def normals(a: np.ndarray) -> np.ndarray:
        n = np.column_stack((np.cos(a), np.sin(a), np.full(len(a), slope)))
        return n / np.linalg.norm(n, axis=1, keepdims=True)

    a = 2 * np.pi * i / sides
    apex = np.tile([0.0, 0.0, apex_z], (sides, 1))
    v = np.concatenate((ring, apex))
    n = np.concatenate((normals(a), normals(a + np.pi / sides)))
    return Shape(v, n, np.column_stack((i, (i + 1) % sides, i + sides)))


# ---------------------------------------------------------------------------------------------
# a hand's target: a ring where the target is, a thin rod along the pull to it


def torus(radius: float, tube: float, segments: int = 32, sides: int = 8) -> Shape:
    """A ring about the z axis in the z = 0 plane: centre line `radius` from the origin, a round
    tube `tube` thick (radius), smooth normals. Seen along z it is a circle of that radius."""
    if not 0.0 < tube < radius:
        raise ValueError("need 0 < tube < radius")
    if segments < 3 or sides < 3:
        raise ValueError("segments and sides must be at least 3")
    a = 2.0 * np.pi * np.arange(segments) / segments  # around the ring
    b = 2.0 * np.pi * np.arange(sides) / sides  # around the tube
    ca, sa = np.cos(a)[:, None], np.sin(a)[:, None]
    cb, sb = np.cos(b)[None, :], np.sin(b)[None, :]
    n = np.stack((ca * cb, sa * cb, np.broadcast_to(sb, (segments, sides))), axis=-1).reshape(-1, 3)
    centre = np.stack((radius * ca, radius * sa, np.zeros((segments, 1))), axis=-1)
    v = (np.broadcast_to(centre, (segments, sides, 3)).reshape(-1, 3) + tube * n)
    i, j = np.meshgrid(np.arange(segments), np.arange(sides), indexing="ij")
    i2, j2 = (i + 1) % segments, (j + 1) % sides
    q00, q10, q11, q01 = i * sides + j, i2 * sides + j, i2 * sides + j2, i * sides + j2
    tris = np.concatenate((np.stack((q00, q10, q11), -1).reshape(-1, 3), np.stack((q00, q11, q01), -1).reshape(-1, 3)))
    return Shape(v, n, tris)


def rod(length: float, radius: float, sides: int = 8) -> Shape:
    """An open cylinder from the origin along +z, `length` long (a thin line in the scene);
    `length <= 0` gives an empty Shape."""
    if length <= 0.0 or not math.isfinite(length):
        return Shape.empty()
    if radius <= 0.0 or sides < 3:
        raise ValueError("need radius > 0 and sides >= 3")
    i = np.arange(sides)
    j = (i + 1) % sides
    radial = np.column_stack((np.cos(2 * np.pi * i / sides), np.sin(2 * np.pi * i / sides), np.zeros(sides)))
    v = np.concatenate((_ring(radius, 0.0, sides), _ring(radius, length, sides)))
    tris = np.concatenate((np.column_stack((i, j, j + sides)), np.column_stack((i, j + sides, i + sides))))
    return Shape(v, np.concatenate((radial, radial)), tris)
