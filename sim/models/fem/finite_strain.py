"""A finite-strain hyperelastic body on a `TetSpace`: internal forces, the tangent on the free
dofs and the energy of a displacement field (`FiniteStrain`), for the Newton solver
(`newton.hold`).

The element is the space's (P1 or P2), displacement-based: the volumetric energy U(J) at each
quadrature point (the default, the reference's). With `mean_dilatation`, one mean dilatation
per element instead: V_e U(theta_e), theta_e = (1/V_e) int_e J dV (Simo, Taylor and Pister
1985; the three-field u/theta/p element with theta and p constant per element, condensed), on
P2 the P2/P0 mixed element, which does not lock as kappa/mu grows but has spurious modes at
finite compression (docs/material.md says why the reference uses plain P2); on P1 theta is J
itself. Kernels: `hyperelastic_kernels`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import scipy.sparse as sp

from sim.errors import ParameterError
from sim.hyperelastic import Hyperelastic, volumetric
from sim.models.fem import p2
from sim.models.fem.hyperelastic_kernels import element_pass, pattern_positions, scatter_matrix, scatter_vector
from sim.models.fem.linear import element_dofs

CHUNK = 16384  # elements per compiled pass: their (30 x 30) tangents stay at 118 MB on P2
_NO_BRANCHES = np.zeros((1, 1, 1, 3, 3))  # the compiled pass's placeholders where there are no Maxwell branches
_NO_LAWS = np.zeros((1, 1))


class FiniteStrain:
    """The law `law` on the space `space` (a `TetSpace` or `LinearFem`); or several laws (a
    sequence) with `law_of` (m, q), the index of each quadrature point's law (the brain's
    regions). `law` is then the first (the grey matter's)."""

    def __init__(self, space, law: Hyperelastic | Sequence[Hyperelastic], mean_dilatation: bool = False, law_of=None):
        self.laws = tuple(law) if isinstance(law, (list, tuple)) else (law,)
        self.space, self.law = space, self.laws[0]
        self.mean_dilatation = bool(mean_dilatation)
        self.G, self.wq = space.quadrature()
        self.G = np.ascontiguousarray(self.G)
        self.law_of = np.zeros(self.wq.shape, dtype=np.int64) if law_of is None else np.ascontiguousarray(law_of, dtype=np.int64)
        if self.law_of.shape != self.wq.shape or self.law_of.min() < 0 or self.law_of.max() >= len(self.laws):
            raise ParameterError(f"law_of: one law index in 0..{len(self.laws) - 1} per quadrature point, shape {self.wq.shape}")
        self.dofs = element_dofs(space.elements)
        n = 3 * space.n_all
        self.free = space.free
        self.free_pos = np.full(n, -1, dtype=np.int64)
        self.free_pos[self.free] = np.arange(len(self.free))
        # the tangent's pattern on the free dofs, found once; each assembly only adds values
        rows = self.free_pos[np.repeat(self.dofs, self.dofs.shape[1], axis=1).ravel()]
        cols = self.free_pos[np.tile(self.dofs, (1, self.dofs.shape[1])).ravel()]
        keep = (rows >= 0) & (cols >= 0)
        nf = len(self.free)
        pattern = sp.csr_matrix((np.ones(int(keep.sum())), (rows[keep], cols[keep])), shape=(nf, nf))
        pattern.sum_duplicates()
        pattern.sort_indices()
        self.indptr, self.indices = pattern.indptr.astype(np.int64), pattern.indices.astype(np.int64)
        self.pos = pattern_positions(self.dofs.astype(np.int64), self.free_pos, self.indptr, self.indices)
        # every law padded to the most terms with mu = 0 (alpha 2: any non-zero value adds nothing)
        terms = max(len(x.mu) for x in self.laws)
        self.mu, self.alpha = np.zeros((len(self.laws), terms)), np.full((len(self.laws), terms), 2.0)
        for i, x in enumerate(self.laws):
            self.mu[i, : len(x.mu)], self.alpha[i, : len(x.alpha)] = x.terms()
        self.kappa = np.array([x.bulk_modulus for x in self.laws])
        # Maxwell branches (`viscous.ViscoelasticStrain` sets them): C_v^-1 per point and branch at
        # the step's start, its update written to Cv_out; the branches' mu, alpha, viscosity per law
        self.Cv = self.Cv_out = None
        self.branch_mu = self.branch_alpha = self.branch_eta = _NO_LAWS
        self.dt = 0.0

    def element_displacements(self, u: np.ndarray) -> np.ndarray:
        """(m, k, 3) element nodal displacements of a full (3 n_all,) vector."""
        k = self.dofs.shape[1] // 3
        return u[self.dofs].reshape(len(self.dofs), k, 3)

    def evaluate(self, u: np.ndarray, tangent: bool = True) -> dict:
        """At the displacement `u` (3 n_all,): the internal force on every dof `f` (3 n_all,),
        the tangent on the free dofs `K` (CSR, or None), the energy, the smallest J of any
        quadrature point `min_jacobian` and the mean dilatations' range. A state with an
        inverted point (min_jacobian <= 0) has infinite energy and no usable force."""
        ue = self.element_displacements(u)
        m, nd = self.dofs.shape
        f = np.zeros(3 * self.space.n_all)
        data = np.zeros(len(self.indices)) if tangent else None
        energy = np.zeros(m)
        theta = np.zeros(m)
        min_j = np.zeros(m)
        kappa = np.ascontiguousarray(np.broadcast_to(np.asarray(self.kappa, dtype=np.float64), (len(self.laws),)))  # NodalPressure sets 0
        viscous = self.Cv is not None
        for a in range(0, m, CHUNK):
            b = min(m, a + CHUNK)
            fe = np.zeros((b - a, nd))
            Ke = np.zeros((b - a, nd, nd)) if tangent else np.zeros((1, 1, 1))
            Cv, Cv_out = (self.Cv[a:b], self.Cv_out[a:b]) if viscous else (_NO_BRANCHES, np.zeros_like(_NO_BRANCHES))
            element_pass(self.G[a:b], self.wq[a:b], np.ascontiguousarray(ue[a:b]), self.mu, self.alpha, kappa, self.law_of[a:b], self.mean_dilatation, tangent,
                         fe, Ke, energy[a:b], theta[a:b], min_j[a:b],
                         viscous, Cv, self.branch_mu, self.branch_alpha, self.branch_eta, self.dt, Cv_out)
            scatter_vector(fe, self.dofs[a:b], f)
            if tangent:
                scatter_matrix(Ke, self.pos[a:b], data)
        K = None
        if tangent:
            nf = len(self.free)
            K = sp.csr_matrix((data, self.indices, self.indptr), shape=(nf, nf))
        return {"f": f, "K": K, "energy": float(np.sum(energy)), "min_jacobian": float(min_j.min()),
                "theta_range": (float(theta.min()), float(theta.max()))}


def point_states(system: FiniteStrain, u: np.ndarray) -> dict:
    """Every quadrature point's state at the displacement `u` (3 n_all,), in NumPy (not the
    compiled element pass): principal stretches (m, q, 3) and their material directions
    (m, q, 3, 3, columns), F (m, q, 3, 3), J (m, q), the stored energy density psi (m, q, Pa)
    of each point's own law and the points' weights (m, q, m^3)."""
    ue = system.element_displacements(u)
    F = np.eye(3) + np.einsum("mka,mqkb->mqab", ue, system.G)
    C = np.einsum("mqka,mqkb->mqab", F, F)
    lam2, N = np.linalg.eigh(C)
    stretches = np.sqrt(np.clip(lam2, 0.0, None))
    J = np.linalg.det(F)
    psi = np.zeros(J.shape)
    with np.errstate(divide="ignore", invalid="ignore"):
        iso = stretches * np.cbrt(J)[..., None] ** -1.0
        for i, law in enumerate(system.laws):
            here = system.law_of == i
            own = volumetric(law.bulk_modulus, J[here])[0]
            for m, a in zip(law.mu, law.alpha):
                own = own + 2.0 * m / a**2 * (np.sum(iso[here] ** a, axis=-1) - 3.0)
            psi[here] = own
    return {"stretches": stretches, "directions": N, "F": F, "J": J, "psi": psi, "weights": system.wq}


def stress_power(system: FiniteStrain, s: dict, du: np.ndarray) -> np.ndarray:
    """P : dF at every point (m, q, Pa per unit of the state's parameter): the rate of the energy
    density as the state moves by `du` (3 n_all,), P the first Piola stress of the point's own law.

    With the Kirchhoff principal stresses beta_i = l_i dpsi/dl_i (the deviatoric split: the
    isochoric terms' lb_i dW/dlb_i less their mean, plus J U'(J)), P : dF = sum_i beta_i / l_i^2
    (F N_i) . (dF N_i), N_i the principal directions of C."""
    lam, N, F, J = s["stretches"], s["directions"], s["F"], s["J"]
    iso = lam * np.cbrt(J)[..., None] ** -1.0
    beta = np.zeros_like(lam)
    for i, law in enumerate(system.laws):
        here = system.law_of == i
        t = np.zeros_like(lam[here])
        for m, a in zip(law.mu, law.alpha):
            t = t + 2.0 * m / a * iso[here] ** a
        beta[here] = t - t.mean(axis=-1, keepdims=True) + (J[here] * volumetric(law.bulk_modulus, J[here])[1])[..., None]
    dF = np.einsum("mka,mqkb->mqab", system.element_displacements(du), system.G)
    FN = np.einsum("mqab,mqbi->mqai", F, N)
    dFN = np.einsum("mqab,mqbi->mqai", dF, N)
    return np.sum(beta / lam**2 * np.sum(FN * dFN, axis=-2), axis=-1)


def fine_jacobian_deviation(system: FiniteStrain, u: np.ndarray, chunk: int = 4096) -> float:
    """The largest |J - 1| of the displacement field `u` at every element's ten nodes and a
    64-point conical product rule (`p2.conical_rule`): P2's J is a polynomial of degree 6 in the
    element, which the four Gauss points of the stiffness do not resolve. On P1 the field is
    affine per element and the Gauss points' J is the element's."""
    space = system.space
    if space.order != 2:
        return float(np.max(np.abs(np.linalg.det(np.eye(3) + np.einsum("mka,mqkb->mqab", system.element_displacements(u), system.G)) - 1.0)))
    bary = np.vstack([p2.node_points(), p2.conical_rule(4)[0]])
    dN = p2.shape_derivatives(bary)  # (p, 10, 4)
    ue = system.element_displacements(u)
    worst = 0.0
    for a in range(0, len(ue), chunk):  # batched matmuls: several times faster than the plain einsums
        A = np.swapaxes(ue[a : a + chunk], 1, 2)[:, None] @ dN[None]  # (m, p, 3, 4)
        F = np.eye(3) + A @ space.grads[a : a + chunk, None]
        worst = max(worst, float(np.max(np.abs(np.linalg.det(F) - 1.0))))
    return worst


def support(system: FiniteStrain, u: np.ndarray, stretch_range, du: np.ndarray | None = None) -> dict:
    """Where a state rests on measured tissue: the share of its stored energy at quadrature
    points with a principal stretch outside `stretch_range` (the range the law's data cover;
    with several laws, a sequence of one range per law, each point judged by its own law's),
    and the largest |J - 1| (at the Gauss points, and at the nodes and a 64-point rule:
    `fine_jacobian_deviation`). With the state's derivative `du` along the pull (`newton.hold`'s
    sensitivity), the **marginal** share dE_out/dE: the force is dE/dd, so a law wrong where no
    one measured moves it by the share of dE/dd those points give (the set of points fixed at
    the state), not by E_out/E; and dE/dd itself (`energy_rate`, the force along the pull: the body's
    part of it when a membrane lies on the body, so the share is then of the body's force).
    The record's `stretch_range` is the first law's."""
    s = point_states(system, u)
    ranges = np.asarray(stretch_range, dtype=np.float64).reshape(-1, 2)
    own = ranges[np.minimum(system.law_of, len(ranges) - 1)]  # one range for every law, or one per law
    lo, hi = own[..., 0], own[..., 1]
    energy = s["psi"] * s["weights"]
    outside = (s["stretches"].min(axis=-1) < lo) | (s["stretches"].max(axis=-1) > hi)
    total = float(np.sum(energy))
    marginal = rate = math.nan
    if du is not None and np.all(np.isfinite(du)):
        power = stress_power(system, s, du) * s["weights"]
        rate = float(np.sum(power))
        marginal = float(np.sum(power[outside]) / rate) if rate > 0 else math.nan  # no energy flowing in: nothing to decide on
    return {"energy_share_outside": float(np.sum(energy[outside]) / total) if total > 0 else 0.0,
            "marginal_share_outside": marginal, "energy_rate": rate,
            "points_outside": int(outside.sum()), "points": int(outside.size), "stretch_range": [float(ranges[0, 0]), float(ranges[0, 1])],
            "max_abs_j_minus_1": float(np.max(np.abs(s["J"] - 1.0))),
            "max_abs_j_minus_1_fine": fine_jacobian_deviation(system, u),
            "principal_stretch_min": float(s["stretches"].min()), "principal_stretch_max": float(s["stretches"].max())}
