"""The FEM core's one neo-Hookean Newton solver (sim/models/fem/newton.py), on P1 and P2:
against P2 (and P1) linear elasticity for small pulls, and against the closed form of a
homogeneous uniaxial stretch, which both elements represent exactly."""

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.optimize import brentq

from sim.models.fem import LinearFem, condense, constraint_matrix, neo_hookean_solve
from sim.volume import grid_tets, locate

E, NU = 3000.0, 0.45
LAM, MU = E * NU / ((1 + NU) * (1 - 2 * NU)), E / (2 * (1 + NU))


def _cube(n: int = 2):
    return grid_tets(np.ones((n, n, n), bool), np.zeros(3), 1.0 / n)


@pytest.mark.parametrize("order", [1, 2])
def test_small_pull_equals_linear_elasticity(order):
    nodes, tets = grid_tets(np.ones((3, 3, 2), bool), np.zeros(3), 0.01)
    fem = LinearFem(nodes, tets, E, NU, nodes[:, 2] < 1e-12, order=order)
    points = np.array([[0.012, 0.015, 0.02], [0.018, 0.016, 0.02], [0.015, 0.011, 0.0199]])  # a patch on the top
    tet, bary = locate(nodes, tets, points)
    W = constraint_matrix(fem, tet, bary, np.full(3, 1 / 3))
    K = condense(fem, W)[2]
    d = np.array([2e-6, -1e-6, 1.5e-6])  # strains of 1e-4: the nonlinear terms are 1e-4 of the force
    _, force, rep = neo_hookean_solve(fem, W, d, steps=1)
    assert rep.converged and rep.completed_steps == 1 and rep.shifts == 0
    assert np.allclose(force, K @ d, rtol=5e-4, atol=5e-4 * np.abs(K @ d).max())


def _face_constraints(fem, stretch: float):
    """Rows holding u_x = 0 on the face x = 0 and u_x = stretch - 1 on x = 1 (every node of the
    face, mid-edge nodes included), and the rigid motions the homogeneous solution leaves at 0."""
    X = fem.all_nodes
    col = -np.ones(3 * fem.n_all, dtype=np.int64)
    col[fem.free] = np.arange(len(fem.free))
    rows, target, top = [], [], []
    def hold(node, comp, value, on_top=False):
        if col[3 * node + comp] >= 0:  # the clamped origin holds itself
            rows.append(col[3 * node + comp])
            target.append(value)
            top.append(on_top)
    for i in np.flatnonzero(np.isclose(X[:, 0], 0.0)):
        hold(i, 0, 0.0)
    for i in np.flatnonzero(np.isclose(X[:, 0], 1.0)):
        hold(i, 0, stretch - 1.0, on_top=True)
    at = lambda p: int(np.argmin(np.linalg.norm(X - p, axis=1)))  # noqa: E731
    hold(at((0, 1, 0)), 2, 0.0)
    hold(at((0, 0, 1)), 1, 0.0)
    hold(at((1, 0, 0)), 1, 0.0)
    hold(at((1, 0, 0)), 2, 0.0)
    W = sp.csr_matrix((np.ones(len(rows)), (np.arange(len(rows)), rows)), shape=(len(rows), len(fem.free)))
    return W, np.array(target), np.array(top)


@pytest.mark.parametrize("order", [1, 2])
@pytest.mark.parametrize("stretch", [1.2, 0.95])
def test_homogeneous_uniaxial_stretch_matches_the_closed_form(order, stretch):
    nodes, tets = _cube()
    fem = LinearFem(nodes, tets, E, NU, np.linalg.norm(nodes, axis=1) < 1e-12, order=order)  # one corner: the origin
    W, target, top = _face_constraints(fem, stretch)
    # only the origin is clamped, so the tangent alone is singular (rotations) and is factorised
    # shifted: Newton converges linearly here, hence the iterations
    u, force, rep = neo_hookean_solve(fem, W, target, steps=4, tol=1e-10, max_iter=300)
    assert rep.converged
    # closed form, F = diag(l, t, t): free lateral faces, P_yy = mu (t - 1/t) + lam ln(l t^2) / t = 0
    t = brentq(lambda t: MU * (t * t - 1.0) + LAM * np.log(stretch * t * t), 0.3, 3.0)
    P_xx = MU * (stretch - 1.0 / stretch) + LAM * np.log(stretch * t * t) / stretch
    X = fem.all_nodes
    exact = X * (np.array([stretch, t, t]) - 1.0)
    assert np.allclose(u, exact, atol=1e-8)  # every node, mid-edge ones too: the field is affine
    assert force[top].sum() == pytest.approx(P_xx * 1.0, rel=1e-8)  # the face's reference area is 1 m^2
