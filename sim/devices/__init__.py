"""Haptic devices behind one interface (`sim.devices.base.HapticDevice`).

Every backend is imported with the package (`BACKENDS`, by the name a scene gives): each imports
the standard library only, the real Omnis load OpenHaptics through ctypes when a device opens, and
the mouse is read through the participant view. Imports: numpy and `sim` below it.
"""

from __future__ import annotations

from sim.devices import mouse, openhaptics, replay, simulated
from sim.errors import SceneError

BACKENDS = {"simulated": simulated, "openhaptics": openhaptics, "replay": replay, "mouse": mouse}


def backend_module(name: str):
    if name not in BACKENDS:
        raise SceneError(f"device: unknown backend {name!r}; available: {', '.join(sorted(BACKENDS))}")
    return BACKENDS[name]
