"""Real-time runs drawn in the participant view: `studyctl sim run --view window` (the scripted
pull, watched) and `studyctl sim live` (try the simulator: mouse, simulated or real devices)."""

from __future__ import annotations

from pathlib import Path

from sim.errors import ParameterError
from sim.run import Pacing, RunResult, run_scene
from sim.view.window import open_view

LIVE_HELP = "Left button: grasp with the left hand. Right button: the right hand. Drag to pull, wheel for depth. Q: quit."


def run_view(scene, view: str = "window", duration: float | None = None, time_scale: float = 1.0,
             screenshot: Path | None = None, live: bool = False, snapshots: bool = False, fullscreen: bool = False) -> RunResult:
    """Run `scene` in real time while the participant view draws every visual frame. With
    `live`, the run lasts until Q, Escape or the window is closed (or `duration`)."""
    if time_scale <= 0:
        raise ParameterError("--view window: the participant view needs real time (--time-scale > 0)")
    if screenshot is not None and not Path(screenshot).parent.is_dir():
        raise ParameterError(f"--screenshot: {Path(screenshot).parent} is not a directory")
    mouse = any(h.device == "mouse" for h in scene.spec.hands)
    shown = open_view(view, scene, show_force=mouse, fullscreen=fullscreen)
    try:
        if live:
            def caption(phase, left):
                return {"top": "Simulator: free pulling", "bottom": LIVE_HELP if mouse else "Q: quit", "center": ""}
        else:
            def caption(phase, left):
                return {"top": f"{left:4.1f} s left", "bottom": "", "center": ""}
        pacing = Pacing(view=shown, caption=caption, stop_keys=("q", "escape"))
        result = run_scene(scene, duration=duration, time_scale=time_scale, pacing=pacing, snapshots=snapshots)
        if screenshot is not None and shown is not None:
            shown.screenshot(screenshot)
        return result
    finally:
        if shown is not None:
            shown.close()
