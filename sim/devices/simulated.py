"""A simulated PHANTOM Omni held by a scripted operator whose hand has an impedance.

The operator's hand is a mass-spring-damper pulled towards a scripted target; the force the
device renders acts on that hand, so a stiff tissue holds the hand back. The device reports
the hand position quantised to 0.055 mm and confined to the 160 x 120 x 70 mm workspace, and
its motors saturate at the peak force.

A script may go beyond its goal and come back (`back`: a second minimum-jerk segment, e.g. a
corrective movement after an overshoot) and may hold back near a force limit (`restraint`): while
the felt force is above `RESTRAINT_ONSET` of `safe_force`, the operator's target retreats along
the pull at `restraint * RESTRAINT_GAIN` m/s per newton above it, and comes forward again at the
same rate per newton below it (never past the script). docs/synthetic.md, "Skill profiles".
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from sim.devices.base import DeviceState, OmniSpec
from sim.models.base import Vec3

RESTRAINT_ONSET = 0.9  # the felt force, as a fraction of the safe limit, at which a restrained operator holds back
RESTRAINT_GAIN = 3.0  # m/s of retreat per newton above the onset, at restraint 1


@dataclass(frozen=True)
class HandImpedance:
    """Operator hand + stylus as seen by the device (typical arm values, Hogan 1985 range)."""

    mass_kg: float = 0.2
    stiffness_n_per_m: float = 300.0
    damping_ns_per_m: float = 11.0  # ~0.7 of critical for the mass and stiffness above


def min_jerk(tau: float) -> float:
    """Minimum-jerk position profile (Flash and Hogan 1985) for tau in [0, 1]."""
    if tau <= 0.0:
        return 0.0
    if tau >= 1.0:
        return 1.0
    return tau**3 * (10.0 - 15.0 * tau + 6.0 * tau * tau)


@dataclass(frozen=True)
class PullScript:
    """Grasp at `start`, pull by `pull` (a vector, m) with a minimum-jerk profile, release."""

    start: Vec3
    pull: Vec3
    grasp_at: float  # s, button pressed
    pull_start: float  # s
    pull_time: float  # s, duration of the pull
    release_at: float  # s, button released
    tremor_m: float = 0.0  # physiological tremor amplitude per axis, m
    tremor_hz: float = 10.0  # its frequency (8-12 Hz in healthy adults)
    tremor_phase: Vec3 = (0.0, 0.0, 0.0)
    impedance: HandImpedance | None = None  # the operator's hand; default HandImpedance()
    # a sudden jump (stability tests): at `jump_at` the operator's target steps by `jump`, or
    # with `glitch` the stylus itself is displaced by it within one step (a slip, a bad reading)
    jump_at: float | None = None
    jump: Vec3 = (0.0, 0.0, 0.0)
    glitch: bool = False
    # a second movement after the pull (e.g. back from an overshoot): by `back` (m) from
    # `back_start` over `back_time` s, minimum jerk; none when back_start is None
    back: Vec3 = (0.0, 0.0, 0.0)
    back_start: float | None = None
    back_time: float = 0.0
    # holding back near a force limit (0: never; 1: most); see the module's docstring
    restraint: float = 0.0
    safe_force: float = math.inf  # N

    def target(self, t: float) -> Vec3:
        # per axis written out, not looped: this runs at 1 kHz per hand (the same operations)
        s = min_jerk((t - self.pull_start) / self.pull_time) if self.pull_time > 0 else float(t >= self.pull_start)
        a, p = self.start, self.pull
        x0, x1, x2 = a[0] + s * p[0], a[1] + s * p[1], a[2] + s * p[2]
        if self.back_start is not None:
            s = min_jerk((t - self.back_start) / self.back_time) if self.back_time > 0 else float(t >= self.back_start)
            b = self.back
            x0, x1, x2 = x0 + s * b[0], x1 + s * b[1], x2 + s * b[2]
        if self.jump_at is not None and not self.glitch and t >= self.jump_at:
            j = self.jump
            x0, x1, x2 = x0 + j[0], x1 + j[1], x2 + j[2]
        if self.tremor_m:
            w = 2.0 * math.pi * self.tremor_hz * t
            m, ph, sin = self.tremor_m, self.tremor_phase, math.sin
            x0 += m * sin(w + ph[0])
            x1 += m * sin(w + ph[1])
            x2 += m * sin(w + ph[2])
        return (x0, x1, x2)

    def button(self, t: float) -> bool:
        return self.grasp_at <= t < self.release_at


class SimulatedOmni:
    """An Omni model. `read(t)` advances the hand dynamics to time t in 1 ms steps."""

    opened = 0  # devices opened in this process (tests check a one-hand scene opens one)

    def __init__(
        self,
        script: PullScript,
        name: str = "simulated",
        spec: OmniSpec = OmniSpec(),
        origin: Vec3 | None = None,
        impedance: HandImpedance = HandImpedance(),
        step: float = 1e-3,
    ):
        self.spec = spec
        self.name = name
        self.script = script
        self.impedance = script.impedance or impedance
        # plain floats, not arrays: this runs 1000 times a second per hand, on 3-vectors
        self.origin = tuple(float(c) for c in (origin if origin is not None else script.start))
        self._half = tuple(w / 2.0 for w in spec.workspace_m)
        self._x = [float(c) for c in script.start]
        self._v = [0.0, 0.0, 0.0]
        self._t = 0.0
        self._step = step
        self._force = (0.0, 0.0, 0.0)
        self.max_force_applied = 0.0
        self.held_back = 0.0  # m the operator's target is held back along the pull (restraint)
        p = script.pull
        n = math.sqrt(p[0] * p[0] + p[1] * p[1] + p[2] * p[2])
        self._along = (p[0] / n, p[1] / n, p[2] / n) if n > 0 else (0.0, 0.0, 0.0)
        SimulatedOmni.opened += 1

    def _advance(self, t: float) -> None:
        imp = self.impedance
        k, c, m = imp.stiffness_n_per_m, imp.damping_ns_per_m, imp.mass_kg
        x, v, f, o, half = self._x, self._v, self._force, self.origin, self._half
        sc = self.script
        gain = sc.restraint * RESTRAINT_GAIN
        if gain:  # the felt force is the one last written: the same through this advance
            excess = math.sqrt(f[0] * f[0] + f[1] * f[1] + f[2] * f[2]) - RESTRAINT_ONSET * sc.safe_force
            u = self._along
        while self._t + 1e-12 < t:
            h = min(self._step, t - self._t)
            if sc.glitch and sc.jump_at is not None and self._t < sc.jump_at <= self._t + h:
                for i in range(3):
                    x[i] += sc.jump[i]
            target = sc.target(self._t + h)
            if gain:
                back = self.held_back + h * gain * excess
                back = self.held_back = back if back > 0.0 else 0.0
                target = (target[0] - back * u[0], target[1] - back * u[1], target[2] - back * u[2])
            for i in range(3):
                a = (k * (target[i] - x[i]) - c * v[i] + f[i]) / m
                v[i] += h * a  # semi-implicit Euler: velocity first
                x[i] += h * v[i]
                rel = x[i] - o[i]  # the stylus cannot leave the mechanical workspace
                if rel > half[i] or rel < -half[i]:
                    x[i] = o[i] + max(-half[i], min(half[i], rel))
                    v[i] = 0.0
            self._t += h

    def read(self, t: float) -> DeviceState:
        self._advance(t)
        r = self.spec.resolution_m
        o, x = self.origin, self._x
        # encoder quantisation, per axis written out (1 kHz per hand)
        q = (o[0] + round((x[0] - o[0]) / r) * r, o[1] + round((x[1] - o[1]) / r) * r, o[2] + round((x[2] - o[2]) / r) * r)
        return DeviceState(position=q, button=self.script.button(t))

    def write_force(self, force: Vec3) -> None:
        fx, fy, fz = force
        fx, fy, fz = float(fx), float(fy), float(fz)
        mag = math.sqrt(fx * fx + fy * fy + fz * fz)
        if not math.isfinite(mag):
            fx = fy = fz = mag = 0.0
        elif mag > self.spec.peak_force_n:  # the motors saturate
            s = self.spec.peak_force_n / mag
            fx, fy, fz, mag = fx * s, fy * s, fz * s, self.spec.peak_force_n
        self._force = (fx, fy, fz)
        self.max_force_applied = max(self.max_force_applied, mag)

    def close(self) -> None:
        self._force = (0.0, 0.0, 0.0)


def open_devices(hands, mesh, scripts=None) -> list[SimulatedOmni]:
    """Open a simulated device for each of a scene's hand specs (`sim.scene.HandSpec`);
    `scripts` replaces their scripted operators (e.g. synthetic participants)."""
    scripts = scripts or [h.script(mesh) for h in hands]
    return [SimulatedOmni(sc, name=f"{h.name} (simulated)") for h, sc in zip(hands, scripts)]
