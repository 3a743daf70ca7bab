"""The haptic-device interface and the PHANTOM Omni's specification."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

from sim.models.base import Vec3


@dataclass(frozen=True)
class OmniSpec:
    """SensAble PHANTOM Omni (seed paper, section 1.1; manufacturer's data sheet)."""

    workspace_m: Vec3 = (0.160, 0.120, 0.070)  # width x height x depth
    resolution_m: float = 0.055e-3  # position quantisation
    peak_force_n: float = 3.3
    continuous_force_n: float = 0.88
    max_stiffness_n_per_m: float = 700.0  # stable closed-loop stiffness at 1 kHz


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
