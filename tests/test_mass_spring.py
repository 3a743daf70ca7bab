"""Mass-spring model: closed forms, stability limits, integrators, and the linear FEM."""

import math

import numpy as np
import pytest

from sim.errors import ParameterError
from sim.geometry.volume import locate
from sim.models.fem import LinearFem, constraint_matrix
from sim.models.mass_spring import MassSpring, StabilityError, from_tets
from tests.helpers import grid_tets


def one_spring(k=40.0, m=0.01, stretch=0.002, damping=0.0):
    # node 0 fixed at the origin, node 1 (mass m) on a spring of rest length 0.01 along x
    s = MassSpring([[0, 0, 0], [0.01, 0, 0]], [[0, 1]], k, [1.0, m], fixed=[True, False], damping=damping)
    s.x[1, 0] += stretch
    return s


def test_one_mass_period_and_critical_step_match_the_closed_form():
    k, m = 40.0, 0.01
    s = one_spring(k, m)
    assert s.critical_dt() == pytest.approx(2 * math.sqrt(m / k), rel=1e-9)
    dt = s.critical_dt() / 200
    xs, ts = [], []
    for _ in range(4000):
        s.step(dt, "explicit")
        xs.append(s.x[1, 0] - 0.01)
        ts.append(s.t)
    xs, ts = np.array(xs), np.array(ts)
    up = np.flatnonzero((xs[:-1] < 0) & (xs[1:] >= 0))  # upward zero crossings
    period = np.mean(np.diff(ts[up]))
    assert period == pytest.approx(2 * math.pi * math.sqrt(m / k), rel=2e-3)


def test_explicit_bounded_below_the_limit_refused_above():
    s = one_spring()
    crit = s.critical_dt()
    amp = []
    for _ in range(10_000):
        s.step(0.9 * crit, "explicit")
        amp.append(abs(s.x[1, 0] - 0.01))
    # symplectic Euler keeps a fixed ellipse: position amplitude 2 mm / sqrt(1 - (w dt / 2)^2)
    bound = 0.002 / math.sqrt(1 - 0.9**2)
    assert not s.unstable
    assert max(amp) <= bound * 1.001
    assert max(amp[-1000:]) == pytest.approx(max(amp[:1000]), rel=1e-3)  # no growth
    with pytest.raises(StabilityError, match=r"critical step 0.0316\d* s"):
        one_spring().step(1.1 * crit, "explicit")
    s = one_spring()
    rep = s.step(1.1 * crit, "explicit", substep=True)
    assert rep.substeps == 3  # sub-steps of at most half the critical step
    assert not s.unstable


def test_critical_dt_of_a_large_lattice_is_the_dense_one_and_the_same_bits_every_time():
    """Above 200 unknowns the largest eigenvalue comes from ARPACK, whose random start vector gave
    the last digits differently on every call (four calls, four values): now a fixed one."""
    nodes, tets = grid_tets(np.ones((6, 6, 4), bool), np.zeros(3), 0.01)
    values = {from_tets(nodes, tets, 3000.0, 1040.0, fixed=nodes[:, 2] < 1e-9).critical_dt() for _ in range(4)}
    s = from_tets(nodes, tets, 3000.0, 1040.0, fixed=nodes[:, 2] < 1e-9)
    free3 = (3 * s.free[:, None] + np.arange(3)).ravel()
    assert len(free3) > 200
    assert len(values) == 1
    K = s.stiffness_at_rest().toarray()[np.ix_(free3, free3)]
    w = 1 / np.sqrt(np.repeat(s.m[s.free], 3))
    lam = np.linalg.eigvalsh(K * w[:, None] * w[None, :]).max()
    assert values.pop() == pytest.approx(2 / math.sqrt(lam), rel=1e-9)


def test_critical_dt_against_a_dense_eigenvalue_computation():
    nodes, tets = grid_tets(np.ones((2, 2, 1), bool), np.zeros(3), 0.01)
    s = from_tets(nodes, tets, 3000.0, 1040.0, fixed=nodes[:, 2] < 1e-9)
    free3 = (3 * s.free[:, None] + np.arange(3)).ravel()
    K = s.stiffness_at_rest().toarray()[np.ix_(free3, free3)]
    M = np.repeat(s.m[s.free], 3)
    lam = np.linalg.eigvals(K / M[:, None]).real.max()
    assert s.critical_dt() == pytest.approx(2 / math.sqrt(lam), rel=1e-9)


@pytest.mark.parametrize("integrator", ["implicit", "local-global"])
def test_implicit_integrators_stay_bounded_at_50_ms_with_stiff_springs(integrator):
    nodes, tets = grid_tets(np.ones((3, 3, 3), bool), np.zeros(3), 0.01)
    s = from_tets(nodes, tets, 1e9, 1040.0, fixed=nodes[:, 2] < 1e-9)  # springs up to ~1e6 N/m
    assert s.k.max() > 1e5  # explicit would need 500+ substeps per 50 ms
    assert s.critical_dt() < 1e-4
    top = nodes[:, 2] > 0.03 - 1e-9
    s.x[top, 0] += 0.003  # a 3 mm shear of the top layer, released
    e0 = s.energy()
    for _ in range(100):
        s.step(0.05, integrator)
    assert not s.unstable
    assert s.energy() <= e0 * 1.0001
    assert np.abs(s.x - s.rest_positions).max() < 0.0031


def test_energy_monitor_flags_blow_up():
    s = one_spring()
    h = 3 * s.critical_dt()
    for _ in range(200):  # force explicit steps above the limit, as a broken caller would
        s._explicit(h)
        s._monitor()
        if s.unstable:
            break
    assert s.unstable
    assert s.unstable_at is not None


def test_static_pull_against_linear_fem_on_the_same_mesh(capsys):
    nodes, tets = grid_tets(np.ones((6, 6, 4), bool), np.zeros(3), 0.005)
    fixed = nodes[:, 2] < 1e-9
    E = 3000.0
    fem = LinearFem(nodes, tets, E, 0.25, fixed)  # nu = 1/4: the lattice's own Poisson ratio
    ms = from_tets(nodes, tets, E, 1040.0, fixed=fixed)
    patch = np.flatnonzero((nodes[:, 2] > 0.02 - 1e-9) & (np.linalg.norm(nodes[:, :2] - 0.015, axis=1) < 0.0055))
    tet, bary = locate(nodes, tets, nodes[patch])
    W = constraint_matrix(fem, tet, bary, np.full(len(patch), 1.0 / len(patch)))
    C_fem = W @ fem.solve_free(W.T.toarray())
    free3 = (3 * ms.free[:, None] + np.arange(3)).ravel()
    K_ms = ms.stiffness_at_rest()[free3][:, free3]
    from sim.models.fem import Factor

    C_ms = W @ Factor(K_ms).solve(W.T.toarray())  # same dof numbering: same free nodes
    k_fem, k_ms = np.linalg.inv(C_fem), np.linalg.inv(C_ms)
    ratio = np.diag(k_ms) / np.diag(k_fem)
    print(f"patch stiffness, mass-spring / linear FEM (x, y, z): {ratio.round(3)}")
    # a spring lattice is not an elastic continuum: close (0.66 to 0.90 here), not equal
    assert np.all((ratio > 0.5) & (ratio < 1.5))


def test_bad_arguments():
    with pytest.raises(ParameterError, match="stiffness"):
        MassSpring([[0, 0, 0], [1, 0, 0]], [[0, 1]], -1.0, 1.0)
    with pytest.raises(ParameterError, match="springs"):
        MassSpring([[0, 0, 0], [1, 0, 0]], [[0, 2]], 1.0, 1.0)
    with pytest.raises(ParameterError, match="integrator"):
        one_spring().step(1e-3, "verlet")


def test_large_pulls_need_explicit_substeps_below_the_rest_critical_step():
    # a stiff coupling drags a light patch far: the rest linearisation underestimates omega_max.
    # At 0.87x the rest critical step explicit Euler settles on a wrong, energetic state; the
    # half-step sub-stepping agrees with the implicit integrators.
    nodes, tets = grid_tets(np.ones((4, 4, 3), bool), np.zeros(3), 0.005)
    out = {}
    for integrator, dt, n in (("explicit", 0.02, 150), ("implicit", 0.02, 150), ("local-global", 0.02, 150), ("too-close", 0.0008, 3750)):
        s = from_tets(nodes, tets, 3000.0, 1040.0, fixed=nodes[:, 2] < 1e-9, damping=20.0)
        top = np.flatnonzero(nodes[:, 2] > 0.015 - 1e-9)[:4]
        s.set_anchors([(top, 300.0, s.rest_positions[top].mean(axis=0) + [0.005, 0, 0])])
        for _ in range(n):
            s.step(dt, "explicit" if integrator == "too-close" else integrator, substep=True)
        out[integrator] = s.x[top].mean(axis=0) - s.rest_positions[top].mean(axis=0)
    assert np.allclose(out["explicit"], out["local-global"], atol=1e-6)
    assert np.allclose(out["implicit"], out["local-global"], atol=5e-5)
    assert np.linalg.norm(out["too-close"] - out["implicit"]) > 1e-3


def _pulled_block(acceleration="none"):
    nodes, tets = grid_tets(np.ones((8, 8, 5), bool), np.zeros(3), 0.005)
    fixed = nodes[:, 2] < 1e-9
    ms = from_tets(nodes, tets, 3000.0, 1040.0, fixed=fixed, damping=5.0)
    ms.acceleration = acceleration
    patch = np.flatnonzero((nodes[:, 2] > 0.025 - 1e-9) & (np.linalg.norm(nodes[:, :2] - 0.02, axis=1) < 0.006))
    ms.set_anchors([(patch, 300.0, nodes[patch].mean(axis=0) + np.array([0.006, 0.0, 0.002]))])
    return ms


def test_compiled_local_step_equals_the_sparse_products():
    import sim.models.mass_spring as msm

    pytest.importorskip("numba")
    ms = _pulled_block()
    ms.step(1 / 30, "local-global")
    solver = ms._lg_solver(1 / 30)
    x = ms.x + np.random.default_rng(0).normal(0, 1e-4, ms.x.shape)
    compiled = ms._lg_local(solver, x)
    saved, msm._spring_rhs = msm._spring_rhs, lambda: None
    try:
        products = ms._lg_local(solver, x)
    finally:
        msm._spring_rhs = saved
    assert np.allclose(compiled, products, rtol=1e-12, atol=1e-12 * np.abs(products).max())


def test_compiled_explicit_steps_equal_the_numpy_steps():
    """Anchors, damping, an external force and clamped nodes; 200 sub-steps of a pulled block."""
    import sim.models.mass_spring as msm

    pytest.importorskip("numba")
    runs = {}
    for name, kernel in (("compiled", msm._explicit_kernel), ("numpy", lambda: None)):
        ms = _pulled_block()
        ms.external[5] = (0.0, 0.01, 0.0)
        saved, msm._explicit_kernel = msm._explicit_kernel, kernel
        try:
            report = ms.step(0.02, "explicit", substep=True)
        finally:
            msm._explicit_kernel = saved
        runs[name] = (ms.x.copy(), ms.v.copy(), ms.t, report.substeps)
    (xc, vc, tc, nc), (xn, vn, tn, nn) = runs["compiled"], runs["numpy"]
    assert nc == nn > 10
    assert tc == tn
    assert np.abs(xc - xn).max() < 1e-12 * np.abs(xn).max()
    assert np.abs(vc - vn).max() < 1e-9 * np.abs(vn).max()
    assert np.abs(vn).max() > 1e-4  # it moved


def test_accelerations_reach_the_backward_euler_step_in_fewer_iterations():
    """Every iteration converges to the same backward-Euler step (the fixed point); Chebyshev
    (Wang 2015) with the estimated spectral radius and Anderson (Peng et al. 2018) get within
    1% in far fewer iterations than the plain one."""
    plain = _pulled_block()
    s0 = plain.state()
    plain.step(1 / 30, "local-global", iterations=5000)
    ref, moved = plain.x.copy(), np.linalg.norm(plain.x - s0[0])
    needed = {}
    for acc in ("none", "chebyshev", "anderson"):
        ms = _pulled_block(acc)
        for it in range(1, 2000):
            ms.set_state(s0)
            ms.step(1 / 30, "local-global", iterations=it)
            if np.linalg.norm(ms.x - ref) / moved < 0.01:
                needed[acc] = it
                break
    rho = _pulled_block("chebyshev").lg_rho(1 / 30)
    assert 0.5 < rho < 1.0
    # the plain iteration's error shrinks by about rho per iteration
    assert needed["none"] > 15, needed
    assert needed["chebyshev"] < needed["none"] / 2.5, needed
    assert needed["anderson"] < needed["none"] / 2.5, needed
    for acc in ("chebyshev", "anderson"):
        ms = _pulled_block(acc)
        ms.set_state(s0)
        ms.step(1 / 30, "local-global", iterations=400)
        assert np.linalg.norm(ms.x - ref) / moved < 1e-6, acc  # the same fixed point


def _hard_pull(acceleration: str):
    """The pulled block under a hard, sideways pull of a stiff coupling (where an unguarded
    Anderson combination overshoots), with what evaluating the step's objective needs:
    (model, start state, h, solver, y, m / h^2 on the free rows)."""
    ms = _pulled_block(acceleration)
    patch = ms.anchors[0][0]
    ms.set_anchors([(patch, 3000.0, ms.rest_positions[patch].mean(axis=0) + np.array([0.03, 0.03, -0.02]))])
    s0, h = ms.state(), 1 / 30
    return ms, s0, h, ms._lg_solver(h), s0[0] + h * s0[1], ms.m[ms.free, None] / (h * h)


def test_anderson_never_raises_the_steps_objective():
    """Peng et al.'s safeguard: an accelerated iterate that raises the backward-Euler objective
    is replaced by the plain update, so the objective falls at every iteration count."""
    ms, s0, h, solver, y, mass = _hard_pull("anderson")
    values = []
    for it in range(1, 40):
        ms.set_state(s0)
        ms.step(h, "local-global", iterations=it)
        x = ms.x.copy()
        values.append(ms._lg_objective(solver, x, x[ms.free].copy(), y[ms.free], mass))
    assert np.all(np.diff(values) <= 1e-12 * abs(values[0])), values


def test_anderson_at_rest_converged_to_the_last_bit_does_not_fail():
    """Review finding: with every residual difference exactly zero the least-squares system was
    singular (LinAlgError). Three nodes at rest: the step converges at once and stays at rest."""
    from sim.models.mass_spring import MassSpring

    x = np.array([[0, 0, 0], [0, 0, 0.01], [0.01, 0, 0.01]], float)
    ms = MassSpring(x, [[0, 1], [1, 2], [0, 2]], 10.0, 0.001, fixed=[True, False, False], acceleration="anderson")
    ms.step(1 / 30, "local-global", iterations=10)
    assert np.allclose(ms.x, x, atol=1e-12)


def test_newton_converges_to_the_local_global_step_with_anchors_and_clamped_nodes():
    """Newton-Krylov (acceleration "newton", sim/models/newton_krylov.py) minimises the same
    backward-Euler objective as local/global: on the clamped, pulled block it reaches the step
    that 5000 plain iterations converge to. 1e-6 of the frame's motion: both are converged far
    below that (Newton quadratically; the plain iteration shrinks its error by rho < 0.9 per
    iteration, rho^5000 is nothing); clamped nodes stay at rest."""
    plain = _pulled_block()
    s0 = plain.state()
    plain.step(1 / 30, "local-global", iterations=5000)
    ref, moved = plain.x.copy(), np.linalg.norm(plain.x - s0[0])
    ms = _pulled_block("newton")
    ms.step(1 / 30, "local-global", iterations=200)
    assert np.linalg.norm(ms.x - ref) / moved < 1e-6
    assert np.array_equal(ms.x[ms.fixed], ms.rest_positions[ms.fixed])
    assert not ms.v[ms.fixed].any()
    assert np.allclose(ms.v, plain.v, atol=1e-6 * moved * 30)
    # fewer solves than the plain iteration to 1% (both count solves with the same factor)
    for it in range(1, 200):
        ms.set_state(s0)
        ms.step(1 / 30, "local-global", iterations=it)
        if np.linalg.norm(ms.x - ref) / moved < 0.01:
            break
    assert it < 30, it


def test_newton_never_raises_the_steps_objective():
    """The line search accepts only decrease: every Newton iterate of a step (each one where a
    gradient is taken) has a lower objective than the last, on the hard pull where an unguarded
    Anderson step overshoots; and the step ends below where it started, whatever its budget."""
    ms, s0, h, solver, y, mass = _hard_pull("newton")
    start = ms._lg_objective(solver, y.copy(), y[ms.free].copy(), y[ms.free], mass)
    seen = []
    gradient = ms._nk_gradient

    def recording(solver, x, xf, yf, mass):
        seen.append(ms._lg_objective(solver, x.copy(), xf, yf, mass))
        return gradient(solver, x, xf, yf, mass)

    ms._nk_gradient = recording
    ms.step(h, "local-global", iterations=60)
    assert len(seen) >= 4, seen
    assert np.all(np.diff(seen) < 0), seen
    del ms._nk_gradient
    for it in range(1, 40):
        ms.set_state(s0)
        ms.step(h, "local-global", iterations=it)
        x = ms.x.copy()
        assert ms._lg_objective(solver, x, x[ms.free].copy(), y[ms.free], mass) < start


def test_newton_hessian_product_and_gradient_match_finite_differences():
    """The compiled exact Hessian product (transverse term unclamped) and gradient against
    central differences of the objective, and the NumPy path against the compiled one."""
    import sim.models.mass_spring as msm

    pytest.importorskip("numba")
    ms = _pulled_block("newton")
    ms.step(1 / 30, "local-global", iterations=3)
    h = 1 / 30
    solver = ms._lg_solver(h)
    rng = np.random.default_rng(1)
    x = ms.x + rng.normal(0, 2e-4, ms.x.shape) * ~ms.fixed[:, None]
    y = x + rng.normal(0, 1e-4, x.shape)
    mass = ms.m[ms.free, None] / (h * h)
    xf, yf = x[ms.free].copy(), y[ms.free]
    g = ms._nk_gradient(solver, x, xf, yf, mass)
    p = rng.normal(0, 1.0, xf.shape)
    hp = ms._nk_hessian_product(solver, x, mass, p)
    eps = 1e-7
    fd = (ms._lg_objective(solver, x.copy(), xf + eps * p, yf, mass) - ms._lg_objective(solver, x.copy(), xf - eps * p, yf, mass)) / (2 * eps)
    assert float(np.sum(g * p)) == pytest.approx(fd, rel=1e-5)
    x[ms.free] = xf
    x2 = x.copy()
    x2[ms.free] = xf + eps * p
    gp = ms._nk_gradient(solver, x2, xf + eps * p, yf, mass)
    x2[ms.free] = xf - eps * p
    gm = ms._nk_gradient(solver, x2, xf - eps * p, yf, mass)
    assert np.allclose(hp, (gp - gm) / (2 * eps), rtol=1e-4, atol=1e-4 * np.abs(hp).max())
    saved, msm._spring_rhs = msm._spring_rhs, lambda: None
    try:
        hp_numpy = ms._nk_hessian_product(solver, x, mass, p)
        g_numpy = ms._nk_gradient(solver, x, xf, yf, mass)
    finally:
        msm._spring_rhs = saved
    assert np.allclose(hp_numpy, hp, rtol=1e-12, atol=1e-12 * np.abs(hp).max())
    assert np.allclose(g_numpy, g, rtol=1e-10, atol=1e-10 * np.abs(g).max())
