"""A finite viscoelastic body (`sim.viscoelastic`) on a `TetSpace`, stepped in time: a
`FiniteStrain` whose laws are the equilibrium laws plus, inside each step, the branches' terms
scaled by their step gains and a history stress at every quadrature point (`newton.follow`
drives it: `step(dt)` before a step's Newton iterations, `commit(u)` once it converged).

The branches' state is Q_k (the non-equilibrium stress) and S_k (the branch's isochoric stress
at the last committed state), (branches, m, q, 3, 3) each, in the reference frame.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from sim.models.fem.finite_strain import FiniteStrain
from sim.viscoelastic import Viscoelastic, isochoric_stress, step_factors


class ViscoelasticStrain(FiniteStrain):
    """The viscoelastic law `law` (or one per region, `law_of` as `FiniteStrain`'s) on `space`, at rest at t = 0."""

    def __init__(self, space, law: Viscoelastic | Sequence[Viscoelastic], mean_dilatation: bool = False, law_of=None):
        rheology = tuple(law) if isinstance(law, (list, tuple)) else (law,)
        super().__init__(space, [x.equilibrium for x in rheology], mean_dilatation, law_of)
        self.rheology = rheology
        nb = max(len(x.branches) for x in rheology)
        n_laws = len(rheology)
        # every law padded to the most branches with mu = 0 (its stress is 0 whatever its alpha and tau)
        self.branch_mu, self.branch_alpha, self.branch_tau = np.zeros((n_laws, nb)), np.full((n_laws, nb), 2.0), np.ones((n_laws, nb))
        for i, x in enumerate(rheology):
            for k, b in enumerate(x.branches):
                self.branch_mu[i, k], self.branch_alpha[i, k], self.branch_tau[i, k] = b.mu, b.alpha, b.tau
        self.equilibrium_mu, self.equilibrium_alpha = self.mu, self.alpha
        shape = (nb,) + self.wq.shape + (3, 3)
        self.Q, self.S = np.zeros(shape), np.zeros(shape)
        self.time = 0.0
        self.dt = 0.0
        self.step(0.0)

    def step(self, dt: float) -> None:
        """Set up the step of `dt` s from the committed state: the branches' terms at their gains
        g_k, the history stress sum_k e^-h_k Q_k - g_k S_k."""
        self.dt = float(dt)
        decay, gain = step_factors(self.branch_tau, self.dt)  # (laws, branches)
        self.mu = np.hstack([self.equilibrium_mu, gain * self.branch_mu])
        self.alpha = np.hstack([self.equilibrium_alpha, self.branch_alpha])
        d, g = decay[self.law_of], gain[self.law_of]  # (m, q, branches)
        H = np.zeros(self.wq.shape + (3, 3))
        for k in range(self.Q.shape[0]):
            H += d[..., k, None, None] * self.Q[k] - g[..., k, None, None] * self.S[k]
        self.history = H

    def branch_stresses(self, u: np.ndarray) -> np.ndarray:
        """S_k at every point of the state `u` (branches, m, q, 3, 3)."""
        ue = self.element_displacements(u)
        F = np.eye(3) + np.einsum("mka,mqkb->mqab", ue, self.G)
        return np.stack([isochoric_stress(F, self.branch_mu[self.law_of, k], self.branch_alpha[self.law_of, k])
                         for k in range(self.Q.shape[0])])

    def commit(self, u: np.ndarray) -> None:
        """The step converged at `u`: Q_k <- e^-h Q_k + g (S_k(u) - S_k), S_k <- S_k(u), the clock on by dt."""
        decay, gain = step_factors(self.branch_tau, self.dt)
        d, g = decay[self.law_of], gain[self.law_of]
        S = self.branch_stresses(u)
        for k in range(self.Q.shape[0]):
            self.Q[k] = d[..., k, None, None] * self.Q[k] + g[..., k, None, None] * (S[k] - self.S[k])
        self.S = S
        self.time += self.dt
