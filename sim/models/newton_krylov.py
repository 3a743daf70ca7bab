"""Newton-Krylov for the mass-spring system's backward-Euler step (`acceleration = "newton"`):
the same objective as local/global (`sim/models/local_global.py`: inertia + springs + anchors
over the free nodes), minimised by inexact Newton steps with the springs' exact Hessian,
each solved by conjugate gradients preconditioned with the local/global matrix ``M/h^2 + L``
(prefactored; the anchors by its Woodbury update). The Laplacian as a Hessian approximation
is Liu, Bouaziz and Kavan 2017 ("Quasi-Newton methods for real-time simulation of
hyperelastic materials"); here it preconditions the exact Hessian instead of seeding L-BFGS
(the two compared: docs/mass_spring.md).

`iterations` counts solves with the prefactored matrix (each comes with one pass over the
springs, a Hessian product or a gradient): the unit of cost of a local/global iteration.
"""

from __future__ import annotations

import numpy as np

from sim.models.spring_kernels import spring_gradient, spring_hessian_product

NEWTON_ETA = 0.3  # CG stops at this fraction of the preconditioned residual (Eisenstat-Walker-like forcing)
NEWTON_CG_CAP = 8  # at most this many CG iterations per Newton step: a new linearisation pays off after that
ARMIJO = 1e-4  # sufficient decrease of the line search
MAX_HALVINGS = 30


class NewtonKrylov:
    """`_newton` of `MassSpring`, a mixin beside `LocalGlobal` (whose solver dict it reuses:
    the factor, the moving springs' arrays, the Woodbury pieces, `_lg_objective`)."""

    def _newton(self, solver: dict, wood, x: np.ndarray, y: np.ndarray, h: float, iterations: int) -> np.ndarray:
        """Minimise the step's objective from x (its free rows move). Every Newton step is a descent direction (CG from zero on an SPD
        preconditioner; a direction of negative curvature ends CG), and an Armijo line search
        accepts it, so the objective falls at every step. At most `iterations` solves in all."""
        free = self.free
        mass = self.m[free, None] / (h * h)
        yf = y[free]
        xf = x[free].copy()
        energy = self._lg_objective(solver, x, xf, yf, mass)
        budget = iterations
        while budget > 0:
            g = self._nk_gradient(solver, x, xf, yf, mass)
            dx, budget = self._nk_cg(solver, wood, x, mass, -g, budget)
            if dx is None:  # zero gradient: converged
                break
            slope = float(np.sum(g * dx))
            if not slope < 0.0:
                break
            t = 1.0
            for _ in range(MAX_HALVINGS):
                trial = self._lg_objective(solver, x, xf + t * dx, yf, mass)
                if trial <= energy + ARMIJO * t * slope:
                    break
                t *= 0.5
            else:  # no decrease left at rounding level: keep the last iterate
                x[free] = xf
                break
            xf, energy = x[free].copy(), trial
        x[free] = xf
        return x

    def _nk_cg(self, solver: dict, wood, x: np.ndarray, mass: np.ndarray, b: np.ndarray, budget: int):
        """PCG on H dx = b from dx = 0, at most NEWTON_CG_CAP iterations; `budget` counts the
        preconditioner's solves (the first included). Returns (dx or None, budget left)."""
        r = b.copy()
        z = self._nk_precondition(solver, wood, r)
        budget -= 1
        rz = float(np.sum(r * z))
        if not rz > 0.0:
            return None, budget
        stop = NEWTON_ETA * NEWTON_ETA * rz
        dx = np.zeros_like(b)
        p = z.copy()
        for k in range(NEWTON_CG_CAP):
            hp = self._nk_hessian_product(solver, x, mass, p)
            php = float(np.sum(p * hp))
            if not php > 0.0:  # negative curvature (compressed springs): stop, or take the preconditioned gradient
                if k == 0:
                    dx = z
                break
            a = rz / php
            dx += a * p
            if budget <= 0 or k == NEWTON_CG_CAP - 1:
                break
            r -= a * hp
            z = self._nk_precondition(solver, wood, r)
            budget -= 1
            rz_new = float(np.sum(r * z))
            if rz_new <= stop:
                break
            p *= rz_new / rz
            p += z
            rz = rz_new
        return dx, budget

    def _nk_precondition(self, solver: dict, wood, r: np.ndarray) -> np.ndarray:
        """(M/h^2 + L + W diag(k) W^T)^-1 r: the local/global matrix with the anchors (Woodbury)."""
        z = solver["factor"].solve(np.ascontiguousarray(r))
        if wood is not None:
            Wm, Z, Sinv, _ = wood
            z -= Z @ (Sinv @ (Wm.T @ z))
        return z

    def _nk_gradient(self, solver: dict, x: np.ndarray, xf: np.ndarray, yf: np.ndarray, mass: np.ndarray) -> np.ndarray:
        """The objective's gradient on the free rows (x's free rows are xf)."""
        g = mass * (xf - yf)
        kernels = self._newton_kernels()
        if kernels is not None:
            g += kernels[0](x, solver["act_i"], solver["act_j"], solver["act_k"], solver["rest_act"], solver["free_pos"], len(self.free))
        else:
            g -= self.spring_forces(x)[self.free]
        pos = solver["free_pos"]
        for nodes, k, target in self.anchors:
            p = pos[nodes]
            g[p[p >= 0]] += k * (x[nodes].mean(axis=0) - target) / len(nodes)
        return g

    def _nk_hessian_product(self, solver: dict, x: np.ndarray, mass: np.ndarray, p: np.ndarray) -> np.ndarray:
        """The objective's exact Hessian at x times p (free rows), matrix free."""
        args = (x, solver["act_i"], solver["act_j"], solver["act_k"], solver["rest_act"], solver["free_pos"])
        kernels = self._newton_kernels()
        out = kernels[1](*args, p) if kernels is not None else _hessian_product_numpy(*args, p)
        out += mass * p
        pos = solver["free_pos"]
        for nodes, k, _ in self.anchors:
            q = pos[nodes]
            q = q[q >= 0]
            out[q] += k * p[q].sum(axis=0) / len(nodes) ** 2
        return out

    def _newton_kernels(self):
        """The compiled gradient and Hessian product (`sim/models/spring_kernels.py`), or None without numba
        (or where the local step's kernel is swapped for the NumPy path)."""
        if self._local_kernel() is None:
            return None

        return spring_gradient, spring_hessian_product


def _hessian_product_numpy(x, ei, ej, k, rest, free_pos, p):
    """`sim.models.spring_kernels.spring_hessian_product` in NumPy (the path without numba)."""
    q = np.zeros((len(ei), 3))
    fi, fj = free_pos[ei], free_pos[ej]
    q[fi >= 0] += p[fi[fi >= 0]]
    q[fj >= 0] -= p[fj[fj >= 0]]
    d = x[ei] - x[ej]
    length = np.sqrt(np.einsum("ij,ij->i", d, d))
    n = d / length[:, None]
    t = 1.0 - rest / length
    along = np.einsum("ij,ij->i", n, q)
    hq = (k * (1.0 - t) * along)[:, None] * n + (k * t)[:, None] * q
    out = np.zeros_like(p)
    np.add.at(out, fi[fi >= 0], hq[fi >= 0])
    np.subtract.at(out, fj[fj >= 0], hq[fj >= 0])
    return out
