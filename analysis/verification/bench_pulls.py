"""A model on the accuracy bench's pulls (`analysis.verification.accuracy`): built as the bench
configures it, pulled from rest along each pull, its force sampled (docs/accuracy.md).

- **In frames** (`speed` None, the timeless truth's pulls): the hand steps through the scene's
  visual frames, `frames_per_sample` of them between samples (7.5 mm/s at the 0.5 mm samples and
  30 Hz), each sample the force right after its frame. A model that uses time is pulled in time
  instead, at `QUASI_STATIC_M_S`: the timeless truth is the tissue at the data's rate.
- **In time** (`speed` m/s): the hand moves at the speed from rest to the last sample, then holds
  there for each of `holds` (s); the frames come at the scene's rate wherever they fall, a model
  that uses time is asked its force at every servo tick (told the time and the hand's velocity),
  and each sample is the force at its own displacement and time, from the state of the last
  frame before it (what the servo renders between frames).
"""

from __future__ import annotations

import dataclasses
import math
import time

import numpy as np

from analysis.verification.pulls_in_time import record_times
from brainsim_assets import path as _asset
from sim.errors import SceneError, SimError
from sim.models.api import REST, deformation_at, force_at
from sim.models.plate_spring import load_params
from sim.models.registry import model_class
from sim.pulls import Pull, scene_with

HANDSET_PARAMS = _asset("protocols/models/plate_spring_handset.toml")
LOCATED_PARAMS = _asset("protocols/models/plate_spring_located.toml")
PULL_SPEED = 0.010  # m/s, a careful surgical pull (the scene's: 12 mm in 1.2 s)
# a hand near the data's rate: at 0.2 mm/s the left-lateral pull strains at the data's fastest
# rate (0.0028/s; docs/viscoelastic.md, Counter-checks), the median pull at about twice it: some
# 70 times slower than the hands' 14.2 mm/s, and 60 s a pull
QUASI_STATIC_M_S = 0.0002
TICK_TIMING_CALLS = 20000  # per pull: the tick's median time


def frames_per_sample(xs, frame_hz: float) -> int:
    """Visual frames between samples: the nearest whole number to PULL_SPEED (at least one); the
    speed the models are then pulled at is `pull_speed` (0.5 mm samples at 30 Hz: 2 frames, 7.5 mm/s)."""
    return max(1, round(float(xs[0]) / PULL_SPEED * frame_hz))


def pull_speed(xs, frame_hz: float) -> float:
    return float(xs[0]) / frames_per_sample(xs, frame_hz) * frame_hz


def hand_speed(speed: float | None, uses_time: bool) -> float | None:
    """The speed (m/s) a model is pulled at for a bench speed (`speed`; None: the timeless
    truth's): that speed; for the timeless truth `QUASI_STATIC_M_S` if the model uses time, else
    None (in frames)."""
    return QUASI_STATIC_M_S if speed is None and uses_time else speed


def pull_plan(xs, frame_hz: float, servo_hz: float, speed: float | None, holds, uses_time: bool) -> tuple[np.ndarray, int, int]:
    """A pull at `hand_speed`'s `speed` (None: in frames): the times (s) it reaches the samples
    `xs` (m) and then, in time, each of `holds` (s after the ramp's end); its visual frames; and
    the servo ticks a frame a model that uses time is asked at (0: none)."""
    if speed is None:
        return np.asarray(xs, dtype=np.float64) / pull_speed(xs, frame_hz), frames_per_sample(xs, frame_hz) * len(xs), 0
    times = record_times(xs, speed, holds)[0]
    return times, math.ceil(times[-1] * frame_hz - 1e-9), max(1, round(servo_hz / frame_hz)) if uses_time else 0


def build_model(scene, setting, handset, e_ratio: float):
    """The bench's model of `setting` (`accuracy.Setting`) on the scene, the plate-spring stack's
    modulus scaled by `e_ratio` with the brain's."""
    cls = model_class(setting.model)
    opts = dict(setting.options)
    options = scene.spec.options_of(setting.model)
    if setting.model == "plate_spring":
        params = {"handset": lambda: load_params(handset), "located": lambda: load_params(LOCATED_PARAMS),
                  "scene": lambda: options["params"]}[opts.pop("params", "scene")]()
        # the stack's modulus is the tissue's: scale it with the bench's modulus
        opts["params"] = dataclasses.replace(params, E=params.E * e_ratio)
    try:
        return cls.build(scene.mesh, options | opts, scene)
    except SimError:
        raise
    except Exception as exc:  # a lab's model may fail in any way: one line naming it
        raise SceneError(f"model {setting.model!r}: build raised {type(exc).__name__}: {exc}") from None


def model_pulls(scene_path, young: float, setting, pulls: list[Pull], xs, handset=HANDSET_PARAMS, e_ratio: float = 1.0,
                speed: float | None = None, holds=()) -> dict:
    """Every pull from rest, in frames or in time (the module's doc), the force sampled at `xs`
    and then, in time, at each hold: `force` (pulls, samples, 3) on the hand, the samples'
    times from rest (`times_s`, s), the hand's speed (`speed_m_s`), the frame's and the
    tick's times, the build's, and the pulls the model gave up on. `e_ratio` is `young` over the
    scene's own modulus (it scales the plate-spring stack's E)."""
    scene = scene_with(scene_path, young)
    xs = np.asarray(xs, dtype=np.float64)
    start = time.perf_counter()
    model = build_model(scene, setting, handset, e_ratio)
    build_s = time.perf_counter() - start
    frame_hz, servo_hz = scene.spec.visual_rate_hz, scene.spec.servo_rate_hz
    speed = hand_speed(speed, bool(model.uses_time))
    times, n_frames, ticks_per_frame = pull_plan(xs, frame_hz, servo_hz, speed, holds, bool(model.uses_time))
    force = np.zeros((len(pulls), len(times), 3))
    frame_s: list[float] = []
    tick_s: list[float] = []
    unstable = 0
    for p, pull in enumerate(pulls):
        model.reset()  # back to rest: the mass-spring's state, the corotational FEM's frame
        contact = model.grasp(pull.point, 0)
        direction = np.asarray(pull.direction)
        if speed is None:
            force[p] = _in_frames(model, contact, direction, xs, n_frames, frame_hz, frame_s)
        else:
            force[p] = _in_time(model, contact, direction, xs[-1] / speed, speed, times, n_frames, ticks_per_frame, frame_hz, frame_s)
        law = model.law(contact)
        v = tuple(float(c) for c in direction * (speed if speed is not None else pull_speed(xs, frame_hz)))
        tick_s.append(_tick_time(law, tuple(float(c) for c in direction * xs[-1]), v if getattr(law, "uses_time", False) else None))
        unstable += int(bool(model.unstable))  # pulls the model gave up on (it renders zero force)
    return {"model": setting.model, "setting": setting.setting, "force": force, "times_s": times, "in_time": speed is not None,
            "speed_m_s": float(speed if speed is not None else pull_speed(xs, frame_hz)),
            "frame_ms": float(np.median(frame_s) * 1e3), "frame_ms_p99": float(np.percentile(frame_s, 99) * 1e3),
            "tick_us": float(np.median(tick_s) * 1e6), "build_s": build_s, "unstable": unstable}


def _in_frames(model, contact, direction, xs, n_frames: int, frame_hz: float, frame_s: list) -> np.ndarray:
    """A model that does not use time through the samples in `n_frames` frames, `frames_per_sample` a sample."""
    per_sample = n_frames // len(xs)
    out = np.zeros((len(xs), 3))
    for f in range(1, n_frames + 1):
        d = tuple(float(c) for c in direction * xs[-1] * f / n_frames)
        t0 = time.perf_counter()
        deformation_at(model, [contact], [d])
        frame_s.append(time.perf_counter() - t0)
        if f % per_sample == 0:
            out[f // per_sample - 1] = force_at(model, contact, d)
    return out


def _in_time(model, contact, direction, t_ramp: float, speed: float, samples, n_frames: int, ticks_per_frame: int, frame_hz: float,
             frame_s: list) -> np.ndarray:
    """The hand at `speed` from rest for `t_ramp` s, then held, asked at the samples' times
    (`pull_plan`): `n_frames` frames at the scene's rate; a model that uses time asked at every
    servo tick (`ticks_per_frame`) and at each sample's own time."""
    ticks = [(f + j / ticks_per_frame) / frame_hz for f in range(n_frames) for j in range(1, ticks_per_frame + 1)]
    # (time, kind, sample index): a frame before a tick before a sample at the same time
    events = sorted([(f / frame_hz, 0, -1) for f in range(1, n_frames + 1)] + [(t, 1, -1) for t in ticks]
                    + [(float(t), 2, k) for k, t in enumerate(samples)])

    def hand(t):
        d = tuple(float(c) for c in direction * speed * min(t, t_ramp))
        v = tuple(float(c) for c in direction * speed) if t <= t_ramp else REST
        return d, v

    out = np.zeros((len(samples), 3))
    for t, kind, k in events:
        d, v = hand(t)
        if kind == 0:
            t0 = time.perf_counter()
            deformation_at(model, [contact], [d], [v], t)
            frame_s.append(time.perf_counter() - t0)
        elif kind == 1:
            force_at(model, contact, d, v, t)
        else:
            out[k] = force_at(model, contact, d, v, t)
    return out


def _tick_time(law, d, velocity=None, reps: int = TICK_TIMING_CALLS) -> float:
    """Median of 5 batches: the per-tick force call the servo makes (the model's law for the
    contact, `sim.models.api.TissueModel.law`: a model that writes only ``force`` has no
    contact law of its own), plain floats; with `velocity`, a law of a model that uses time,
    told the velocity and a time."""
    batches = []
    for _ in range(5):
        t0 = time.perf_counter()
        if velocity is None:
            for _ in range(reps // 5):
                law.force(d)
        else:
            for _ in range(reps // 5):
                law.force(d, velocity, 1.0)
        batches.append((time.perf_counter() - t0) / (reps // 5))
    return float(np.median(batches))
