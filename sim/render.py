"""Offscreen pictures of the deforming brain with the virtual hands (open3d, headless).

Importing this module loads open3d; only scenes with ``renderer.kind = "offscreen"`` do.

Which open3d renderer: on these machines (no GPU) the Filament ``OffscreenRenderer`` runs on
Mesa's CPU Vulkan driver at 2 to 30 s per frame of the 40k-triangle brain, while the classic
OpenGL ``Visualizer`` with an invisible window falls back to an EGL offscreen context on Mesa's
llvmpipe and draws the same frame in about 25 ms (measured with bench/render.py). We use the
latter; it needs the EGL packages the Makefile installs.
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Callable
from pathlib import Path

import numpy as np
import open3d as o3d

SKIN = (0.93, 0.76, 0.63)
TISSUE = np.array([0.88, 0.80, 0.78])  # colour where nothing moves


def hand_mesh() -> o3d.geometry.TriangleMesh:
    """A stylised pinching hand, fingertips at the origin, +x along the pull, +z up (metres)."""
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


class BrainRenderer:
    """One invisible OpenGL window reused for every frame."""

    def __init__(self, mesh, width: int = 640, height: int = 480):
        import matplotlib

        o3d.utility.set_verbosity_level(o3d.utility.VerbosityLevel.Error)
        # Mesa's software rasteriser would take every core; leave one to the servo process
        os.environ.setdefault("LP_NUM_THREADS", "1")
        if not os.environ.get("XDG_RUNTIME_DIR"):  # Mesa's EGL complains without one
            os.environ["XDG_RUNTIME_DIR"] = tempfile.mkdtemp(prefix="xdg-")
        self.mesh = mesh
        self.width, self.height = width, height
        self.vis = o3d.visualization.Visualizer()
        if not self.vis.create_window(window_name="brain", width=width, height=height, visible=False):
            raise RuntimeError("open3d could not create an offscreen OpenGL context (EGL); see README set-up")
        opt = self.vis.get_render_option()
        opt.background_color = np.array([1.0, 1.0, 1.0])
        opt.mesh_show_back_face = True
        opt.light_on = True
        self.brain = o3d.geometry.TriangleMesh(
            o3d.utility.Vector3dVector(mesh.vertices), o3d.utility.Vector3iVector(mesh.triangles)
        )
        self.brain.vertex_colors = o3d.utility.Vector3dVector(np.tile(TISSUE, (mesh.n_vertices, 1)))
        self.brain.compute_vertex_normals()
        self.vis.add_geometry(self.brain)
        self._hand_rest = hand_mesh()
        self._hand_vertices = np.asarray(self._hand_rest.vertices).copy()
        self.hands: list[o3d.geometry.TriangleMesh] = []
        lo, hi = mesh.bounds()
        self.center = (lo + hi) / 2.0
        self.cmap = matplotlib.colormaps["inferno"]
        self._camera_set = False

    def _set_camera(self) -> None:
        ctr = self.vis.get_view_control()
        ctr.set_lookat(self.center)
        ctr.set_front([0.0, -0.42, 0.91])  # from above and behind, like the surgeon's view
        ctr.set_up([0.0, 0.0, 1.0])
        ctr.set_zoom(0.66)
        self._camera_set = True

    def render(self, positions: np.ndarray, magnitude01: np.ndarray, hands: list[tuple[np.ndarray, np.ndarray]]) -> np.ndarray:
        """positions (n, 3); magnitude01 in [0, 1] per vertex; hands: (point, pull direction).

        Returns an (height, width, 3) uint8 image.
        """
        heat = self.cmap(0.25 + 0.7 * magnitude01)[:, :3]
        w = np.clip(magnitude01 * 4.0, 0.0, 1.0)[:, None]
        self.brain.vertices = o3d.utility.Vector3dVector(positions)
        self.brain.vertex_colors = o3d.utility.Vector3dVector((1 - w) * TISSUE + w * heat)
        self.brain.compute_vertex_normals()
        self.vis.update_geometry(self.brain)
        while len(self.hands) < len(hands):
            h = o3d.geometry.TriangleMesh(self._hand_rest)
            self.vis.add_geometry(h, reset_bounding_box=False)
            self.hands.append(h)
        for h, (point, direction) in zip(self.hands, hands):
            T = _pose(point, direction)
            h.vertices = o3d.utility.Vector3dVector(self._hand_vertices @ T[:3, :3].T + T[:3, 3])
            h.compute_vertex_normals()
            self.vis.update_geometry(h)
        if not self._camera_set:
            self._set_camera()
        self.vis.poll_events()
        self.vis.update_renderer()
        img = np.asarray(self.vis.capture_screen_float_buffer(do_render=True))
        return (np.clip(img, 0.0, 1.0) * 255).astype(np.uint8)

    def close(self) -> None:
        self.vis.destroy_window()


def _pose(point, direction) -> np.ndarray:
    x = np.asarray(direction, dtype=np.float64)
    x = x - x[2] * np.array([0.0, 0.0, 1.0])
    x = x / np.linalg.norm(x) if np.linalg.norm(x) > 1e-9 else np.array([1.0, 0.0, 0.0])
    z = np.array([0.0, 0.0, 1.0])
    y = np.cross(z, x)
    T = np.eye(4)
    T[:3, 0], T[:3, 1], T[:3, 2], T[:3, 3] = x, y, z, point
    return T


def render_snapshots(result, scene, out_dir: Path, progress: Callable[[int, int], None] | None = None) -> int:
    """Write frame_NNNN.png for every snapshot: the rendering, a colour bar and the forces."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    mesh = scene.mesh
    r = scene.spec.renderer
    renderer = BrainRenderer(mesh, r.width, r.height)
    scale = max(float(np.linalg.norm(s.displacement, axis=1).max()) for s in result.snapshots) or 1e-3
    pulls = [np.asarray(h.pull) for h in scene.spec.hands]
    total = len(result.snapshots)
    norm = matplotlib.colors.Normalize(0.0, scale * 1e3)
    for k, snap in enumerate(result.snapshots):
        mag = np.linalg.norm(snap.displacement, axis=1)
        hands = [(np.asarray(p), d) for p, d in zip(snap.hand_positions, pulls)]
        img = renderer.render(mesh.vertices + snap.displacement.astype(np.float64), mag / scale, hands)
        fig = plt.figure(figsize=(r.width / 100 + 1.3, r.height / 100 + 0.5), dpi=100)
        ax = fig.add_axes((0.0, 0.0, r.width / (r.width + 130), 1.0 - 50 / (r.height + 50)))
        ax.imshow(img)
        ax.axis("off")
        cax = fig.add_axes((r.width / (r.width + 130) + 0.02, 0.15, 0.025, 0.6))
        fig.colorbar(matplotlib.cm.ScalarMappable(norm=norm, cmap=renderer.cmap), cax=cax, label="displacement (mm)")
        forces = ", ".join(
            f"{name} {np.linalg.norm(f):.2f} N" + ("" if g else " (open)")
            for name, f, g in zip(result.hand_names, snap.forces, snap.grasped)
        )
        fig.suptitle(f"{result.model}  t = {snap.t:.2f} s   {forces}", fontsize=10, y=0.985)
        fig.savefig(out_dir / f"frame_{k:04d}.png")
        plt.close(fig)
        if progress is not None:
            progress(k + 1, total)
    renderer.close()
    return total
