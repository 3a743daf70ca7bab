"""A finite viscoelastic body (`sim.material.Viscoelastic`) on a `TetSpace`, stepped in time: a
`FiniteStrain` of the equilibrium laws whose points also carry the Maxwell branches' state,
C_v^-1 per point and branch (identity at rest), updated implicitly in the compiled element pass
(`hyperelastic_kernels._branch_point`). `newton.follow` drives it: `step(dt)` before a step's
Newton iterations, `commit(u)` once it converged.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from sim.material import Viscoelastic
from sim.models.fem.finite_strain import FiniteStrain


class ViscoelasticStrain(FiniteStrain):
    """The viscoelastic law `law` (or one per region, `law_of` as `FiniteStrain`'s) on `space`, at rest at t = 0."""

    def __init__(self, space, law: Viscoelastic | Sequence[Viscoelastic], mean_dilatation: bool = False, law_of=None):
        rheology = tuple(law) if isinstance(law, (list, tuple)) else (law,)
        super().__init__(space, [x.equilibrium for x in rheology], mean_dilatation, law_of)
        self.rheology = rheology
        nb = max(len(x.branches) for x in rheology)
        # every law padded to the most branches with mu = 0 (skipped, whatever its alpha and viscosity)
        self.branch_mu, self.branch_alpha, self.branch_eta = np.zeros((len(rheology), nb)), np.full((len(rheology), nb), 2.0), np.ones((len(rheology), nb))
        for i, x in enumerate(rheology):
            for k, b in enumerate(x.branches):
                self.branch_mu[i, k], self.branch_alpha[i, k], self.branch_eta[i, k] = b.mu, b.alpha, b.viscosity
        self.Cv = np.ascontiguousarray(np.broadcast_to(np.eye(3), self.wq.shape + (nb, 3, 3)))
        self.Cv_out = self.Cv.copy()
        self.time = 0.0

    def step(self, dt: float) -> None:
        """The next evaluations take a step of `dt` s from the committed state."""
        self.dt = float(dt)

    def commit(self, u: np.ndarray) -> None:
        """The step converged at `u`: its branches' state becomes the committed one, the clock on by
        dt, and the next evaluation an instant from there (dt = 0) until `step` says otherwise."""
        self.evaluate(u, tangent=False)
        self.Cv, self.Cv_out = self.Cv_out, self.Cv
        self.time += self.dt
        self.dt = 0.0
