"""A hand's target: pull the grasped tissue by a distance along the hand's pull, hold
it there, and keep the force under a safe limit.

- `TargetSpec`: a scene's ``[hands.target]`` (distance, tolerance, hold time, safe force);
- `HandTarget`: that target on a scene's mesh (the pull's unit direction on the surface);
- `TargetTracker`: follows the hands during a run (the visual step calls it every frame): where
  the target lies, the progress along the pull, when each hand has held its target.

The tip's displacement counts from where the hand was when its button was pressed for the grasp
that took hold (as the metrics count from the first tick of the button held); the target is
that displacement equal to `distance` times the pull's direction, within `tolerance` (the
metrics' `analysis.validity.metrics.Goal` uses the same rule on the stored trace, at every tick).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

# Brain damage began at a continuous retraction force of 30 g (0.29 N): Yokoh, Sugita and
# Kobayashi 1983, J Neurosurg 58:918-923 (docs/metrics.md).
SAFE_FORCE_N = 0.030 * 9.80665
TRIAL_ENDS = ("time", "targets")  # a protocol's design.trial_end


@dataclass(frozen=True)
class TargetSpec:
    distance: float  # m along the pull, from where the grasp took hold
    tolerance: float = 0.002  # m
    hold: float = 0.5  # s within tolerance
    safe_force: float = SAFE_FORCE_N  # N


@dataclass(frozen=True)
class HandTarget:
    spec: TargetSpec
    direction: tuple[float, float, float]  # unit: the hand's pull on the surface's tangent plane

    def point(self, origin) -> tuple[float, float, float]:
        d, s = self.direction, self.spec.distance
        return (origin[0] + s * d[0], origin[1] + s * d[1], origin[2] + s * d[2])

    @property
    def displacement(self) -> tuple[float, float, float]:
        """The target as a displacement of the tip from where its grasp took hold, m."""
        return tuple(self.spec.distance * c for c in self.direction)


@dataclass
class TargetState:
    """One hand's target during a run (what the view draws)."""

    point: tuple  # where the target is now: from the grasp's origin, or from the scene's grasp point before
    progress: float = 0.0  # displacement along the pull over the target distance (1: at the target)
    error: float = math.nan  # m from the target (NaN: not grasped)
    on_target: bool = False
    held: bool = False  # held for the hold time (stays True for the rest of the run)
    over_limit: bool = False  # the force is above the safe limit now


class TargetTracker:
    """The hands' targets during one run; `update(t, hands)` with the servo's hands (position,
    force, contact) at every visual step."""

    def __init__(self, targets: list[HandTarget | None], starts: list[tuple]):
        self.targets = targets
        self.starts = starts  # each hand's grasp point on the surface (the target shown before a grasp)
        self.origins: list[tuple | None] = [None] * len(targets)
        self.since: list[float | None] = [None] * len(targets)
        self.states = [TargetState(point=t.point(s)) if t is not None else None for t, s in zip(targets, starts)]

    @property
    def any(self) -> bool:
        return any(t is not None for t in self.targets)

    @property
    def all_held(self) -> bool:
        """Every hand that has a target has held it (False when no hand has one)."""
        return self.any and all(s is None or s.held for s in self.states)

    def grasped(self, i: int, at) -> None:
        """Hand i's grasp took hold; its button was pressed with the tip `at` (the target's origin)."""
        self.origins[i], self.since[i] = tuple(float(c) for c in at), None

    def update(self, t: float, hands) -> None:
        for i, (target, h) in enumerate(zip(self.targets, hands)):
            if target is None:
                continue
            st = self.states[i]
            f = h.force
            st.over_limit = f[0] * f[0] + f[1] * f[1] + f[2] * f[2] > target.spec.safe_force ** 2
            if h.contact is None:  # not holding tissue: a new grasp starts from where it takes hold
                self.origins[i], self.since[i] = None, None
                st.point, st.progress, st.error, st.on_target = target.point(self.starts[i]), 0.0, math.nan, False
                continue
            if self.origins[i] is None:  # a grasp not announced through `grasped`: from here
                self.origins[i] = tuple(h.position)
            o, p, d = self.origins[i], h.position, target.direction
            disp = (p[0] - o[0], p[1] - o[1], p[2] - o[2])
            st.point = target.point(o)
            along = disp[0] * d[0] + disp[1] * d[1] + disp[2] * d[2]
            st.progress = along / target.spec.distance
            st.error = math.dist(p, st.point)
            st.on_target = st.error <= target.spec.tolerance
            if not st.on_target:
                self.since[i] = None
            elif self.since[i] is None:
                self.since[i] = t
            if st.on_target and t - self.since[i] >= target.spec.hold - 1e-9:
                st.held = True
