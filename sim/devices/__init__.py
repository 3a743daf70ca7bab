"""Haptic devices behind one interface (`sim.devices.base.HapticDevice`).

Backends are imported only when a scene opens a device of that kind (the real Omnis load
OpenHaptics through ctypes, the mouse loads glfw). Imports: numpy and `sim` below it.
"""

from __future__ import annotations

import importlib

from sim.errors import SceneError

BACKENDS = {
    "simulated": "sim.devices.simulated",
    "openhaptics": "sim.devices.openhaptics",
    "replay": "sim.devices.replay",
    "mouse": "sim.devices.mouse",
}


def backend_module(name: str):
    if name not in BACKENDS:
        raise SceneError(f"device: unknown backend {name!r}; available: {', '.join(sorted(BACKENDS))}")
    return importlib.import_module(BACKENDS[name])
