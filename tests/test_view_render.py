"""What the participant view draws, checked pixel by pixel offscreen (EGL, no display): the brain
where the camera projects it, filling the view's height, the grasped patch, the instruments
following the hands, legible text, picking; with open3d as the independent reference for the
ray cast and the normals."""

import numpy as np
import pytest

from sim.view.window import PATCH, TISSUE, HandState

FAR = (5.0, 5.0, 5.0)  # a hand out of the picture: no instrument in the way


@pytest.fixture(scope="module")
def mesh():
    from sim.geometry.mesh import load_mesh

    return load_mesh()


@pytest.fixture(scope="module")
def view(mesh):
    from sim.view.window import ParticipantView

    v = ParticipantView(mesh, width=640, height=360, visible=False)
    yield v
    v.close()


def _chroma(rgb) -> np.ndarray:
    rgb = np.asarray(rgb, dtype=np.float64)
    return rgb / rgb.sum(axis=-1, keepdims=True)


def _visible(view, mesh, n: int, seed: int = 0) -> np.ndarray:
    """Vertices that face the camera and that nothing hides (the first surface a ray from the
    eye meets), away from the silhouette."""
    from sim.view.camera import ray_hit

    rng = np.random.default_rng(seed)
    out = []
    normals = mesh.vertex_normals
    for v in rng.permutation(mesh.n_vertices):
        p = mesh.vertices[v]
        d = p - view.camera.eye
        dist = np.linalg.norm(d)
        if normals[v] @ (-d / dist) < 0.6:
            continue
        if abs(ray_hit(view.camera.eye, d / dist, mesh.vertices, mesh.triangles) - dist) < 1e-4:
            out.append(v)
        if len(out) == n:
            break
    return np.asarray(out)


def test_each_marked_vertex_is_drawn_at_its_projected_pixel_and_the_brain_fills_the_height(view, mesh):
    """A small heat mark (a different colour) around each of 12 visible vertices lands on the
    pixel the camera's K, R, t put the vertex; the brain at rest spans the view's height."""
    vertices = _visible(view, mesh, 12)
    assert len(vertices) == 12
    heat = np.zeros(mesh.n_vertices)
    for v in vertices:
        heat[np.linalg.norm(mesh.vertices - mesh.vertices[v], axis=1) < 0.003] = 1.0
    view.set_text(top="", bottom="", center="", corner="")
    view.draw(None, [HandState(FAR)], heat01=heat)
    img = view.image()
    uv = view.camera.project(mesh.vertices[vertices])
    mark = _chroma(view.cmap(0.95)[:3])
    for u, v, _ in uv:
        px = img[int(v), int(u)]
        assert np.abs(_chroma(px) - mark).max() < 0.05, (u, v, px)
    # the same pixels, unmarked: tissue (the mark's colour came from the vertex, not the place)
    view.draw(None, [HandState(FAR)])
    img = view.image()
    for u, v, _ in uv:
        assert np.abs(_chroma(img[int(v), int(u)]) - _chroma(TISSUE)).max() < 0.02
    rows = np.flatnonzero(np.any(np.all(img < 245, axis=2), axis=1))
    assert rows[-1] - rows[0] > 0.85 * view.height  # the camera's fit: 92% of the height


def test_the_grasped_patch_is_coloured_around_the_grasped_vertex(view, mesh):
    v = _visible(view, mesh, 1, seed=3)[0]
    u, w, _ = view.camera.project(mesh.vertices[v])[0]
    view.draw(None, [HandState(FAR, grasped_vertex=int(v))])
    img = view.image()
    assert np.abs(_chroma(img[int(w), int(u)]) - _chroma(PATCH)).max() < 0.03
    blue = np.abs(_chroma(img) - _chroma(PATCH)).max(axis=2) < 0.05
    ys, xs = np.nonzero(blue)
    assert 10 < blue.sum() < 2000  # a patch, centred on it
    assert np.hypot(xs.mean() - u, ys.mean() - w) < 6
    view.draw(None, [HandState(FAR)])  # let go: no patch
    assert (np.abs(_chroma(view.image()) - _chroma(PATCH)).max(axis=2) < 0.05).sum() == 0


def _steel(img) -> np.ndarray:
    """Pixels of the instruments: grey-blue steel, unlike the warm tissue and the white ground."""
    f = img.astype(np.float64)
    return (f[:, :, 2] > f[:, :, 0] + 4) & (f.max(axis=2) < 250) & (f.max(axis=2) > 40)


def test_the_instruments_follow_the_hands_and_close_on_a_grasp(view, mesh):
    right = view.camera.R[0]
    p = mesh.vertices[_visible(view, mesh, 1, seed=5)[0]] - 0.03 * view.camera.R[2]  # 3 cm above the surface: nothing hides the tips
    centres = []
    for dx in (0.0, 0.02):
        view.draw(None, [HandState(tuple(p + dx * right)), HandState(FAR)])
        ys, xs = np.nonzero(_steel(view.image()))
        assert len(xs) > 300
        centres.append((xs.mean(), ys.mean()))
    moved = view.camera.project(p + 0.02 * right)[0, 0] - view.camera.project(p)[0, 0]
    assert moved > 30
    assert abs(centres[1][0] - centres[0][0] - moved) < 0.15 * moved
    assert abs(centres[1][1] - centres[0][1]) < 0.2 * moved  # sideways only (the brain hides a little more or less)
    # the open tips sit either side of the hand (3.3 mm, about 7 px here): steel within 10 px of its projection
    u, w, _ = view.camera.project(p + 0.02 * right)[0]
    near = _steel(view.image())[int(w) - 10:int(w) + 11, int(u) - 10:int(u) + 11]
    assert near.sum() > 10
    opened = view.image()
    view.draw(None, [HandState(tuple(p + 0.02 * right), holding=True), HandState(FAR)])  # no patch: only the jaws change
    closed = view.image()
    assert np.abs(_steel(opened).astype(int) - _steel(closed)).sum() > 300  # the blades turned about the hinge (2013 px here)


def test_a_late_latch_draws_the_newest_hand_positions_and_forces(mesh):
    """`draw(latch=)`: the instrument and the force arrow are drawn where the latch says the hand
    is now, not where the visual step saw it; motion-to-photon runs from the latch's read."""
    import time

    from sim.view.window import ParticipantView

    v = ParticipantView(mesh, width=640, height=360, visible=False, show_force=True)
    try:
        lifted = mesh.vertices[3386] - 0.03 * v.camera.R[2]
        now = lifted + 0.03 * v.camera.R[0]
        v.draw(None, [HandState(tuple(now), (0.5, 0.0, 0.0))])
        want = v.image()
        read = time.perf_counter()
        v.draw(None, [HandState(tuple(lifted))], read_t=0.0, latch=lambda: ([tuple(now)], [(0.5, 0.0, 0.0)], read))
        assert np.array_equal(v.image(), want)
        assert v.text()["corner"] == "force:  hand 0.50 N"
        assert 0 < v.motion_to_photon_s[-1] < time.perf_counter() - read + 1e-9
    finally:
        v.close()


def test_text_pixels_are_the_font_atlas_glyphs_where_the_layout_puts_them(view):
    """Every glyph of a status line and an instruction, drawn over white: its pixels are the
    atlas bitmap blended onto the background, to 2 levels, at the laid-out place."""
    view.set_text(top="Condition B (2 of 3) - trial 1 of 3", bottom="", center="", corner="")
    view.draw(None, [HandState(FAR)])
    img = view.image().astype(np.int64)
    (text, x, y, px, colour, align), = view.layout()
    quads, atlas = view.gl.text_quads(text, x, y, px, align)
    assert len(quads) == len(text.replace(" ", ""))
    H, W = atlas.image.shape
    ink = 0
    for x0, y0, x1, y1, s0, t0, s1, t1 in quads:
        cov = atlas.image[round(t0 * H):round(t1 * H), round(s0 * W):round(s1 * W)].astype(np.float64) / 255.0
        want = 255.0 - cov[:, :, None] * (255.0 - 255.0 * np.asarray(colour))
        got = img[int(y0):int(y1), int(x0):int(x1)]
        assert got.shape == want.shape
        assert np.abs(got - want).max() <= 2.0
        ink += int((cov > 0.5).sum())
    assert ink > 200
    view.set_text(top="")


def test_a_resized_view_refits_the_camera_and_lays_the_text_out_again(mesh):
    from sim.view.window import ParticipantView

    v = ParticipantView(mesh, width=400, height=300, visible=False)
    try:
        v.set_text(bottom="Pull the brain freely")
        before = v.layout()[0]
        v.resize(800, 800)  # now the width limits: the brain fills 92% of it
        v.draw(None, [])
        img = v.image()
        assert img.shape == (800, 800, 3)
        cols = np.flatnonzero(np.any(np.all(img < 245, axis=2), axis=0))
        rows = np.flatnonzero(np.any(np.all(img < 245, axis=2), axis=1))
        assert max(cols[-1] - cols[0], rows[-1] - rows[0]) > 0.85 * 800
        after = v.layout()[0]
        assert after[1] == 400  # centred, at the bottom, larger
        assert after[2] > before[2] + 400
        assert after[3] > before[3]
    finally:
        v.close()


def test_picking_agrees_with_open3d_raycasting(view, mesh):
    import open3d as o3d

    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(mesh.vertices.astype(np.float32), mesh.triangles.astype(np.uint32))
    view.draw(None, [])
    hits = 0
    for u, v in [(320, 180), (250, 120), (400, 260), (20, 20), (330, 60), (280, 300)]:
        mine = view.pick(u, v)
        d = view.camera.ray(u, v)
        t = float(scene.cast_rays(o3d.core.Tensor([[*view.camera.eye, *d]], dtype=o3d.core.Dtype.Float32))["t_hit"].numpy()[0])
        if not np.isfinite(t):
            assert mine is None
            continue
        hits += 1
        assert np.linalg.norm(mine - (view.camera.eye + t * d)) < 1e-5
    assert hits >= 4


def test_vertex_normals_agree_with_open3d(mesh):
    import open3d as o3d

    from sim.view.normals import vertex_normals

    u = np.random.default_rng(2).normal(0, 0.002, mesh.vertices.shape)
    X = mesh.vertices + u
    o = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(X), o3d.utility.Vector3iVector(mesh.triangles))
    o.compute_vertex_normals()
    assert np.abs(vertex_normals(X, mesh.triangles) - np.asarray(o.vertex_normals)).max() < 1e-6


def test_pictures_equal_a_fresh_render(mesh):
    """The offscreen framebuffer read as drawn (a picture) equals a render of the same state by
    another view from scratch, pixel for pixel, over changing deformations, hands and colours."""
    from sim.view.window import ParticipantView

    a = ParticipantView(mesh, width=320, height=240, visible=False, show_force=True)
    b = ParticipantView(mesh, width=320, height=240, visible=False, show_force=True)
    try:
        hands = [HandState(tuple(mesh.vertices[3386]), (0.3, 0.1, 0.0), 3386), HandState(tuple(mesh.vertices[13629]))]
        for k in range(5):
            u = np.zeros_like(mesh.vertices)
            u[:, 0] = 0.004 * k
            heat = np.linspace(0, 1, mesh.n_vertices) * (k % 3) / 2 if k < 4 else None  # and back to plain tissue
            a.set_text(top=f"trial {k + 1}")
            a.draw(u, hands[: 1 + k % 2], heat01=heat)
            b.draw(np.zeros_like(u), [])  # something else first
            b.set_text(top=f"trial {k + 1}")
            b.draw(u, hands[: 1 + k % 2], heat01=heat)
            b._fresh = False  # b draws again before it is read
            assert np.array_equal(a.image(), b.image())
    finally:
        a.close()
        b.close()
