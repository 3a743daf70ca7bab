"""The view's instrument and arrow meshes (sim/view/shapes.py): well-formed, closed, outward-facing,
the right size, and placed by a right-handed frame."""

import math

import numpy as np
import pytest

from sim.view.shapes import Shape, _blade_pose, _check_opening, arrow, forceps, forceps_parts, frame, transform

OPENINGS = (0.0, 0.3, 0.5, 1.0)


def _all_shapes():
    yield "arrow(0.05)", arrow(0.05)
    yield "arrow(0.004)", arrow(0.004)
    yield "arrow(0.05, sides=32)", arrow(0.05, sides=32)
    for o in OPENINGS:
        yield f"forceps({o})", forceps(o)


def _closed_parts():
    yield "arrow(0.05)", arrow(0.05)
    yield "arrow(0.004)", arrow(0.004)
    yield "arrow(0.02, sides=5)", arrow(0.02, sides=5)
    for o in OPENINGS:
        for name, part in zip(("blade+y", "blade-y", "hinge"), forceps_parts(o)):
            yield f"forceps({o}) {name}", part


def _merged_edges(shape: Shape) -> np.ndarray:
    """Undirected edges after merging vertices that coincide to 1e-7 m."""
    key = np.round(shape.vertices.astype(np.float64) / 1e-7).astype(np.int64)
    _, ids = np.unique(key, axis=0, return_inverse=True)
    t = ids.reshape(-1)[shape.triangles]
    e = np.concatenate((t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]))
    return np.sort(e, axis=1)


def _signed_volume(shape: Shape) -> float:
    v = shape.vertices.astype(np.float64)[shape.triangles]
    return float(np.einsum("ij,ij->i", v[:, 0], np.cross(v[:, 1], v[:, 2])).sum() / 6)


def _ngon_area(r: float, n: int) -> float:
    return 0.5 * n * r * r * math.sin(2 * math.pi / n)


@pytest.mark.parametrize("name,shape", list(_all_shapes()), ids=lambda x: x if isinstance(x, str) else "")
def test_well_formed(name, shape):
    v, n, t = shape.vertices, shape.normals, shape.triangles
    assert v.dtype == np.float32
    assert n.dtype == np.float32
    assert t.dtype == np.int32
    assert v.shape == n.shape
    assert v.shape[1] == 3
    assert t.shape[1] == 3
    assert len(t) > 0
    assert np.all(np.isfinite(v))
    assert np.all(np.isfinite(n))
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-5)
    assert t.min() >= 0
    assert t.max() < len(v)
    p = v.astype(np.float64)[t]
    geo = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    area = 0.5 * np.linalg.norm(geo, axis=1)
    assert area.min() > 1e-12, f"{name}: a degenerate triangle"  # the smallest real ones are ~1e-8 m^2
    # winding faces the way the normals do: outward
    mean_n = n.astype(np.float64)[t].mean(axis=1)
    assert np.all(np.einsum("ij,ij->i", geo, mean_n) > 0), f"{name}: a triangle wound inward"


@pytest.mark.parametrize("name,shape", list(_closed_parts()), ids=lambda x: x if isinstance(x, str) else "")
def test_closed_and_positive(name, shape):
    _, counts = np.unique(_merged_edges(shape), axis=0, return_counts=True)
    assert np.all(counts == 2), f"{name}: an edge used {sorted(set(counts.tolist()))} times"
    assert _signed_volume(shape) > 0


@pytest.mark.parametrize("length", [0.05, 0.02, 0.004])
def test_arrow_volume_exact_for_its_polygons(length):
    sides, rs, rh, hl = 32, 0.0016, 0.0035, 0.010
    shape = arrow(length, sides=sides)
    if length < 2.5 * hl:  # a short arrow is the 2.5-head-length arrow scaled down
        k = length / (2.5 * hl)
        rs, rh, hl = rs * k, rh * k, 0.4 * length
    prism = _ngon_area(rs, sides) * (length - hl)
    pyramid = _ngon_area(rh, sides) * hl / 3
    assert _signed_volume(shape) == pytest.approx(prism + pyramid, rel=1e-6)
    # and close to the round solid it stands for
    round_ = math.pi * rs**2 * (length - hl) + math.pi * rh**2 * hl / 3
    assert _signed_volume(shape) == pytest.approx(round_, rel=0.02)


def test_arrow_lengths():
    assert arrow(0.05).vertices[:, 2].max() == pytest.approx(0.05, abs=1e-9)
    assert arrow(0.05).vertices[:, 2].min() == pytest.approx(0.0, abs=1e-12)
    short = arrow(0.004)
    assert short.vertices[:, 2].max() == pytest.approx(0.004, abs=1e-9)
    # proportions kept: the head is 0.4 of it, and it is no wider than the arrow is long
    assert np.ptp(short.vertices[:, 0]) < 0.004
    for empty in (arrow(0.0), arrow(-0.01)):
        assert empty.vertices.shape == (0, 3)
        assert empty.normals.shape == (0, 3)
        assert empty.triangles.shape == (0, 3)
        assert empty.vertices.dtype == np.float32
        assert empty.triangles.dtype == np.int32


def test_arrow_bad_input():
    with pytest.raises(ValueError):
        arrow(float("nan"))
    with pytest.raises(ValueError):
        arrow(0.05, shaft_radius=0.004, head_radius=0.003)
    with pytest.raises(ValueError):
        arrow(0.05, sides=2)


def _tip_points(blade: Shape) -> tuple[np.ndarray, np.ndarray]:
    """(centre of the tip end, centre of its gripping edge) read off the mesh: the tip section's
    four corners are the only vertices within 1 mm of z = 0."""
    v = blade.vertices.astype(np.float64)
    corners = np.unique(v[v[:, 2] < 0.001], axis=0)
    assert len(corners) == 4
    inner = corners[np.argsort(np.abs(corners[:, 1]))[:2]]
    return corners.mean(axis=0), inner.mean(axis=0)


def test_forceps_closed_tips_meet_at_origin():
    plus, minus, _ = forceps_parts(0.0)
    (_, a), (_, b) = _tip_points(plus), _tip_points(minus)
    assert np.linalg.norm(a) < 3e-4
    assert np.linalg.norm(b) < 3e-4
    assert np.linalg.norm(a - b) < 3e-4
    np.testing.assert_allclose(forceps_tips(0.0), [a, b], atol=1e-6)


def test_forceps_open_gap():
    plus, minus, _ = forceps_parts(1.0)
    (ca, ia), (cb, ib) = _tip_points(plus), _tip_points(minus)
    assert 0.005 <= ca[1] - cb[1] <= 0.007  # tip centres
    assert 0.005 <= ia[1] - ib[1] <= 0.007  # gripping faces
    np.testing.assert_allclose(forceps_tips(1.0), [ia, ib], atol=1e-6)
    # only the tips part: the hinge end does not move
    closed = forceps(0.0).vertices
    opened = forceps(1.0).vertices
    far = closed[:, 2] > 0.075
    np.testing.assert_allclose(opened[far][:, 1], closed[far][:, 1], atol=2e-4)
    # the gap grows with the opening, and the opening is clipped to [0, 1]
    gaps = [np.ptp(forceps_tips(o)[:, 1]) for o in (0.0, 0.25, 0.5, 0.75, 1.0)]
    assert np.all(np.diff(gaps) > 0)
    np.testing.assert_allclose(forceps_tips(1.5), forceps_tips(1.0))
    np.testing.assert_allclose(forceps_tips(-0.2), forceps_tips(0.0))
    with pytest.raises(ValueError):
        forceps(float("nan"))


@pytest.mark.parametrize("opening", OPENINGS)
def test_forceps_size(opening):
    s = forceps(opening)
    lo, hi = s.vertices.min(axis=0), s.vertices.max(axis=0)
    assert 0.080 <= hi[2] - lo[2] <= 0.095
    assert abs(lo[2]) < 3e-4  # the tips at z = 0, the handle along +z
    assert hi[0] - lo[0] < 0.012
    assert s.n_vertices < 2000
    # the blades open along y: the tips are farther apart in y than in x
    assert abs(forceps_tips(opening)[:, 0]).max() < 1e-9


def _rotations():
    rng = np.random.default_rng(3)
    for _ in range(20):
        yield rng.normal(size=3), rng.normal(size=3)
    yield [0, 0, 1], [0, 1, 0]
    yield [0, 0, -2], [1, 1, 5]  # a side with a large component along the axis


@pytest.mark.parametrize("axis,side", list(_rotations()))
def test_frame(axis, side):
    R = frame(axis, side)
    np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-12)
    assert np.linalg.det(R) == pytest.approx(1.0)
    a = np.asarray(axis, float)
    np.testing.assert_allclose(R[:, 2], a / np.linalg.norm(a), atol=1e-12)
    s = np.asarray(side, float)
    assert R[:, 1] @ s > 0  # the second column is side's direction, not its opposite
    np.testing.assert_allclose(np.cross(R[:, 2], R[:, 1]) @ s, 0.0, atol=1e-12)  # and in its plane


@pytest.mark.parametrize(
    "axis,side",
    [([0, 0, 0], [1, 0, 0]), ([0, 0, 1], [0, 0, 3]), ([0, 0, 1], [0, 0, -1]), ([1, 2, 3], [0, 0, 0]), ([np.nan, 0, 1], [1, 0, 0])],
)
def test_frame_bad_input(axis, side):
    with pytest.raises(ValueError):
        frame(axis, side)


def test_transform_places_forceps():
    """The forceps' axis and opening direction land where the frame says."""
    axis, side, t = np.array([1.0, 1.0, 0.0]), np.array([0.0, 0.0, 1.0]), np.array([0.1, -0.2, 0.3])
    R = frame(axis, side)
    s = forceps(1.0)
    v, n = transform(s, R, t)
    assert v.dtype == np.float32
    assert n.dtype == np.float32
    np.testing.assert_allclose(v, s.vertices.astype(np.float64) @ R.T + t, atol=1e-7)
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-5)
    tips = forceps_tips(1.0) @ R.T + t
    gap = tips[0] - tips[1]
    assert gap @ side / np.linalg.norm(gap) == pytest.approx(1.0, abs=1e-6)  # jaws open along `side`
    handle = v[np.argmax(s.vertices[:, 2])]
    assert (handle - t) @ axis > 0  # the handle runs along `axis`
    with pytest.raises(ValueError):
        transform(s, np.eye(2), t)


def forceps_tips(opening: float) -> np.ndarray:
    """The two jaw points (centre of each blade's gripping face at its tip), (2, 3) float64:
    (+y blade, -y blade). Both at the origin when closed."""
    R, t = _blade_pose(_check_opening(opening))
    tip = t.copy()  # the +y jaw point is the origin before turning
    return np.array([tip, tip * [1.0, -1.0, 1.0]])
