"""Pictures of a hand's target in the participant view (docs/participant.md, issue 32): the
retraction scene (protocols/scenes/retraction.toml) run in real time with its scripted hands,
drawn offscreen (EGL, no display) at 1280x720 with the captions of a trial ending on its
targets; a frame kept before the grasp, one mid-pull and one once both targets are held.

    .venv/bin/python scripts/target_screenshots.py [--out docs/img] [--frames]

`--frames` also prints the view's frame time (p50, p99) of this run and of the same frames
drawn without the targets (how much the targets cost a frame).
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "protocols" / "scenes" / "retraction.toml"
NAMES = ("participant_target_before.png", "participant_target_pull.png", "participant_target_held.png")


def scene_file(tmp: Path) -> Path:
    """The retraction scene with its scripted pull starting once the grasp has surely taken hold
    (a target counts from where the grasp took hold, and the first grasp of a process takes a
    few hundred ms: pulling before it, the scripted hands would stop short of their targets)."""
    text = SCENE.read_text().replace('"../../data/', f'"{ROOT}/data/').replace('"../models/', f'"{ROOT}/protocols/models/')
    text = text.replace("pull_start = 0.5", "pull_start = 1.5").replace('kind = "offscreen"', 'kind = "none"')
    path = tmp / "retraction.toml"
    path.write_text(text)
    return path


def shoot(out: Path, width: int = 1280, height: int = 720, frames: bool = False) -> dict:
    import copy
    import tempfile

    from sim.run import Pacing, run_scene
    from sim.scene import build_scene
    from sim.view.window import HandState, ParticipantView

    with tempfile.TemporaryDirectory() as tmp:
        scene = build_scene(scene_file(Path(tmp)))
    view = ParticipantView(scene.mesh, pulls=[h.pull for h in scene.spec.hands], width=width, height=height, visible=False,
                           camera=scene.spec.view, targets=scene.targets())
    taken: list[Path] = []
    drawn: list = []  # (displacement, hands with their targets as drawn) of every frame
    draw = view.draw

    def caption(phase, left):
        return {"top": "Condition A (1 of 1) - trial 1 of 10", "center": f"{math.ceil(left)} s",
                "bottom": "Pull to the target and hold it there to end the trial"}

    def draw_and_keep(displacement, hands, read_t=None, heat01=None, latch=None):
        draw(displacement, hands, read_t, heat01, latch)
        hands = view._last_hands
        if frames:
            drawn.append((None if displacement is None else np.array(displacement), copy.deepcopy(hands)))
        states = [h.target for h in hands if h.target is not None]
        if len(taken) == len(NAMES) or not states:
            return
        wanted = (all(h.grasped_vertex is None for h in hands), 0.45 <= min(s.progress for s in states) <= 0.75,
                  False)[len(taken)]
        if wanted:
            taken.append(out / NAMES[len(taken)])
            view.screenshot(taken[-1])

    view.draw = draw_and_keep
    start = time.perf_counter()
    try:
        result = run_scene(scene, duration=scene.spec.duration, time_scale=1.0, pacing=Pacing(view=view, caption=caption),
                           end_on_targets=True)
        if len(taken) == len(NAMES) - 1:  # the run ended on the frame both were held: that state, drawn
            draw(view._positions - scene.mesh.vertices, view._last_hands)
            taken.append(out / NAMES[-1])
            view.screenshot(taken[-1])
        report = {"ended_early": result.ended_early, "targets_held": result.targets_held, "ran_s": round(time.perf_counter() - start, 2),
                  "pictures": [str(p) for p in taken]}
        if frames:  # the run's frames drawn again, alone, without and with their targets in turn: what the targets cost
            ms: dict = {False: [], True: []}
            for _ in range(3):
                for u, hands in drawn:
                    for keep in (False, True):
                        view.reset_stats()
                        draw(u, [HandState(h.position, h.force, h.grasped_vertex, h.holding, h.target if keep else None) for h in hands])
                        ms[keep].append(view.frame_s[0] * 1e3)
            own = []  # the view's own work for the targets (rings, lines, bars), besides the GL calls
            for _, hands in drawn:
                t0 = time.perf_counter()
                view._show_targets(hands)
                own.append((time.perf_counter() - t0) * 1e3)
            report["frame_ms"] = {("with_targets" if keep else "without_targets"): {"p50": round(float(np.percentile(v, 50)), 2),
                                  "p99": round(float(np.percentile(v, 99)), 2), "frames": len(v)} for keep, v in ms.items()}
            report["frame_ms"]["targets_prepare_ms"] = {"p50": round(float(np.percentile(own, 50)), 3), "p99": round(float(np.percentile(own, 99)), 3)}
            report["renderer"] = view.renderer_name
    finally:
        view.close()
    return report


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "img")
    ap.add_argument("--frames", action="store_true", help="also the frame time with and without the targets")
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    print(json.dumps(shoot(args.out, frames=args.frames), indent=2))


if __name__ == "__main__":
    main()
