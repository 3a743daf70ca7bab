"""Static compressible neo-Hookean solve with a grasp held, on P1 or P2 tetrahedra: the one
Newton solver of the haptic model's nonlinear reference (`studyctl model fem`) and of the
converged reference (`analysis.reference`).

Energy density ``mu/2 (I1 - 3) - mu ln J + lam/2 (ln J)^2``, integrated at the element's
quadrature points (one for P1, four for P2). The grasp ``W u = d`` is imposed with a Lagrange
multiplier, condensed (Schur complement: 3 extra solves per iteration). The displacement is
applied in equal load steps, each Newton-iterated to a relative residual below `tol`; an
indefinite tangent is factorised shifted (`sim.linalg.shifted_factor`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp

from sim.linalg import shifted_factor
from sim.models.fem.linear import element_dofs


@dataclass
class NewtonReport:
    load_steps: int
    iterations: list[int] = field(default_factory=list)  # per load step
    residuals: list[list[float]] = field(default_factory=list)  # relative residual per iteration
    converged: bool = True
    min_jacobian: float = 1.0  # smallest det(F) seen: <= 0 means an inverted element
    shifts: int = 0  # Newton iterations whose tangent was indefinite (factorised shifted)
    tangent_updates: int = 0  # refactorisations (corotational solver)
    completed_steps: int | None = None  # load steps solved; fewer than load_steps when the solve stopped


def stress(F: np.ndarray, lam: float, mu: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """First Piola-Kirchhoff stress P, F^-1 and ln J at deformation gradients F (..., 3, 3)."""
    J = np.linalg.det(F)
    Finv = np.linalg.inv(F)
    FinvT = np.swapaxes(Finv, -1, -2)
    lnJ = np.log(J)
    return mu * (F - FinvT) + (lam * lnJ)[..., None, None] * FinvT, Finv, lnJ


def tangent(G: np.ndarray, wq: np.ndarray, Finv: np.ndarray, lnJ: np.ndarray, lam: float, mu: float) -> np.ndarray:
    """Element tangents (m, 3k, 3k) of A_iJkL = mu d_ik d_JL + (mu - lam lnJ) Finv_Li Finv_Jk + lam Finv_Ji Finv_Lk."""
    m, nq, k = G.shape[:3]
    X = np.einsum("mqLi,mqaL->mqai", Finv, G).reshape(m, nq, 3 * k)  # (g_a . Finv)_i
    c1 = (mu - lam * lnJ) * wq
    K = (lam * np.matmul(np.swapaxes(X * wq[..., None], 1, 2), X)).reshape(m, k, 3, k, 3)
    K += np.matmul(np.swapaxes(X * c1[..., None], 1, 2), X).reshape(m, k, 3, k, 3).transpose(0, 1, 4, 3, 2)
    gg = np.einsum("mqaj,mqbj->mab", G * wq[..., None, None], G)
    K += mu * gg[:, :, None, :, None] * np.eye(3)[None, None, :, None, :]
    return K.reshape(m, 3 * k, 3 * k)


def neo_hookean_solve(fem, W: sp.csr_matrix, target: np.ndarray, steps: int = 10, tol: float = 1e-8, max_iter: int = 25,
                      on_step=None):
    """Hold the grasp (W u = d) at `target` (3,) on `fem` (a `LinearFem`, either order). W may
    have any number of rows k (then `target` is (k,)): any linear constraints on the free dofs.

    Returns (nodal displacements (n_all, 3), force holding the grasp (k,), NewtonReport); a
    solve that stops (an inverted element, or no convergence in `max_iter`) returns its last
    state with ``converged`` False. `on_step(step, u (n_all, 3), force (3,))`, if given, sees
    each converged load step (a whole force-displacement curve from one solve)."""
    lam, mu = fem.lam, fem.mu
    G, wq = fem.quadrature()
    m, k = G.shape[0], G.shape[2]
    dofs = element_dofs(fem.elements)
    rows, cols = np.repeat(dofs, 3 * k, axis=1).ravel(), np.tile(dofs, (1, 3 * k)).ravel()
    free, n = fem.free, 3 * fem.n_all
    u, lam_mult = np.zeros(n), np.zeros(W.shape[0])
    Wt = np.ascontiguousarray(W.T.toarray())
    report = NewtonReport(load_steps=steps, completed_steps=0)
    scale = max(float(np.linalg.norm(target)), 1e-12)
    for step in range(1, steps + 1):
        d = np.asarray(target, dtype=np.float64) * step / steps
        hist: list[float] = []
        report.residuals.append(hist)
        for _ in range(max_iter):
            F = np.eye(3) + np.einsum("mai,mqaj->mqij", u[dofs].reshape(m, k, 3), G)
            J = np.linalg.det(F)
            report.min_jacobian = min(report.min_jacobian, float(J.min()))
            if np.any(J <= 0):
                break
            P, Finv, lnJ = stress(F, lam, mu)
            f_int = np.bincount(dofs.ravel(), weights=np.einsum("mq,mqij,mqaj->mai", wq, P, G).ravel(), minlength=n)
            r = f_int[free] - Wt @ lam_mult  # internal force minus the grasp's
            gap = W @ u[free] - d
            res = float(np.linalg.norm(r)) / max(float(np.linalg.norm(f_int[free])), float(np.linalg.norm(Wt @ lam_mult)), 1e-30)
            hist.append(max(res, float(np.linalg.norm(gap)) / scale))
            if len(hist) > 1 and hist[-1] < tol:
                break
            Kt = sp.coo_matrix((tangent(G, wq, Finv, lnJ, lam, mu).ravel(), (rows, cols)), shape=(n, n)).tocsr()[free][:, free]
            factor = shifted_factor(0.5 * (Kt + Kt.T))
            del Kt
            report.shifts += int(factor.shift > 0)
            Kr, KW = factor.solve(-r), factor.solve(Wt)
            dl = np.linalg.solve(W @ KW, -gap - W @ Kr)
            u[free] += Kr + KW @ dl
            lam_mult = lam_mult + dl
            del factor
        report.iterations.append(len(hist))
        if not (len(hist) > 1 and hist[-1] < tol):
            report.converged = False
            return u.reshape(-1, 3), lam_mult, report
        report.completed_steps = step
        if on_step is not None:
            on_step(step, u.reshape(-1, 3).copy(), lam_mult.copy())
    return u.reshape(-1, 3), lam_mult, report
