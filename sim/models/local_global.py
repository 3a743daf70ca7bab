"""The local/global integrator of the mass-spring system (`sim.models.mass_spring.MassSpring`):
Liu, Bargteil, O'Brien and Kavan 2013, "Fast simulation of mass-spring systems". Per step,
alternate a local projection of every spring to its rest length with a global solve of the
constant matrix ``M + h^2 L`` (factorised once per step size; the hands' coupling springs by a
low-rank Woodbury update), optionally accelerated by Chebyshev (Wang 2015) or Anderson (Peng,
Deng, Zhang and Liu 2018). See docs/mass_spring.md.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from sim.linalg import Factor

RHO_ITERATIONS = 120  # plain iterations that estimate the spectral radius (once per step size)
ANDERSON_DEPTH = 5  # past iterates Anderson acceleration combines (Peng et al. 2018 use 5-6)


class LocalGlobal:
    """The local/global step of `MassSpring`, a mixin: it reads the system's nodes (n, m, x, v,
    rest_positions, free, fixed), springs (springs, k, rest, _moving, _A), anchors, external
    forces, damping and acceleration, and keeps its factorisations in `_lg_cache`; the local
    step's compiled kernel comes from `_local_kernel()`, and the objective's spring energy from
    `_spring_energy(x)`."""

    def _local_global(self, h: float, iterations: int) -> None:
        """Liu et al. 2013: minimise |x - y|_M^2 / (2 h^2) + sum k/2 |x_i - x_j - d_ij|^2.

        With `acceleration = "chebyshev"` (Wang 2015), iterate k+1 is
        ``omega_k+1 (xhat_k+1 - x_k-1) + x_k-1`` from the second on, omega from the spectral
        radius of the plain iteration (`lg_rho`, estimated once per step size)."""
        solver = self._lg_solver(h)
        m = self.m[:, None]
        y = self.x + h * self.v + h * h * self.external / m
        fixed, clamped = solver["fixed_idx"], solver["fixed_mask"]
        # y with the clamped nodes at rest: a masked select, not a fancy-index scatter (the
        # clamped nodes are most of the mesh)
        x = np.where(clamped, self.rest_positions, y)
        free = self.free
        if "fixed_part" not in solver:  # the clamped nodes sit at rest: their pull is the same every step
            solver["fixed_part"] = solver["L_fixed"] @ self.rest_positions[fixed] if len(fixed) else 0.0
        wood = self._woodbury(solver, free)
        # the right-hand side's fixed part, once per step (the same sums as inside the loop)
        base = solver["m_free"] * np.take(y.reshape(-1), solver["free_flat"]).reshape(-1, 3) / (h * h) - solver["fixed_part"]
        if self.acceleration == "anderson":
            x = self._anderson(solver, wood, base, x, y, h, iterations)
            iterations = 0
        elif self.acceleration == "newton":  # the same minimum by Newton-Krylov (newton_krylov.py)
            x = self._newton(solver, wood, x, y, h, iterations)
            iterations = 0
        rho = self.lg_rho(h) if self.acceleration == "chebyshev" else None
        prev, omega = None, 1.0
        for k in range(iterations):
            xf = self._lg_global(solver, wood, base + self._lg_local(solver, x))
            if rho is not None and k >= 1:  # Chebyshev semi-iteration on the free nodes
                omega = 2.0 / (2.0 - rho * rho) if k == 1 else 4.0 / (4.0 - rho * rho * omega)
                xf = omega * (xf - prev) + prev
            prev = x[free].copy() if rho is not None else None
            self._set_free(solver, x, xf)
        v = np.where(clamped, 0.0, (x - self.x) / h)
        self.v = v / (1.0 + h * self.damping)  # mass-proportional damping, implicitly
        self.x = x

    def _set_free(self, solver: dict, x: np.ndarray, xf: np.ndarray) -> None:
        """x[free] = xf, through flat indices in xf's own memory order (the solves return
        Fortran-ordered arrays): a third of the time of a row scatter, the same values."""
        if not x.flags.c_contiguous:  # no flat view of x to write through
            x[self.free] = xf
        elif xf.flags.f_contiguous:
            x.reshape(-1)[solver["free_flat_f"]] = xf.ravel(order="F")
        else:
            x.reshape(-1)[solver["free_flat"]] = xf.ravel()

    def _anderson(self, solver: dict, wood, base: np.ndarray, x: np.ndarray, y: np.ndarray, h: float, iterations: int) -> np.ndarray:
        """Anderson-accelerated local/global (Peng, Deng, Zhang and Liu 2018): each iterate
        combines the last `ANDERSON_DEPTH` local/global updates, least squares on their
        residuals (normal equations of at most ANDERSON_DEPTH columns); one that raises the
        step's objective is replaced by the plain update and the history cleared (their
        safeguard), so the objective still falls every iteration."""
        free = self.free
        size = 3 * len(free)
        F = np.empty((ANDERSON_DEPTH, size))  # rows: differences of successive residuals (a ring)
        G = np.empty((ANDERSON_DEPTH, size))  # and of successive updates
        used, head = 0, 0
        f_prev = g_prev = None
        yf = y[free]
        mass = self.m[free, None] / (h * h)
        xf = x[free]  # the free rows of x, kept alongside it (x's free rows are written by _lg_objective)
        energy = self._lg_objective(solver, x, xf, yf, mass)
        for _ in range(iterations):
            g = self._lg_global(solver, wood, base + self._lg_local(solver, x))
            f = g - xf
            if f_prev is not None:
                np.subtract(f.ravel(), f_prev.ravel(), out=F[head])
                np.subtract(g.ravel(), g_prev.ravel(), out=G[head])
                head, used = (head + 1) % ANDERSON_DEPTH, min(used + 1, ANDERSON_DEPTH)
            f_prev, g_prev = f, g
            dF = F[:used]
            gram = dF @ dF.T
            if np.trace(gram) > 0.0:  # no history, or all-zero differences (converged to the last bit): plain update
                # a tiny ridge keeps nearly parallel residual differences solvable
                theta = np.linalg.solve(gram + 1e-12 * np.trace(gram) * np.eye(used), dF @ f.ravel())
                cand = g - (theta @ G[:used]).reshape(g.shape)
                trial = self._lg_objective(solver, x, cand, yf, mass)
                if trial <= energy:
                    energy, xf = trial, cand
                    continue
                used = head = 0
            energy, xf = self._lg_objective(solver, x, g, yf, mass), g
        return x

    def _lg_objective(self, solver: dict, x: np.ndarray, xf: np.ndarray, yf: np.ndarray, mass: np.ndarray) -> float:
        """The step's objective sum m |x - y|^2 / (2 h^2) + springs + anchors at x with its free
        nodes at `xf` (x is changed: its free rows become xf). `mass` is m / h^2 on the free
        rows; springs between two clamped nodes are left out (they are constant)."""
        x[self.free] = xf
        d = xf - yf
        total = 0.5 * float(np.sum(mass * d * d))
        for nodes, k, target in self.anchors:
            total += 0.5 * k * float(np.sum((x[nodes].mean(axis=0) - target) ** 2))
        return total + self._spring_energy(x)

    def _lg_local(self, solver: dict, x: np.ndarray) -> np.ndarray:
        """The local step and its share of the right-hand side, A^T diag(k) d (free rows): each
        moving spring's vector projected to its rest length. One pass over the springs
        (compiled, `sim/models/spring_kernels.py`) where numba is installed, else sparse products."""
        kernel = self._local_kernel()
        if kernel is not None:
            return kernel(x, solver["act_i"], solver["act_j"], solver["act_k"], solver["rest_act"], solver["free_pos"], len(self.free))
        dvec = solver["A_act"] @ x  # vectors x_i - x_j of the springs that touch a free node
        length = np.sqrt(np.einsum("ij,ij->i", dvec, dvec))
        dvec *= (solver["rest_act"] / np.where(length > 0, length, 1.0))[:, None]
        return solver["Ak"] @ dvec

    @staticmethod
    def _lg_global(solver: dict, wood, rhs: np.ndarray) -> np.ndarray:
        """The global step: (M / h^2 + L) x = rhs on the free nodes (prefactored)."""
        if wood is None:
            return solver["factor"].solve(np.ascontiguousarray(rhs))
        Wm, Z, Sinv, Wkt = wood  # anchors: (Q + W diag(k) W^T) x = rhs + W diag(k) T, by Woodbury
        xb = solver["factor"].solve(np.ascontiguousarray(rhs + Wkt))
        return xb - Z @ (Sinv @ (Wm.T @ xb))

    def lg_rho(self, h: float) -> float:
        """Spectral radius of the plain local/global iteration at step `h`: estimated once,
        from the decay of successive updates over plain iterations from the rest state pulled
        by a unit-scale random displacement (the iteration matrix depends on the step and the
        springs, barely on the state). Capped at 0.9999."""
        solver = self._lg_solver(h)
        if "rho" not in solver:
            # a smooth start (the whole tissue shifted and sheared): the slow modes that
            # decide the rate; the fast ones have died out by the iterations measured
            x = self.rest_positions.copy()
            c = x[self.free] - x[self.free].mean(axis=0)
            x[self.free] += 0.05 * c[:, [1, 2, 0]] + 1e-3
            inertia = (self.m[:, None] * self.rest_positions / (h * h))[self.free]
            fixed_part = solver["L_fixed"] @ x[self.fixed] if self.fixed.any() else 0.0
            steps = []
            for _ in range(RHO_ITERATIONS):
                xf = self._lg_global(solver, None, inertia - fixed_part + self._lg_local(solver, x))
                steps.append(float(np.linalg.norm(xf - x[self.free])))
                x[self.free] = xf
            tail = RHO_ITERATIONS // 2
            ratios = np.array(steps[tail + 1:]) / np.array(steps[tail:-1])
            solver["rho"] = float(min(np.exp(np.mean(np.log(ratios))), 0.9999))
        return solver["rho"]

    def _woodbury(self, solver: dict, free: np.ndarray):
        """Precomputed pieces for the anchors' low-rank update of the global matrix."""
        if not self.anchors:
            return None
        key = tuple((n, k) for n, k, _ in self.anchors)  # the arrays themselves: an id could be reused
        cached = solver.get("wood")
        pos = -np.ones(self.n, dtype=np.int64)
        pos[free] = np.arange(len(free))
        if cached is None or len(cached[0]) != len(key) or any(a is not b or ka != kb for (a, ka), (b, kb) in zip(cached[0], key)):
            cols = []
            for nodes, _, _ in self.anchors:
                w = np.zeros(len(free))
                p = pos[nodes]
                w[p[p >= 0]] = 1.0 / len(nodes)
                cols.append(w)
            Wm = np.stack(cols, axis=1)  # (n_free, m)
            Z = solver["factor"].solve(np.ascontiguousarray(Wm))
            ks = np.array([k for _, k, _ in self.anchors])
            Sinv = np.linalg.inv(np.diag(1.0 / ks) + Wm.T @ Z)
            solver["wood"] = cached = (key, Wm, Z, Sinv)
        _, Wm, Z, Sinv = cached
        kt = np.stack([k * t for _, k, t in self.anchors])  # (m, 3)
        return Wm, Z, Sinv, Wm @ kt  # W diag(k) T: the same for every iteration of the step

    def _lg_flops(self, h: float, iterations: int) -> float:
        """`step_flops` of a local/global step (`iterations` iterations at step `h`)."""
        n, nf, m = self.n, len(self.free), len(self.anchors)
        solver = self._lg_solver(h)
        nnz_L = solver["factor"].nnz_L
        m_act = len(self._moving)
        per_iter = 6 * solver["A_act"].nnz + 10 * m_act + 6 * solver["Ak"].nnz + 6 * nf + 12 * nnz_L + (18 * nf * m if m else 0)
        return float(iterations * per_iter + 6 * solver["L_fixed"].nnz + 20 * n)

    def _lg_solver(self, h: float) -> dict:
        if h not in self._lg_cache:
            L = (self._A.T @ sp.diags(self.k) @ self._A).tocsr()  # (n, n) spring Laplacian
            M = sp.diags(self.m / (h * h))
            free, fixed = self.free, np.flatnonzero(self.fixed)
            Q = (M + L).tocsr()
            active = self._moving  # springs between two clamped nodes never move: leave them out
            A_act = self._A[active].tocsr()
            Ak = (A_act.T.multiply(self.k[active][None, :])).tocsr()[free]  # (A^T diag(k)) on free rows
            free_pos = -np.ones(self.n, dtype=np.int64)
            free_pos[free] = np.arange(len(free))
            e = self.springs[active]
            self._lg_cache = {h: {"factor": Factor(Q[free][:, free], simplicial=True), "L_fixed": L[free][:, fixed],  # one step size at a time
                                  "A_act": A_act, "Ak": Ak, "rest_act": self.rest[active],
                                  "act_i": np.ascontiguousarray(e[:, 0]), "act_j": np.ascontiguousarray(e[:, 1]),
                                  "act_k": np.ascontiguousarray(self.k[active]), "free_pos": free_pos, "fixed_idx": fixed,
                                  "fixed_mask": np.repeat(self.fixed[:, None], 3, axis=1), "m_free": self.m[free, None],
                                  # x's free entries, flat, in C order (row by row) and in Fortran order (x, then y, then z)
                                  "free_flat": (3 * free[:, None] + np.arange(3)).ravel(), "free_flat_f": (3 * free[None, :] + np.arange(3)[:, None]).ravel()}}
        return self._lg_cache[h]
