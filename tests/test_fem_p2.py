"""Quadratic (P2) tetrahedra: beam theory, scikit-fem's ElementTetP2, the patch test, and the
locking flag that follows the element (issue 16)."""

import numpy as np
import pytest

from sim.models.fem import LinearFem
from sim.models.fem.p2 import mesh as p2_mesh
from tests.helpers import box

L, H, E, NU, P = 0.1, 0.01, 1e6, 0.3, 1e-3


def _timoshenko(nu=NU):
    inertia = H**4 / 12
    G = E / (2 * (1 + nu))
    return P * L**3 / (3 * E * inertia) + P * L / (5 / 6 * G * H * H)


def _tip_deflection(order, n=1, nu=NU):
    nodes, tets = box(10 * n, n, n, H / n)
    fixed = nodes[:, 0] < 1e-12
    tip = nodes[:, 0] > L - 1e-12
    f = np.zeros_like(nodes)
    f[tip, 2] = -P / tip.sum()
    fem = LinearFem(nodes, tets, E, nu, fixed, order=order)
    return -fem.solve(f)[tip, 2].mean(), fem


def test_p2_cantilever_matches_beam_theory_where_p1_cannot():
    # two elements across the thickness (20 x 2 x 2 cubes, 6 tets each): P1 -50%, P2 -1.1%
    # (one element: P1 -78%, P2 -2.4%; the 3D clamp also holds the Poisson contraction)
    beam = _timoshenko()
    d1, _ = _tip_deflection(1, n=2)
    d2, _ = _tip_deflection(2, n=2)
    print(f"tip deflection: P1 {d1:.5g}, P2 {d2:.5g}, Timoshenko {beam:.5g}")
    assert abs(d1 - beam) / beam > 0.2  # P1 shear-locks in bending
    assert abs(d2 - beam) / beam < 0.02


def test_p2_agrees_with_scikit_fem_element_tet_p2():
    skfem = pytest.importorskip("skfem")
    from skfem.helpers import ddot, sym_grad, trace
    from skfem.models.elasticity import lame_parameters

    nodes, tets = box(4, 3, 2, 0.01)
    E_, nu = 3000.0, 0.45
    fixed = nodes[:, 2] < 1e-12
    top = nodes[:, 2] > 0.02 - 1e-12
    ours = LinearFem(nodes, tets, E_, nu, fixed, order=2)
    mesh = skfem.MeshTet(nodes.T.copy(), tets.T.copy())
    basis = skfem.Basis(mesh, skfem.ElementVector(skfem.ElementTetP2()))
    lam, mu = lame_parameters(E_, nu)

    @skfem.BilinearForm
    def elasticity(u, v, w):
        eu, ev = sym_grad(u), sym_grad(v)
        return 2 * mu * ddot(eu, ev) + lam * trace(eu) * trace(ev)

    K = elasticity.assemble(basis)
    # loads on the top corners only (the same nodal forces for both codes)
    f = np.zeros(basis.N)
    corner_dofs = basis.nodal_dofs  # (3, n_corners): component c of corner i
    f[corner_dofs[0, top]] = 1e-3
    D = basis.get_dofs(lambda x: x[2] < 1e-12).all()  # corners and mid-edge nodes on the clamped face
    x = skfem.solve(*skfem.condense(K, f, D=D))
    u_sk = x[corner_dofs].T  # (n_corners, 3)
    load = np.zeros_like(nodes)
    load[top, 0] = 1e-3
    u = ours.solve(load)
    assert np.abs(u - u_sk).max() <= 1e-8 * np.abs(u_sk).max()
    # and the mid-edge dofs agree too (their positions matched by coordinates)
    all_nodes, _, _ = p2_mesh(nodes, tets)
    ours_full = np.zeros(3 * ours.n_all)
    full_load = np.zeros(3 * ours.n_all)
    full_load[: 3 * len(nodes)] = load.ravel()
    ours_full[ours.free] = ours.solve_free(full_load[ours.free])
    edge_dofs = basis.edge_dofs  # (3, n_edges)
    mids = mesh.p[:, mesh.edges].mean(axis=1).T  # (n_edges, 3)
    index = {tuple(np.round(p, 12)): k for k, p in enumerate(all_nodes)}
    ours_mid = np.array([ours_full.reshape(-1, 3)[index[tuple(np.round(p, 12))]] for p in mids])
    assert np.abs(ours_mid - x[edge_dofs].T).max() <= 1e-8 * np.abs(u_sk).max()


def test_p2_patch_test_linear_and_quadratic_fields():
    nodes, tets = box(3, 3, 3, 0.01)
    rng = np.random.default_rng(1)
    inner = np.all((nodes > 1e-9) & (nodes < 0.03 - 1e-9), axis=1)
    nodes = nodes + np.where(inner[:, None], rng.uniform(-0.002, 0.002, nodes.shape), 0.0)  # distorted elements
    fem = LinearFem(nodes, tets, 3000.0, 0.45, np.ones(len(nodes), bool) & ~inner, order=2)
    all_nodes, _, _ = p2_mesh(nodes, tets)
    A = np.array([[1e-3, 2e-4, -3e-4], [5e-4, -5e-4, 3e-4], [1e-4, 7e-4, 2e-3]])
    # a uniform strain has no internal force at any node not on the boundary
    free_nodes = np.unique(fem.free // 3)
    r = (fem.stiffness @ (all_nodes @ A.T).ravel()).reshape(-1, 3)
    assert len(free_nodes) > 8
    assert np.abs(r[free_nodes]).max() < 1e-12
    # P2 also solves the boundary-value problem exactly for a linear field
    exact = all_nodes @ A.T
    ub = exact.copy().ravel()
    ub[fem.free] = 0.0
    u = np.zeros(3 * fem.n_all)
    u[fem.free] = fem.solve_free(-(fem.stiffness @ ub)[fem.free])
    assert np.abs(u[fem.free] - exact.ravel()[fem.free]).max() < 1e-10 * np.abs(exact).max()


def test_locking_flag_follows_the_element():
    _, p1 = _tip_deflection(1, nu=0.45)
    _, p2 = _tip_deflection(2, nu=0.45)
    assert p1.locking
    assert not p2.locking
    _, p2_near = _tip_deflection(2, nu=0.499)
    assert p2_near.locking
    _, p1_ok = _tip_deflection(1, nu=0.3)
    assert not p1_ok.locking
