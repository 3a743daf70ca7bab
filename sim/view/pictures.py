"""Pictures of a run after it ended: each snapshot drawn by the participant view's renderer
offscreen (sim/view/window.py with `visible=False`: OpenGL on EGL, no display needed), composed with a
colour bar and the forces (matplotlib). Only scenes with ``renderer.kind = "offscreen"`` import it.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import matplotlib
import matplotlib.pyplot as plt
import numpy as np

from sim.view.window import HandState, ParticipantView


def render_snapshots(result, scene, out_dir: Path, progress: Callable[[int, int], None] | None = None) -> int:
    """Write frame_NNNN.png for every snapshot: the rendering, a colour bar and the forces."""
    matplotlib.use("Agg")

    mesh = scene.mesh
    r = scene.spec.renderer
    renderer = ParticipantView(mesh, pulls=[h.pull for h in scene.spec.hands], width=r.width, height=r.height, visible=False,
                               camera=scene.spec.view)
    scale = max(float(np.linalg.norm(s.displacement, axis=1).max()) for s in result.snapshots) or 1e-3
    total = len(result.snapshots)
    norm = matplotlib.colors.Normalize(0.0, scale * 1e3)
    for k, snap in enumerate(result.snapshots):
        u = snap.displacement.astype(np.float64)
        renderer.draw(u, [HandState(p, holding=g) for p, g in zip(snap.hand_positions, snap.grasped)], heat01=np.linalg.norm(u, axis=1) / scale)
        img = renderer.image()
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
