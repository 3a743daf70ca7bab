"""The corotational (stiffness-warping) update of linear P1 elasticity: each element's
rotation from the polar decomposition of its deformation gradient (a compiled kernel when
numba is there), the rotated internal force, the warped tangent, and a static solve."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from sim.linalg import Factor
from sim.models.fem import corotational_kernels
from sim.models.fem.linear import LinearFem, assemble, element_dofs
from sim.models.fem.newton import NewtonReport


def _element_arrays(fem: LinearFem, elements: np.ndarray | None) -> tuple:
    """Contiguous tets, gradients and element matrices of `elements` (all when None) for the
    compiled kernels; kept for the last set asked for (a grasp's active elements, every frame)."""
    cached = fem.solver_cache.get("element_arrays")
    if cached is not None and cached[0] is elements:
        return cached[1]
    sel = slice(None) if elements is None else elements
    arrays = (np.ascontiguousarray(fem.tets[sel], dtype=np.int64), np.ascontiguousarray(fem.grads[sel]),
              np.ascontiguousarray(fem.element_matrices[sel]))
    fem.solver_cache["element_arrays"] = (elements, arrays)
    return arrays


def _kernels():
    """The compiled passes (`corotational_kernels`); the tests replace it with None for the NumPy path."""
    return corotational_kernels


def element_rotations(fem: LinearFem, u: np.ndarray, elements: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Rotation of each element's polar decomposition F = R S, and det F, for nodal u (3n,)."""
    kernels = _kernels()
    if kernels is None:
        tets = fem.tets if elements is None else fem.tets[elements]
        grads = fem.grads if elements is None else fem.grads[elements]
        ue = u[element_dofs(tets)].reshape(-1, 4, 3)
        F = np.eye(3) + np.einsum("mai,maj->mij", ue, grads)
        return _svd_rotations(F), np.linalg.det(F)
    tets, grads, _ = _element_arrays(fem, elements)
    F = np.empty((len(tets), 3, 3))
    kernels.deformation_gradients(np.ascontiguousarray(u, dtype=np.float64), tets, grads, F)
    polar_rotations = kernels.polar_rotations  # compiled scaled-Newton polar iteration: faster than the batched SVD, the same R (docs/fem.md)
    R, det = np.empty_like(F), np.empty(len(F))
    left = polar_rotations(np.ascontiguousarray(F), R, det)
    if left.any():  # inverted (det F <= 0): the SVD's nearest rotation
        R[left] = _svd_rotations(F[left])
    return R, det


def _svd_rotations(F: np.ndarray) -> np.ndarray:
    Uf, _, Vt = np.linalg.svd(F)
    flip = np.linalg.det(Uf) * np.linalg.det(Vt) < 0  # a reflection: make it the nearest rotation
    Uf[flip, :, 2] *= -1.0
    return Uf @ Vt


def _corotate_compiled(fem: LinearFem, u: np.ndarray, R: np.ndarray, elements: np.ndarray, out: np.ndarray) -> float:
    """Add the `elements`' corotational force's change from the linear one to `out` (one
    compiled pass); returns the energy's change."""
    tets, _, Ke = _element_arrays(fem, elements)
    return corotational_kernels.corotated_minus_linear(np.ascontiguousarray(u, dtype=np.float64), np.ascontiguousarray(fem.nodes, dtype=np.float64),
                                                       tets, Ke, np.ascontiguousarray(R), out)


def corotational_internal_force(fem: LinearFem, u: np.ndarray, R: np.ndarray, elements: np.ndarray | None = None) -> np.ndarray:
    """f = sum_e R_e K_e (R_e^T x_e - X_e): linear elasticity in each element's rotated frame.

    With `elements`, only those are corotated (R given for them); the others stay linear,
    which is what they are when their rotation is negligible.
    """
    if _kernels() is not None and elements is not None:  # one compiled pass over the elements
        out = fem.stiffness @ u
        _corotate_compiled(fem, u, R, elements, out)
        return out
    tets = fem.tets if elements is None else fem.tets[elements]
    Ke = fem.element_matrices if elements is None else fem.element_matrices[elements]
    dofs = element_dofs(tets)
    X = fem.nodes[tets]  # (m, 4, 3)
    ue = u[dofs].reshape(-1, 4, 3)
    local = np.matmul(X + ue, R) - X  # R^T x - X, per node (batched products: faster than einsum here)
    fl = np.matmul(Ke, local.reshape(-1, 12, 1)).reshape(-1, 4, 3)
    fe = np.matmul(fl, R.transpose(0, 2, 1))  # R f per node
    n = 3 * len(fem.nodes)
    if elements is None:
        return np.bincount(dofs.ravel(), weights=fe.ravel(), minlength=n)
    linear = np.einsum("mij,mj->mi", Ke, ue.reshape(-1, 12))
    return fem.stiffness @ u + np.bincount(dofs.ravel(), weights=(fe.reshape(-1, 12) - linear).ravel(), minlength=n)


def warped_stiffness(fem: LinearFem, R: np.ndarray) -> sp.csr_matrix:
    """sum_e R_e K_e R_e^T on the free dofs (the stiffness-warping tangent, dR ignored)."""
    K5 = fem.element_matrices.reshape(-1, 4, 3, 4, 3)
    Kw = np.einsum("mij,majbk,mlk->maibl", R, K5, R, optimize=True)  # R K_ab R^T for every 3x3 block
    return assemble(Kw.reshape(-1, 12, 12), fem.tets, len(fem.nodes))[fem.free][:, fem.free]


def corotational_energy(fem: LinearFem, u: np.ndarray, R: np.ndarray, elements: np.ndarray | None = None) -> float:
    """E = sum_e 1/2 l_e^T K_e l_e with l_e = R_e^T x_e - X_e: the energy whose gradient is the
    corotational force (with the polar rotation, or the SVD's for an inverted element, the
    rotation's derivative adds nothing; McAdams et al. 2011). With `elements`, only those are
    corotated and the others keep the linear energy, as in `corotational_internal_force`."""
    tets = fem.tets if elements is None else fem.tets[elements]
    Ke = fem.element_matrices if elements is None else fem.element_matrices[elements]
    X = fem.nodes[tets]
    ue = u[element_dofs(tets)].reshape(-1, 4, 3)
    local = (np.matmul(X + ue, R) - X).reshape(-1, 12)
    corot = 0.5 * float(np.einsum("mi,mij,mj->", local, Ke, local, optimize=True))
    if elements is None:
        return corot
    ue = ue.reshape(-1, 12)
    return 0.5 * float(u @ (fem.stiffness @ u)) + corot - 0.5 * float(np.einsum("mi,mij,mj->", ue, Ke, ue, optimize=True))


@dataclass
class Precond:
    solve: object  # callable: b -> K^-1 b on the free dofs
    U: np.ndarray  # K^-1 W^T
    C: np.ndarray  # W K^-1 W^T


@dataclass(frozen=True)
class State:
    """A corotational state's rotations, det F, internal force (all dofs) and energy: what a
    step needs at its start, so the line search's accepted trial serves the next step."""
    u: np.ndarray
    R: np.ndarray
    J: np.ndarray
    f: np.ndarray
    energy: float


def evaluate(fem: LinearFem, u: np.ndarray, elements: np.ndarray | None = None) -> State:
    R, J = element_rotations(fem, u, elements)
    if elements is not None and _kernels() is not None:  # the haptic frame's path: one compiled pass gives both
        f = fem.stiffness @ u
        linear = 0.5 * float(u @ f)
        return State(u, R, J, f, linear + _corotate_compiled(fem, u, R, elements, f))
    return State(u, R, J, corotational_internal_force(fem, u, R, elements), corotational_energy(fem, u, R, elements))


MAX_HALVINGS = 8  # the preconditioned step is a descent direction, so some halving decreases


def corotational_step(fem: LinearFem, W, pre: Precond, at: State, lam_mult: np.ndarray, d: np.ndarray, elements=None):
    """One preconditioned step towards corotational equilibrium with W u = d, from the state `at`.

    The step is du = -P (f - W^T lam'), the multiplier lam' chosen so that W du closes the gap:
    with P symmetric positive definite it descends the Lagrangian E(u) - lam'.(W u - d), which
    is bounded below. Near an inverted element the rotations turn fast and the full step
    (which omits their derivative) can overshoot, so it is halved until the Lagrangian
    decreases (Armijo). Returns (state, lam_mult, relative residual at `at`, min det F at `at`,
    halvings; -1 when no halving decreased and the state is kept).
    """
    free = fem.free
    f_int = at.f[free]
    r = f_int - (W.T @ lam_mult)
    gap = W @ at.u[free] - d
    res = max(float(np.linalg.norm(r)) / max(float(np.linalg.norm(f_int)), 1e-30), float(np.linalg.norm(gap)) / max(float(np.linalg.norm(d)), 1e-12))
    Kr = pre.solve(-r)
    dl = np.linalg.solve(pre.C, -gap - W @ Kr)
    step = Kr + pre.U @ dl
    lam_new = lam_mult + dl
    slope = float((f_int - W.T @ lam_new) @ step)  # < 0: a descent direction
    base = at.energy - float(lam_new @ gap)
    grad = float(np.linalg.norm(f_int - W.T @ lam_new))
    alpha = 1.0
    for halvings in range(MAX_HALVINGS + 1):
        u = at.u.copy()
        u[free] += alpha * step
        trial = evaluate(fem, u, elements)
        merit = trial.energy - float(lam_new @ (W @ u[free] - d))
        if math.isfinite(merit) and merit <= base + 1e-4 * alpha * slope:
            return trial, lam_mult + alpha * dl, res, float(at.J.min()), halvings
        # near convergence the energy's change falls below its round-off: there the step must
        # shrink the Lagrangian's gradient instead
        if (math.isfinite(merit) and abs(merit - base) <= 1e-12 * abs(base)
                and float(np.linalg.norm(trial.f[free] - W.T @ lam_new)) < grad):
            return trial, lam_mult + alpha * dl, res, float(at.J.min()), halvings
        alpha *= 0.5
    return at, lam_mult, res, float(at.J.min()), -1


def corotational_solve(fem: LinearFem, W, U: np.ndarray, target: np.ndarray, steps: int = 5, tol: float = 1e-7, max_iter: int = 100):
    """Static corotational solve with the grasp point held at `target` (3,).

    Load steps, each iterated to a relative residual below `tol`. The steps are preconditioned
    by the linear stiffness (already factorised, so cheap); when that stalls (less than a
    halving of the residual over four steps) the warped stiffness at the current state is
    factorised and used instead (a modified Newton method). The warped stiffness omits the
    derivative of the rotations, so convergence is linear, not quadratic: at large pulls
    expect tens of iterations per step. Returns (nodal displacements, force holding the grasp
    point, NewtonReport).
    """
    pre = Precond(solve=fem.solve_free, U=U, C=W @ U)
    u = np.zeros(3 * len(fem.nodes))
    lam_mult = np.zeros(3)
    report = NewtonReport(load_steps=steps)
    Wt = np.ascontiguousarray(W.T.toarray())
    report.completed_steps = 0
    at = evaluate(fem, u)
    for step in range(1, steps + 1):
        d = np.asarray(target, dtype=np.float64) * step / steps
        hist: list[float] = []
        good = (at, lam_mult)
        for _ in range(max_iter):
            R = at.R
            at, lam_mult, res, jmin, _ = corotational_step(fem, W, pre, at, lam_mult, d)
            report.min_jacobian = min(report.min_jacobian, jmin)
            hist.append(res)
            if not math.isfinite(res) or res > 1e3 * min(hist):
                # diverging: return the state before this load step (an inverted element is not
                # a failure: its rotation is the SVD's, Irving et al. 2004, and min det F is reported)
                at, lam_mult = good
                report.converged = False
                report.iterations.append(len(hist))
                report.residuals.append(hist)
                return at.u.reshape(-1, 3), lam_mult, report
            if len(hist) > 1 and res < tol:
                break
            if len(hist) >= 5 and hist[-1] > 0.5 * hist[-5]:
                factor = Factor(warped_stiffness(fem, R))
                Uw = factor.solve(Wt)
                pre = Precond(solve=factor.solve, U=Uw, C=W @ Uw)
                report.tangent_updates += 1
        else:
            report.converged = False
        if report.converged:
            report.completed_steps = step
        report.iterations.append(len(hist))
        report.residuals.append(hist)
    return at.u.reshape(-1, 3), lam_mult, report




def warped_active(fem: LinearFem, R: np.ndarray, active: np.ndarray) -> sp.csc_matrix:
    """Warped stiffness on the free dofs with only the `active` elements rotated: the linear
    reduced stiffness plus the change of those elements, added straight into a copy of its
    values (where each element entry lands is found once per active set; the matrix is
    symmetric, so its CSR arrays serve as CSC)."""
    cached = fem.solver_cache.get("warp_map")
    if cached is None or cached[0] is not active:
        Kr = fem.reduced
        Kr.sum_duplicates()  # canonical: sorted indices, so keys below increase
        n = Kr.shape[0]
        where = -np.ones(3 * len(fem.nodes), dtype=np.int64)
        where[fem.free] = np.arange(len(fem.free))
        dofs = where[element_dofs(fem.tets[active])]  # (m, 12) free index or -1
        rows = np.repeat(dofs, 12, axis=1).ravel()
        cols = np.tile(dofs, (1, 12)).ravel()
        valid = (rows >= 0) & (cols >= 0)
        keys = np.repeat(np.arange(n, dtype=np.int64), np.diff(Kr.indptr)) * n + Kr.indices
        query = rows[valid] * n + cols[valid]
        pos = np.minimum(np.searchsorted(keys, query), len(keys) - 1)
        if not np.array_equal(keys[pos], query):  # an entry outside the pattern (a dropped zero): assemble
            pos = None
        fem.solver_cache["warp_map"] = cached = (active, valid, pos)
    _, valid, pos = cached
    K5 = fem.element_matrices[active].reshape(-1, 4, 3, 4, 3)
    Kw = np.einsum("mij,majbk,mlk->maibl", R, K5, R, optimize=True)  # R K_ab R^T for every 3x3 block
    Kr = fem.reduced
    if pos is None:
        delta = assemble((Kw - K5).reshape(-1, 12, 12), fem.tets[active], len(fem.nodes))
        return (Kr + delta[fem.free][:, fem.free]).tocsc()
    data = Kr.data + np.bincount(pos, weights=(Kw - K5).ravel()[valid], minlength=len(Kr.data))
    return sp.csc_matrix((data, Kr.indices, Kr.indptr), shape=Kr.shape)

