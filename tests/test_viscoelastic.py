"""The finite viscoelastic law (sim/viscoelastic.py) in the project's FEM (sim/models/fem/viscous.py,
newton.follow), against closed forms worked here:

- the branch stress is its energy's gradient (central differences of the energy, here);
- small strain: a shear ramp and its hold equal the standard linear solid's closed form;
- finite strain: uniaxial (isochoric) and simple-shear ramps to the measured range and their
  relaxation equal the convolution integral S_inf(C(t)) + sum_k [S_k(C(t)) - (1/tau_k) int_0^t
  e^-(t-s)/tau_k S_k(C(s)) ds] (integrated by parts; scipy's adaptive quadrature), and the step's
  error falls as dt^2;
- in a solve (`follow`), a cube whose boundary is held to a homogeneous shear history reacts as
  the closed form; and held long, a non-homogeneous body's force is the equilibrium law's
  (`hold` of the hyperelastic solver) to 1e-6.
"""

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.integrate import quad

from sim.errors import ParameterError
from sim.hyperelastic import ogden
from sim.models.fem import FiniteStrain, TetSpace, ViscoelasticStrain, follow, hold
from sim.viscoelastic import Branch, Viscoelastic, isochoric_stress, read_rheology
from tests.helpers import grid_tets

# Budday et al. 2017 (Acta Biomater 60) cortex's moduli and time; alpha as the shipped fit's
LAW = Viscoelastic(ogden([700.0], [-20.8], 96.5), (Branch(2000.0, -20.8, 9.7),))
RAMP = 1.2  # s: a synthetic pull's


def _cube(n=1, order=2):
    nodes, tets = grid_tets(np.ones((n, n, n), bool), np.zeros(3), 1.0 / n)
    fixed = np.zeros(len(nodes), bool)
    fixed[0] = True
    return TetSpace(nodes, tets, fixed, order)


def _shear(gamma):
    F = np.eye(3)
    F[0, 1] = gamma
    return F


def _uniaxial(stretch):
    return np.diag([stretch, stretch**-0.5, stretch**-0.5])


def _history(kind, amount, ramp=RAMP):
    """F(t): a constant-rate ramp to `amount` over `ramp` s, then held."""
    def F(t):
        x = min(t, ramp) / ramp
        return _shear(amount * x) if kind == "shear" else _uniaxial(1.0 + (amount - 1.0) * x)
    return F


def _energy(F, mu, alpha):
    lb = np.sqrt(np.linalg.eigvalsh(F.T @ F)) / np.linalg.det(F) ** (1 / 3)
    return 2 * mu / alpha**2 * (np.sum(lb**alpha) - 3)


def _closed_form(F_of, t, law=LAW):
    """P(t) = F [S_inf + sum_k (S_k - (1/tau) int_0^t e^-(t-s)/tau S_k ds)], by quadrature."""
    F = F_of(t)
    eq = law.equilibrium
    S = isochoric_stress(F, eq.mu[0], eq.alpha[0])  # J = 1: no volumetric stress
    for b in law.branches:
        Sk = isochoric_stress(F, b.mu, b.alpha)
        conv = np.zeros((3, 3))
        for i in range(3):
            for j in range(i, 3):
                g = lambda s: isochoric_stress(F_of(s), b.mu, b.alpha)[i, j] * np.exp(-(t - s) / b.tau)  # noqa: E731, B023
                pts = [RAMP] if t > RAMP else None
                conv[i, j] = conv[j, i] = quad(g, 0.0, t, points=pts, epsabs=1e-13, epsrel=1e-12, limit=400)[0]
        S = S + Sk - conv / b.tau
    return F @ S


def _stepped(F_of, times, order=2):
    """The FEM's P at each time: every node moved by the homogeneous field, P = (1/V) sum_a f_a X_a."""
    space = _cube(order=order)
    X = space.all_nodes
    system = ViscoelasticStrain(space, LAW)
    out = []
    for t in times:
        u = ((F_of(t) - np.eye(3)) @ X.T).T.ravel()
        system.step(t - system.time)
        f = system.evaluate(u, tangent=False)["f"].reshape(-1, 3)
        system.commit(u)
        out.append(f.T @ X)
    return np.array(out)


def test_branch_stress_is_the_energy_gradient():
    rng = np.random.default_rng(3)
    F = np.eye(3) + 0.15 * rng.standard_normal((3, 3))
    F *= 1.0 / np.linalg.det(F) ** (1 / 3) * 1.02  # J = 1.02^3: the isochoric split matters
    C = F.T @ F
    S = isochoric_stress(F, 2000.0, -20.8)
    h = 1e-6
    num = np.zeros((3, 3))
    for i in range(3):
        for j in range(3):
            E = np.zeros((3, 3))
            E[i, j] += 0.5 * h
            E[j, i] += 0.5 * h
            # C moves by 2E (+ O(h^2), cancelling): dW = S : E
            dF = np.linalg.inv(F).T @ E
            num[i, j] = (_energy(F + dF, 2000.0, -20.8) - _energy(F - dF, 2000.0, -20.8)) / (2 * h)
    assert np.abs(num - S).max() <= 1e-6 * np.abs(S).max()
    assert np.allclose(S, S.T)
    assert np.abs(C @ S).max() > 0  # not trivially zero


def test_small_strain_ramp_and_hold_are_the_standard_linear_solid():
    g, T = 1e-5, RAMP
    times = np.arange(1, 501) * 0.01  # 5 s
    P = _stepped(_history("shear", g), times)[:, 0, 1]
    mu_inf, (b,) = LAW.equilibrium.mu[0], LAW.branches
    rate = g / T
    ramp = mu_inf * rate * times + b.mu * rate * b.tau * -np.expm1(-times / b.tau)
    held = mu_inf * g + b.mu * rate * b.tau * -np.expm1(-T / b.tau) * np.exp(-(times - T) / b.tau)
    sls = np.where(times <= T, ramp, held)
    assert np.abs(P - sls).max() <= 1e-5 * np.abs(sls).max()
    at_end = int(round(T / 0.01)) - 1
    assert P[at_end] / (mu_inf * g) > 3.0  # the branch barely relaxed in 1.2 s: about 3.7 x the equilibrium


@pytest.mark.parametrize("kind, amount", [("uniaxial", 0.9), ("uniaxial", 1.1), ("shear", 0.2)])
def test_finite_ramps_and_relaxation_equal_the_convolution_integral(kind, amount):
    F_of = _history(kind, amount)
    checks = [0.6, RAMP, 2.0, 6.0]
    errs = []
    for dt in (0.04, 0.02):
        times = np.arange(1, int(round(6.0 / dt)) + 1) * dt
        P = _stepped(F_of, times)
        idx = [int(round(c / dt)) - 1 for c in checks]
        errs.append(max(np.abs(P[i] - _closed_form(F_of, c)).max() / np.abs(_closed_form(F_of, c)).max() for i, c in zip(idx, checks)))
    assert errs[1] <= 2e-5  # measured 2e-6..5e-6
    assert errs[0] / errs[1] > 3.0  # second order in the step


def _rows(space, dofs):
    col = -np.ones(3 * space.n_all, dtype=np.int64)
    col[space.free] = np.arange(len(space.free))
    rows = col[dofs]
    return sp.csr_matrix((np.ones(len(rows)), (np.arange(len(rows)), rows)), shape=(len(rows), len(space.free)))


def test_a_solve_held_to_a_shear_history_reacts_as_the_closed_form():
    nodes, tets = grid_tets(np.ones((2, 2, 2), bool), np.zeros(3), 0.5)
    space = TetSpace(nodes, tets, np.isclose(nodes[:, 1], 0.0), 2)
    X = space.all_nodes
    boundary = np.flatnonzero(np.any(np.isclose(X, 0.0) | np.isclose(X, 1.0), axis=1) & ~np.isclose(X[:, 1], 0.0))
    dofs = (3 * boundary[:, None] + np.arange(3)).ravel()
    F_of = _history("shear", 0.2)
    times = np.arange(1, 151) * 0.02  # ramp 1.2 s, hold to 3 s
    targets = [((F_of(t) - np.eye(3)) @ X[boundary].T).T.ravel() for t in times]
    system = ViscoelasticStrain(space, LAW)
    res = follow(system, _rows(space, dofs), times, targets, tol=1e-10)
    assert res.report.converged
    exact = ((F_of(times[-1]) - np.eye(3)) @ X.T).T
    assert np.abs(res.u.reshape(-1, 3) - exact).max() <= 1e-8
    # the reactions on the prescribed nodes give P: P_ij = sum_a f_ai X_aj (the clamped face's part from the body's internal force)
    f = system.evaluate(res.u, tangent=False)["f"].reshape(-1, 3)
    P = f.T @ X
    ref = _closed_form(F_of, times[-1])
    assert np.abs(P - ref).max() <= 2e-4 * np.abs(ref).max()
    reactions = res.forces[-1].reshape(-1, 3)
    assert np.abs(reactions - f[boundary]).max() <= 1e-7 * np.abs(f).max()


def test_held_long_the_force_is_the_equilibrium_laws():
    """A cantilever's end pulled sideways in 1.2 s and held 1e9 s: the force is the hyperelastic
    solver's with the equilibrium law alone, to 1e-6; at the ramp's end it is well above it. (A step
    of dt leaves the branch a gain tau/dt of its stress change in the step: the body's strain
    redistributes as it relaxes, so one step of 100 tau is 1e-3 off, one of 1e8 tau is not.)"""
    h = 0.02 / 2
    nodes, tets = grid_tets(np.ones((6, 2, 2), bool), np.zeros(3), h)
    space = TetSpace(nodes, tets, nodes[:, 0] < 1e-12, 2)
    end = np.flatnonzero(np.isclose(space.all_nodes[:, 0], 0.06))
    col = -np.ones(3 * space.n_all, dtype=np.int64)
    col[space.free] = np.arange(len(space.free))
    W = sp.csr_matrix((np.full(len(end), 1.0 / len(end)), (np.zeros(len(end), int), col[3 * end + 1])), shape=(1, len(space.free)))
    d = 0.01
    times = np.concatenate([np.arange(1, 13) * 0.1, [1.2 + 1e3, 1.2 + 1e9]])
    targets = np.array([[d * min(t, 1.2) / 1.2] for t in times])
    res = follow(ViscoelasticStrain(space, LAW), W, times, targets, tol=1e-11)
    assert res.report.converged
    eq = hold(FiniteStrain(space, LAW.equilibrium), W, [d], tol=1e-11)
    assert res.forces[-1][0] == pytest.approx(eq.forces[-1][0], rel=1e-6)
    assert res.forces[11][0] > 2.5 * eq.forces[-1][0]


def test_shipped_rheology_files_and_their_errors(tmp_path):
    from brainsim_assets import path as asset

    for name, mu_inf, tau in (("human_cortex_rheology.toml", 700.0, 9.7), ("human_white_matter_rheology.toml", 300.0, 14.9)):
        law, prov = read_rheology(asset(f"protocols/materials/{name}"))
        assert law.equilibrium.shear_modulus == mu_inf and law.branches[0].tau == tau
        assert "Budday" in prov["source"]
    bad = tmp_path / "bad.toml"
    bad.write_text('[material]\nlaw = "ogden"\nmu = [700.0]\nalpha = [-20.0]\n\n[viscous]\nmu = [2000.0]\nalpha = [-20.0]\ntau = [0.0]\n')
    with pytest.raises(ParameterError, match=r"bad.toml:9.*tau.*out of range"):
        read_rheology(bad)
    bad.write_text('[material]\nlaw = "ogden"\nmu = [700.0]\nalpha = [-20.0]\n\n[viscous]\nmu = [2000.0, 1.0]\nalpha = [-20.0]\ntau = [9.7]\n')
    with pytest.raises(ParameterError, match=r"one of each per branch"):
        read_rheology(bad)
