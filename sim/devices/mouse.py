"""The mouse as a haptic device: the participant view's pointer drives a hand.

The view (sim/view/window.py) turns pointer events into a target point and a button per hand (left
mouse button: left hand, right button: right hand) and writes them to the servo's shared board;
this device, in the servo process, moves the hand towards the target at most `speed_m_s` (so
the 1 kHz trace is smooth although the pointer is sampled at the frame rate, and never trips
the servo's 20 mm jump guard) and reports the button pressed once the hand has reached the
point the pointer grasped. Forces cannot be felt: they are recorded, and the view draws them.
"""

from __future__ import annotations

import math

from sim.devices.base import DeviceState, OmniSpec
from sim.errors import DeviceError

REACH_M = 0.5e-3  # the hand closes once it is this close to the grasped point


class MouseDevice:
    def __init__(self, source, start, name: str = "mouse", spec: OmniSpec = OmniSpec(), speed_m_s: float = 0.5):
        """`source()` returns (target (x, y, z), pressed) as the view last wrote them."""
        self.spec = spec
        self.name = name
        self.source = source
        self.speed = speed_m_s
        self._x = [float(c) for c in start]
        self._t = 0.0
        self._closed = False
        self.force = (0.0, 0.0, 0.0)

    def read(self, t: float) -> DeviceState:
        target, pressed = self.source()
        dt = max(t - self._t, 0.0)
        self._t = t
        x = self._x
        d = [target[k] - x[k] for k in range(3)]
        dist = math.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
        if not math.isfinite(dist):
            return DeviceState(position=tuple(x), button=False, fault="pointer gave a non-finite point")
        step = self.speed * dt
        if dist <= step:
            x[:] = [float(c) for c in target]
        elif dist > 0.0:
            x[:] = [x[k] + d[k] * step / dist for k in range(3)]
        # press: only once the hand is where the pointer grasped; hold until released
        self._closed = bool(pressed) and (self._closed or dist <= max(step, REACH_M))
        return DeviceState(position=(x[0], x[1], x[2]), button=self._closed)

    def write_force(self, force) -> None:
        fx, fy, fz = force
        self.force = (fx, fy, fz) if math.isfinite(fx + fy + fz) else (0.0, 0.0, 0.0)

    def close(self) -> None:
        self.force = (0.0, 0.0, 0.0)


def open_devices(hands, mesh):
    raise DeviceError("device mouse: the mouse drives a hand only in a real-time run with the participant view "
                      "(studyctl sim live, or session run --device mouse --view window)")
