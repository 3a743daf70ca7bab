"""An elastic half-space under the grasp disc, as a brainsim tissue model (model API 1).

The tissue is a linear elastic half-space (shear modulus G = E / (2 (1 + nu)) from the scene's
material) whose surface is the grasped place's tangent plane; the grasp is a rigid disc of
radius a bonded to it. Closed-form stiffness of the disc (Johnson, Contact Mechanics, 1985,
sections 3.8 and 7.2):

- normal (Boussinesq's flat punch): K_n = 4 G a / (1 - nu);
- tangential (Mindlin, no slip): K_t = 8 G a / (2 - nu).

The hand feels f = -K d with K = K_n n n^T + K_t (I - n n^T), a constant 3 x 3 matrix per grasp:
the built-in law `sim.laws.Linearised` carries it to the servo. The surface moves with the
punch's decay, u(r) = d for r <= a and d (2 / pi) asin(a / r) beyond (exact for the normal load;
for the tangential load it is the same decay without Cerruti's angular term), out to `reach`.
Two hands superpose; the coupling between two discs (order a / distance) is left out.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sim.models.api import Contact, Linearised, TissueModel, option

__version__ = "0.1.0"


@dataclass(frozen=True)
class Options:
    grasp_radius: float = option(0.005, unit="m", lo=0.001, hi=0.02, doc="radius a of the rigid disc the hand holds")
    reach: float = option(0.05, unit="m", lo=0.005, hi=0.2, doc="surface farther than this from the grasp does not move")

    def __post_init__(self) -> None:
        if self.reach <= self.grasp_radius:
            raise ValueError(f"reach: {self.reach:g} m is not beyond the grasp radius {self.grasp_radius:g} m")


def disc_stiffness(young: float, poisson: float, a: float) -> tuple[float, float]:
    """(K_n, K_t) in N/m of a rigid disc of radius `a` bonded to an elastic half-space."""
    g = young / (2.0 * (1.0 + poisson))
    return 4.0 * g * a / (1.0 - poisson), 8.0 * g * a / (2.0 - poisson)


class HalfSpace(TissueModel):
    description = "elastic half-space under a rigid grasp disc (closed form; example plugin)"
    Options = Options
    material_keys = ("young", "poisson")
    scales_stiffness = True
    name = "halfspace"

    def __init__(self, mesh, options: dict, scene, young: float | None = None):
        material = scene.spec.material
        self.mesh, self.scene, self.options = mesh, scene, options
        self.young = float(material.young if young is None else young)
        self.poisson = float(material.poisson)
        self.kn, self.kt = disc_stiffness(self.young, self.poisson, options["grasp_radius"])
        self._out = np.zeros_like(mesh.vertices)
        mesh.prepare_queries()

    def grasp(self, point, hand: int = 0) -> Contact:
        v = self.mesh.nearest_vertex(point)
        p = self.mesh.vertices[v]
        n = self.mesh.vertex_normals[v]
        K = self.kn * np.outer(n, n) + self.kt * (np.eye(3) - np.outer(n, n))
        near = np.flatnonzero(np.linalg.norm(self.mesh.vertices - p, axis=1) <= self.options["reach"])
        r = np.linalg.norm(self.mesh.vertices[near] - p, axis=1)
        a = self.options["grasp_radius"]
        decay = np.where(r <= a, 1.0, (2.0 / math.pi) * np.arcsin(np.minimum(1.0, a / np.maximum(r, a))))
        return Contact(hand=hand, vertex=int(v), point=tuple(float(c) for c in p), normal=tuple(float(c) for c in n),
                       data=(near, decay), law=Linearised(K=tuple(float(c) for c in K.ravel())))

    def deformation(self, contacts, displacements) -> np.ndarray:
        out = self._out
        out[:] = 0.0
        # counted work (what the synthetic observer judges latency from, machine-independent):
        # a multiply and an add per component of every moved vertex
        self.frame_flops = 0.0
        for c, d in zip(contacts, displacements):
            near, decay = c.data
            out[near] += decay[:, None] * np.asarray(d, dtype=np.float64)[None, :]
            self.frame_flops += 6.0 * len(near)
        return out

    def with_stiffness(self, scale: float) -> HalfSpace:
        return HalfSpace(self.mesh, self.options, self.scene, young=self.young * float(scale))
