"""Simulation library: brain scene, tissue models, haptic devices, servo loop, rendering.

Modules are imported lazily by what a scene asks for, so a headless plate-spring scene loads
neither open3d nor any finite element code.
"""

from brainsim_assets import version as _version

__version__ = _version()
