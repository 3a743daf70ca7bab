"""The FEM core's one Newton solver for finite strain: hold linear constraints on the free dofs
(a grasp's ``W u = d``, or a cube's faces) at a target, following the load path from rest.

The constraint is a Lagrange multiplier, condensed (a Schur complement: k extra solves per
iteration for k constraint rows). The path ``d(t) = t target``, t in (0, 1], is followed in
adaptive steps: each step starts from the last two states extrapolated, is Newton-iterated
to a relative residual below `tol`, halved when it fails (an inverted element or no
convergence) and lengthened when it converges quickly; steps land on every requested
fraction, where the force and the condensed tangent stiffness ``(W K_t^-1 W^T)^-1`` of the
converged state are recorded. The tangent's pattern is fixed, so CHOLMOD's symbolic analysis
is done once; an indefinite tangent is factorised shifted (`sim.linalg.shifted_factor`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp

from sim.linalg import SingularSystemError, shifted_factor, symbolic

FLOOR = 1e-6  # a residual below this whose Newton steps no longer move the state is at round-off (kappa = 50 mu)


@dataclass
class NewtonReport:
    load_steps: int
    iterations: list[int] = field(default_factory=list)  # per load step
    residuals: list[list[float]] = field(default_factory=list)  # relative residual per iteration
    converged: bool = True
    min_jacobian: float = 1.0  # smallest det(F) of a converged state: <= 0 means an inverted element
    shifts: int = 0  # Newton iterations whose tangent was indefinite (factorised shifted)
    tangent_updates: int = 0  # refactorisations (corotational solver)
    completed_steps: int | None = None  # load steps solved; fewer than load_steps when the solve stopped
    cut_steps: int = 0  # steps halved after a failure (inverted elements or no convergence)
    reason: str = ""  # why a solve stopped
    linear_iterations: int = 0  # GMRES iterations (each: a tangent product and a solve with the last factor)


@dataclass
class HeldPath:
    """What `hold` returns: the state at the last converged step, and the records."""

    u: np.ndarray  # (3 n_all,) displacement of the last converged state
    multipliers: np.ndarray  # (k,) force holding the constraints there (on the body: + pulls along W)
    fractions: np.ndarray  # the recorded t
    forces: np.ndarray  # (len(fractions), k); NaN where not reached
    stiffness: np.ndarray | None  # (len(fractions), k, k) condensed tangents, when asked for
    report: NewtonReport
    states: list = field(default_factory=list)  # the u of each recorded fraction, when asked for
    # du/dd of each recorded state along the target's direction (3 n_all,), when asked for: the
    # converged tangent's [K -W^T; W 0] [du; dl] = [0; e]
    sensitivities: list = field(default_factory=list)
    fraction_done: float = 1.0  # the t of the last converged state


def _residual(f_free, Wt, lam, gap, scale) -> tuple[np.ndarray, float]:
    r = f_free - Wt @ lam
    denom = max(float(np.linalg.norm(f_free)), float(np.linalg.norm(Wt @ lam)), 1e-300)
    return r, max(float(np.linalg.norm(r)) / denom, float(np.linalg.norm(gap)) / scale)


def hold(system, W: sp.csr_matrix, target, fractions=(1.0,), *, first_step: float = 0.25, min_step: float = 1e-3,
         tol: float = 1e-8, max_iter: int = 12, stiffness: bool = False, keep_states: bool = False,
         sensitivity: bool = False) -> HeldPath:
    """Follow ``W u = t target`` from t = 0 to the largest of `fractions` on `system` (a
    `FiniteStrain`). W (k, n_free) any linear constraints on the free dofs. With `sensitivity`,
    each record also keeps the state's derivative along the target's direction (`sensitivities`),
    from the same factorisation as the condensed stiffness."""
    space = system.space
    free, n = space.free, 3 * space.n_all
    target = np.asarray(target, dtype=np.float64).reshape(-1)
    fractions = np.asarray(sorted(float(t) for t in fractions), dtype=np.float64)
    if W.shape != (len(target), len(free)) or not (fractions[0] > 0 and fractions[-1] <= 1.0 + 1e-12):
        raise ValueError("hold: W must be (k, n_free) for k targets, fractions in (0, 1]")
    Wt = np.ascontiguousarray(W.T.toarray())
    scale = max(float(np.linalg.norm(target)), 1e-300)
    report = NewtonReport(load_steps=0, completed_steps=0)
    forces = np.full((len(fractions), len(target)), np.nan)
    Ks = np.full((len(fractions), len(target), len(target)), np.nan) if stiffness else None
    states: list = []
    sens: list = []
    steps = _Steps(W, Wt)
    t_done, u_done, lam_done = 0.0, np.zeros(n), np.zeros(len(target))
    prev = None  # (t, u, lam) of the step before, for the predictor
    h = min(first_step, fractions[-1])
    record = 0
    while record < len(fractions):
        t_new = min(t_done + h, fractions[record])
        if fractions[record] - t_new < 0.25 * h:  # no sliver of a step before a record
            t_new = fractions[record]
        d = target * t_new
        guess = None
        if prev is not None and t_done > prev[0]:  # secant predictor from the last two states
            w = (t_new - t_done) / (t_done - prev[0])
            guess = (u_done + w * (u_done - prev[1]), lam_done + w * (lam_done - prev[2]))
        ok, last = _attempt_from(system, W, Wt, (u_done, lam_done), guess, d, scale, tol, max_iter, steps, report)
        if not ok:
            report.cut_steps += 1
            h = 0.5 * (t_new - t_done)
            if h < min_step * fractions[-1]:
                report.converged = False
                report.reason = last if isinstance(last, str) else "no convergence"
                break
            continue
        u_new, lam_new, min_j = last
        prev = (t_done, u_done, lam_done)
        t_done, u_done, lam_done = t_new, u_new, lam_new
        report.completed_steps += 1
        report.load_steps += 1
        report.min_jacobian = min(report.min_jacobian, min_j)
        if report.iterations[-1] <= 4:  # the planned step grows after a quick one (a step shortened to land on a record leaves it)
            h = min(2.0 * h, 0.5)
        while record < len(fractions) and t_done >= fractions[record] - 1e-12:
            forces[record] = lam_done
            if stiffness or sensitivity:
                Kc = _condensed(system, W, Wt, u_done, steps, report)
                if stiffness:
                    Ks[record] = Kc
            if sensitivity:
                sens.append(_sensitivity(steps, target / scale, n, free))
            if keep_states:
                states.append(u_done.copy())
            record += 1
    return HeldPath(u=u_done, multipliers=lam_done, fractions=fractions, forces=forces, stiffness=Ks, report=report, states=states,
                    sensitivities=sens, fraction_done=t_done)


@dataclass
class FollowedPath:
    """What `follow` returns: the force holding the constraints at each requested time, the last state."""

    times: np.ndarray
    forces: np.ndarray  # (len(times), k); NaN from the first time not reached
    u: np.ndarray
    report: NewtonReport
    time_done: float = 0.0
    states: list = field(default_factory=list)  # the u at each time reached, when asked for


def follow(system, W: sp.csr_matrix, times, targets, *, tol: float = 1e-8, max_iter: int = 12, min_step: float = 1e-6,
           max_dt: float = math.inf, keep_states: bool = False) -> FollowedPath:
    """Hold ``W u = targets[i]`` at ``times[i]`` (s, increasing, after 0) on a body stepped in time
    (`viscous.ViscoelasticStrain`), from rest at t = 0 with the target moving linearly between the
    given times: steps of at most `max_dt` s per interval, halved (the target interpolated) where
    Newton fails, each committed once it converged. A hold is a repeated target. With
    `keep_states`, the state at each time reached (`states`)."""
    free, n = system.space.free, 3 * system.space.n_all
    times = np.asarray(times, dtype=np.float64)
    targets = np.asarray(targets, dtype=np.float64).reshape(len(times), -1)
    if W.shape != (targets.shape[1], len(free)) or not (times[0] > 0 and np.all(np.diff(times) > 0)):
        raise ValueError("follow: W must be (k, n_free) for k targets a row, times increasing after 0")
    if system.time != 0.0:
        raise ValueError(f"follow: the body was stepped to t = {system.time:g} s; a path starts from rest (a new body)")
    Wt = np.ascontiguousarray(W.T.toarray())
    scale = max(float(np.abs(targets).max()), 1e-300)
    report = NewtonReport(load_steps=0, completed_steps=0)
    forces = np.full(targets.shape, np.nan)
    steps = _Steps(W, Wt)
    t_done, u, lam, d_done = 0.0, np.zeros(n), np.zeros(targets.shape[1]), np.zeros(targets.shape[1])
    prev = None  # (t, u, lam, d) of the step before, for the predictor
    states: list = []
    for i, (t_i, d_i) in enumerate(zip(times, targets)):
        span = t_i - t_done
        h = span / max(1, math.ceil(span / max_dt - 1e-9)) if math.isfinite(max_dt) else span
        while t_done < t_i:
            t_new = min(t_done + h, t_i)
            if t_i - t_new < 0.25 * h:
                t_new = t_i
            d = d_done + (d_i - d_done) * (t_new - t_done) / (t_i - t_done)
            system.step(t_new - t_done)
            guess = None
            # secant predictor from the last two states where the target keeps its velocity (a ramp
            # at one speed, a hold); where it changes (a ramp's end) the last state is the better guess
            if prev is not None and np.allclose((d - d_done) / (t_new - t_done), (d_done - prev[3]) / (t_done - prev[0]),
                                                rtol=1e-9, atol=1e-12 * scale / (t_done - prev[0])):
                w = (t_new - t_done) / (t_done - prev[0])
                guess = (u + w * (u - prev[1]), lam + w * (lam - prev[2]))
            ok, last = _attempt_from(system, W, Wt, (u, lam), guess, d, scale, tol, max_iter, steps, report)
            if not ok:
                report.cut_steps += 1
                h = 0.5 * (t_new - t_done)
                if h < min_step * span:  # of this interval: a long hold after it does not excuse a stalled ramp
                    report.converged, report.reason = False, last if isinstance(last, str) else "no convergence"
                    return FollowedPath(times, forces, u, report, t_done, states)
                continue
            prev = (t_done, u, lam, d_done)
            u, lam, min_j = last
            system.commit(u)
            t_done, d_done = t_new, d
            report.completed_steps += 1
            report.load_steps += 1
            report.min_jacobian = min(report.min_jacobian, min_j)
        forces[i] = lam
        if keep_states:
            states.append(u.copy())
    return FollowedPath(times, forces, u, report, t_done, states)


class _Steps:
    """The constrained Newton step, [K -W^T; W 0] [du; dl] = [-r; -gap], for one solve.

    Factorising the tangent is most of a Newton iteration's cost (CHOLMOD; docs/material.md), so the step is found by GMRES on the KKT system, preconditioned by
    the exact step of the last factorised tangent (its factor and K0^-1 W^T kept); the tangent is
    factorised afresh when GMRES needs more than `REFRESH` iterations. Where K is not positive
    definite (compression can make it so while the constrained problem is not), the factor is
    of the augmented Lagrangian's K + rho W^T W, whose constrained step is the same; failing
    that, shifted (a modified Newton step)."""

    REFRESH = 20

    def __init__(self, W: sp.csr_matrix, Wt: np.ndarray):
        self.W, self.Wt = W, Wt
        self.WtW = None
        self.analyses: dict = {}
        self.factor = None
        self.K = None  # the tangent `_condensed` last factorised

    def refactor(self, K, report) -> None:
        self.factor = None  # free the old factor before the new one is made
        rho = 0.0
        try:
            f = shifted_factor(K, analysis=self._analysis("plain", K), shifts=(0.0,))
        except SingularSystemError:
            if self.WtW is None:
                self.WtW = (self.W.T @ self.W).tocsr()
            rho = float(np.mean(np.abs(K.diagonal()))) / max(float(np.max(np.abs(self.WtW.diagonal()))), 1e-300) * 10.0
            Ka = (K + rho * self.WtW).tocsr()
            f = shifted_factor(Ka, analysis=self._analysis("augmented", Ka))
            report.shifts += int(f.shift > 0)
        report.tangent_updates += 1
        KW = f.solve(self.Wt)
        self.factor, self.rho, self.KW, self.S = f, rho, KW, self.W @ KW

    def _analysis(self, kind, A):
        if kind not in self.analyses:
            self.analyses[kind] = symbolic(A)
        return self.analyses[kind]

    def exact(self, a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The factorised tangent's solution of [K -W^T; W 0] [x; y] = [a; b]."""
        rhs = a + self.rho * (self.Wt @ b) if self.rho else a
        Kr = self.factor.solve(rhs)
        y = np.linalg.solve(self.S, b - self.W @ Kr)
        return Kr + self.KW @ y, y

    def step(self, K, r: np.ndarray, gap: np.ndarray, report, rtol: float = 1e-8) -> tuple[np.ndarray, np.ndarray]:
        """The step to a relative accuracy `rtol` of the KKT residual (an inexact Newton step:
        loose far from the solution, tight near it)."""
        if self.factor is None:
            self.refactor(K, report)
            if self.factor.shift == 0.0:
                return self.exact(-r, -gap)
        W, Wt = self.W, self.Wt

        def kkt(x, y):
            return K @ x - Wt @ y, W @ x

        x, y, its = right_gmres(kkt, self.exact, -r, -gap, rtol, self.REFRESH)
        report.linear_iterations += its
        if x is None:
            if self.factor.shift == 0.0:
                self.refactor(K, report)
            # a shifted factor's own step: modified Newton (slower, but the residual stays exact)
            return self.exact(-r, -gap)
        return x, y


def right_gmres(A, M, a: np.ndarray, b: np.ndarray, rtol: float, maxiter: int):
    """GMRES with right preconditioning on the block system A (x, y) = (a, b), M the
    preconditioner (x, y) -> (x, y); the true residual's norm is what is minimised, so the
    stopping test is on it. Returns (x, y, iterations), or (None, None, iterations) when
    `maxiter` iterations do not reach `rtol`."""
    n = len(a)
    rhs = np.concatenate([a, b])
    beta = float(np.linalg.norm(rhs))
    if beta == 0.0:
        return np.zeros_like(a), np.zeros_like(b), 0
    V = [rhs / beta]
    Z: list[np.ndarray] = []
    H = np.zeros((maxiter + 1, maxiter))
    for j in range(maxiter):
        zx, zy = M(V[j][:n], V[j][n:])
        Z.append(np.concatenate([zx, zy]))
        wx, wy = A(zx, zy)
        w = np.concatenate([wx, wy])
        for i in range(j + 1):  # modified Gram-Schmidt
            H[i, j] = float(V[i] @ w)
            w = w - H[i, j] * V[i]
        H[j + 1, j] = float(np.linalg.norm(w))
        e1 = np.zeros(j + 2)
        e1[0] = beta
        c, *_ = np.linalg.lstsq(H[: j + 2, : j + 1], e1, rcond=None)
        res = float(np.linalg.norm(H[: j + 2, : j + 1] @ c - e1))
        if res <= rtol * beta or H[j + 1, j] <= 1e-14 * float(np.linalg.norm(H[: j + 2, j])):
            sol = np.column_stack(Z) @ c
            return sol[:n], sol[n:], j + 1
        V.append(w / H[j + 1, j])
    return None, None, maxiter


def _attempt(system, W, Wt, u, lam, d, scale, tol, max_iter, steps: _Steps, report) -> tuple[bool, object]:
    """`_iterate`, its residuals and iterations recorded in the report: (converged, its last)."""
    ok, hist, last = _iterate(system, W, Wt, u, lam, d, scale, tol, max_iter, steps, report)
    report.residuals.append(hist)
    report.iterations.append(len(hist))
    return ok, last


def _attempt_from(system, W, Wt, last_state, guess, d, scale, tol, max_iter, steps: _Steps, report) -> tuple[bool, object]:
    """`_attempt` from the predictor's `guess` (u, lam; None: none), and from `last_state` (the
    last converged u, lam) where there is no guess or it fails: a predictor may overshoot into
    inverted elements."""
    if guess is not None and not np.array_equal(guess[0], last_state[0]):
        ok, last = _attempt(system, W, Wt, guess[0], guess[1], d, scale, tol, max_iter, steps, report)
        if ok:
            return ok, last
    return _attempt(system, W, Wt, last_state[0].copy(), last_state[1].copy(), d, scale, tol, max_iter, steps, report)


def _iterate(system, W, Wt, u, lam, d, scale, tol, max_iter, steps: _Steps, report):
    """Newton on one step from (u, lam). Returns (converged, residual history, (u, lam, min J) or
    why it stopped)."""
    free = system.space.free
    hist: list[float] = []
    moved = np.inf
    state = system.evaluate(u, tangent=True)
    if state["min_jacobian"] <= 0:
        return False, hist, "elements inverted"
    for _ in range(max_iter):
        gap = W @ u[free] - d
        r, res = _residual(state["f"][free], Wt, lam, gap, scale)
        hist.append(res)
        if len(hist) > 1 and (res < tol or (res < FLOOR and moved <= 1e-12 * max(float(np.linalg.norm(u[free])), 1e-300))):
            # converged, or at the round-off floor (the residual no longer falls and the steps are nothing)
            return True, hist, (u, lam, state["min_jacobian"])
        if len(hist) > 1 and hist[-1] > 0.25 * hist[-2] and res > FLOOR:
            steps.factor = None  # Newton is not contracting on the old tangent's steps: factorise this one
        try:
            # Eisenstat-Walker-like forcing: the linear solve as accurate as the residual warrants
            du, dl = steps.step(state["K"], r, gap, report, rtol=float(np.clip(0.1 * res, 1e-10, 1e-2)))
        except SingularSystemError:
            return False, hist, "tangent singular"
        step = 1.0
        for _ in range(6):  # back off a step that inverts elements
            trial = u.copy()
            trial[free] += step * du
            state = system.evaluate(trial, tangent=True)
            if state["min_jacobian"] > 0:
                break
            step *= 0.5
        else:
            return False, hist, "elements inverted"
        moved = step * float(np.linalg.norm(du))
        u, lam = trial, lam + step * dl
        if len(hist) > 3 and hist[-1] > 10.0 * hist[-4]:
            return False, hist, "diverging"
    gap = W @ u[free] - d
    r, res = _residual(state["f"][free], Wt, lam, gap, scale)
    hist.append(res)
    if res < tol:
        return True, hist, (u, lam, state["min_jacobian"])
    return False, hist, "no convergence"


def _sensitivity(steps: _Steps, e: np.ndarray, n: int, free: np.ndarray) -> np.ndarray:
    """du/dd (3 n_all,) along the unit direction `e` at the state `_condensed` just factorised:
    [K -W^T; W 0] [du; dl] = [0; e] (GMRES on the unshifted system where the factor is shifted)."""
    K = steps.K
    if steps.factor.shift > 0.0:
        x, _, _ = right_gmres(lambda a, b: (K @ a - steps.Wt @ b, steps.W @ a), steps.exact, np.zeros(K.shape[0]), e, 1e-10, 200)
        if x is None:
            return np.full(n, np.nan)
    else:
        x, _ = steps.exact(np.zeros(K.shape[0]), e)
    out = np.zeros(n)
    out[free] = x
    return out


def _condensed(system, W, Wt, u, steps: _Steps, report) -> np.ndarray:
    """(W K_t^-1 W^T)^-1 at the converged state u, from a fresh factorisation there: the force's
    tangent against the target (with the augmented factor, (W Ka^-1 W^T)^-1 - rho I: the same)."""
    K = system.evaluate(u, tangent=True)["K"]
    steps.refactor(K, report)
    steps.K = K  # for `_sensitivity` at the same state
    if steps.factor.shift > 0.0:
        # the factor is of a shifted matrix: the condensed columns by GMRES on the unshifted
        # constrained system, the shifted factor's exact step preconditioning it
        cols = []
        for j in range(W.shape[0]):
            e = np.zeros(W.shape[0])
            e[j] = 1.0
            x, y, _ = right_gmres(lambda a, b: (K @ a - Wt @ b, W @ a), steps.exact, np.zeros(K.shape[0]), e, 1e-10, 200)
            if y is None:
                return np.full((W.shape[0], W.shape[0]), np.nan)
            cols.append(y)  # [K -W^T; W 0] [x; y] = [0; e]: y = (W K^-1 W^T)^-1 e
        return np.column_stack(cols)
    out = np.linalg.inv(0.5 * (steps.S + steps.S.T))
    return out - steps.rho * np.eye(len(out)) if steps.rho else out
