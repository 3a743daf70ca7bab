"""The participant view: a real window with the deforming brain, the two instruments (forceps
whose jaws close on a grasp), the grasped patch, and on-screen text (instructions, condition and
trial, countdowns, rest screens), drawn with OpenGL (sim/view/renderer.py); the same view offscreen
(EGL) draws the analyst's pictures.

The window is resizable and may be fullscreen; the camera follows its size so the brain at rest
fills the view's height (sim/view/camera.py). Text comes from a font atlas, sized relative to a
720-pixel-high view, so it is as crisp and as large on a lab's monitor as in a test's window.

The view never names a tissue model: callers give it only participant-facing text. It is drawn
by the visual side of a run (sim/run.py); the servo runs in its own process and never waits for
it. Late latch: `draw(..., latch=)` reads the newest hand positions from the servo just before
the frame is drawn, so the instruments show where the hands are now, not where they were when
the tissue's deformation was computed; motion-to-photon is measured from that read. With a
mouse device, the pointer drives the hands (left button: left hand, right button: right hand;
drag in the view plane, wheel in depth) and the force that would be felt is drawn as an arrow
and a number.

For a questionnaire the window shows a rating scale (boxes with their numbers, the anchors under
the two ends; also used for the choice among blind labels) or a visual analogue scale (a line
with its anchors, and a mark the person sets with the mouse): `answers.show_scale`,
`answers.show_slider` (`sim.view.widgets.WidgetPanel`). In questionnaire mode (`set_questionnaire`,
on while a question is asked) the mouse answers questions; and a click grasps the brain only
while a run is drawn (`draw`), never on a still screen (`idle`: a rest screen, questions asked
in the window or in the terminal).
"""

from __future__ import annotations

import contextlib
import os
import time

import glfw
import matplotlib
import moderngl
import numpy as np
from PIL import Image

from sim.errors import ViewError
from sim.geometry.mesh import point_tree
from sim.geometry.patch import GRASP_RADIUS
from sim.scene import ViewSpec
from sim.view import hud, shapes
from sim.view.camera import fit, ray_hit
from sim.view.hands import HandState
from sim.view.hud import ARROW, DESIGN_HEIGHT, SLOTS
from sim.view.normals import vertex_normals
from sim.view.renderer import Overlay, Placed, Renderer, open_offscreen, open_window
from sim.view.widgets import WidgetPanel

TISSUE = np.array([0.88, 0.80, 0.78])
PATCH = np.array([0.20, 0.55, 0.95])  # the grasped patch
BACKING = (1.0, 1.0, 1.0, 0.82)  # behind a line of text over the brain
# GLFW key codes -> names the callers use: the top row's digits and the keypad's give the same
# names ("0".."9"), as do Enter and the keypad's Enter
KEYS = {32: "space", 257: "enter", 335: "enter", 256: "escape", 259: "backspace", 262: "right", 263: "left",
        **{ord(c): c.lower() for c in "ABCDEFGHIJKLMNOPQRSTUVWXYZ"},
        **{48 + k: str(k) for k in range(10)}, **{320 + k: str(k) for k in range(10)}}
FORCE_ARROW_M_PER_N = 0.08
WHEEL_M = 0.002  # depth per wheel step


def _unit(v) -> np.ndarray:
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v)


class ParticipantView:
    """One window reused for a whole session (or an offscreen one with `visible=False`)."""

    def __init__(self, mesh, pulls=((-1.0, 0.0, 0.0), (1.0, 0.0, 0.0)), width: int = 1280, height: int = 720,
                 visible: bool = True, title: str = "Brain surgery simulator", show_force: bool = False,
                 grasp_radius: float = GRASP_RADIUS, camera=None, fullscreen: bool = False, max_fps: float = 60.0,
                 targets=None):

        # Mesa's CPU rasteriser: a thread per core but one, which the servo process keeps
        cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1
        os.environ.setdefault("LP_NUM_THREADS", str(max(1, cores - 1)))
        if visible and not os.environ.get("DISPLAY") and not os.environ.get("WAYLAND_DISPLAY"):
            raise ViewError("--view window: no display (DISPLAY is not set); run on a desktop, or under xvfb-run")
        self.mesh = mesh
        self.spec = camera or ViewSpec()  # front, up, zoom: the scene's [view]
        self.show_force = show_force
        self.grasp_radius = grasp_radius
        self.pulls = [np.asarray(p, dtype=np.float64) for p in pulls]
        self.n_hands = len(pulls)
        # each hand's sim.targets.HandTarget (or None): the tolerance and the pull a target's
        # state is drawn with (the ring's size, the bar's band, the line along the pull)
        self.targets = list(targets) if targets is not None else []
        self.max_fps = max_fps
        self.window = None
        self.ctx = None
        try:
            if visible:
                self.window = open_window(width, height, title, fullscreen)
                self.ctx = moderngl.create_context()
                width, height = glfw.get_framebuffer_size(self.window)
                self._callbacks()
            else:
                self.ctx = open_offscreen()
            self.width, self.height = int(width), int(height)
            self._fit()
            self._positions = mesh.vertices.copy()
            self._colour_key = None
            with self._current():
                self.gl = Renderer(self.ctx, mesh)
                self.renderer_name = self.ctx.info.get("GL_RENDERER", "?")
                self.gl.set_brain(self._positions, mesh.vertex_normals)
                self._set_colours(None, [])
        except Exception:  # nothing left current or open: a later view in this process must still work
            self.closed = False
            self.close()
            raise
        self.cmap = matplotlib.colormaps["inferno"]
        self._rest_tree = None
        self._texts: dict[str, str] = {}
        self._flat = None  # the overlay's vertices, made again when a text or the widget changes
        self._fresh = False  # the last frame drawn shows the scene as it is now
        self._scene = ([], None)  # instruments placed and arrow triangles of the last frame
        self._last_hands: list[HandState] = []
        self._markers = None  # the targets' rings and lines (triangles) of the last frame
        self._bars = None  # the targets' progress bars (flat vertices) of the last frame
        self._bar_key = None  # what the bars' labels say: made again (with the overlay) when it changes
        self._target_texts: list = []
        self._target_shapes: dict = {}
        self.keys: list[str] = []
        self.pointer = (self.width / 2.0, self.height / 2.0)
        self.inputs: dict[int, list] = {}  # hand -> [target, pressed, depth]
        self.questionnaire = False  # the mouse answers questions, never grasps
        self._running = False  # frames of a run are drawn (draw), not a still screen (idle): a click may grasp
        self.answers = WidgetPanel(self._changed)  # the widget a question shows (questionnaire mode)
        self.answers.resize(self.width, self.height, self.ui)
        self.closed = False
        self.frames = 0
        self.frame_s: list[float] = []
        self.prepare_s: list[float] = []
        self.motion_to_photon_s: list[float] = []
        self.first_frame_at: float | None = None
        self.last_frame_at: float | None = None

    # -- window, camera ----------------------------------------------------------------------
    @contextlib.contextmanager
    def _current(self):
        """This view's GL context current on the thread while GL is used, and none after: views
        of both kinds live in one process (a session's window, offscreen pictures, tests), and a
        thread may not switch between a GLX and an EGL context while one is current (libglvnd:
        BadAccess, which ends the process)."""
        if self.window is not None:
            glfw.make_context_current(self.window)
            try:
                yield
            finally:
                glfw.make_context_current(None)
        else:
            self.ctx.__enter__()
            try:
                yield
            finally:
                self.ctx.__exit__(None, None, None)

    def _callbacks(self) -> None:
        w = self.window

        def key(win, code, scancode, action, mods):
            if action in (glfw.PRESS, glfw.REPEAT) and code in KEYS:
                self.keys.append(KEYS[code])

        glfw.set_key_callback(w, key)
        glfw.set_framebuffer_size_callback(w, lambda win, width, height: self.resize(width, height))
        glfw.set_window_refresh_callback(w, lambda win: setattr(self, "_fresh", False))  # uncovered: draw again
        glfw.set_mouse_button_callback(w, lambda win, button, action, mods: self._on_button(button, action))
        glfw.set_cursor_pos_callback(w, lambda win, x, y: self._on_move(*self._to_pixels(x, y)))
        glfw.set_scroll_callback(w, lambda win, dx, dy: self._on_scroll(dx, dy))

    def resize(self, width: int, height: int) -> None:
        """The view's new size in pixels (the window's framebuffer, or offscreen): the camera
        refitted, text and widget laid out again. 0 x 0 (a minimised window) is ignored."""
        if width > 0 and height > 0 and (width, height) != (self.width, self.height):
            self.width, self.height = int(width), int(height)
            self._fit()
            self.answers.resize(self.width, self.height, self.ui)
            self._changed()

    def _to_pixels(self, x: float, y: float) -> tuple[float, float]:
        """Window coordinates (the mouse) to framebuffer pixels (differ on a high-density display)."""
        ww, wh = glfw.get_window_size(self.window)
        return x * self.width / max(ww, 1), y * self.height / max(wh, 1)

    def _fit(self) -> None:
        self.camera = fit(self.mesh.vertices, self.spec.front, self.spec.up, self.width, self.height, self.spec.zoom)
        self.ui = self.height / DESIGN_HEIGHT

    def _changed(self) -> None:
        self._flat = None
        self._fresh = False

    # -- text --------------------------------------------------------------------------------
    def set_text(self, **slots: str | None) -> None:
        """Slots: top (status line), center (the main message, large), question (a question of
        the questionnaire), bottom (instructions), corner (bottom right: forces), notice (bottom
        left: the devices' notices). '' or None clears a slot."""
        for slot, text in slots.items():
            if slot not in SLOTS:
                raise ValueError(f"unknown text slot {slot!r}")
            text = text or ""
            if self._texts.get(slot, "") != text:
                self._texts[slot] = text
                self._changed()

    def text(self) -> dict[str, str]:
        """What the window shows as text now (tests read it to check no model is named); a
        questionnaire widget's labels, anchors and value are under "widget"."""
        out = {k: v for k, v in self._texts.items() if v}
        w = self.answers.widget
        if w is not None:
            parts = list(w.labels) + list(w.anchors or ()) + ([f"{w.value:g}"] if w.value is not None else [])
            out["widget"] = "  ".join(parts)
        return out

    def layout(self) -> list[tuple]:
        """Every text item as drawn now: (text, x, baseline y, pixel size, rgb, align), slots
        then the widget's labels (tests look for their pixels where they are laid out)."""
        return hud.items(self._texts, self.width, self.height) + self._target_texts + self.answers.texts

    def _overlay(self):
        """The flat overlay's vertices: a light backing under each slot's text (legible over the
        brain), the widget's shapes, then every text."""
        if self._flat is None:
            texts = self.layout()
            quads = []
            pad = 5.0 * self.ui
            for text, x, y, px, _, align in texts[: len(texts) - len(self.answers.texts)]:
                q, _ = self.gl.text_quads(text, x, y, px, align)
                if len(q):
                    quads.append((q[:, 0].min() - pad, q[:, 1].min() - pad, q[:, 2].max() + pad, q[:, 3].max() + pad, BACKING))
            quads += self.answers.quads
            self._flat = self.gl.flat_vertices(Overlay(quads=quads, texts=texts))
        return self._flat

    # -- drawing -----------------------------------------------------------------------------
    def _set_colours(self, heat01, grasped: list[int]) -> None:
        """The tissue's colours: plain, or (the analyst's pictures) by `heat01`, with the
        grasped patches over them; written only when they change."""
        key = tuple(grasped)
        if heat01 is None and key == self._colour_key:  # heat changes from picture to picture: always written
            return
        self._colour_key = key if heat01 is None else None
        n = self.mesh.n_vertices
        if heat01 is not None:  # tissue colour, then inferno
            heat = np.asarray(heat01, dtype=np.float64)
            w = np.clip(heat * 4.0, 0.0, 1.0)[:, None]
            colours = (1 - w) * TISSUE + w * self.cmap(0.25 + 0.7 * np.clip(heat, 0.0, 1.0))[:, :3]
        else:
            colours = np.tile(TISSUE, (n, 1))
        if grasped:
            if self._rest_tree is None:
                self._rest_tree = point_tree(self.mesh.vertices)
            for v in grasped:
                colours[self._rest_tree.query_ball_point(self.mesh.vertices[v], max(self.grasp_radius, 0.004))] = PATCH
        self.gl.set_colours(colours)

    def _instrument(self, k: int, position, grasped: bool):
        """Forceps with their tips at the hand: the handle comes towards the viewer from the
        bottom of the screen on the hand's side; the jaws open across the view."""
        right, down, forward = self.camera.R
        sx = float(self.pulls[k % len(self.pulls)] @ right)
        side = np.sign(sx) if abs(sx) > 1e-6 else (-1.0 if k == 0 else 1.0)
        axis = _unit(0.45 * down - 0.6 * forward + 0.45 * side * right)
        R = shapes.frame(axis, np.cross(axis, forward))
        return Placed("closed" if grasped else "open", R, np.asarray(position, dtype=np.float64))

    def _arrows(self, hands) -> np.ndarray | None:
        """Triangles (vertices of position, normal, colour) of the force arrows at the hands."""
        parts, corner = [], []
        for k, h in enumerate(hands):
            f = np.asarray(h.force, dtype=np.float64)
            n = float(np.linalg.norm(f))
            corner.append(f"{('left', 'right')[k] if len(hands) == 2 else 'hand'} {n:.2f} N")
            length = n * FORCE_ARROW_M_PER_N
            if length < 1e-4:
                continue
            z = f / n
            R = shapes.frame(z, [1.0, 0.0, 0.0] if abs(z[0]) < 0.9 else [0.0, 1.0, 0.0])
            s = shapes.arrow(length)
            V, N = shapes.transform(s, R, np.asarray(h.position, dtype=np.float64))
            T = s.triangles.ravel()
            parts.append(np.hstack([V[T], N[T], np.tile(np.asarray(ARROW, dtype=np.float32), (len(T), 1))]))
        self.set_text(corner="force:  " + "   ".join(corner))
        return np.concatenate(parts) if parts else None

    # -- the hands' targets --------------------------------------------------------------------
    def _side(self, k: int) -> float:
        """-1 for a hand whose pull goes left on the screen, +1 for right (the first hand left
        when its pull is along the view's depth)."""
        sx = float(self.pulls[k % len(self.pulls)] @ self.camera.R[0])
        return float(np.sign(sx)) if abs(sx) > 1e-6 else (-1.0 if k == 0 else 1.0)

    def _target_shape(self, kind: str, size: float):
        """A target's ring (`size`: its radius) or line (its length), made once."""
        key = (kind, size)
        if key not in self._target_shapes:
            self._target_shapes[key] = shapes.torus(size, max(0.25 * size, 0.0006), 40, 8) if kind == "ring" else shapes.rod(size, 0.00025, 6)
        return self._target_shapes[key]

    def _show_targets(self, hands) -> None:
        """The targets of the hands that have one: a ring at the target (the tolerance's size,
        facing the viewer: magenta, green while within the tolerance, gold once held) with a thin
        line to it from where the grasp took hold, and a progress bar per hand in the overlay
        (hud.target_bars). Nothing at all when no hand has a target."""
        shown = [(k, h.target) for k, h in enumerate(hands) if h.target is not None]
        if not shown and self._bar_key is None:
            self._markers = self._bars = None
            return
        parts, bars, names = [], [], []
        right, _, forward = self.camera.R
        for k, st in shown:
            spec = self.targets[k] if k < len(self.targets) else None
            colour = hud.TARGET_HELD if st.held else hud.TARGET_ON if st.on_target else hud.TARGET_AWAY
            radius = max(spec.spec.tolerance, 0.0015) if spec is not None else 0.003
            ring = self._target_shape("ring", radius)
            point = np.asarray(st.point, dtype=np.float64)
            items = [(ring, shapes.frame(forward, right), point)]
            band = None
            if spec is not None:
                d, dist = np.asarray(spec.direction, dtype=np.float64), spec.spec.distance
                length = dist - radius
                line = self._target_shape("rod", length)
                side = right if abs(d @ right) < 0.9 else forward
                items.append((line, shapes.frame(d, side), point - dist * d))
                band = (1.0 - spec.spec.tolerance / dist, 1.0 + spec.spec.tolerance / dist)
            for shape, R, t in items:
                if shape.n_triangles:
                    V, N = shapes.transform(shape, R, t)
                    T = shape.triangles.ravel()
                    parts.append(np.hstack([V[T], N[T], np.broadcast_to(np.asarray(colour, dtype=np.float32), (len(T), 3))]))
            bars.append((self._side(k), st.progress, band, st.on_target, st.held, st.over_limit))
            names.append(("Left", "Right")[k] if len(hands) == 2 else "Your")
        self._markers = np.concatenate(parts) if parts else None
        self._bars = self.gl.flat_vertices(Overlay(quads=hud.target_bars(bars, self.width, self.ui))) if bars else None
        key = (tuple((b[0], b[4], b[5]) for b in bars), tuple(names), self.width, self.height) if bars else None
        if key != self._bar_key:
            self._bar_key = key
            self._target_texts = hud.target_labels(bars, names, self.width, self.ui) if bars else []
            self._changed()

    def draw(self, displacement, hands: list[HandState], read_t: float | None = None, heat01=None, latch=None) -> None:
        """Draw one frame and present it. `read_t` (perf_counter) is when the devices were read
        for this state; `latch()`, if given, returns (the hands' newest positions, their forces,
        when the devices were read for them), taken just before drawing. Motion-to-photon runs from that read to the presented
        frame. `heat01` (per vertex, 0..1) colours the tissue by it (the analyst's pictures)."""
        start = time.perf_counter()
        self._events()
        u = np.zeros_like(self.mesh.vertices) if displacement is None else np.asarray(displacement, dtype=np.float64)
        self._positions = self.mesh.vertices + u
        normals = vertex_normals(self._positions, self.mesh.triangles)
        with self._current():
            self.gl.set_brain(self._positions, normals)
            self._set_colours(heat01, [h.grasped_vertex for h in hands if h.grasped_vertex is not None])
            self.prepare_s.append(time.perf_counter() - start)  # this process's own work, besides the GL calls
            if latch is not None:  # the newest hand positions and forces, read now
                positions, forces, read_t = latch()
                hands = [HandState(tuple(p), tuple(f), h.grasped_vertex, h.holding, h.target) for h, p, f in zip(hands, positions, forces)]
            self._last_hands = hands
            arrows = self._arrows(hands) if self.show_force else None
            self._scene = ([self._instrument(k, h.position, h.closed) for k, h in enumerate(hands)], arrows)
            self._show_targets(hands)
            self._running = True
            self._present()
        now = time.perf_counter()
        self.frames += 1
        self.frame_s.append(now - start)
        if read_t is not None and read_t > 0:
            self.motion_to_photon_s.append(now - read_t)
        self.first_frame_at = self.first_frame_at or now
        self.last_frame_at = now

    def _events(self) -> None:
        if self.window is not None:
            glfw.poll_events()
            if glfw.window_should_close(self.window):
                self.closed = True

    def _render(self, target) -> None:
        placed, arrows = self._scene
        self.gl.draw(target, self.camera, placed, arrows, self._overlay(), self._markers, self._bars)

    def _present(self) -> None:
        """Draw the scene as it is into the window (swap, and wait until it is shown) or into the
        offscreen framebuffer."""
        if self.window is not None:
            self._render(self.ctx.screen)
            glfw.swap_buffers(self.window)
        else:
            self._render(self.gl.target(self.width, self.height))
        self.ctx.finish()
        self._fresh = True

    def at_rest(self) -> None:
        """Between runs: the tissue undeformed, nothing grasped, the hands where they were."""
        hands = [HandState(h.position) for h in self._last_hands]
        self.draw(None, hands)
        self.frames -= 1  # not a frame of any run
        self.frame_s.pop()
        self.prepare_s.pop()

    def idle(self) -> None:
        """Keep the window alive (events, a redraw when something changed) while nothing moves,
        e.g. on a rest screen or during the questions: a click made meanwhile grasps nothing.
        Waits for an event up to a frame's time, so a caller's loop does not spin."""
        self._running = False
        if self.window is None:
            if not self._fresh:
                with self._current():
                    self._present()
            else:
                time.sleep(1.0 / self.max_fps)
            return
        self._events()
        if not self._fresh:
            with self._current():
                self._present()
        else:
            glfw.wait_events_timeout(1.0 / self.max_fps)

    def take_keys(self) -> list[str]:
        keys, self.keys = self.keys, []
        return keys

    def screenshot(self, path) -> None:
        Image.fromarray(self.image()).save(str(path))

    def image(self) -> np.ndarray:
        """The frame as RGB bytes (height, width, 3). Offscreen, the framebuffer holds the frame
        last drawn: it is read as it is while it shows the scene as it is now, else drawn again.
        A window's frame is drawn again offscreen (the same state): its back buffer is undefined
        after a swap."""
        with self._current():
            target = self.gl.target(self.width, self.height)
            if self.window is not None or not self._fresh:
                self._render(target)
                self._fresh = self._fresh or self.window is None
            return self.gl.read(target, self.width, self.height)

    def stats(self) -> dict:
        span = (self.last_frame_at or 0.0) - (self.first_frame_at or 0.0)
        m2p = np.asarray(self.motion_to_photon_s) * 1e3
        ft = np.asarray(self.frame_s) * 1e3
        pt = np.asarray(self.prepare_s) * 1e3

        def pct(a):
            return {"p50": float(np.percentile(a, 50)) if len(a) else None, "p99": float(np.percentile(a, 99)) if len(a) else None}

        return {
            "frames_shown": self.frames,
            "fps": (self.frames - 1) / span if self.frames > 1 and span > 0 else None,
            "frame_ms": pct(ft),
            # geometry, normals and colours for the frame: what is left of a frame with a GPU
            "prepare_ms": pct(pt),
            "motion_to_photon_ms": pct(m2p),
            "size": f"{self.width}x{self.height}",
            "renderer": self.renderer_name,
        }

    def reset_stats(self) -> None:
        self.frames, self.frame_s, self.prepare_s, self.motion_to_photon_s = 0, [], [], []
        self.first_frame_at = self.last_frame_at = None

    def close(self) -> None:
        if self.closed and self.window is None and self.ctx is None:
            return
        self.closed = True
        if self.window is not None:  # the window's context, and every GL object, go with it
            glfw.destroy_window(self.window)
            self.window = None
        elif self.ctx is not None:
            self.ctx.release()  # an EGL context is destroyed at once when it is not current (it never is between calls)
        self.ctx = None

    # -- the questionnaire -------------------------------------------------------------------
    def set_questionnaire(self, on: bool) -> None:
        """Questionnaire mode: mouse clicks answer questions (on the widget shown, if any) and
        never grasp the brain; a hand held when it begins is let go."""
        self.questionnaire = bool(on)
        if on:
            for state in self.inputs.values():
                state[1] = False

    # -- the pointer (mouse device) ---------------------------------------------------------
    def pick(self, u: float, v: float) -> np.ndarray | None:
        """The point of the brain surface (as drawn now) under pixel (u, v), or None."""
        d = self.camera.ray(u, v)
        hit = ray_hit(self.camera.eye, d, self._positions, self.mesh.triangles)
        return None if not np.isfinite(hit) else self.camera.eye + hit * d

    def _on_button(self, button: int, action: int) -> None:
        w = self.answers.widget
        if self.questionnaire or w is not None:  # the mouse answers, never grasps
            if w is not None and button == 0:
                if action == 1:
                    self.answers.press(*self.pointer)
                else:
                    w.dragging = False
            return
        hand = min(button, self.n_hands - 1) if button in (0, 1) else None
        if hand is None:
            return
        if action == 1 and self._running:  # press: grasp the surface under the pointer (only while a run is drawn)
            p = self.pick(*self.pointer)
            if p is not None:
                self.inputs[hand] = [p, True, self.camera.depth(p)]
        elif action == 0 and hand in self.inputs:
            self.inputs[hand][1] = False

    def _on_move(self, x: float, y: float) -> None:
        self.pointer = (float(x), float(y))
        w = self.answers.widget
        if w is not None and w.dragging:
            self.answers.set_value(w.value_at(x))
        for state in self.inputs.values():
            if state[1]:
                state[0] = self.camera.at_depth(x, y, state[2])

    def _on_scroll(self, dx: float, dy: float) -> None:
        if self.questionnaire:
            return
        for state in self.inputs.values():
            if state[1]:
                state[2] = max(state[2] - dy * WHEEL_M, 0.01)  # wheel up: towards the viewer
                state[0] = self.camera.at_depth(*self.pointer, state[2])

    def pointer_inputs(self) -> dict[int, tuple]:
        """hand -> (target point, pressed) from the pointer, for mouse devices."""
        return {i: (tuple(float(c) for c in s[0]), bool(s[1])) for i, s in self.inputs.items()}


def open_view(kind: str, scene, show_force: bool = False, fullscreen: bool = False):
    """The participant view for `--view window` (None for none)."""
    if kind == "none":
        return None
    pulls = [h.pull for h in scene.spec.hands]
    # one patch size for every model: a model-specific one would be a cue in a blind study
    return ParticipantView(scene.mesh, pulls=pulls, visible=(kind == "window"), show_force=show_force, camera=scene.spec.view,
                           fullscreen=fullscreen, targets=scene.targets())
