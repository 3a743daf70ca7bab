"""The tissue-model contract's low-level types: `Contact`, the checks of what a model returns,
the pull limits and the budgets. A model's author imports them from `sim.models.api`, the
contract's one module (its docstring is the reference). They live here so that the servo
process reads them without loading the API, and `sim.tomltable`, which the API uses, without a
cycle.

``displacement`` is the hand position minus the contact's anchor point, in metres; ``force``
returns the force on the hand in newtons as a 3-tuple of floats (plain floats keep the
per-tick path free of array allocations). ``deformation`` returns the displacement of every
surface vertex, ``(n_vertices, 3)``. Two hands are two contacts passed together.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

Vec3 = tuple[float, float, float]

# The budgets a model keeps on this machine (`studyctl model check`), per call, 99th percentile:
# a servo tick is 1 ms shared with the device's I/O and the safety rules (sim/servo/loop.py), a
# visual frame at 30 Hz is 33 ms, a grasp stalls the frames it falls in. The one table of them:
# authors read it as sim.models.api.BUDGETS; it is defined here so that the servo process judges
# its calls without importing the API (and the scene reader it brings).
BUDGETS = {"force_us_p99": 20.0, "deformation_ms_p99": 33.0, "grasp_ms_p99": 250.0}

# Poisson's ratio, one bound for scene files and the FEM: POISSON_MIN <= nu < POISSON_MAX
# (nu = 0.5 is incompressible: linear elasticity's Lame lambda is infinite there).
POISSON_MIN, POISSON_MAX = 0.0, 0.5

# The longest pull (hand displacement from its grasp point, m) the tissue models are meant for.
# The scene's scripted pulls are 12 mm and the plate-spring calibration reaches 24 mm
# (protocols/scenes/brain_pull.toml, protocols/models/plate_spring_brain.toml), and only the
# brain's top 47 mm above the skull clamp are free to move: 50 mm is four scripted pulls and
# about that free height. Longer pulls are outside what the models were built and checked for
# (the corotational FEM already inverts elements near 50 mm on the coarse mesh).
MAX_PULL_M = 0.05


def pull_problem(displacement) -> str | None:
    """Why `displacement` (a pull vector or magnitude, m) is not a pull the models are meant
    for, or None when it is one."""
    d = np.atleast_1d(np.asarray(displacement, dtype=np.float64))
    if not np.all(np.isfinite(d)):
        return "is not finite; allowed: finite numbers (metres)"
    length = float(np.linalg.norm(d))
    if length > MAX_PULL_M:
        return f"is {length:.4g} m long; allowed: at most {MAX_PULL_M:g} m ({MAX_PULL_M * 1e3:g} mm, the longest pull the tissue models are meant for)"
    return None


@dataclass(frozen=True)
class Contact:
    """State fixed at grasp time. ``data`` holds what the model precomputed for this contact."""

    hand: int
    vertex: int
    point: Vec3
    normal: Vec3
    data: Any = field(default=None, compare=False, repr=False)
    law: Any = field(default=None, compare=False, repr=False)  # sim.laws: what a servo tick evaluates


def surface_checked(u, mesh) -> np.ndarray:
    """`u`, a model's surface displacement, as the frame uses it: one finite row of three per
    vertex of the surface it moves. Raises ValueError saying what it got."""
    a = np.asarray(u, dtype=np.float64)
    want = (len(mesh.vertices), 3)
    if a.shape != want:
        raise ValueError(f"returned an array of shape {a.shape}; allowed: {want}, one (dx, dy, dz) in m per surface vertex")
    if not np.isfinite(a).all():
        raise ValueError(f"returned {int(np.size(a) - np.isfinite(a).sum())} non-finite values; allowed: finite displacements in m")
    return a


def contact_checked(contact) -> Contact:
    """`contact`, what a model's `grasp` returned, as the servo uses it: a `Contact` whose point
    is three finite floats. Raises ValueError saying what it got."""
    if not isinstance(contact, Contact):
        raise ValueError(f"returned {type(contact).__name__}; allowed: a sim.models.base.Contact")
    p = contact.point
    if len(p) != 3 or not all(math.isfinite(float(c)) for c in p):
        raise ValueError(f"returned a contact whose point is {p!r}; allowed: three finite floats (m)")
    return contact
