"""The tissue-model contract: three calls at three rates.

| call                                   | when                         | budget               |
|----------------------------------------|------------------------------|----------------------|
| ``grasp(point, hand) -> Contact``      | a hand closes on the tissue  | tens of ms           |
| ``force(contact, displacement)``       | every servo tick (1 kHz)     | microseconds         |
| ``deformation(contacts, displacements)``| every visual frame          | a few ms, whole brain|

``displacement`` is the hand position minus the contact's anchor point, in metres; ``force``
returns the force on the hand in newtons as a 3-tuple of floats (plain floats keep the
per-tick path free of array allocations). ``deformation`` returns the displacement of every
surface vertex, ``(n_vertices, 3)``. Two hands are two contacts passed together.

Every contact carries a `law` (sim/laws.py): the small picklable state a servo tick
evaluates, which `force` delegates to and which a servo in another process receives. Models
whose contacts couple also give ``pair_law(contacts)``; models whose laws change between frames
update them in ``deformation``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

Vec3 = tuple[float, float, float]


@dataclass(frozen=True)
class Contact:
    """State fixed at grasp time. ``data`` holds what the model precomputed for this contact."""

    hand: int
    vertex: int
    point: Vec3
    normal: Vec3
    data: Any = field(default=None, compare=False, repr=False)
    law: Any = field(default=None, compare=False, repr=False)  # sim.laws: what a servo tick evaluates


class TissueModel(Protocol):
    name: str

    def grasp(self, point: Sequence[float], hand: int = 0) -> Contact: ...

    def force(self, contact: Contact, displacement: Sequence[float]) -> Vec3: ...

    def deformation(
        self, contacts: Sequence[Contact], displacements: Sequence[Sequence[float]]
    ) -> np.ndarray: ...
