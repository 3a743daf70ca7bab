"""The participant view: a real window with the deforming brain, both virtual hands, the grasped
patch, and on-screen text (instructions, condition and trial, countdowns, rest screens).

Which renderer: open3d's classic OpenGL `Visualizer` (with key and mouse callbacks) opens a real
window under Xvfb or on a lab display and draws the whole brain at 1280x720 in about 50-75 ms
per frame on Mesa's CPU driver here; the Filament renderer took 2-30 s per frame on the CPU.
The classic renderer has no 2D text overlay, so text is drawn as flat glyph meshes
(`open3d.t.geometry.TriangleMesh.create_text`) laid in a plane just in front of the fixed
camera, sized in pixels: no second window or compositing pass, and one renderer for all.

The view never names a tissue model: callers give it only participant-facing text. It is drawn
by the visual side of a run (sim/run.py); the servo runs in its own process and never waits for
it. With a mouse device, the pointer drives the hands (left button: left hand, right button:
right hand; drag in the view plane, wheel in depth) and the force that would be felt is drawn
as an arrow and a number.

For a questionnaire the window shows a rating scale (boxes with their numbers, the anchors under
the two ends; also used for the choice among blind labels) or a visual analogue scale (a line
with its anchors, and a mark the person sets with the mouse): `show_scale`, `show_slider`. In
questionnaire mode (`set_questionnaire`, on while a question is asked) the mouse answers
questions; and a click grasps the brain only while a run is drawn (`draw`), never on a still
screen (`idle`: a rest screen, questions asked in the window or in the terminal).
"""

from __future__ import annotations

import os
import tempfile
import time
from dataclasses import dataclass, field

import numpy as np

from sim.errors import ViewError

SKIN = (0.93, 0.76, 0.63)
TISSUE = np.array([0.88, 0.80, 0.78])
PATCH = np.array([0.20, 0.55, 0.95])  # the grasped patch
TEXT = (0.05, 0.05, 0.12)
ACCENT = (0.70, 0.10, 0.05)
ARROW = (0.85, 0.15, 0.10)
PANEL = (0.96, 0.96, 0.97)  # behind a questionnaire widget
BOX = (0.86, 0.89, 0.94)  # a point of a scale
BORDER = (0.35, 0.38, 0.45)
SELECTED = (0.12, 0.40, 0.85)  # the chosen point, the slider's mark
WHITE = (1.0, 1.0, 1.0)
# GLFW key codes -> names the callers use: the top row's digits and the keypad's give the same
# names ("0".."9"), as do Enter and the keypad's Enter
KEYS = {32: "space", 257: "enter", 335: "enter", 256: "escape", 259: "backspace", 262: "right", 263: "left",
        **{ord(c): c.lower() for c in "ABCDEFGHIJKLMNOPQRSTUVWXYZ"},
        **{48 + k: str(k) for k in range(10)}, **{320 + k: str(k) for k in range(10)}}
FORCE_ARROW_M_PER_N = 0.08
WHEEL_M = 0.002  # depth per wheel step


def hand_mesh():
    """A stylised pinching hand, fingertips at the origin, +x along the pull, +z up (metres)."""
    import open3d as o3d

    parts = []
    for k, y in enumerate((-0.013, -0.0045, 0.0045, 0.013)):  # four fingers
        length = 0.036 - 0.003 * abs(k - 1.5)
        f = o3d.geometry.TriangleMesh.create_cylinder(radius=0.0042, height=length, resolution=12)
        f.translate((0.0, y, length / 2 + 0.003))
        parts.append(f)
        tip = o3d.geometry.TriangleMesh.create_sphere(radius=0.0042, resolution=8)
        tip.translate((0.0, y, 0.003))
        parts.append(tip)
    palm = o3d.geometry.TriangleMesh.create_box(width=0.016, height=0.040, depth=0.032)
    palm.translate((-0.008, -0.020, 0.036))
    parts.append(palm)
    thumb = o3d.geometry.TriangleMesh.create_cylinder(radius=0.0048, height=0.034, resolution=12)
    thumb.rotate(o3d.geometry.get_rotation_matrix_from_xyz((0.0, -0.6, 0.0)), center=(0, 0, 0))
    thumb.translate((-0.012, 0.0, 0.018))
    parts.append(thumb)
    wrist = o3d.geometry.TriangleMesh.create_cylinder(radius=0.012, height=0.040, resolution=16)
    wrist.translate((0.0, 0.0, 0.088))
    parts.append(wrist)
    mesh = parts[0]
    for p in parts[1:]:
        mesh += p
    mesh.scale(0.7, center=(0.0, 0.0, 0.0))
    mesh.paint_uniform_color(SKIN)
    return mesh


def hand_pose(point, direction) -> np.ndarray:
    x = np.asarray(direction, dtype=np.float64)
    x = x - x[2] * np.array([0.0, 0.0, 1.0])
    x = x / np.linalg.norm(x) if np.linalg.norm(x) > 1e-9 else np.array([1.0, 0.0, 0.0])
    z = np.array([0.0, 0.0, 1.0])
    y = np.cross(z, x)
    T = np.eye(4)
    T[:3, 0], T[:3, 1], T[:3, 2], T[:3, 3] = x, y, z, point
    return T


@dataclass
class HandState:
    """What the view draws of one hand."""

    position: tuple
    force: tuple = (0.0, 0.0, 0.0)
    grasped_vertex: int | None = None


@dataclass
class Widget:
    """A questionnaire widget: a `scale` (labels in boxes side by side: a rating's points, or
    blind condition labels) or a `slider` (a visual analogue scale, 0..100). Geometry in window
    pixels (x right, y down), as the mouse reports them."""

    kind: str  # "scale" or "slider"
    labels: tuple[str, ...] = ()
    anchors: tuple[str, str] | None = None
    selected: int | None = None  # scale: index of the chosen box (None: none yet)
    value: float | None = None  # slider: the mark, 0..100 (None: not set yet; there is no default)
    confirmed: bool = False  # scale: the chosen box was clicked again
    boxes: list = field(default_factory=list)  # scale: (u0, v0, u1, v1) of each label's box
    line: tuple = ()  # slider: (u0, u1, v), the line from 0 to 100
    dragging: bool = False

    def value_at(self, u: float) -> float:
        """The slider's value at pixel column u (0 at the left end, 100 at the right, 0.1 steps)."""
        u0, u1, _ = self.line
        return round(min(max((u - u0) / (u1 - u0), 0.0), 1.0) * 100.0, 1)


class ParticipantView:
    """One window reused for a whole session (or an offscreen one with `visible=False`)."""

    def __init__(self, mesh, pulls=((-1.0, 0.0, 0.0), (1.0, 0.0, 0.0)), width: int = 1280, height: int = 720,
                 visible: bool = True, title: str = "Brain surgery simulator", show_force: bool = False,
                 grasp_radius: float = 0.005, camera=None):
        import open3d as o3d

        self.o3d = o3d
        o3d.utility.set_verbosity_level(o3d.utility.VerbosityLevel.Error)
        # Mesa's CPU rasteriser: a thread per core but one, which the servo process keeps
        os.environ.setdefault("LP_NUM_THREADS", str(max(1, len(os.sched_getaffinity(0)) - 1)))
        if not os.environ.get("XDG_RUNTIME_DIR"):
            os.environ["XDG_RUNTIME_DIR"] = tempfile.mkdtemp(prefix="xdg-")
        headless = not os.environ.get("DISPLAY") and not os.environ.get("WAYLAND_DISPLAY")
        if visible and headless:
            raise ViewError("--view window: no display (DISPLAY is not set); run on a desktop, or under xvfb-run")
        self.mesh = mesh
        self._fresh = False  # the framebuffer holds the scene as it is now (rendered since the last change)
        # reading that framebuffer gives the frame: only offscreen without a display (EGL), and
        # checked once (`image`); a window's back buffer is undefined after a swap
        self._read_ok: bool | None = None if headless and not visible else False
        self.width, self.height = width, height
        self.show_force = show_force
        self.vis = o3d.visualization.VisualizerWithKeyCallback()
        if not self.vis.create_window(window_name=title, width=width, height=height, visible=visible):
            raise ViewError(f"--view window: open3d could not open a {width}x{height} OpenGL window on display "
                            f"{os.environ.get('DISPLAY')!r}")
        opt = self.vis.get_render_option()
        opt.background_color = np.array([1.0, 1.0, 1.0])
        opt.mesh_show_back_face = False  # culling halves the fill work of Mesa's CPU rasteriser
        opt.light_on = True
        self.brain = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(mesh.vertices), o3d.utility.Vector3iVector(mesh.triangles))
        self.brain.vertex_colors = o3d.utility.Vector3dVector(np.tile(TISSUE, (mesh.n_vertices, 1)))
        self.brain.compute_vertex_normals()
        self.vis.add_geometry(self.brain)
        lo, hi = mesh.bounds()
        self.center = (lo + hi) / 2.0
        self.radius = float(np.linalg.norm(hi - lo)) / 2.0
        ctr = self.vis.get_view_control()
        ctr.set_lookat(self.center)
        from sim.scene import ViewSpec

        camera = camera or ViewSpec()  # front, up, zoom: the scene's [view]
        ctr.set_front(list(camera.front))
        ctr.set_up(list(camera.up))
        ctr.set_zoom(camera.zoom)
        self.vis.poll_events()
        self.vis.update_renderer()
        cam = ctr.convert_to_pinhole_camera_parameters()
        self.K = np.asarray(cam.intrinsic.intrinsic_matrix, dtype=np.float64)
        E = np.asarray(cam.extrinsic, dtype=np.float64)
        # open3d reports the up vector as set, not orthogonalised as OpenGL's look-at uses it:
        # rebuild the camera's orthonormal frame (x right, y down the image, z forward)
        self.eye = -np.linalg.solve(E[:3, :3], E[:3, 3])
        forward = self.center - self.eye
        forward /= np.linalg.norm(forward)
        right = np.cross(forward, np.asarray(camera.up, dtype=np.float64))
        right /= np.linalg.norm(right)
        self.R = np.stack([right, np.cross(forward, right), forward])
        self.t = -self.R @ self.eye
        # text lies in a plane between the camera and everything else, so nothing hides it
        self.text_depth = 0.3 * max(float(np.linalg.norm(self.eye - self.center)) - self.radius, 0.02)
        self._hand_rest = hand_mesh()
        self._hand_rest.scale(0.6, center=(0.0, 0.0, 0.0))  # the surgeon's view is closer than the pictures'
        self._hand_vertices = np.asarray(self._hand_rest.vertices).copy()
        self.pulls = [np.asarray(p, dtype=np.float64) for p in pulls]
        self.hands = []
        self.arrows = []
        arrow = o3d.geometry.TriangleMesh.create_arrow(cylinder_radius=0.0016, cone_radius=0.0035, cylinder_height=0.75, cone_height=0.25)
        arrow.paint_uniform_color(ARROW)
        self._arrow_vertices = np.asarray(arrow.vertices).copy()  # along +z, length 1
        self._arrow_rest = arrow
        from scipy.spatial import cKDTree

        self._rest_tree = cKDTree(mesh.vertices)
        import matplotlib

        self.cmap = matplotlib.colormaps["inferno"]
        self.grasp_radius = grasp_radius
        self._texts: dict[str, tuple[str, object]] = {}
        self._positions = mesh.vertices
        self.keys: list[str] = []
        for code, name in KEYS.items():
            self.vis.register_key_callback(code, lambda vis, name=name: self.keys.append(name) or False)
        self.vis.register_mouse_button_callback(self._on_button)
        self.vis.register_mouse_move_callback(self._on_move)
        self.vis.register_mouse_scroll_callback(self._on_scroll)
        self.pointer = (width / 2.0, height / 2.0)
        self.inputs: dict[int, list] = {}  # hand -> [target, pressed, depth]
        self.questionnaire = False  # the mouse answers questions, never grasps
        self._running = False  # frames of a run are drawn (draw), not a still screen (idle): a click may grasp
        self.widget: Widget | None = None
        self._widget_meshes: list = []
        self._widget_dirty = False
        self.n_hands = len(pulls)
        self.closed = False
        self.frames = 0
        self.frame_s: list[float] = []
        self.prepare_s: list[float] = []
        self.motion_to_photon_s: list[float] = []
        self.first_frame_at: float | None = None
        self.last_frame_at: float | None = None

    # -- text --------------------------------------------------------------------------------
    def set_text(self, **slots: str | None) -> None:
        """Slots: top (status line), center (the main message, large), question (a question of
        the questionnaire), bottom (instructions), corner (bottom right: forces). '' or None
        clears a slot."""
        self._fresh = False
        layout = {"top": (24, 34, 22, TEXT, "left"), "center": (self.width / 2, 92, 34, ACCENT, "center"),
                  "bottom": (self.width / 2, self.height - 30, 20, TEXT, "center"),
                  "corner": (self.width - 24, self.height - 62, 18, ARROW, "right"),
                  "question": (self.width / 2, 92, 24, TEXT, "center"),
                  "notice": (24, self.height - 62, 18, ACCENT, "left")}
        for slot, text in slots.items():
            text = text or ""
            old = self._texts.get(slot)
            if old is not None and old[0] == text:
                continue
            if old is not None:
                self.vis.remove_geometry(old[1], reset_bounding_box=False)
                del self._texts[slot]
            if text:
                u, v, px, colour, align = layout[slot]
                m = self._text_mesh(text, u, v, px, colour, align)
                self.vis.add_geometry(m, reset_bounding_box=False)
                self._texts[slot] = (text, m)

    def text(self) -> dict[str, str]:
        """What the window shows as text now (tests read it to check no model is named); a
        questionnaire widget's labels, anchors and value are under "widget"."""
        out = {k: v[0] for k, v in self._texts.items()}
        w = self.widget
        if w is not None:
            parts = list(w.labels) + list(w.anchors or ()) + ([f"{w.value:g}"] if w.value is not None else [])
            out["widget"] = "  ".join(parts)
        return out

    def _text_mesh(self, text: str, u: float, v: float, px: float, colour, align: str, max_width: float | None = None,
                   depth: float | None = None):
        """Glyphs of `text` `px` high (the cell; capitals are 0.62 px) with their baseline near
        v - px / 4, aligned left, right, center or middle (the ink's middle) at u; made smaller
        to fit `max_width` pixels."""
        o3d = self.o3d
        m = o3d.t.geometry.TriangleMesh.create_text(text.encode("ascii", "replace").decode()).to_legacy()
        V = np.asarray(m.vertices, dtype=np.float64)
        if len(V) == 0:
            return m
        if max_width is not None and V[:, 0].max() * px / 16.0 > max_width:
            px = max_width / V[:, 0].max() * 16.0
        scale_px = px / 16.0  # glyph units (a 16-unit cell) to pixels
        width_px = V[:, 0].max() * scale_px
        lines = text.count("\n") + 1
        if align == "middle":
            u0 = u - (V[:, 0].min() + V[:, 0].max()) / 2 * scale_px
        else:
            u0 = u - (width_px / 2 if align == "center" else width_px if align == "right" else 0.0)
        z = self.text_depth if depth is None else depth
        origin = self.R.T @ (z * np.linalg.solve(self.K, [u0, v - (lines - 1) * px * 1.2, 1.0]) - self.t)
        metre = z / self.K[1, 1] * scale_px  # one glyph unit at that depth, in metres
        right, up = self.R[0], -self.R[1]  # camera y points down the image
        m.vertices = o3d.utility.Vector3dVector(origin + metre * (V[:, 0:1] * right + V[:, 1:2] * up))
        m.triangles = o3d.utility.Vector3iVector(np.asarray(m.triangles)[:, ::-1].copy())  # glyphs wind away from +z: face the camera
        m.paint_uniform_color(colour)
        m.compute_vertex_normals()
        return m

    # -- drawing -----------------------------------------------------------------------------
    def draw(self, displacement, hands: list[HandState], read_t: float | None = None, heat01=None) -> None:
        """Draw one frame and present it. `read_t` (perf_counter) is when the devices were read
        for this state: motion-to-photon is measured from there to the presented frame.
        `heat01` (per vertex, 0..1) colours the tissue by it (the analyst's pictures)."""
        o3d = self.o3d
        start = time.perf_counter()
        u = np.zeros_like(self.mesh.vertices) if displacement is None else np.asarray(displacement, dtype=np.float64)
        self._positions = self.mesh.vertices + u
        if heat01 is not None:  # the analyst's pictures (a participant sees plain tissue): tissue colour, then inferno
            heat = np.asarray(heat01, dtype=np.float64)
            w = np.clip(heat * 4.0, 0.0, 1.0)[:, None]
            colours = (1 - w) * TISSUE + w * self.cmap(0.25 + 0.7 * np.clip(heat, 0.0, 1.0))[:, :3]
        else:
            colours = np.tile(TISSUE, (len(u), 1))
        for h in hands:
            if h.grasped_vertex is not None:
                patch = self._rest_tree.query_ball_point(self.mesh.vertices[h.grasped_vertex], max(self.grasp_radius, 0.004))
                colours[patch] = PATCH
        self.brain.vertices = o3d.utility.Vector3dVector(self._positions)
        self.brain.vertex_colors = o3d.utility.Vector3dVector(colours)
        self.brain.compute_vertex_normals()
        self.vis.update_geometry(self.brain)
        while len(self.hands) < len(hands):
            m = o3d.geometry.TriangleMesh(self._hand_rest)
            self.vis.add_geometry(m, reset_bounding_box=False)
            self.hands.append(m)
        for k, (m, h) in enumerate(zip(self.hands, hands)):
            T = hand_pose(h.position, self.pulls[k % len(self.pulls)])
            m.vertices = o3d.utility.Vector3dVector(self._hand_vertices @ T[:3, :3].T + T[:3, 3])
            m.compute_vertex_normals()
            self.vis.update_geometry(m)
        if self.show_force:
            self._draw_forces(hands)
        self._last_hands = hands
        self.prepare_s.append(time.perf_counter() - start)  # this process's own work, before the rasteriser
        self._running = True
        self._present()
        now = time.perf_counter()
        self.frames += 1
        self.frame_s.append(now - start)
        if read_t is not None and read_t > 0:
            self.motion_to_photon_s.append(now - read_t)
        self.first_frame_at = self.first_frame_at or now
        self.last_frame_at = now

    def _draw_forces(self, hands) -> None:
        o3d = self.o3d
        while len(self.arrows) < len(hands):
            m = o3d.geometry.TriangleMesh(self._arrow_rest)
            self.vis.add_geometry(m, reset_bounding_box=False)
            self.arrows.append(m)
        parts = []
        for k, (m, h) in enumerate(zip(self.arrows, hands)):
            f = np.asarray(h.force, dtype=np.float64)
            n = float(np.linalg.norm(f))
            length = n * FORCE_ARROW_M_PER_N
            if length < 1e-4:
                V = np.zeros_like(self._arrow_vertices)
            else:
                z = f / n
                x = np.cross([0.0, 0.0, 1.0], z) if abs(z[2]) < 0.99 else np.array([1.0, 0.0, 0.0])
                x /= np.linalg.norm(x)
                y = np.cross(z, x)
                R = np.stack([x, y, z], axis=1)
                V = (self._arrow_vertices * [1.0, 1.0, length]) @ R.T + np.asarray(h.position)
            m.vertices = o3d.utility.Vector3dVector(V)
            m.compute_vertex_normals()
            self.vis.update_geometry(m)
            parts.append(f"{('left', 'right')[k] if len(hands) == 2 else 'hand'} {n:.2f} N")
        self.set_text(corner="force:  " + "   ".join(parts))

    def _present(self) -> None:
        if not self.vis.poll_events():
            self.closed = True
        if self._widget_dirty:  # the mouse changed it during the events
            self._build_widget()
        self.vis.update_renderer()
        self._fresh = True

    def at_rest(self) -> None:
        """Between runs: the tissue undeformed, nothing grasped, the hands where they were."""
        hands = [HandState(h.position) for h in getattr(self, "_last_hands", [])]
        self.draw(None, hands)
        self.frames -= 1  # not a frame of any run
        self.frame_s.pop()
        self.prepare_s.pop()

    def idle(self) -> None:
        """Keep the window alive (events, redraw) while nothing moves, e.g. on a rest screen or
        during the questions: a click made meanwhile grasps nothing."""
        self._running = False
        self._present()

    def take_keys(self) -> list[str]:
        keys, self.keys = self.keys, []
        return keys

    def screenshot(self, path) -> None:
        self.vis.capture_screen_image(str(path), do_render=True)

    def image(self) -> np.ndarray:
        """The frame as RGB bytes. A second render cost 56 of the 80 ms of an offscreen 640x480
        frame here, so right after a frame was presented, offscreen, its framebuffer is read as it
        is where that gives the frame: without a display (EGL), checked once against a fresh render
        (they agree but for 1-level differences in a few dozen pixels). A hidden window under Xvfb
        always renders: its back buffer is undefined after the swap (measured: every pixel differed)."""
        capture = self.vis.capture_screen_float_buffer
        if self._fresh and self._read_ok is not False:
            img = np.asarray(capture(do_render=False))
            if self._read_ok is None:
                again = np.asarray(capture(do_render=True))
                self._read_ok = bool(np.mean(np.abs(img - again).max(axis=2) > 1.5 / 255) < 1e-3)
                img = again
        else:
            img = np.asarray(capture(do_render=True))
        return (np.clip(img, 0.0, 1.0) * 255).astype(np.uint8)

    def stats(self) -> dict:
        span = (self.last_frame_at or 0.0) - (self.first_frame_at or 0.0)
        m2p = np.asarray(self.motion_to_photon_s) * 1e3
        ft = np.asarray(self.frame_s) * 1e3
        pt = np.asarray(self.prepare_s) * 1e3
        return {
            "frames_shown": self.frames,
            "fps": (self.frames - 1) / span if self.frames > 1 and span > 0 else None,
            "frame_ms": {"p50": float(np.percentile(ft, 50)) if len(ft) else None, "p99": float(np.percentile(ft, 99)) if len(ft) else None},
            # geometry, colours and normals for the frame: what is left of a frame with a GPU
            "prepare_ms": {"p50": float(np.percentile(pt, 50)) if len(pt) else None, "p99": float(np.percentile(pt, 99)) if len(pt) else None},
            "motion_to_photon_ms": {"p50": float(np.percentile(m2p, 50)) if len(m2p) else None,
                                    "p99": float(np.percentile(m2p, 99)) if len(m2p) else None},
            "size": f"{self.width}x{self.height}",
        }

    def reset_stats(self) -> None:
        self.frames, self.frame_s, self.prepare_s, self.motion_to_photon_s = 0, [], [], []
        self.first_frame_at = self.last_frame_at = None

    def close(self) -> None:
        if not self.closed:
            self.vis.destroy_window()
            self.closed = True

    # -- the questionnaire -------------------------------------------------------------------
    def set_questionnaire(self, on: bool) -> None:
        """Questionnaire mode: mouse clicks answer questions (on the widget shown, if any) and
        never grasp the brain; a hand held when it begins is let go."""
        self.questionnaire = bool(on)
        if on:
            for state in self.inputs.values():
                state[1] = False

    def show_scale(self, labels, anchors: tuple[str, str] | None = None) -> Widget:
        """Boxes side by side, one per label (a rating's points "1".."n", or blind labels), the
        anchors under the two ends; nothing chosen yet. With anchors the scale spans 55% of the
        width, so its ends stay where they are whatever the number of points."""
        n = len(labels)
        cx, vc = self.width / 2.0, self.height / 2.0
        if anchors:
            span = round(0.55 * self.width)
            b = min(56.0, span / (n + 0.25 * (n - 1)))
        else:
            b = 72.0
            span = n * b + (n - 1) * 0.75 * b
        gap = (span - n * b) / (n - 1) if n > 1 else 0.0
        left = cx - span / 2.0
        boxes = [(round(left + k * (b + gap)), round(vc - b / 2), round(left + k * (b + gap) + b), round(vc + b / 2)) for k in range(n)]
        self.widget = Widget("scale", labels=tuple(str(x) for x in labels), anchors=tuple(anchors) if anchors else None, boxes=boxes)
        self._build_widget()
        return self.widget

    def show_slider(self, anchors: tuple[str, str] | None = None) -> Widget:
        """A visual analogue scale: a horizontal line (55% of the width) from 0 to 100 with the
        anchors under its ends, and no mark until the person sets one."""
        span = round(0.55 * self.width)
        u0 = round(self.width / 2.0 - span / 2.0)
        self.widget = Widget("slider", anchors=tuple(anchors) if anchors else None, line=(u0, u0 + span, round(self.height / 2.0)))
        self._build_widget()
        return self.widget

    def clear_widget(self) -> None:
        self.widget = None
        self._build_widget()

    def select(self, index: int | None) -> None:
        """Choose a box of the scale (None: none)."""
        w = self.widget
        if w is not None and w.kind == "scale" and index != w.selected:
            w.selected = None if index is None else min(max(int(index), 0), len(w.labels) - 1)
            self._widget_dirty = True

    def set_value(self, value: float | None) -> None:
        """Set (or with None, take away) the slider's mark."""
        w = self.widget
        if w is not None and w.kind == "slider":
            value = None if value is None else round(min(max(float(value), 0.0), 100.0), 1)
            if value != w.value:
                w.value = value
                self._widget_dirty = True

    def move(self, step: int) -> None:
        """An arrow key: the scale's choice moves by `step` boxes (with none chosen yet, right
        chooses the first and left the last); the slider's mark moves by `step` (none set: nothing)."""
        w = self.widget
        if w is None:
            return
        if w.kind == "scale":
            if w.selected is None:
                self.select(0 if step > 0 else len(w.labels) - 1)
            else:
                self.select(w.selected + step)
        elif w.value is not None:
            self.set_value(w.value + step)

    def _widget_press(self, x: float, y: float) -> None:
        w = self.widget
        if w.kind == "scale":
            for k, (u0, v0, u1, v1) in enumerate(w.boxes):
                if u0 - 4 <= x <= u1 + 4 and v0 - 4 <= y <= v1 + 4:
                    if w.selected == k:
                        w.confirmed = True  # a second click on the chosen box
                    self.select(k)
                    return
        else:
            u0, u1, v = w.line
            if u0 - 20 <= x <= u1 + 20 and abs(y - v) <= 30:
                w.dragging = True
                self.set_value(w.value_at(x))

    def _build_widget(self) -> None:
        """(Re)make the widget's meshes: shapes (a panel, boxes or the line, the mark) in one
        mesh with vertex colours, just behind the text plane; labels and anchors in another."""
        self._widget_dirty = False
        self._fresh = False
        for m in self._widget_meshes:
            self.vis.remove_geometry(m, reset_bounding_box=False)
        self._widget_meshes = []
        w = self.widget
        if w is None:
            return
        z = self.text_depth
        quads, texts = [], []  # (u0, v0, u1, v1, depth, colour); (text, u, v, px, colour, align, max_width)
        if w.kind == "scale":
            first, last = w.boxes[0], w.boxes[-1]
            b = first[2] - first[0]
            bottom = first[3] + (58 if w.anchors else 26)
            quads.append((first[0] - 48, first[1] - 34, last[2] + 48, bottom, z * 1.03, PANEL))
            for k, (u0, v0, u1, v1) in enumerate(w.boxes):
                chosen = k == w.selected
                quads.append((u0 - 2, v0 - 2, u1 + 2, v1 + 2, z * 1.02, SELECTED if chosen else BORDER))
                quads.append((u0, v0, u1, v1, z * 1.01, SELECTED if chosen else BOX))
                px = 0.5 * b if len(w.labels[k]) <= 2 else 0.3 * b
                texts.append((w.labels[k], (u0 + u1) / 2, (v0 + v1) / 2 + 0.5625 * px, px, WHITE if chosen else TEXT, "middle", b - 6))
            if w.anchors:
                half = (last[2] - first[0]) / 2 - 12
                texts.append((w.anchors[0], first[0], first[3] + 34, 18, TEXT, "left", half))
                texts.append((w.anchors[1], last[2], first[3] + 34, 18, TEXT, "right", half))
        else:
            u0, u1, v = w.line
            quads.append((u0 - 56, v - 76, u1 + 56, v + 64, z * 1.03, PANEL))
            quads.append((u0, v - 2, u1, v + 2, z * 1.02, BORDER))
            for u in (u0, u1):
                quads.append((u - 2, v - 14, u + 2, v + 14, z * 1.02, BORDER))
            if w.anchors:
                half = (u1 - u0) / 2 - 12
                texts.append((w.anchors[0], u0, v + 44, 18, TEXT, "left", half))
                texts.append((w.anchors[1], u1, v + 44, 18, TEXT, "right", half))
            if w.value is not None:
                u = u0 + (u1 - u0) * w.value / 100.0
                quads.append((u - 3, v - 22, u + 3, v + 22, z * 1.01, SELECTED))
                texts.append((f"{w.value:g}", u, v - 32, 24, SELECTED, "middle", None))
        self._widget_meshes.append(self._quads_mesh(quads))
        for text, u, v, px, colour, align, max_width in texts:
            m = self._text_mesh(text, u, v, px, colour, align, max_width=max_width)
            m.triangle_normals = self.o3d.utility.Vector3dVector()  # as the shapes: drawn in their own colour, without shading
            self._widget_meshes.append(m)
        for m in self._widget_meshes:
            self.vis.add_geometry(m, reset_bounding_box=False)

    def _quads_mesh(self, quads):
        """Flat rectangles given in pixels, each at its own depth, facing the camera."""
        o3d = self.o3d
        V, T, C = [], [], []
        Kinv = np.linalg.inv(self.K)
        for u0, v0, u1, v1, depth, colour in quads:
            n = len(V)
            for u, v in ((u0, v0), (u1, v0), (u1, v1), (u0, v1)):
                V.append(self.R.T @ (depth * (Kinv @ [u, v, 1.0]) - self.t))
                C.append(colour)
            T += [(n, n + 2, n + 1), (n, n + 3, n + 2)]  # x right, y down: this winding faces the camera
        m = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(np.asarray(V)), o3d.utility.Vector3iVector(np.asarray(T, dtype=np.int32)))
        m.vertex_colors = o3d.utility.Vector3dVector(np.asarray(C, dtype=np.float64))
        m.vertex_normals = o3d.utility.Vector3dVector(np.tile(-self.R[2], (len(V), 1)))
        return m

    # -- the pointer (mouse device) ---------------------------------------------------------
    def _ray(self, u: float, v: float) -> np.ndarray:
        d = self.R.T @ np.linalg.solve(self.K, [u, v, 1.0])
        return d / np.linalg.norm(d)

    def pick(self, u: float, v: float) -> np.ndarray | None:
        """The point of the brain surface (as drawn now) under pixel (u, v), or None."""
        o3d = self.o3d
        scene = o3d.t.geometry.RaycastingScene()
        scene.add_triangles(self._positions.astype(np.float32), self.mesh.triangles.astype(np.uint32))
        d = self._ray(u, v)
        rays = o3d.core.Tensor([[*self.eye, *d]], dtype=o3d.core.Dtype.Float32)
        hit = float(scene.cast_rays(rays)["t_hit"].numpy()[0])
        return None if not np.isfinite(hit) else self.eye + hit * d

    def _depth(self, p) -> float:
        return float((self.R @ np.asarray(p) + self.t)[2])

    def _at_depth(self, u: float, v: float, depth: float) -> np.ndarray:
        return self.R.T @ (depth * np.linalg.solve(self.K, [u, v, 1.0]) - self.t)

    def _on_button(self, vis, button: int, action: int, mods: int) -> bool:
        if self.questionnaire or self.widget is not None:  # the mouse answers, never grasps
            if self.widget is not None and button == 0:
                if action == 1:
                    self._widget_press(*self.pointer)
                else:
                    self.widget.dragging = False
            return False
        hand = min(button, self.n_hands - 1) if button in (0, 1) else None
        if hand is None:
            return False
        if action == 1 and self._running:  # press: grasp the surface under the pointer (only while a run is drawn)
            p = self.pick(*self.pointer)
            if p is not None:
                self.inputs[hand] = [p, True, self._depth(p)]
        elif action == 0 and hand in self.inputs:
            self.inputs[hand][1] = False
        return False

    def _on_move(self, vis, x: float, y: float) -> bool:
        self.pointer = (float(x), float(y))
        w = self.widget
        if w is not None and w.dragging:
            self.set_value(w.value_at(x))
        for state in self.inputs.values():
            if state[1]:
                state[0] = self._at_depth(x, y, state[2])
        return False

    def _on_scroll(self, vis, dx: float, dy: float) -> bool:
        if self.questionnaire:
            return False
        for state in self.inputs.values():
            if state[1]:
                state[2] = max(state[2] - dy * WHEEL_M, 0.01)  # wheel up: towards the viewer
                state[0] = self._at_depth(*self.pointer, state[2])
        return False

    def pointer_inputs(self) -> dict[int, tuple]:
        """hand -> (target point, pressed) from the pointer, for mouse devices."""
        return {i: (tuple(float(c) for c in s[0]), bool(s[1])) for i, s in self.inputs.items()}


def open_view(kind: str, scene, show_force: bool = False):
    """The participant view for `--view window` (None for none)."""
    if kind == "none":
        return None
    pulls = [h.pull for h in scene.spec.hands]
    # one patch size for every model: a model-specific one would be a cue in a blind study
    return ParticipantView(scene.mesh, pulls=pulls, visible=(kind == "window"), show_force=show_force, camera=scene.spec.view)
