"""Play a stored trial back: the recorded hand motion of each hand drives a replay device in the
same scene and model, in lockstep (deterministic: the forces of a lockstep trial come out
exactly as recorded) or in real time in the participant view."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from analysis.errors import InputError
from analysis.study.trace_files import read_trace, trace_file
from sim.run import run_scene, write_outputs
from sim.scene import Scene
from studyctl.conditions import condition_scene_spec, config_sha256, resolved_config
from studyctl.store import Store
from studyctl.store.trials import session_exists, session_trials


def replay_trial(db, session_id: int, k: int, view: str = "none", frames_dir: Path | None = None, fullscreen: bool = False) -> dict:
    with Store(db, mode="read") as store:
        if not session_exists(store, session_id):
            raise InputError(f"--session: {db}: no session {session_id}")
        trials = session_trials(store, session_id)
        if not 1 <= k <= len(trials):
            raise InputError(f"--trial: {k} is out of range; session {session_id} has {len(trials)} stored trials (allowed: 1..{len(trials)})")
        row = trials[k - 1]
        if not row["trace_path"]:
            raise InputError(f"--trial: trial {k} of session {session_id} was stored without a trace (before schema 2)")
        trace = read_trace(db, row["trace_path"], row["trace_sha256"])  # checks the SHA-256
        protocol = store.protocol()
    path = trace_file(db, row["trace_path"])
    spec = condition_scene_spec(protocol, row["model"])
    if row["config_sha256"] and config_sha256(resolved_config(row["model"], spec)) != row["config_sha256"]:
        raise InputError(f"--trial: condition {row['model']!r} of session {session_id} ran configuration {row['config_sha256'][:12]}; "
                         f"the protocol's scene now gives another (its scene or parameter files changed): cannot replay it")
    scene = Scene(spec)
    hands = tuple(dataclasses.replace(h, device="replay", trace=path, trace_hand=name)
                  for h, name in zip(scene.spec.hands, trace.hand_names))
    scene.spec = dataclasses.replace(scene.spec, hands=hands)
    duration = len(trace.times) / scene.spec.servo_rate_hz
    if view == "window":
        from sim.live import run_view  # lazy: OpenGL and glfw, only for a window

        result = run_view(scene, "window", duration=duration, fullscreen=fullscreen)
    else:
        result = run_scene(scene, duration=duration, time_scale=0.0, snapshots=frames_dir is not None)
    n = min(len(result.forces), len(trace.forces))
    diff = float(np.max(np.abs(result.forces[:n] - trace.forces[:n]))) if n else None
    out = {"session": session_id, "trial": k, "model": row["model"], "label": row["label"], "ticks": int(len(result.times)),
           "recorded_ticks": int(len(trace.times)), "mode": result.mode, "max_force_difference_n": diff}
    if frames_dir is not None:
        out["frames"] = write_outputs(result, scene, frames_dir)
    if result.view is not None:
        out["view"] = result.view
    return out
