"""Compiled element passes (numba) of the finite-strain laws (`sim/hyperelastic.py`) on P1/P2
tetrahedra with a mean dilatation per element (`finite_strain.py`): internal forces, tangents,
energies, and their scatter into a fixed sparse pattern.

At each quadrature point the isochoric Ogden energy is an isotropic function of C = F^T F,
taken in C's eigenbasis (c_a, N_a; a cyclic Jacobi iteration, accurate for repeated
eigenvalues): S = sum_a s_a N_a N_a with s_a = 2 dW/dc_a, and the material tangent
4 d2W/dCdC = sum_ab 2 ds_a/dc_b N_aN_aN_bN_b + sum_(a!=b) (s_a - s_b)/(c_a - c_b)
(N_aN_bN_aN_b + N_aN_bN_bN_a), the divided difference taken in a form that stays accurate as
c_a -> c_b (the reference state, where every point has c = 1). The volumetric part uses the
element's mean J (theta = int J / V, Simo, Taylor and Pister 1985): its energy V U(theta).
"""

from __future__ import annotations

import math

import numba
import numpy as np

from sim.models.fem.corotational_kernels import inv3

# The element pass runs its elements in parallel. Numba's OpenMP layer would set the system's
# OpenMP runtime, which CHOLMOD shares, back to every core at its first launch, undoing
# `sim.linalg.one_thread_pools` (the same bits in every process: libgomp would go
# from 1 thread to 2). Its own work queue touches no OpenMP setting.
if numba.config.THREADING_LAYER == "default":
    numba.config.THREADING_LAYER = "workqueue"


@numba.njit(cache=True, inline="always")
def _eig3(A, w, V):
    """Eigenvalues w (3,) and eigenvectors (columns of V) of the symmetric 3 x 3 A (overwritten):
    cyclic Jacobi rotations to round-off."""
    for i in range(3):
        for j in range(3):
            V[i, j] = 1.0 if i == j else 0.0
    for _ in range(30):
        off = A[0, 1] * A[0, 1] + A[0, 2] * A[0, 2] + A[1, 2] * A[1, 2]
        diag = A[0, 0] * A[0, 0] + A[1, 1] * A[1, 1] + A[2, 2] * A[2, 2]
        if off <= 1e-36 * diag:
            break
        for p, q in ((0, 1), (0, 2), (1, 2)):
            apq = A[p, q]
            if apq == 0.0:
                continue
            theta = (A[q, q] - A[p, p]) / (2.0 * apq)
            t = (1.0 if theta >= 0.0 else -1.0) / (abs(theta) + math.sqrt(theta * theta + 1.0))
            c = 1.0 / math.sqrt(t * t + 1.0)
            s = t * c
            A[p, p] -= t * apq
            A[q, q] += t * apq
            A[p, q] = 0.0
            A[q, p] = 0.0
            r = 3 - p - q
            arp, arq = A[r, p], A[r, q]
            A[r, p] = c * arp - s * arq
            A[p, r] = A[r, p]
            A[r, q] = s * arp + c * arq
            A[q, r] = A[r, q]
            for k in range(3):
                vkp, vkq = V[k, p], V[k, q]
                V[k, p] = c * vkp - s * vkq
                V[k, q] = s * vkp + c * vkq
    for i in range(3):
        w[i] = A[i, i]


@numba.njit(cache=True, inline="always")
def _power_dd(ca, cb, beta):
    """(ca^beta - cb^beta) / (ca - cb), accurate as ca -> cb (limit beta cb^(beta - 1))."""
    t = math.log(ca / cb)
    if abs(t) < 1e-5:
        r = beta * (1.0 + 0.5 * (beta - 1.0) * t + (2.0 * beta - 1.0) * (beta - 1.0) * t * t / 12.0)
    else:
        r = math.expm1(beta * t) / math.expm1(t)
    return cb ** (beta - 1.0) * r


@numba.njit(cache=True, inline="always")
def _iso_point(F, J, mu, alpha, c, N, s, M, D):
    """The isochoric part at one point: eigen-pairs of C (c, N), s_a = 2 dW/dc_a, M_ab =
    2 ds_a/dc_b and D_ab = (s_a - s_b)/(c_a - c_b) (a != b); returns the energy density."""
    C = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            C[i, j] = F[0, i] * F[0, j] + F[1, i] * F[1, j] + F[2, i] * F[2, j]
    _eig3(C, c, N)
    for a in range(3):
        s[a] = 0.0
        for b in range(3):
            M[a, b] = 0.0
            D[a, b] = 0.0
    energy = 0.0
    for p in range(mu.shape[0]):
        al = alpha[p]
        beta = 0.5 * al - 1.0
        Jp = J ** (-al / 3.0)
        A = 2.0 * mu[p] / al * Jp
        pw0, pw1, pw2 = c[0] ** (0.5 * al), c[1] ** (0.5 * al), c[2] ** (0.5 * al)
        m = (pw0 + pw1 + pw2) / 3.0
        energy += 2.0 * mu[p] / (al * al) * (Jp * 3.0 * m - 3.0)
        cb = (pw0 / c[0], pw1 / c[1], pw2 / c[2])  # c_a^beta
        for a in range(3):
            sa = cb[a] - m / c[a]
            s[a] += A * sa
            for b in range(3):
                v = -al / (6.0 * c[b]) * sa - al / 6.0 * cb[b] / c[a]
                if a == b:
                    v += beta * cb[a] / c[a] + m / (c[a] * c[a])
                M[a, b] += 2.0 * A * v
                if a != b:
                    D[a, b] += A * (_power_dd(c[a], c[b], beta) + m / (c[a] * c[b]))
    return energy


@numba.njit(cache=True, inline="always")
def _add_pressure(Ke, e, X, q, k, c1, c2):
    """Ke[e]'s upper triangle += c2 X_ai X_bk + c1 (X_ai X_bk - X_ak X_bi) at point q: the
    volumetric tangent's terms (c1 = p J w, c2 = U'' J^2 w; the mean dilatation adds its own)."""
    for ap in range(k):
        for i in range(3):
            row = 3 * ap + i
            for bp in range(k):
                for kk in range(3):
                    col = 3 * bp + kk
                    if col >= row:
                        Ke[e, row, col] += (c1 + c2) * X[q, ap, i] * X[q, bp, kk] - c1 * X[q, ap, kk] * X[q, bp, i]


@numba.njit(cache=True, inline="always")
def _branch_stresses(eps, mu, al, tau, D):
    """The isochoric Ogden energy 2 mu/al^2 (sum lb^al - 3) at logarithmic principal stretches
    eps (lb_a = exp(eps_a - mean eps)): its principal Kirchhoff stresses tau_a = 2 mu/al (lb_a^al -
    mean lb^al) and D_ab = dtau_a/deps_b = 2 mu (lb_a^al (delta_ab - 1/3) - (lb_b^al - mean)/3);
    returns the energy."""
    me = (eps[0] + eps[1] + eps[2]) / 3.0
    p0, p1, p2 = math.exp(al * (eps[0] - me)), math.exp(al * (eps[1] - me)), math.exp(al * (eps[2] - me))
    m = (p0 + p1 + p2) / 3.0
    p = (p0, p1, p2)
    for a in range(3):
        tau[a] = 2.0 * mu / al * (p[a] - m)
        for b in range(3):
            D[a, b] = 2.0 * mu * (p[a] * ((1.0 if a == b else 0.0) - 1.0 / 3.0) - (p[b] - m) / 3.0)
    return 2.0 * mu / (al * al) * (p0 + p1 + p2 - 3.0)


@numba.njit(cache=True, inline="always")
def _congruent(A, M, out):
    """out = A M A^T (3 x 3)."""
    for i in range(3):
        for j in range(3):
            acc = 0.0
            for r in range(3):
                for t in range(3):
                    acc += A[i, r] * M[r, t] * A[j, t]
            out[i, j] = acc


# an orthonormal basis of the deviatoric plane of principal log stretches: the flow is isochoric,
# so the update moves eps only there (D's null vector (1, 1, 1) never enters a solve)
_R2, _R6 = 1.0 / math.sqrt(2.0), 1.0 / math.sqrt(6.0)
LOCAL_ITERATIONS = 100


@numba.njit(cache=True, inline="always")
def _form(D, x, y):
    """x . D y for a 3 x 3 D."""
    acc = 0.0
    for a in range(3):
        acc += x[a] * (D[a, 0] * y[0] + D[a, 1] * y[1] + D[a, 2] * y[2])
    return acc


@numba.njit(cache=True, inline="always")
def _dev_solve(s, D, r, out):
    """out (3,) = -(I + s D)^-1 r for r in the deviatoric plane, solved in its basis (2 x 2, positive
    definite: D is positive semi-definite); False where the 2 x 2 system is not solvable in floating point."""
    b0 = (_R2, -_R2, 0.0)
    b1 = (_R6, _R6, -2.0 * _R6)
    h00 = 1.0 + s * _form(D, b0, b0)
    h11 = 1.0 + s * _form(D, b1, b1)
    h01 = s * _form(D, b0, b1)
    det = h00 * h11 - h01 * h01
    if not (det > 0.0 and math.isfinite(det)):
        return False
    g0 = b0[0] * r[0] + b0[1] * r[1] + b0[2] * r[2]
    g1 = b1[0] * r[0] + b1[1] * r[1] + b1[2] * r[2]
    x0 = -(h11 * g0 - h01 * g1) / det
    x1 = -(h00 * g1 - h01 * g0) / det
    for a in range(3):
        out[a] = b0[a] * x0 + b1[a] * x1
    return True


@numba.njit(cache=True, inline="always")
def _branch_point(F, Finv, Cv, mu, al, eta, dt, Cv_new, tauM, Cp, Tab, nv, work, v3, want_tangent):
    """One Maxwell branch at one point over a step of dt (Reese and Govindjee 1998): the trial elastic
    left stretch b_tr = F C_v^-1 F^T (C_v^-1 of the step's start), its principal logarithmic
    stretches eps_tr and directions nv; the implicit exponential update eps + dt/(2 eta) tau(eps)
    = eps_tr, the stationary point of the strictly convex Phi(eps) = |eps - eps_tr|^2 / 2 +
    dt/(2 eta) psi(eps): Newton in the deviatoric plane with a backtracking line search on Phi
    (converges from any start; a step so long that the branch fully relaxes included). Then b_e =
    sum exp(2 eps_a) n_a n_a and the new C_v^-1 = F^-1 b_e F^-T. Fills the Kirchhoff stress tauM =
    sum tau_a n_a n_a, and for the tangent Cp_ab = dtau_a/deps_tr_b - 2 tau_a delta_ab (dtau/deps_tr
    = D (I + s D)^-1, through the deviatoric plane) and the off-diagonal shear terms
    Tab = (tau_a l_b^2 - tau_b l_a^2)/(l_a^2 - l_b^2) (l^2 the trial's eigenvalues; as they meet,
    the limit (C_aa - C_ab)/2 - tau_a), these only with `want_tangent`. Returns the branch's
    elastic energy, or NaN where the update did not converge (the caller rejects the state)."""
    btr, D, Kl, Ki = work[0], work[1], work[2], work[3]
    _congruent(F, Cv, btr)
    lam2 = v3[0]
    _eig3(btr, lam2, nv)
    etr, eps, tau = v3[1], v3[2], v3[3]
    for a in range(3):
        etr[a] = 0.5 * math.log(lam2[a])
        eps[a] = etr[a]
    s = dt / (2.0 * eta)
    res, step, trial = Kl[0], Kl[1], Kl[2]  # rows of Kl as (3,) work vectors
    converged = s == 0.0
    psi = _branch_stresses(eps, mu, al, tau, D)
    floor = 0.0
    for _ in range(LOCAL_ITERATIONS):
        if converged:
            break
        phi = s * psi
        size = 0.0
        stiff = 0.0
        for a in range(3):
            res[a] = eps[a] - etr[a] + s * tau[a]
            phi += 0.5 * (eps[a] - etr[a]) ** 2
            size = max(size, abs(res[a]))
            stiff = max(stiff, abs(D[a, 0]) + abs(D[a, 1]) + abs(D[a, 2]))
        # round-off in s tau(eps) is about s |D| times eps's: no Newton step gets below that
        floor = 1e-14 * (1.0 + s * stiff)
        if size <= floor:
            converged = True
            break
        if not _dev_solve(s, D, res, step):
            break
        slope = res[0] * step[0] + res[1] * step[1] + res[2] * step[2]
        lam = 1.0
        for _ in range(60):  # backtracking: Phi falls enough (Armijo), or near the solution, where Phi's
            # round-off hides its fall, the residual falls
            for a in range(3):
                trial[a] = eps[a] + lam * step[a]
            psi_t = _branch_stresses(trial, mu, al, tau, D)
            phi_t = s * psi_t
            size_t = 0.0
            for a in range(3):
                phi_t += 0.5 * (trial[a] - etr[a]) ** 2
                size_t = max(size_t, abs(trial[a] - etr[a] + s * tau[a]))
            if math.isfinite(phi_t) and (phi_t <= phi + 1e-4 * lam * slope or size_t <= 0.5 * size):
                break
            lam *= 0.5
        for a in range(3):
            eps[a] = trial[a]
        psi = _branch_stresses(eps, mu, al, tau, D)
        if lam * max(abs(step[0]), abs(step[1]), abs(step[2])) <= 1e-15:
            break  # no more progress: accepted below only at round-off
    if not converged:
        worst = 0.0
        for a in range(3):
            worst = max(worst, abs(eps[a] - etr[a] + s * tau[a]))
        converged = worst <= 1e4 * max(floor, 1e-14)  # stalled at round-off, within four digits of its floor
    if not converged or not math.isfinite(psi):
        return math.nan
    for i in range(3):
        for j in range(3):
            acc, be = 0.0, 0.0
            for a in range(3):
                acc += tau[a] * nv[i, a] * nv[j, a]
                be += math.exp(2.0 * eps[a]) * nv[i, a] * nv[j, a]
            tauM[i, j] = acc
            btr[i, j] = be  # b_e
    _congruent(Finv, btr, Cv_new)
    if not want_tangent:
        return psi
    # dtau/deps_tr = D (I + s D)^-1: (I + s D)^-1 is identity on (1, 1, 1) and the 2 x 2 inverse on the plane
    for b in range(3):
        for a in range(3):
            res[a] = 1.0 if a == b else 0.0
        mean = (res[0] + res[1] + res[2]) / 3.0
        for a in range(3):
            res[a] -= mean  # the unit vector's deviatoric part; its mean passes through unchanged and D kills it
        if not _dev_solve(s, D, res, step):
            return math.nan
        for a in range(3):
            Ki[a, b] = -step[a] + mean
    for a in range(3):
        for b in range(3):
            acc = 0.0
            for c in range(3):
                acc += D[a, c] * Ki[c, b]
            Cp[a, b] = acc
    for a in range(3):
        for b in range(3):
            if a == b:
                Tab[a, b] = 0.0
                continue
            den = lam2[a] - lam2[b]
            if abs(den) <= 1e-7 * max(lam2[a], lam2[b]):
                Tab[a, b] = 0.5 * (Cp[a, a] - Cp[a, b]) - tau[a]
            else:
                Tab[a, b] = (tau[a] * lam2[b] - tau[b] * lam2[a]) / den
    for a in range(3):
        Cp[a, a] -= 2.0 * tau[a]
    return psi


@numba.njit(cache=True, inline="always")
def _add_yz(Ke, e, Y, Z, nd, w):
    """Ke[e]'s upper triangle += w Y^T Z (Y, Z: (9, nd), a material tangent's two factors)."""
    for i in range(nd):
        for j in range(i, nd):
            acc = 0.0
            for r in range(9):
                acc += Y[r, i] * Z[r, j]
            Ke[e, i, j] += w * acc


@numba.njit(cache=True, inline="always")
def _add_branch_tangent(Ke, e, X, q, k, w, tauM, Cp, Tab, nv, Xn, M9, Y, Z):
    """Ke[e]'s upper triangle += w (X c X + delta_ik X tau X) at point q for a branch's spatial
    tangent c = sum_ab Cp_ab m_a m_b + sum_(a!=b) Tab (n_a n_b n_a n_b + n_a n_b n_b n_a)
    (m_a = n_a n_a; Bonet and Wood 2008's principal-direction form, with the algorithmic dtau/deps_tr of the trial
    state, Simo 1992): Y^T M Y with Y[(p, r), (a', i)] = n_ip (X_a' . n_r)."""
    nd = 3 * k
    for a in range(k):
        for p in range(3):
            Xn[a, p] = X[q, a, 0] * nv[0, p] + X[q, a, 1] * nv[1, p] + X[q, a, 2] * nv[2, p]
    for p in range(3):
        for r in range(3):
            for a in range(k):
                for i in range(3):
                    Y[3 * p + r, 3 * a + i] = nv[i, p] * Xn[a, r]
    for i in range(9):
        for j in range(9):
            M9[i, j] = 0.0
    for p in range(3):
        for r in range(3):
            M9[4 * p, 4 * r] = Cp[p, r]
            if p != r:
                M9[3 * p + r, 3 * p + r] += Tab[p, r]
                M9[3 * p + r, 3 * r + p] += Tab[p, r]
    for i in range(9):
        for col in range(nd):
            acc = 0.0
            for j in range(9):
                acc += M9[i, j] * Y[j, col]
            Z[i, col] = acc
    _add_yz(Ke, e, Y, Z, nd, w)
    for a in range(k):
        for b in range(a, k):
            geo = 0.0
            for r in range(3):
                for t in range(3):
                    geo += X[q, a, r] * tauM[r, t] * X[q, b, t]
            for i in range(3):
                Ke[e, 3 * a + i, 3 * b + i] += w * geo


@numba.njit(cache=True, parallel=True)
def element_pass(G, wq, ue, mu, alpha, kappa, law_of, mean, want_tangent, fe, Ke, energy, theta, minJ,
                 viscous, Cv, bmu, balpha, beta, dt, Cv_out):
    """For every element e: the internal force fe[e] (3k,), the tangent Ke[e] (3k, 3k) when
    `want_tangent`, the energy, the mean dilatation theta and the smallest J of its points.

    The laws: mu, alpha (n_laws, terms) (a law with fewer terms padded with mu = 0), kappa
    (n_laws,); law_of (m, q) the law of each quadrature point (the brain's regions). With the
    mean dilatation an element's kappa is its points' volume-weighted mean.

    G (m, q, k, 3) shape-function gradients at the quadrature points, wq (m, q) their weights,
    ue (m, k, 3) the element's nodal displacements. `mean`: the volumetric energy of the
    element's mean J (P2/P0); else of each point's J (the plain displacement element). An element with a point at J <= 0 gets
    minJ <= 0 and no force (the caller rejects the state).

    With `viscous`, each point also carries Maxwell branches (`sim.material.Viscoelastic`): branch b of law l
    has the isochoric Ogden energy bmu[l, b], balpha[l, b] of its elastic part and viscosity
    beta[l, b]; Cv (m, q, branches, 3, 3) is its C_v^-1 at the step's start, and the step of `dt`
    seconds is taken implicitly (`_branch_point`), its updated C_v^-1 written to Cv_out; else Cv,
    Cv_out are (1, 1, 1, 3, 3) placeholders. A point whose branch update does not converge gives its
    element minJ = -1: the Newton solver rejects the state, as it does an inverted one, and a step in
    time is then halved."""
    m, nq, k = G.shape[0], G.shape[1], G.shape[2]
    nd = 3 * k
    for e in numba.prange(m):
        F = np.empty((3, 3))
        Finv = np.empty((3, 3))
        c = np.empty(3)
        N = np.empty((3, 3))
        s = np.empty(3)
        Mab = np.empty((3, 3))
        Dab = np.empty((3, 3))
        n = np.empty((3, 3))
        tauM = np.empty((3, 3))
        Cp = np.empty((3, 3))
        Tab = np.empty((3, 3))
        nv = np.empty((3, 3))
        Xn = np.empty((k, 3))
        M9 = np.empty((9, 9))
        vwork = np.empty((4, 3, 3))
        v3 = np.empty((4, 3))
        qg = np.empty((k, 3))
        Y = np.empty((9, nd))
        Z = np.empty((9, nd))
        X = np.empty((nq, k, 3))
        Jq = np.zeros(nq)
        g = np.zeros(nd)
        f = np.zeros(nd)
        if want_tangent:
            for i in range(nd):
                for j in range(nd):
                    Ke[e, i, j] = 0.0
        vol, jint, en, jmin = 0.0, 0.0, 0.0, np.inf
        for q in range(nq):
            w = wq[e, q]
            vol += w
            for i in range(3):
                for J_ in range(3):
                    acc = 1.0 if i == J_ else 0.0
                    for a in range(k):
                        acc += ue[e, a, i] * G[e, q, a, J_]
                    F[i, J_] = acc
            Jd = (F[0, 0] * (F[1, 1] * F[2, 2] - F[1, 2] * F[2, 1]) - F[0, 1] * (F[1, 0] * F[2, 2] - F[1, 2] * F[2, 0])
                  + F[0, 2] * (F[1, 0] * F[2, 1] - F[1, 1] * F[2, 0]))
            jmin = min(jmin, Jd)
            if Jd <= 0.0:
                continue
            law = law_of[e, q]
            en += w * _iso_point(F, Jd, mu[law], alpha[law], c, N, s, Mab, Dab)
            jint += w * Jd
            # n_a = F N_a; qg[a', b] = grad N_a' . N_b
            for i in range(3):
                for a in range(3):
                    n[i, a] = F[i, 0] * N[0, a] + F[i, 1] * N[1, a] + F[i, 2] * N[2, a]
            for a in range(k):
                for b in range(3):
                    qg[a, b] = G[e, q, a, 0] * N[0, b] + G[e, q, a, 1] * N[1, b] + G[e, q, a, 2] * N[2, b]
            for a in range(k):
                for i in range(3):
                    acc = 0.0
                    for b in range(3):
                        acc += s[b] * n[i, b] * qg[a, b]
                    f[3 * a + i] += w * acc
            inv3(F, Finv)  # F^-1, for the volumetric variations: X[a, i] = grad N_a . F^-1[:, i]
            Jq[q] = Jd
            for a in range(k):
                for i in range(3):
                    X[q, a, i] = G[e, q, a, 0] * Finv[0, i] + G[e, q, a, 1] * Finv[1, i] + G[e, q, a, 2] * Finv[2, i]
                    g[3 * a + i] += w * Jd * X[q, a, i]
            if viscous:
                for br in range(bmu.shape[1]):
                    if bmu[law, br] == 0.0:  # a padded branch: nothing, its state kept
                        for i in range(3):
                            for j in range(3):
                                Cv_out[e, q, br, i, j] = Cv[e, q, br, i, j]
                        continue
                    psi_b = _branch_point(F, Finv, Cv[e, q, br], bmu[law, br], balpha[law, br], beta[law, br], dt,
                                          Cv_out[e, q, br], tauM, Cp, Tab, nv, vwork, v3, want_tangent)
                    if not math.isfinite(psi_b):  # the branch's update failed here: the state is rejected as an inverted one is
                        jmin = -1.0
                        break
                    en += w * psi_b
                    for a in range(k):  # f_ai += tau_ij grad_x N_a,j
                        for i in range(3):
                            f[3 * a + i] += w * (tauM[i, 0] * X[q, a, 0] + tauM[i, 1] * X[q, a, 1] + tauM[i, 2] * X[q, a, 2])
                    if want_tangent:
                        _add_branch_tangent(Ke, e, X, q, k, w, tauM, Cp, Tab, nv, Xn, M9, Y, Z)
            if not want_tangent:
                continue
            # isochoric material part: Y^T Q Y with Y[(a,b), (a', i)] = qg[a', b] n[i, a]
            for a in range(3):
                for b in range(3):
                    r = 3 * a + b
                    for ap in range(k):
                        for i in range(3):
                            Y[r, 3 * ap + i] = qg[ap, b] * n[i, a]
            for a in range(3):
                for b in range(3):
                    r = 3 * a + b
                    if a == b:
                        for col in range(nd):
                            Z[r, col] = Mab[a, 0] * Y[0, col] + Mab[a, 1] * Y[4, col] + Mab[a, 2] * Y[8, col]
                    else:
                        rt = 3 * b + a
                        for col in range(nd):
                            Z[r, col] = Dab[a, b] * (Y[rt, col] + Y[r, col])
            _add_yz(Ke, e, Y, Z, nd, w)
            # geometric part: delta_ik sum_b s_b qg[a', b] qg[b', b]
            for ap in range(k):
                for bp in range(ap, k):
                    geo = w * (s[0] * qg[ap, 0] * qg[bp, 0] + s[1] * qg[ap, 1] * qg[bp, 1] + s[2] * qg[ap, 2] * qg[bp, 2])
                    for i in range(3):
                        Ke[e, 3 * ap + i, 3 * bp + i] += geo
        theta[e] = jint / vol
        minJ[e] = jmin
        if jmin <= 0.0:
            for i in range(nd):
                fe[e, i] = 0.0
            energy[e] = np.inf
            continue
        if not mean:
            # each point's own J: U(J), P = U'(J) J F^-T, tangent (U'' J^2 X X + U' J (X X - X X))
            env = 0.0
            for q in range(nq):
                w, Jd = wq[e, q], Jq[q]
                kappa_q = kappa[law_of[e, q]]
                # U(J) = kappa/4 (J^2 - 1 - 2 ln J), convex for every J > 0 (sim.hyperelastic.volumetric)
                env += w * 0.25 * kappa_q * (Jd * Jd - 1.0 - 2.0 * math.log(Jd))
                p = 0.5 * kappa_q * (Jd - 1.0 / Jd)
                dp = 0.5 * kappa_q * (1.0 + 1.0 / (Jd * Jd))
                for a in range(k):
                    for i in range(3):
                        f[3 * a + i] += w * p * Jd * X[q, a, i]
                if want_tangent:
                    _add_pressure(Ke, e, X, q, k, w * p * Jd, w * dp * Jd * Jd)
            energy[e] = en + env
            for i in range(nd):
                fe[e, i] = f[i]
            if want_tangent:
                for i in range(nd):
                    for j in range(i):
                        Ke[e, i, j] = Ke[e, j, i]
            continue
        th = theta[e]
        kappa_e = kappa[law_of[e, 0]]
        for q in range(1, nq):
            if law_of[e, q] != law_of[e, 0]:  # an element across the interface: its points' mean
                kappa_e = 0.0
                for r in range(nq):
                    kappa_e += wq[e, r] * kappa[law_of[e, r]]
                kappa_e /= vol
                break
        p = 0.5 * kappa_e * (th - 1.0 / th)
        dp = 0.5 * kappa_e * (1.0 + 1.0 / (th * th))
        energy[e] = en + vol * 0.25 * kappa_e * (th * th - 1.0 - 2.0 * math.log(th))
        for i in range(nd):
            fe[e, i] = f[i] + p * g[i]
        if want_tangent:
            for q in range(nq):  # the pressure's geometric term: p int J (X_ai X_bk - X_ak X_bi)
                _add_pressure(Ke, e, X, q, k, p * wq[e, q] * Jq[q], 0.0)
            c2 = dp / vol
            for i in range(nd):
                for j in range(i, nd):
                    Ke[e, i, j] += c2 * g[i] * g[j]
            for i in range(nd):
                for j in range(i):
                    Ke[e, i, j] = Ke[e, j, i]


@numba.njit(cache=True)
def pattern_positions(dofs, free_pos, indptr, indices):
    """Where each element entry (e, r, c) lands in the data of a CSR matrix over the free dofs
    (-1: a clamped row or column): binary search in the row's sorted columns."""
    m, nd = dofs.shape
    out = np.full((m, nd, nd), -1, dtype=np.int32)
    for e in range(m):
        for r in range(nd):
            row = free_pos[dofs[e, r]]
            if row < 0:
                continue
            lo0, hi0 = indptr[row], indptr[row + 1]
            for c in range(nd):
                col = free_pos[dofs[e, c]]
                if col < 0:
                    continue
                lo, hi = lo0, hi0
                while lo < hi:
                    mid = (lo + hi) // 2
                    if indices[mid] < col:
                        lo = mid + 1
                    else:
                        hi = mid
                out[e, r, c] = lo
    return out


@numba.njit(cache=True)
def scatter_matrix(Ke, pos, data):
    """data[pos[e, r, c]] += Ke[e, r, c] for every entry with a position."""
    m, nd = Ke.shape[0], Ke.shape[1]
    for e in range(m):
        for r in range(nd):
            for c in range(nd):
                p = pos[e, r, c]
                if p >= 0:
                    data[p] += Ke[e, r, c]


@numba.njit(cache=True)
def scatter_vector(fe, dofs, out):
    m, nd = fe.shape
    for e in range(m):
        for r in range(nd):
            out[dofs[e, r]] += fe[e, r]
