"""The force plot's lines: each condition's force on the scene's scripted pull, and beside it what
the synthetic observer's truth (the converged reference) would push back with for the same hand
motion. Runs the simulator, so it lives above the reports that draw it (analysis.reports.plots)."""

from __future__ import annotations

import numpy as np

from analysis.verification.truth import load_truth
from sim.run import run_scene
from sim.scene import Scene, load_scene
from studyctl.conditions import condition_scene_spec, scene_itself
from studyctl.synthetic.observer import truth_forces


def force_traces(protocol, duration: float = 3.0) -> dict:
    """The scene's scripted pull, run with each of the study's conditions (lockstep); the
    converged reference's force (the synthetic observer's truth, analysis/verification/truth.py) for each
    run's own hand motion. Returns {condition: (t, force, reference)} for the first hand."""
    out = {}
    truth = load_truth(scene_itself(protocol))  # the scene's own, whatever a condition changes
    spec = load_scene(protocol.scene)
    for m in protocol.conditions:
        scene = Scene(condition_scene_spec(protocol, m, spec))
        r = run_scene(scene, duration=duration, time_scale=0)
        f = np.linalg.norm(r.forces[:, 0], axis=1)
        out[m] = (r.times, f, truth_forces(r, truth, scene.mesh)[:, 0])
    return out
