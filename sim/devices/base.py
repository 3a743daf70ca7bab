"""The haptic-device interface and the PHANTOM Omni's specification."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

from sim.models.base import Vec3
from sim.view.camera import orientation


@dataclass(frozen=True)
class OmniSpec:
    """SensAble PHANTOM Omni (seed paper, section 1.1; manufacturer's data sheet)."""

    workspace_m: Vec3 = (0.160, 0.120, 0.070)  # width x height x depth
    resolution_m: float = 0.055e-3  # position quantisation
    peak_force_n: float = 3.3
    continuous_force_n: float = 0.88
    max_stiffness_n_per_m: float = 700.0  # stable closed-loop stiffness at 1 kHz


@dataclass(frozen=True)
class DeviceFrame:
    """Where a real device sits in the scene: a point p (metres) in the device's frame (the
    Omni's: x to the user's right, y up, z toward the user) is `origin + scale * R p` in the
    scene; a force goes back as R^T f (forces are not scaled). With the participant view's
    camera, R maps device right/up/toward-the-user to screen right/up/out of the screen."""

    rotation: tuple = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))  # rows; columns are the device axes in the scene
    scale: float = 1.0
    origin: Vec3 = (0.0, 0.0, 0.0)

    def to_scene(self, p) -> Vec3:
        R, s, o = self.rotation, self.scale, self.origin
        return tuple(o[i] + s * (R[i][0] * p[0] + R[i][1] * p[1] + R[i][2] * p[2]) for i in range(3))

    def force_to_device(self, f) -> Vec3:
        R = self.rotation
        return tuple(R[0][j] * f[0] + R[1][j] * f[1] + R[2][j] * f[2] for j in range(3))


def view_rotation(front, up) -> tuple:
    """The rotation whose columns are the screen's right, up and out-of-the-screen directions
    for the participant's camera looking along -front with `up` (sim/view/camera.py's)."""
    right, down, forward = orientation(front, up)
    return tuple((float(right[i]), float(-down[i]), float(-forward[i])) for i in range(3))


@dataclass(frozen=True)
class DeviceState:
    position: Vec3  # scene coordinates, m
    button: bool
    fault: str | None = None


class HapticDevice(Protocol):
    """Position in metres (scene frame), buttons, force out in newtons, limits in `spec`."""

    spec: OmniSpec
    name: str

    def read(self, t: float) -> DeviceState: ...

    def write_force(self, force: Vec3) -> None: ...

    def close(self) -> None: ...
