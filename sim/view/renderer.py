"""OpenGL drawing of one frame of the participant view (moderngl): the brain, the instruments,
the force arrows, then a flat overlay of panels and text, into a window or an offscreen buffer.

Why moderngl (with glfw for the window, EGL without a display): a frame costs what its
triangles cost. The brain's positions and normals are written into buffers that live on the
GPU (or Mesa's CPU driver) and drawn in one call; instruments and arrows are small meshes placed
by a matrix; text is textured quads from a font atlas (sim/view/font.py). It replaced open3d's
classic visualiser (the two compared: `python -m bench render`, docs/participant.md).

Conventions: world coordinates in metres; overlay coordinates in framebuffer pixels from the top
left corner (x right, y down), as the mouse reports them.
"""

from __future__ import annotations

import os
import tempfile
from dataclasses import dataclass, field

import glfw
import moderngl
import numpy as np

from sim.errors import ViewError
from sim.view import shapes
from sim.view.font import atlas

# lit per vertex (Gouraud): llvmpipe's cost is per fragment, and the brain has a vertex every
# pixel or two at this size, so per-fragment lighting bought nothing visible for its time;
# a headlight (what faces the viewer is bright) and a key light from the top left (relief),
# Blinn-Phong highlights: strong for steel, faint for wet tissue
LIT_VS = """
#version 330
uniform mat4 mvp;
uniform mat4 model;
uniform mat3 normal_matrix;
uniform vec3 eye;
uniform vec3 key;
uniform float specular;
uniform float shininess;
in vec3 in_position;
in vec3 in_normal;
in vec3 in_colour;
out vec3 v_colour;
void main() {
    vec4 w = model * vec4(in_position, 1.0);
    gl_Position = mvp * w;
    vec3 n = normalize(normal_matrix * in_normal);
    vec3 v = normalize(eye - w.xyz);
    float head = max(dot(n, v), 0.0);
    float side = max(dot(n, key), 0.0);
    float s = specular * pow(max(dot(n, normalize(key + v)), 0.0), shininess);
    v_colour = min(in_colour * (0.30 + 0.50 * head + 0.25 * side) + vec3(s), 1.0);
}
"""

LIT_FS = """
#version 330
in vec3 v_colour;
out vec4 colour;
void main() {
    colour = vec4(v_colour, 1.0);
}
"""

FLAT_VS = """
#version 330
uniform vec2 screen;
in vec2 in_xy;
in vec2 in_st;
in vec4 in_rgba;
out vec2 v_st;
out vec4 v_rgba;
void main() {
    gl_Position = vec4(2.0 * in_xy.x / screen.x - 1.0, 1.0 - 2.0 * in_xy.y / screen.y, 0.0, 1.0);
    v_st = in_st;
    v_rgba = in_rgba;
}
"""

FLAT_FS = """
#version 330
uniform sampler2D atlas;
uniform bool textured;
in vec2 v_st;
in vec4 v_rgba;
out vec4 colour;
void main() {
    float a = textured ? texture(atlas, v_st).r : 1.0;
    colour = vec4(v_rgba.rgb, v_rgba.a * a);
}
"""

STEEL = (0.72, 0.74, 0.78)
FLAT_FLOATS = 8  # x, y, s, t, r, g, b, a per overlay vertex


@dataclass
class Overlay:
    """What is drawn flat over the scene, in framebuffer pixels: rectangles (x0, y0, x1, y1,
    rgba) in order, then text items (text, x, baseline y, pixel size, rgb, align: left, right,
    center or middle (the ink's middle))."""

    quads: list = field(default_factory=list)
    texts: list = field(default_factory=list)


@dataclass(frozen=True)
class Placed:
    """A shape placed in the scene: `kind` ("open", "closed" forceps), rotation and position."""

    kind: str
    R: np.ndarray
    t: np.ndarray


def _x_runtime_dir() -> None:
    if not os.environ.get("XDG_RUNTIME_DIR"):  # Mesa and GLFW warn without one
        os.environ["XDG_RUNTIME_DIR"] = tempfile.mkdtemp(prefix="xdg-")


def open_window(width: int, height: int, title: str, fullscreen: bool = False):
    """A resizable window with an OpenGL 3.3 core context (glfw), made current. Returns the
    glfw window; raises ViewError with what failed."""
    _x_runtime_dir()
    if not glfw.init():
        raise ViewError(f"--view window: could not open a window on display {os.environ.get('DISPLAY')!r} (glfw.init failed)")
    glfw.window_hint(glfw.CONTEXT_VERSION_MAJOR, 3)
    glfw.window_hint(glfw.CONTEXT_VERSION_MINOR, 3)
    glfw.window_hint(glfw.OPENGL_PROFILE, glfw.OPENGL_CORE_PROFILE)
    glfw.window_hint(glfw.OPENGL_FORWARD_COMPAT, glfw.TRUE)  # macOS gives a 3.3 core context only so
    glfw.window_hint(glfw.RESIZABLE, glfw.TRUE)
    glfw.window_hint(glfw.DOUBLEBUFFER, glfw.TRUE)
    monitor = None
    if fullscreen:
        monitor = glfw.get_primary_monitor()
        mode = glfw.get_video_mode(monitor) if monitor else None
        if mode is None:
            raise ViewError("--fullscreen: the display reports no monitor")
        width, height = mode.size.width, mode.size.height
    window = glfw.create_window(int(width), int(height), title, monitor, None)
    if not window:
        raise ViewError(f"--view window: could not open a {width}x{height} OpenGL 3.3 window on display {os.environ.get('DISPLAY')!r}")
    glfw.make_context_current(window)
    # a real display: wait for its refresh (no tearing); Xvfb has none, the frame loop paces itself
    glfw.swap_interval(1)
    return window


def open_offscreen():
    """A standalone OpenGL 3.3 context on EGL: no display needed (Mesa's llvmpipe here, the GPU's
    driver where there is one)."""
    _x_runtime_dir()
    try:
        ctx = moderngl.create_context(standalone=True, backend="egl", require=330)
    except Exception as exc:  # no EGL library, no device
        raise ViewError(f"offscreen rendering: no EGL OpenGL 3.3 context ({exc}); `make test` installs libegl1 and Mesa") from exc
    ctx.__exit__(None, None, None)  # current since its creation: a view makes it current only while it draws
    return ctx


class Renderer:
    """The GL resources of one view and the drawing of a frame."""

    def __init__(self, ctx, mesh):
        self.ctx = ctx
        self.lit = ctx.program(vertex_shader=LIT_VS, fragment_shader=LIT_FS)
        self.flat = ctx.program(vertex_shader=FLAT_VS, fragment_shader=FLAT_FS)
        n = mesh.n_vertices
        self.positions = ctx.buffer(reserve=n * 12, dynamic=True)
        self.normals = ctx.buffer(reserve=n * 12, dynamic=True)
        self.colours = ctx.buffer(reserve=n * 12, dynamic=True)
        index = ctx.buffer(np.ascontiguousarray(mesh.triangles, dtype=np.int32).tobytes())
        self.brain = ctx.vertex_array(self.lit, [(self.positions, "3f", "in_position"), (self.normals, "3f", "in_normal"),
                                                 (self.colours, "3f", "in_colour")], index_buffer=index, index_element_size=4)
        self.instruments = {kind: self._static(shapes.forceps(opening), STEEL) for kind, opening in (("open", 1.0), ("closed", 0.0))}
        self.arrow_buffer = ctx.buffer(reserve=4096 * 9 * 4, dynamic=True)
        self.arrow = ctx.vertex_array(self.lit, [(self.arrow_buffer, "3f 3f 3f", "in_position", "in_normal", "in_colour")])
        self.marker_buffer = ctx.buffer(reserve=4096 * 9 * 4, dynamic=True)  # the hands' targets (made on first use)
        self.marker = ctx.vertex_array(self.lit, [(self.marker_buffer, "3f 3f 3f", "in_position", "in_normal", "in_colour")])
        self.flat_buffer = ctx.buffer(reserve=6 * FLAT_FLOATS * 4 * 4096, dynamic=True)
        self.flat_vao = ctx.vertex_array(self.flat, [(self.flat_buffer, "2f 2f 4f", "in_xy", "in_st", "in_rgba")])
        self.atlases: dict[int, tuple] = {}  # pixel size -> (font atlas, texture)
        self.fbo = None  # offscreen target, made on demand at the view's size

    def _static(self, shape, colour):
        """A vertex array of a fixed shape (sim.view.shapes.Shape), flat triangles."""
        V = shape.vertices[shape.triangles].reshape(-1, 3)
        N = shape.normals[shape.triangles].reshape(-1, 3)
        C = np.tile(np.asarray(colour, dtype=np.float32), (len(V), 1))
        data = np.hstack([V, N, C]).astype(np.float32)
        buf = self.ctx.buffer(data.tobytes())
        return self.ctx.vertex_array(self.lit, [(buf, "3f 3f 3f", "in_position", "in_normal", "in_colour")])

    def set_brain(self, positions: np.ndarray, normals: np.ndarray) -> None:
        self.positions.write(np.ascontiguousarray(positions, dtype=np.float32))
        self.normals.write(np.ascontiguousarray(normals, dtype=np.float32))

    def set_colours(self, colours: np.ndarray) -> None:
        self.colours.write(np.ascontiguousarray(colours, dtype=np.float32))

    def target(self, width: int, height: int):
        """The offscreen framebuffer at this size (made again when the size changed)."""
        if self.fbo is None or self.fbo.size != (width, height):
            if self.fbo is not None:
                self.fbo.release()
            self.fbo = self.ctx.framebuffer(color_attachments=[self.ctx.renderbuffer((width, height))],
                                            depth_attachment=self.ctx.depth_renderbuffer((width, height)))
        return self.fbo

    def _atlas(self, px: int):
        if px not in self.atlases:
            if len(self.atlases) >= 32:  # a window dragged through many sizes: drop the oldest
                oldest = next(iter(self.atlases))
                self.atlases.pop(oldest)[1].release()
            a = atlas(px)
            tex = self.ctx.texture((a.image.shape[1], a.image.shape[0]), 1, np.ascontiguousarray(a.image).tobytes(), alignment=1)
            tex.filter = (self.ctx.NEAREST, self.ctx.NEAREST)  # glyphs land on whole pixels: texel for pixel
            self.atlases[px] = (a, tex)
        return self.atlases[px]

    def text_quads(self, text: str, x: float, y: float, px: int, align: str):
        """(quads (n, 8) in framebuffer pixels and atlas coordinates, atlas) of one text item;
        lines after the first go down by the atlas's line height."""
        a, _ = self._atlas(px)
        out = []
        for k, line in enumerate(text.split("\n")):
            quads, width = a.layout(line)
            if align == "middle" and len(quads):
                x0, _, x1, _ = a.ink(line)
                dx = x - (x0 + x1) / 2.0
            else:
                dx = x - {"left": 0.0, "center": width / 2.0, "right": width}.get(align, 0.0)
            q = quads.copy()
            q[:, [0, 2]] += round(dx)
            q[:, [1, 3]] += round(y + k * a.line_height)
            out.append(q)
        return (np.concatenate(out) if out else np.zeros((0, 8), np.float32)), a

    def flat_vertices(self, overlay: Overlay):
        """The overlay as triangles: (vertex data, [(atlas px or None, first, count)])."""
        parts, runs, first = [], [], 0

        def rect(x0, y0, x1, y1, s0, t0, s1, t1, rgba):
            return np.array([[x0, y0, s0, t0, *rgba], [x1, y0, s1, t0, *rgba], [x1, y1, s1, t1, *rgba],
                             [x0, y0, s0, t0, *rgba], [x1, y1, s1, t1, *rgba], [x0, y1, s0, t1, *rgba]], dtype=np.float32)

        if overlay.quads:
            parts += [rect(x0, y0, x1, y1, 0, 0, 0, 0, rgba) for x0, y0, x1, y1, rgba in overlay.quads]
            runs.append((None, 0, 6 * len(overlay.quads)))
            first = 6 * len(overlay.quads)
        for text, x, y, px, rgb, align in overlay.texts:
            q, _ = self.text_quads(text, x, y, int(px), align)
            if not len(q):
                continue
            rgba = (*rgb, 1.0)
            x0, y0, x1, y1, s0, t0, s1, t1 = (q[:, k:k + 1] for k in range(8))
            colour = np.tile(np.asarray(rgba, dtype=np.float32), (len(q), 1))
            corners = [np.hstack(c + [colour]) for c in ([x0, y0, s0, t0], [x1, y0, s1, t0], [x1, y1, s1, t1],
                                                          [x0, y0, s0, t0], [x1, y1, s1, t1], [x0, y1, s0, t1])]
            parts.append(np.stack(corners, axis=1).reshape(-1, FLAT_FLOATS))
            runs.append((int(px), first, 6 * len(q)))
            first += 6 * len(q)
        data = np.concatenate(parts).astype(np.float32) if parts else np.zeros((0, FLAT_FLOATS), np.float32)
        return data, runs

    def draw(self, target, camera, placed: list[Placed], arrows: np.ndarray | None, flat, markers: np.ndarray | None = None,
             bars=None) -> None:
        """One frame into `target` (the window's screen or an offscreen framebuffer): `arrows`
        are triangles of the force arrows (k, 9) or None; `flat` is flat_vertices' result.
        `markers` (triangles like the arrows) are the hands' targets, drawn over the scene (no
        depth test: the tissue pulled up never hides them); `bars` (flat_vertices' result) are
        drawn over the overlay: what changes every frame, kept out of the overlay's cache."""
        ctx = self.ctx
        target.use()
        ctx.viewport = (0, 0, camera.width, camera.height)
        ctx.clear(1.0, 1.0, 1.0, 1.0, depth=1.0)
        ctx.enable(moderngl.DEPTH_TEST | moderngl.CULL_FACE)
        ctx.disable(moderngl.BLEND)
        mvp = camera.projection() @ camera.view_matrix()
        self.lit["mvp"].write(mvp.T.astype(np.float32).tobytes())
        self.lit["eye"].value = tuple(camera.eye)
        up, right, out = -camera.R[1], camera.R[0], -camera.R[2]
        key = 0.6 * up - 0.4 * right + 0.7 * out
        self.lit["key"].value = tuple(key / np.linalg.norm(key))
        self._place(np.eye(3), np.zeros(3))
        self.lit["specular"].value, self.lit["shininess"].value = 0.06, 24.0
        self.brain.render()
        self.lit["specular"].value, self.lit["shininess"].value = 0.55, 48.0
        for p in placed:
            self._place(p.R, p.t)
            self.instruments[p.kind].render()
        if arrows is not None and len(arrows):
            self._place(np.eye(3), np.zeros(3))
            self.lit["specular"].value = 0.15
            self.arrow_buffer.orphan(max(len(arrows) * 36, 36))
            self.arrow_buffer.write(np.ascontiguousarray(arrows, dtype=np.float32))
            self.arrow.render(vertices=len(arrows))
        if markers is not None and len(markers):
            ctx.disable(moderngl.DEPTH_TEST)
            self._place(np.eye(3), np.zeros(3))
            self.lit["specular"].value = 0.25
            self.marker_buffer.orphan(max(len(markers) * 36, 36))
            self.marker_buffer.write(np.ascontiguousarray(markers, dtype=np.float32))
            self.marker.render(vertices=len(markers))
            ctx.enable(moderngl.DEPTH_TEST)
        self._flat(flat, camera)
        if bars is not None:
            self._flat(bars, camera)

    def _flat(self, flat, camera) -> None:
        ctx = self.ctx
        data, runs = flat
        if runs:
            ctx.disable(moderngl.DEPTH_TEST | moderngl.CULL_FACE)
            ctx.enable(moderngl.BLEND)
            ctx.blend_func = moderngl.SRC_ALPHA, moderngl.ONE_MINUS_SRC_ALPHA
            self.flat["screen"].value = (float(camera.width), float(camera.height))
            self.flat_buffer.orphan(max(data.nbytes, 4))
            self.flat_buffer.write(data)
            for px, first, count in runs:
                self.flat["textured"].value = px is not None
                if px is not None:
                    self._atlas(px)[1].use(0)
                    self.flat["atlas"].value = 0
                self.flat_vao.render(first=first, vertices=count)

    def _place(self, R, t) -> None:
        M = np.eye(4)
        M[:3, :3], M[:3, 3] = R, t
        self.lit["model"].write(M.T.astype(np.float32).tobytes())
        self.lit["normal_matrix"].write(np.asarray(R, dtype=np.float32).T.tobytes())

    def read(self, target, width: int, height: int) -> np.ndarray:
        """RGB bytes of `target`, top row first."""
        data = target.read(viewport=(0, 0, width, height), components=3, alignment=1)
        return np.frombuffer(data, dtype=np.uint8).reshape(height, width, 3)[::-1].copy()
