"""Tissue models behind one contract (see `sim.models.base`).

`MODELS` maps a scene's model name to the module that implements it; the module is imported
only when a scene asks for that model.
"""

from __future__ import annotations

import importlib

MODELS = {
    "plate_spring": "sim.models.plate_spring",
    "fem": "sim.models.fem",
    "mass_spring": "sim.models.mass_spring",
}


# Options that scene files validate without importing the model modules
MASS_SPRING_INTEGRATORS = ("explicit", "implicit", "local-global")
MASS_SPRING_ACCELERATIONS = ("none", "chebyshev", "anderson", "newton")  # of local-global; newton: sim/models/newton.py


def model_module(name: str):
    """Import and return the module implementing model `name`."""
    from sim.errors import SceneError

    if name not in MODELS:
        raise SceneError(f"model: unknown model {name!r}; available: {', '.join(sorted(MODELS))}")
    return importlib.import_module(MODELS[name])
