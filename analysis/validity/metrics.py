"""Performance metrics from the stored per-tick traces: per trial and hand,
outcome, safety, efficiency, force and smoothness; per trial, bimanual. Each metric's name, unit,
definition and source are in `METRICS` (and docs/metrics.md, which a test keeps in step).

- `Goal`: what the task asks of a hand (a pull target, its tolerance and hold time, a safe force
  limit); outcome metrics and the time and impulse above the limit need one, the rest do not;
- `trial_metrics(trace, goals)`: one trace's metrics as rows ``hand, metric, value``;
- `metrics_table(study, goals)`: every stored trial's, tidy (`COLUMNS`): one row per participant,
  condition, trial, hand and metric (bimanual metrics: hand "both").

The movement of a hand is its grasp: from the first tick its button is held to the last (the
whole trial if it never grasps). Kinematic metrics use low-passed positions
(analysis/validity/kinematics.py: 20 Hz keeps tremor, removes the encoders' quantisation).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
import pandas as pd

from analysis.study.study_snapshot import Study
from analysis.study.trace_files import read_trace
from analysis.validity import kinematics as kin
from sim.scene import build_scene
from sim.targets import SAFE_FORCE_N

# Brain damage began at a continuous retraction force of 30 g (0.29 N) in Yokoh, Sugita and
# Kobayashi 1983 (J Neurosurg 58:918-923, dog brain, strain-gauge retractor); the forces
# neurosurgeons use on brain tissue are of the same order (Marcus et al. 2014, Int J Med Robot,
# doi:10.1002/rcs.1568: 0.03-0.22 N; nervous tissue's mean of average forces 0.4 N across 45
# studies, Golahmadi et al. 2021, Ann Med Surg). A scene's target may set its own.

COLUMNS = ["code", "synthetic", "condition", "trial", "hand", "metric", "value", "unit"]
BOTH = "both"


@dataclass(frozen=True)
class Goal:
    """What the task asks of one hand. `target_m`: a displacement of the tip from where it grasped
    (3 values, m), or a distance along the pull (one value, m: the distance from the grasp point,
    in whatever direction); reached when the tip stays within `tolerance_m` of it for `hold_s`."""

    target_m: float | tuple[float, float, float]
    tolerance_m: float = 0.002
    hold_s: float = 0.5
    safe_force_n: float = SAFE_FORCE_N

    def __post_init__(self):
        t = np.atleast_1d(np.asarray(self.target_m, dtype=float))
        if t.shape not in ((1,), (3,)) or not np.all(np.isfinite(t)):
            raise ValueError(f"target_m {self.target_m!r}: a distance (m) or a 3-vector displacement (m)")
        if not (self.tolerance_m > 0 and self.hold_s >= 0 and self.safe_force_n > 0):
            raise ValueError("tolerance_m and safe_force_n must be positive, hold_s not negative")


@dataclass(frozen=True)
class Metric:
    name: str
    unit: str
    family: str  # outcome, safety, efficiency, force, smoothness, bimanual
    definition: str
    source: str
    needs_goal: bool = False


AZARNOUSH = "Azarnoush et al. 2015, Int J CARS (NeuroTouch metric tiers)"
ALOTAIBI = "Alotaibi et al. 2015, Surg Innov, doi:10.1177/1553350615579729"
METRICS: tuple[Metric, ...] = (
    Metric("target_reached", "1", "outcome", "1 when the tip stayed within the goal's tolerance of its target for the hold time, else 0",
           AZARNOUSH + ", tier 1", True),
    Metric("time_to_target", "s", "outcome", "from the grasp to the start of the first hold within tolerance (NaN when not reached)",
           AZARNOUSH + ", tier 2", True),
    Metric("final_error", "m", "outcome", "distance from the target at the release", AZARNOUSH + ", tier 1", True),
    Metric("overshoot", "m", "outcome", "how far the progress along the pull went beyond the target (0 if never)",
           "target-directed movement; this platform (docs/metrics.md)", True),
    Metric("peak_force", "N", "safety", "largest force magnitude over the whole trial", AZARNOUSH + ", tier 2"),
    Metric("time_above_limit", "s", "safety", "time, over the whole trial, the force magnitude exceeded the safe limit",
           "Yokoh et al. 1983, J Neurosurg 58:918-923 (the limit)", True),
    Metric("impulse_above_limit", "N s", "safety", "integral over the whole trial of max(|F| - limit, 0)",
           "Yokoh et al. 1983, J Neurosurg 58:918-923 (the limit)", True),
    Metric("duration", "s", "efficiency", "time from the grasp to the release", AZARNOUSH + ", tier 2"),
    Metric("path_length", "m", "efficiency", "length of the tip's path during the movement", AZARNOUSH + ", tier 2"),
    Metric("path_ratio", "1", "efficiency", "path length over the straight-line distance from grasp to release (1: straight)",
           ALOTAIBI + " (efficiency index)"),
    Metric("mean_speed", "m/s", "efficiency", "path length over duration", AZARNOUSH + ", tier 2"),
    Metric("peak_speed", "m/s", "efficiency", "largest tip speed during the movement", "Flash and Hogan 1985, J Neurosci 5:1688-1703"),
    Metric("pull_distance", "m", "efficiency", "largest distance of the tip from where it grasped during the movement",
           "this platform (docs/metrics.md; the bench's pulls, docs/viscoelastic.md)"),
    Metric("ramp_time", "s", "efficiency", "rise time of that distance, from 10% to 90% of the pull distance",
           "the step response's 10-90% rise time; this platform (docs/metrics.md)"),
    Metric("ramp_speed", "m/s", "efficiency", "0.8 pull distance over the ramp time: the speed of a constant-rate pull of the same rise",
           "this platform (docs/metrics.md; the bench's pull speeds, docs/viscoelastic.md)"),
    Metric("hold_time", "s", "efficiency", "from the ramp's end, how long the distance stays at 90% of the pull distance or more",
           "this platform (docs/metrics.md)"),
    Metric("mean_force", "N", "force", "mean force magnitude during the movement", AZARNOUSH + ", tier 2"),
    Metric("force_integral", "N s", "force", "integral of the force magnitude over the movement (summed force)", AZARNOUSH + ", tier 2"),
    Metric("force_p50", "N", "force", "median of the force magnitudes during the movement (the force histogram)", AZARNOUSH + ", tier 3"),
    Metric("force_p90", "N", "force", "90th percentile of the force magnitudes during the movement", AZARNOUSH + ", tier 3"),
    Metric("force_p99", "N", "force", "99th percentile of the force magnitudes during the movement", AZARNOUSH + ", tier 3"),
    Metric("sparc", "1", "smoothness", "spectral arc length of the speed profile (0 smoothest; minimum jerk about -1.40)",
           "Balasubramanian et al. 2015, J NeuroEng Rehabil 12:112"),
    Metric("force_ratio", "1", "bimanual", "mean force of the lighter hand over that of the heavier (1: even)",
           ALOTAIBI + " (bimanual forces ratio)"),
    Metric("movement_overlap", "1", "bimanual", "time both hands grasp over the time either does",
           "arXiv:2511.14879 (2025), simultaneous usage time"),
)
UNITS = {m.name: m.unit for m in METRICS}


def _goal_for(goals, hand: str) -> Goal | None:
    if goals is None or isinstance(goals, Goal):
        return goals
    return goals.get(hand) if isinstance(goals, Mapping) else None


def _outcome(times, disp, dt, goal: Goal) -> dict:
    """Error to the target and progress along the pull at every tick of the movement."""
    target = np.atleast_1d(np.asarray(goal.target_m, dtype=float))
    if target.shape == (3,):
        distance = float(np.linalg.norm(target))
        error = np.linalg.norm(disp - target, axis=1)
        progress = disp @ (target / distance) if distance > 0 else np.zeros(len(disp))
    else:
        distance = float(target[0])
        progress = np.linalg.norm(disp, axis=1)
        error = np.abs(progress - distance)
    inside = error <= goal.tolerance_m
    reached_at = math.nan
    start, held = None, 0.0
    for k in range(len(inside)):  # the first run of ticks within tolerance lasting the hold time
        if inside[k]:
            start = k if start is None else start
            held += dt[k]
            if held >= goal.hold_s - 1e-9:
                reached_at = float(times[start] - times[0])
                break
        else:
            start, held = None, 0.0
    return {"target_reached": float(not math.isnan(reached_at)), "time_to_target": reached_at,
            "final_error": float(error[-1]), "overshoot": max(0.0, float(progress.max()) - distance)}


def hand_metrics(times, positions, forces, buttons, goal: Goal | None = None) -> dict[str, float]:
    """One hand's metrics: positions (ticks, 3) m, forces (ticks, 3) N, buttons (ticks,)."""
    dt = kin.tick_durations(times)
    fmag = np.linalg.norm(np.asarray(forces, dtype=float), axis=1)
    out = {"peak_force": float(fmag.max()) if len(fmag) else math.nan}
    if goal is not None:
        out["time_above_limit"], out["impulse_above_limit"] = kin.above_limit(fmag, dt, goal.safe_force_n)
    w = kin.movement_window(buttons)
    t, p, f, d = times[w], kin.smooth_positions(times, positions)[w], fmag[w], dt[w]
    if len(t) < 2:
        return out
    duration = float(t[-1] - t[0])
    path = float(np.sum(np.linalg.norm(np.diff(p, axis=0), axis=1)))
    straight = float(np.linalg.norm(p[-1] - p[0]))
    v = kin.speed(t, p)
    if goal is not None:
        out |= _outcome(t, p - p[0], d, goal)
    out |= {"duration": duration, "path_length": path, "path_ratio": path / straight if straight > 0 else math.nan,
            "mean_speed": path / duration if duration > 0 else math.nan, "peak_speed": float(v.max())}
    top, rise, hold = kin.ramp(t, np.linalg.norm(p - p[0], axis=1))
    out |= {"pull_distance": top, "ramp_time": rise, "ramp_speed": 0.8 * top / rise if rise > 0 else math.nan, "hold_time": hold}
    # the last tick's hold is outside the movement: integrate over the intervals between its ticks
    out |= {"mean_force": float(f.mean()), "force_integral": float(np.sum(f[:-1] * np.diff(t)))}
    out |= {f"force_p{q}": float(np.percentile(f, q)) for q in (50, 90, 99)}
    out["sparc"] = kin.sparc(v, 1.0 / float(np.median(np.diff(t))))
    return out


def bimanual_metrics(times, forces, buttons) -> dict[str, float]:
    """Force ratio and movement overlap of a two-handed trial (forces (ticks, 2, 3), buttons (ticks, 2))."""
    dt = kin.tick_durations(times)
    means = []
    for h in range(2):
        w = kin.movement_window(buttons[:, h])
        means.append(float(np.linalg.norm(forces[w, h], axis=1).mean()))
    ratio = min(means) / max(means) if max(means) > 0 else math.nan
    b = np.asarray(buttons, dtype=bool)
    either = float(np.sum(dt[b.any(axis=1)]))
    both = float(np.sum(dt[b.all(axis=1)]))
    return {"force_ratio": ratio, "movement_overlap": both / either if either > 0 else math.nan}


def trial_metrics(trace, goals: Goal | Mapping[str, Goal] | None = None) -> list[dict]:
    """A trace's (analysis.study.trace_files.Trace, or anything with its arrays) metrics as rows
    ``hand, metric, value``, in METRICS order. `goals`: one Goal for every hand, or per hand name."""
    order = [m.name for m in METRICS]
    rows = []
    for h, name in enumerate(trace.hand_names):
        vals = hand_metrics(trace.times, trace.positions[:, h], trace.forces[:, h], trace.buttons[:, h], _goal_for(goals, name))
        rows += [{"hand": name, "metric": k, "value": vals[k]} for k in order if k in vals]
    if len(trace.hand_names) == 2:
        vals = bimanual_metrics(trace.times, trace.forces, trace.buttons)
        rows += [{"hand": BOTH, "metric": k, "value": v} for k, v in vals.items()]
    return rows


def scene_goals(scene) -> dict[str, Goal]:
    """The Goal of each hand of a `sim.scene.Scene` that has a target (`[hands.target]`), by hand name."""
    out = {}
    for h, target in zip(scene.spec.hands, scene.targets()):
        if target is not None:
            s = target.spec
            out[h.name] = Goal(target_m=target.displacement, tolerance_m=s.tolerance, hold_s=s.hold, safe_force_n=s.safe_force)
    return out


def study_goals(study: Study) -> dict[str, Goal]:
    """The goals of a study's task: its protocol's scene's targets (every condition runs that scene)."""
    return scene_goals(build_scene(study.protocol.scene))


def metrics_table(study: Study, goals: Goal | Mapping[str, Goal] | None = None) -> pd.DataFrame:
    """Every stored trial's metrics (the study's traced trials, their traces read from beside its
    database), tidy in `COLUMNS`. The condition is the protocol's name for it (as in every
    report); `trial` the stored 0-based index. A trial run again in a later session of the same
    participant: the later one counts."""
    rows = study.traced_trials.to_dict(orient="records")
    latest = {(r["code"], r["model"], r["trial"]): r for r in rows}  # ordered by session: the last wins
    out = []
    for r in latest.values():
        trace = read_trace(study.path, r["trace_path"], r["trace_sha256"])
        key = {"code": r["code"], "synthetic": bool(r["synthetic"]), "condition": r["model"], "trial": int(r["trial"])}
        out += [key | m | {"unit": UNITS[m["metric"]]} for m in trial_metrics(trace, goals)]
    return pd.DataFrame(out, columns=COLUMNS)


SPEED_METRICS = ("ramp_speed", "ramp_time", "pull_distance", "hold_time")
MIN_PULL_M = 1e-3  # a grasp that moved less than this is not a pull (a tremor's reach is 0.1-0.4 mm)


def pull_speeds(table: pd.DataFrame) -> dict:
    """How the study's hands pulled, from `metrics_table`'s rows: over every pull (a hand's grasp
    that moved at least `MIN_PULL_M`), the 10th, 50th and 90th percentiles of the ramp speed, the
    ramp time, the pull distance and the hold time, with the counts of pulls and participants and
    whether they are synthetic; the bench's speeds read off them: typical (the median ramp speed)
    and fast (the 90th percentile), each with the median hold."""
    rows = table[table["metric"].isin(SPEED_METRICS) & (table["hand"] != BOTH)]
    wide = rows.pivot_table(index=["code", "condition", "trial", "hand"], columns="metric", values="value", aggfunc="first")
    wide = wide[wide.get("pull_distance", pd.Series(dtype=float)) >= MIN_PULL_M].dropna(subset=["ramp_speed"]) if len(wide) else wide
    codes = sorted({k[0] for k in wide.index})
    synthetic = sorted(set(table.loc[table["code"].isin(codes), "synthetic"].astype(bool))) if codes else []
    out = {"pulls": int(len(wide)), "participants": len(codes), "synthetic": synthetic == [True], "mixed": len(synthetic) > 1,
           "percentiles": {m: {f"p{q}": float(np.percentile(wide[m].dropna(), q)) if wide[m].notna().any() else math.nan for q in (10, 50, 90)}
                           for m in SPEED_METRICS if m in wide}}
    if out["pulls"]:
        p = out["percentiles"]
        out["speeds"] = {"typical": {"speed_m_s": p["ramp_speed"]["p50"], "hold_s": p["hold_time"]["p50"]},
                         "fast": {"speed_m_s": p["ramp_speed"]["p90"], "hold_s": p["hold_time"]["p50"]}}
    return out
