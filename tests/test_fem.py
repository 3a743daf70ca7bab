"""Linear FEM against exact solutions, beam theory, scikit-fem; extreme cases; the reference solver."""

import numpy as np
import pytest

from sim.errors import ParameterError
from sim.geometry.volume import locate, tet_volumes
from sim.hyperelastic import neo_hookean
from sim.models.fem import FiniteStrain, LinearFem, SingularSystemError, constraint_matrix, hold, lame
from tests.helpers import box


def test_kuhn_tets_are_positive_and_fill_the_box():
    nodes, tets = box(3, 2, 4, 0.01)
    vol = tet_volumes(nodes, tets)
    assert np.all(vol > 0)
    assert vol.sum() == pytest.approx(3 * 2 * 4 * 1e-6)


def test_patch_test_uniform_strain_is_exact():
    nodes, tets = box(4, 3, 3, 0.01)
    A = np.array([[1e-3, 2e-4, -3e-4], [5e-4, -5e-4, 3e-4], [1e-4, 7e-4, 2e-3]])
    exact = nodes @ A.T
    boundary = np.any((nodes < 1e-9) | (nodes > nodes.max(axis=0) - 1e-9), axis=1)
    fem = LinearFem(nodes, tets, 3000.0, 0.45, boundary)
    ub = np.where(boundary[:, None], exact, 0.0)
    u = fem.solve(-(fem.stiffness @ ub.ravel()).reshape(-1, 3))  # K_ff u_f = -K_fb u_b
    assert (~boundary).sum() == 12
    assert np.abs(u[~boundary] - exact[~boundary]).max() < 1e-14 * np.abs(exact).max() * 1e3
    # a uniform strain has no internal force: K u = 0 away from the boundary
    r = (fem.stiffness @ exact.ravel()).reshape(-1, 3)
    assert np.abs(r[~boundary]).max() < 1e-12


def _cantilever(n, L=0.1, h=0.01, E=1e6, nu=0.3, P=1e-3):
    nodes, tets = box(10 * n, n, n, h / n)
    fixed = nodes[:, 0] < 1e-12
    tip = nodes[:, 0] > L - 1e-12
    fem = LinearFem(nodes, tets, E, nu, fixed)
    f = np.zeros_like(nodes)
    f[tip, 2] = -P / tip.sum()
    return -fem.solve(f)[tip, 2].mean(), fem


def test_cantilever_converges_to_beam_theory():
    # 100 x 10 x 10 mm, clamped at x = 0, 1 mN down at the tip; Timoshenko beam theory
    L, h, E, nu, P = 0.1, 0.01, 1e6, 0.3, 1e-3
    inertia = h**4 / 12
    G = E / (2 * (1 + nu))
    timoshenko = P * L**3 / (3 * E * inertia) + P * L / (5 / 6 * G * h * h)
    levels = (1, 2, 4, 8)  # elements across the thickness
    d = np.array([_cantilever(n)[0] for n in levels])
    errors = np.abs(d - timoshenko) / timoshenko
    rates = np.log2(errors[:-1] / errors[1:])
    print(f"tip deflection {d} vs Timoshenko {timoshenko:.6g}: errors {errors.round(4)}, observed rates {rates.round(2)}")
    assert np.all(np.diff(errors) < 0)  # P1 tetrahedra are too stiff, less so when refined
    assert np.all(d < timoshenko)
    # shear locking makes the coarse levels pre-asymptotic; the rate climbs towards 2 (h^2 for P1)
    assert np.all(np.diff(rates) > 0)
    assert 1.4 < rates[-1] < 2.2
    assert errors[-1] < 0.1


def test_agrees_with_scikit_fem():
    skfem = pytest.importorskip("skfem")
    from skfem.helpers import ddot, sym_grad, trace
    from skfem.models.elasticity import lame_parameters

    nodes, tets = box(4, 3, 2, 0.01)
    E, nu = 3000.0, 0.45
    fixed = nodes[:, 2] < 1e-12
    ours = LinearFem(nodes, tets, E, nu, fixed)
    mesh = skfem.MeshTet(nodes.T.copy(), tets.T.copy())
    basis = skfem.Basis(mesh, skfem.ElementVector(skfem.ElementTetP1()))
    lam, mu = lame_parameters(E, nu)
    assert (lam, mu) == pytest.approx(lame(E, nu))

    @skfem.BilinearForm
    def elasticity(u, v, w):
        eu, ev = sym_grad(u), sym_grad(v)
        return 2 * mu * ddot(eu, ev) + lam * trace(eu) * trace(ev)

    K = elasticity.assemble(basis)
    order = basis.nodal_dofs.T.ravel()  # our dof 3 i + c is their nodal_dofs[c, i]
    Ks = K[order][:, order]
    diff = abs(Ks - ours.stiffness).max()
    assert diff <= 1e-8 * abs(ours.stiffness).max()
    # same load, same solution
    f = np.zeros_like(nodes)
    f[nodes[:, 2] > 0.02 - 1e-12, 0] = 1e-3
    D = basis.get_dofs(lambda x: x[2] < 1e-12).all()
    x = skfem.solve(*skfem.condense(K, f.ravel()[np.argsort(order)], D=D))
    u_sk = x[order].reshape(-1, 3)
    u = ours.solve(f)
    assert np.abs(u - u_sk).max() <= 1e-8 * np.abs(u_sk).max()


def test_reduced_stiffness_is_symmetric_positive_definite():
    nodes, tets = box(3, 2, 2, 0.01)
    fem = LinearFem(nodes, tets, 3000.0, 0.45, nodes[:, 2] < 1e-12)
    K = fem.reduced.toarray()
    assert np.abs(K - K.T).max() <= 1e-12 * np.abs(K).max()
    assert np.linalg.eigvalsh(K).min() > 0
    full = np.linalg.eigvalsh(fem.stiffness.toarray())
    assert np.sum(np.abs(full) < 1e-9 * full.max()) == 6  # six rigid-body modes when unclamped


def test_nearly_incompressible_locks_and_is_reported():
    d_ok, fem_ok = _cantilever(2, nu=0.3)
    d_lock, fem_lock = _cantilever(2, nu=0.499)
    beam = 1e-3 * 0.1**3 / (3 * 1e6 * 0.01**4 / 12)
    assert not fem_ok.locking
    assert fem_lock.locking
    assert d_lock < 0.5 * beam < d_ok  # volumetric locking: far too stiff in bending


def test_modulus_range_scales_exactly():
    nodes, tets = box(3, 2, 2, 0.01)
    fixed = nodes[:, 2] < 1e-12
    f = np.zeros_like(nodes)
    f[-1] = (1e-3, 0, 0)
    ref = None
    for E in (1.0, 3e3, 1e9):
        u = LinearFem(nodes, tets, E, 0.45, fixed).solve(f)
        assert np.all(np.isfinite(u))
        ref = u * E if ref is None else ref
        assert np.allclose(u * E, ref, rtol=1e-7, atol=0)


def test_bad_input():
    nodes, tets = box(2, 2, 2, 0.01)
    with pytest.raises(SingularSystemError, match="no fixed nodes"):
        LinearFem(nodes, tets, 3000.0, 0.45, np.zeros(len(nodes), bool))
    with pytest.raises(ParameterError, match=r"poisson: 0.5 is out of range; allowed: \[0, 0.5\)"):
        LinearFem(nodes, tets, 3000.0, 0.5, nodes[:, 2] < 1e-12)
    with pytest.raises(ParameterError, match="young"):
        LinearFem(nodes, tets, 0.0, 0.45, nodes[:, 2] < 1e-12)
    flipped = tets.copy()
    flipped[0, [0, 1]] = flipped[0, [1, 0]]
    with pytest.raises(ParameterError, match="inverted"):
        LinearFem(nodes, flipped, 3000.0, 0.45, nodes[:, 2] < 1e-12)


def neo_hookean_solve(fem, W, d, steps):
    """The neo-Hookean law with the linear model's mu and bulk modulus (kappa = lambda + 2 mu / 3)
    through the FEM core's finite-strain solver: (u (n_all, 3), force, report)."""
    law = neo_hookean(fem.mu, (fem.lam + 2.0 * fem.mu / 3.0) / fem.mu)
    res = hold(FiniteStrain(fem, law, mean_dilatation=False), W, d, first_step=1.0 / steps)
    return res.u.reshape(-1, 3), res.multipliers, res.report


def _block_pull(d):
    nodes, tets = box(4, 4, 3, 0.01)
    fixed = nodes[:, 2] < 1e-12
    fem = LinearFem(nodes, tets, 3000.0, 0.45, fixed)
    top = int(np.argmin(np.linalg.norm(nodes - (0.02, 0.02, 0.03), axis=1)))
    tet, bary = locate(nodes, tets, nodes[[top]])
    W = constraint_matrix(fem, tet, bary, np.array([1.0]))
    return fem, W, np.asarray(d, float)


def test_neo_hookean_matches_linear_for_small_pulls_and_converges():
    fem, W, d = _block_pull((1e-5, 0.0, 0.0))
    Kc = np.linalg.inv(W @ fem.solve_free(W.T.toarray()))
    lin = Kc @ d
    u, force, rep = neo_hookean_solve(fem, W, d, steps=2)
    assert rep.converged
    assert force == pytest.approx(lin, rel=1e-3, abs=1e-9 * np.abs(lin).max())
    # Newton converges quadratically: the last residuals fall fast
    last = rep.residuals[-1]
    assert len(last) <= 6


def test_neo_hookean_large_pull_differs_from_linear():
    fem, W, d = _block_pull((0.008, 0.0, 0.006))
    Kc = np.linalg.inv(W @ fem.solve_free(W.T.toarray()))
    u, force, rep = neo_hookean_solve(fem, W, d, steps=8)
    assert rep.converged
    assert rep.min_jacobian > 0
    assert np.allclose(W @ u.ravel()[fem.free], d, atol=1e-10)  # the grasp point is where the hand is
    rel = np.linalg.norm(force - Kc @ d) / np.linalg.norm(Kc @ d)
    assert 0.01 < rel < 0.8  # geometric and material nonlinearity at 25-35% strain


def test_corotational_small_pull_matches_linear_and_large_rotation_is_invariant():
    from sim.models.fem import corotational_internal_force, corotational_solve, element_rotations

    fem, W, d = _block_pull((1e-5, 0.0, 0.0))
    U = fem.solve_free(W.T.toarray())
    Kc = np.linalg.inv(W @ U)
    u, force, rep = corotational_solve(fem, W, U, d, steps=1)
    assert rep.converged
    assert force == pytest.approx(Kc @ d, rel=1e-3, abs=1e-3 * np.linalg.norm(Kc @ d))
    # a rigid rotation of the whole block produces no corotational force (linear FEM would)
    th = 0.6
    Rz = np.array([[np.cos(th), -np.sin(th), 0], [np.sin(th), np.cos(th), 0], [0, 0, 1]])
    u_rot = (fem.nodes @ Rz.T - fem.nodes).ravel()
    R, J = element_rotations(fem, u_rot)
    assert np.allclose(R, Rz, atol=1e-12)
    assert np.allclose(J, 1.0)
    assert np.abs(corotational_internal_force(fem, u_rot, R)).max() < 1e-12 * np.abs(fem.stiffness @ u_rot).max()


def test_corotational_force_is_the_gradient_of_its_energy_also_for_inverted_elements(monkeypatch):
    """The line search's merit: E = sum 1/2 l.K l (l = R^T x - X) has the corotational force as
    its gradient (central differences), with the polar rotation and with the SVD's for
    inverted elements; the compiled frame path's energy equals the NumPy one."""
    import sim.models.fem.corotational as fm

    fem, _, _ = _block_pull((0.008, 0.0, 0.006))
    rng = np.random.default_rng(5)
    u = rng.normal(0, 2.5e-3, 3 * len(fem.nodes))  # element edges are 1 cm: some invert
    state = fm.evaluate(fem, u)
    assert (state.J <= 0).any()
    assert (state.J > 0).any()
    probe = rng.normal(size=u.size)
    h = 1e-8
    fd = (fm.evaluate(fem, u + h * probe).energy - fm.evaluate(fem, u - h * probe).energy) / (2 * h)
    assert fd == pytest.approx(float(state.f @ probe), rel=1e-5)
    elements = np.flatnonzero(state.J < 0.9)
    part = fm.evaluate(fem, u, elements)
    assert part.energy == pytest.approx(fm.corotational_energy(fem, u, part.R, elements), rel=1e-12)
    fd = (fm.evaluate(fem, u + h * probe, elements).energy - fm.evaluate(fem, u - h * probe, elements).energy) / (2 * h)
    assert fd == pytest.approx(float(part.f @ probe), rel=1e-5)
    monkeypatch.setattr(fm, "_kernels", lambda: None)
    numpy_part = fm.evaluate(fem, u, elements)
    assert numpy_part.energy == pytest.approx(part.energy, rel=1e-12)
    assert np.allclose(numpy_part.f, part.f, rtol=1e-10, atol=1e-12 * np.abs(part.f).max())


def test_compiled_corotational_passes_equal_the_numpy_ones(monkeypatch):
    """The compiled rotations and force (a subset of elements, as the haptic frame uses) equal
    the batched NumPy products on a large, rotating displacement."""
    import sim.models.fem.corotational as fm

    pytest.importorskip("numba")
    fem, _, _ = _block_pull((0.008, 0.0, 0.006))
    rng = np.random.default_rng(3)
    th = 0.4
    Rz = np.array([[np.cos(th), -np.sin(th), 0], [np.sin(th), np.cos(th), 0], [0, 0, 1]])
    u = (fem.nodes @ Rz.T - fem.nodes).ravel() + rng.normal(0, 5e-4, 3 * len(fem.nodes))
    elements = np.sort(rng.choice(len(fem.tets), len(fem.tets) // 3, replace=False))
    R, J = fm.element_rotations(fem, u, elements)
    f = fm.corotational_internal_force(fem, u, R, elements)
    monkeypatch.setattr(fm, "_kernels", lambda: None)
    R0, J0 = fm.element_rotations(fem, u, elements)
    f0 = fm.corotational_internal_force(fem, u, R0, elements)
    assert np.allclose(R, R0, atol=1e-12)
    assert np.allclose(J, J0, rtol=1e-12)
    assert np.allclose(f, f0, rtol=1e-10, atol=1e-11 * np.abs(f0).max())
    assert np.abs(f - fem.stiffness @ u).max() > 1e-3 * np.abs(f0).max()  # the rotation matters here


def test_warped_stiffness_of_the_active_elements_is_the_full_warp_with_the_others_unrotated():
    """The frame's warped tangent (values added into the linear pattern, factorised on the
    linear factor's analysis) equals `warped_stiffness` assembled from scratch with identity
    rotations outside the active set, and solves like a fresh factorisation of it."""
    import sim.models.fem.corotational as fm

    fem, W, d = _block_pull((0.008, 0.0, 0.006))
    U = fem.solve_free(W.T.toarray())
    u, _, _ = fm.corotational_solve(fem, W, U, d, steps=2)
    u = u.ravel()
    mag = np.linalg.norm(u.reshape(-1, 3), axis=1)
    active = np.flatnonzero((mag > 0.3 * mag.max())[fem.tets].any(axis=1))
    assert 0 < len(active) < len(fem.tets)
    R, _ = fm.element_rotations(fem, u, active)
    Rall = np.broadcast_to(np.eye(3), (len(fem.tets), 3, 3)).copy()
    Rall[active] = R
    full = fm.warped_stiffness(fem, Rall)
    fast = fm.warped_active(fem, R, active)
    assert abs(fast - full).max() <= 1e-12 * abs(full).max()
    assert abs(fast - fem.reduced).max() > 1e-3 * abs(full).max()
    b = np.random.default_rng(0).normal(size=fast.shape[0])
    from sim.linalg import Factor

    assert np.allclose(fem.factor.with_values(fast).solve(b), Factor(full).solve(b), rtol=1e-9, atol=1e-12)


def test_corotational_large_pull_converges_and_flags_inversion():
    from sim.models.fem import corotational_solve

    fem, W, d = _block_pull((0.008, 0.0, 0.006))
    U = fem.solve_free(W.T.toarray())
    u, force, rep = corotational_solve(fem, W, U, d, steps=4)
    assert rep.converged
    assert rep.min_jacobian > 0
    assert np.allclose(W @ u.ravel()[fem.free], d, atol=1e-10)
    # pushing the grasp point 4 cm down into a 3 cm block inverts elements: flagged, not NaN
    u, force, rep = corotational_solve(fem, W, U, np.array([0.0, 0.0, -0.04]), steps=2, max_iter=30)
    assert rep.min_jacobian <= 0
    assert np.all(np.isfinite(u))
    assert np.all(np.isfinite(force))


def _block_force_ratios(mode: str, frac: float):
    """A 4 x 4 x 12 cm block clamped at its base, its top face's mean displacement held."""
    import scipy.sparse as sp

    from sim.models.fem import LinearFem, corotational_solve
    from tests.helpers import grid_tets

    nodes, tets = grid_tets(np.ones((4, 4, 12), bool), np.zeros(3), 0.01)
    z = nodes[:, 2]
    fem = LinearFem(nodes, tets, 3000.0, 0.45, np.isclose(z, 0))
    free = np.flatnonzero(~np.isclose(z, 0))
    col = {v: i for i, v in enumerate(free)}
    top = np.flatnonzero(np.isclose(z, z.max()))
    W = sp.csr_matrix(([1 / len(top)] * 3 * len(top), ([k for _ in top for k in range(3)], [3 * col[v] + k for v in top for k in range(3)])),
                      shape=(3, 3 * len(free)))
    U = fem.solve_free(np.ascontiguousarray(W.T.toarray()))
    d = np.array([0, 0, frac * z.max()]) if mode == "stretch" else np.array([frac * z.max(), 0, 0])
    lin = np.linalg.norm(np.linalg.inv(W @ U) @ d)
    _, fc, rc = corotational_solve(fem, W, U, d, steps=4)
    _, fn, rn = neo_hookean_solve(fem, W, d, steps=4)
    assert rc.converged
    assert rn.converged
    return np.linalg.norm(fc) / lin, np.linalg.norm(fn) / lin


def test_corotational_is_linear_in_stretch_and_follows_neo_hookean_in_bending():
    """Independent physics: the corotational model is linear elasticity in the rotated frame, so
    a 10% stretch gives the linear force (a Biot material), where the neo-Hookean softens; a
    10% sideways pull of the block bends it, and both nonlinear models stiffen alike."""
    corot, nh = _block_force_ratios("stretch", 0.10)
    assert abs(corot - 1) < 0.01
    assert 0.88 < nh < 0.95
    corot, nh = _block_force_ratios("shear", 0.10)
    assert corot > 1.3
    assert nh > 1.3
    assert abs(corot / nh - 1) < 0.08


# -- the nodal-pressure element (sim/models/fem/nodal_pressure.py) ---------------------------

def _np_block(n=3):
    from sim.models.fem import TetSpace

    nodes, tets = box(n, n, n, 0.03 / n)
    return nodes, tets, TetSpace(nodes, tets, nodes[:, 2] < 1e-12, order=1)


def test_volume_hessians_are_the_gradients_derivative():
    """The analytic second derivatives against central differences of the gradient (exact: the
    gradient of a volume is quadratic in the corners)."""
    from sim.models.fem.nodal_pressure import volume_hessians, volumes

    x = np.random.default_rng(3).normal(size=(20, 4, 3))
    h = 1e-3
    fd = np.empty((20, 12, 12))
    for k in range(12):
        a, i = divmod(k, 3)
        xp, xm = x.copy(), x.copy()
        xp[:, a, i] += h
        xm[:, a, i] -= h
        fd[:, :, k] = (volumes(xp)[1] - volumes(xm)[1]).reshape(20, 12) / (2 * h)
    assert np.abs(volume_hessians(x) - fd).max() < 1e-12 * np.abs(fd).max()
    assert np.allclose(volumes(x)[0], np.linalg.det(x[:, 1:] - x[:, :1]) / 6.0)


def test_nodal_pressure_force_and_tangent_are_its_energys_derivatives():
    from sim.models.fem.nodal_pressure import NodalPressure

    _, _, space = _np_block()
    system = NodalPressure(space, neo_hookean(1000.0, 50.0))
    rng = np.random.default_rng(4)
    u = np.zeros(3 * space.n_all)
    u[space.free] = rng.normal(size=len(space.free)) * 3e-4
    st = system.evaluate(u)
    assert st["min_jacobian"] > 0.5
    du = np.zeros_like(u)
    du[space.free] = rng.normal(size=len(space.free)) * 1e-8
    plus, minus = system.evaluate(u + du, tangent=False), system.evaluate(u - du, tangent=False)
    assert (plus["energy"] - minus["energy"]) / 2 == pytest.approx(st["f"] @ du, rel=1e-5)
    Kdu = st["K"] @ du[space.free]
    assert np.linalg.norm((plus["f"] - minus["f"])[space.free] / 2 - Kdu) < 1e-5 * np.linalg.norm(Kdu)


def test_nodal_pressure_is_the_plain_element_under_uniform_strain_and_locks_less():
    """Under a uniform deformation every node's J is every element's, so the energies agree;
    pulling a nearly incompressible block (kappa = 50 mu), the plain P1 block is twice as stiff
    as P2 (locking) and the nodal pressure lies well between."""
    from sim.models.fem import TetSpace
    from sim.models.fem.nodal_pressure import NodalPressure

    nodes, tets, space = _np_block(4)
    law = neo_hookean(1000.0, 50.0)
    F = np.array([[1.05, 0.02, 0.0], [0.0, 0.97, 0.01], [0.0, 0.0, 1.01]])
    u = (nodes @ (F - np.eye(3)).T).ravel()
    assert NodalPressure(space, law).evaluate(u, tangent=False)["energy"] == pytest.approx(
        FiniteStrain(space, law).evaluate(u, tangent=False)["energy"], rel=1e-12)
    top = nodes[nodes[:, 2] > 0.03 - 1e-9]
    forces = {}
    for name, order in (("p1", 1), ("nodal", 1), ("p2", 2)):
        sp_ = TetSpace(nodes, tets, nodes[:, 2] < 1e-12, order=order)
        tet, bary = locate(nodes, tets, top)
        W = constraint_matrix(sp_, tet, bary, np.full(len(top), 1.0 / len(top)))
        system = NodalPressure(sp_, law) if name == "nodal" else FiniteStrain(sp_, law, mean_dilatation=False)
        res = hold(system, W, np.array([0.0, 0.0, 0.003]))
        assert res.report.converged
        forces[name] = res.multipliers[2]
    assert forces["p1"] > 1.5 * forces["p2"]  # measured 1.73
    assert forces["p2"] < forces["nodal"] < forces["p2"] + 0.7 * (forces["p1"] - forces["p2"])  # measured 0.56 of the gap
    with pytest.raises(ParameterError, match="linear"):
        NodalPressure(TetSpace(nodes, tets, nodes[:, 2] < 1e-12, order=2), law)
