"""Force laws: the small, picklable part of a contact that a servo tick evaluates.

Each tissue model hands the servo a law per contact (and, for coupled grasps, a pair law):
a few numbers fixed at grasp time, plus a state the visual step may refresh each frame. A law
can be evaluated in the model's process or sent to a servo process (sim/servo/process.py),
where the interpreter lock of the rendering and deformation work cannot delay it.
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass, field


@dataclass
class RadialTable:
    """Plate-spring: magnitude from a piecewise-linear table of |d|, against d."""

    x0: list[float]
    f0: list[float]
    slope: list[float]

    def force(self, d) -> tuple[float, float, float]:
        dx, dy, dz = d
        x = math.sqrt(dx * dx + dy * dy + dz * dz)
        if x == 0.0:
            return (0.0, 0.0, 0.0)
        k = bisect.bisect_right(self.x0, x) - 1
        s = -(self.f0[k] + self.slope[k] * (x - self.x0[k])) / x
        return (s * dx, s * dy, s * dz)

    def update(self, **state) -> None:  # nothing changes between frames
        pass


@dataclass
class TensorTable:
    """Location-aware plate-spring: the stack's curve shapes the force, a 3 x 3 stiffness of
    the grasped place sets its size and direction: f = -(f(|d|) / (k0 |d|)) S d."""

    x0: list[float]
    f0: list[float]
    slope: list[float]
    k0: float  # the stack's initial slope, N/m
    S: tuple  # 9 floats, row-major, N/m

    def force(self, d) -> tuple[float, float, float]:
        # RadialTable's lookup, inlined: a shared helper would add a call to every servo tick
        dx, dy, dz = d
        x = math.sqrt(dx * dx + dy * dy + dz * dz)
        if x == 0.0:
            return (0.0, 0.0, 0.0)
        k = bisect.bisect_right(self.x0, x) - 1
        s = -(self.f0[k] + self.slope[k] * (x - self.x0[k])) / (self.k0 * x)
        m = self.S
        return (s * (m[0] * dx + m[1] * dy + m[2] * dz), s * (m[3] * dx + m[4] * dy + m[5] * dz),
                s * (m[6] * dx + m[7] * dy + m[8] * dz))

    def update(self, **state) -> None:  # nothing changes between frames
        pass


@dataclass
class Linearised:
    """FEM: f = -(f_frame + K (d - d_frame)); f_frame = 0, d_frame = 0 for linear elasticity,
    refreshed each frame by the corotational update."""

    K: tuple  # 9 floats, row-major
    f_frame: tuple = (0.0, 0.0, 0.0)
    d_frame: tuple = (0.0, 0.0, 0.0)

    def force(self, d) -> tuple[float, float, float]:
        k = self.K
        fx, fy, fz = self.f_frame
        dx, dy, dz = d[0] - self.d_frame[0], d[1] - self.d_frame[1], d[2] - self.d_frame[2]
        return (
            -(fx + k[0] * dx + k[1] * dy + k[2] * dz),
            -(fy + k[3] * dx + k[4] * dy + k[5] * dz),
            -(fz + k[6] * dx + k[7] * dy + k[8] * dz),
        )

    def update(self, f_frame=None, d_frame=None, **_) -> None:
        if f_frame is not None:
            self.f_frame, self.d_frame = tuple(f_frame), tuple(d_frame)


@dataclass
class Coupling:
    """Mass-spring: a spring of stiffness k between the hand and the patch:
    f = -k (anchor + d - patch(d)).

    The simulation publishes the patch at the visual rate (30 Hz). Held fixed between frames,
    it jumps at each frame by what the tissue moved in 33 ms (in a steady 10 mm/s pull, about
    0.1-0.2 N at 300 N/m, 30 times a second: a felt ripple). Between frames the patch is
    therefore carried along with the hand by the gain the last frames measured:
    patch(d) = patch + gain (d - d_frame), gain = how far the patch moved per metre of hand
    motion (0..1, along the hand's motion). In a steady pull the next published patch lands
    where this prediction put it, so the force has no step."""

    k: float
    anchor: tuple
    patch: tuple
    d_frame: tuple = (0.0, 0.0, 0.0)
    gain: float = 0.0

    def force(self, d) -> tuple[float, float, float]:
        a, p, k, g, f = self.anchor, self.patch, self.k, self.gain, self.d_frame
        return (-k * (a[0] + d[0] - p[0] - g * (d[0] - f[0])), -k * (a[1] + d[1] - p[1] - g * (d[1] - f[1])),
                -k * (a[2] + d[2] - p[2] - g * (d[2] - f[2])))

    def update(self, patch=None, d_frame=None, gain=None, **_) -> None:
        if patch is not None:
            self.patch = tuple(patch)
        if d_frame is not None:
            self.d_frame = tuple(d_frame)
        if gain is not None:
            self.gain = float(gain)


@dataclass
class Zero:
    """A model that reported itself unstable: no force."""

    def force(self, d) -> tuple[float, float, float]:
        return (0.0, 0.0, 0.0)

    def update(self, **_) -> None:
        pass


@dataclass
class Constant:
    """A fixed force, whatever the displacement: the device check's gentle pulse."""

    f: tuple

    def force(self, d) -> tuple[float, float, float]:
        return self.f

    def update(self, **_) -> None:
        pass


@dataclass
class PairTable:
    """Two coupled grasps (FEM on one hemisphere): forces = -K6 [d1; d2]."""

    K: list = field(default_factory=list)  # 36 floats, row-major

    def forces(self, d1, d2):
        k = self.K
        d = (d1[0], d1[1], d1[2], d2[0], d2[1], d2[2])
        out = []
        for r in range(6):
            row = k[6 * r : 6 * r + 6]
            out.append(-(row[0] * d[0] + row[1] * d[1] + row[2] * d[2] + row[3] * d[3] + row[4] * d[4] + row[5] * d[5]))
        return [(out[0], out[1], out[2]), (out[3], out[4], out[5])]
