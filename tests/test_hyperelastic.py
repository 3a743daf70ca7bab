"""The finite-strain laws through the project's own FEM (sim/hyperelastic.py, sim/models/fem/hyperelastic_kernels.py,
finite_strain.py, newton.py), against closed forms worked here by hand:

- the element passes: force = the energy's gradient, tangent = the force's Jacobian (central
  differences), at rest the tangent is linear elasticity with the law's mu and Poisson ratio;
- homogeneous cubes: uniaxial tension and compression with free lateral faces, and simple
  shear, on every element the reference can use (P1, P2, P2/P0): displacements and face forces
  equal the closed form to 1e-6 relative;
- the Newton solver follows a finite-strain bending to a converged answer as the mesh is
  refined (P2), where P1 is far off on the coarse meshes.
"""


import numpy as np
import pytest
import scipy.sparse as sp

from sim.hyperelastic import mooney_rivlin, neo_hookean, ogden, uniaxial
from sim.models.fem import FiniteStrain, LinearFem, TetSpace, hold
from tests.helpers import grid_tets, simple_shear

CORTEX = ogden([1552.7], [-17.93])  # the shipped human cortex (protocols/materials/human_cortex.toml)
LAWS = [CORTEX, mooney_rivlin(600.0, 400.0), neo_hookean(1000.0), ogden([500.0, 700.0], [-15.0, 5.0])]
ELEMENTS = [(1, True), (2, False), (2, True)]  # (order, mean dilatation): P1, P2, P2/P0


def _cube(n: int = 2):
    return grid_tets(np.ones((n, n, n), bool), np.zeros(3), 1.0 / n)


# -- the laws by hand, in principal stretches -------------------------------------------------------

def _nominal_by_hand(law, l1, l2, l3):
    """dpsi/dl_i of psi = sum 2 mu/a^2 (J^(-a/3) sum l^a - 3) + kappa/4 (J^2 - 1 - 2 ln J), each term
    differentiated here, term by term (not the library's formula)."""
    J = l1 * l2 * l3
    kappa = law.bulk_ratio * sum(law.mu)
    out = []
    for li in (l1, l2, l3):
        dJ = J / li  # dJ/dl_i
        v = kappa / 4 * (2 * J - 2 / J) * dJ
        for m, a in zip(law.mu, law.alpha):
            s = l1**a + l2**a + l3**a
            v += 2 * m / a**2 * ((-a / 3) * J ** (-a / 3 - 1) * dJ * s + J ** (-a / 3) * a * li ** (a - 1))
        out.append(v)
    return out


def _lateral_by_hand(law, stretch):
    """Bisection for the lateral stretch of free lateral faces (P_22 = 0)."""
    lo, hi = 0.5, 2.0
    f = lambda t: _nominal_by_hand(law, stretch, t, t)[1]  # noqa: E731
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if f(lo) * f(mid) > 0 else (lo, mid)
    return 0.5 * (lo + hi)


@pytest.mark.parametrize("law", LAWS, ids=lambda law: f"{law.law}{len(law.mu)}")
def test_closed_form_uniaxial_is_the_hand_worked_one(law):
    for stretch in (0.9, 0.95, 1.05, 1.1, 1.3):
        t = _lateral_by_hand(law, stretch)
        P, lt = uniaxial(law, stretch)
        assert lt[0] == pytest.approx(t, rel=1e-10)
        assert P[0] == pytest.approx(_nominal_by_hand(law, stretch, t, t)[0], rel=1e-9)


def test_closed_forms_of_the_special_laws():
    # small-strain limit: the slope at stretch 1 is Young's modulus 2 mu (1 + nu), nu of kappa = 50 mu
    law = neo_hookean(1000.0)
    h = 1e-6
    slope = (uniaxial(law, 1 + h)[0][0] - uniaxial(law, 1 - h)[0][0]) / (2 * h)
    nu = law.poisson
    assert nu == pytest.approx((3 * 50 - 2) / (2 * (3 * 50 + 1)))
    assert slope == pytest.approx(2 * 1000.0 * (1 + nu), rel=1e-6)
    # simple shear: neo-Hookean and Mooney-Rivlin give Cauchy shear mu gamma, and J = 1 so P_12 = sigma_12
    F = np.array([[1.0, 0.3, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    for law in (neo_hookean(1000.0), mooney_rivlin(600.0, 400.0)):
        sigma = simple_shear(law, 0.3) @ F.T  # J = 1: sigma = P F^T
        assert sigma[0, 1] == pytest.approx(1000.0 * 0.3, rel=1e-12)
        # Rivlin: sigma_22 - sigma_33 = -mu2 gamma^2 (the second invariant's term), 0 for neo-Hookean
        assert sigma[2, 2] - sigma[1, 1] == pytest.approx(400.0 * 0.3**2 if law.law == "mooney-rivlin" else 0.0, abs=1e-9)
    # the incompressible limit: a large bulk ratio approaches P = sum 2 mu/a (l^(a-1) - l^(-a/2-1))
    stiff = ogden([1552.7], [-17.93], bulk_ratio=1e4)
    for lam in (0.9, 1.1):
        inc = 2 * 1552.7 / -17.93 * (lam ** (-17.93 - 1) - lam ** (17.93 / 2 - 1))
        assert uniaxial(stiff, lam)[0][0] == pytest.approx(inc, rel=5e-3)


# -- the element passes ---------------------------------------------------------------------------

@pytest.mark.parametrize("order, mean", ELEMENTS)
@pytest.mark.parametrize("law", LAWS, ids=lambda law: f"{law.law}{len(law.mu)}")
def test_force_is_the_energy_gradient_and_the_tangent_its_jacobian(order, mean, law):
    nodes, tets = grid_tets(np.ones((2, 2, 2), bool), np.zeros(3), 0.5)
    space = TetSpace(nodes, tets, nodes[:, 2] < 1e-12, order)
    fs = FiniteStrain(space, law, mean)
    rng = np.random.default_rng(3)
    u = np.zeros(3 * space.n_all)
    u[space.free] = 0.03 * rng.standard_normal(len(space.free))
    state = fs.evaluate(u)
    K = state["K"].toarray()
    assert state["min_jacobian"] > 0
    h = 1e-7
    for j in rng.choice(len(space.free), 6, replace=False):
        k = space.free[j]
        up, um = u.copy(), u.copy()
        up[k] += h
        um[k] -= h
        ep, em = fs.evaluate(up, False), fs.evaluate(um, False)
        assert (ep["energy"] - em["energy"]) / (2 * h) == pytest.approx(state["f"][k], abs=1e-7 * np.abs(state["f"]).max())
        col = (ep["f"][space.free] - em["f"][space.free]) / (2 * h)
        assert np.abs(col - K[:, j]).max() <= 1e-6 * np.abs(K).max()


@pytest.mark.parametrize("order", [1, 2])
def test_tangent_at_rest_is_linear_elasticity_with_the_laws_moduli(order):
    nodes, tets = grid_tets(np.ones((2, 2, 2), bool), np.zeros(3), 0.5)
    fixed = nodes[:, 2] < 1e-12
    law = CORTEX
    space = TetSpace(nodes, tets, fixed, order)
    K = FiniteStrain(space, law).evaluate(np.zeros(3 * space.n_all))["K"].toarray()  # the default element: displacement-based
    lin = LinearFem(nodes, tets, law.young(law.poisson), law.poisson, fixed, order=order).reduced.toarray()
    assert np.abs(K - lin).max() <= 1e-9 * np.abs(lin).max()


# -- homogeneous cubes ---------------------------------------------------------------------------------

def _rows(space, dofs):
    col = -np.ones(3 * space.n_all, dtype=np.int64)
    col[space.free] = np.arange(len(space.free))
    rows = col[dofs]
    assert np.all(rows >= 0)
    return sp.csr_matrix((np.ones(len(rows)), (np.arange(len(rows)), rows)), shape=(len(rows), len(space.free)))


@pytest.mark.parametrize("order, mean", ELEMENTS)
@pytest.mark.parametrize("law", LAWS, ids=lambda law: f"{law.law}{len(law.mu)}")
@pytest.mark.parametrize("stretch", [0.9, 1.1, 0.95, 1.25])
def test_cube_in_uniaxial_tension_and_compression_with_free_lateral_faces(order, mean, law, stretch):
    nodes, tets = _cube()
    fixed = np.zeros((len(nodes), 3), bool)  # x = 0 slides (u_x = 0); rigid motions held at three corners
    fixed[np.isclose(nodes[:, 0], 0.0), 0] = True
    fixed[np.argmin(np.linalg.norm(nodes, axis=1))] = True
    fixed[np.argmin(np.linalg.norm(nodes - [0, 1, 0], axis=1)), 2] = True
    fixed[np.argmin(np.linalg.norm(nodes - [0, 0, 1], axis=1)), 1] = True
    space = TetSpace(nodes, tets, fixed, order)
    X = space.all_nodes
    top = np.flatnonzero(np.isclose(X[:, 0], 1.0))
    W = _rows(space, 3 * top)
    res = hold(FiniteStrain(space, law, mean), W, np.full(len(top), stretch - 1.0), tol=1e-10)
    assert res.report.converged
    t = _lateral_by_hand(law, stretch)
    exact = X * (np.array([stretch, t, t]) - 1.0)
    assert np.abs(res.u.reshape(-1, 3) - exact).max() <= 1e-6 * abs(stretch - 1.0)  # every node: the field is affine
    P = _nominal_by_hand(law, stretch, t, t)[0]
    assert res.forces[-1].sum() == pytest.approx(P * 1.0, rel=1e-6)  # the face's reference area is 1 m^2


def _boundary_loads(space, P):
    """Consistent nodal forces of the homogeneous traction P N on the cube's faces (per node),
    from the boundary triangles: a P1 triangle gives A/3 to each corner, a P2 one A/3 to each
    mid-edge node and nothing to its corners."""
    tets = space.tets
    faces = np.sort(np.vstack([tets[:, [0, 1, 2]], tets[:, [0, 1, 3]], tets[:, [0, 2, 3]], tets[:, [1, 2, 3]]]), axis=1)
    uniq, counts = np.unique(faces, axis=0, return_counts=True)
    out = np.zeros((space.n_all, 3))
    X = space.all_nodes
    key = {tuple(sorted((int(a), int(b)))): i for i, (a, b) in enumerate(_edges(space))} if space.order == 2 else {}
    for f in uniq[counts == 1]:
        p = X[f]
        c = p.mean(axis=0)
        n = np.zeros(3)
        ax = int(np.argmax([np.ptp(p[:, k]) < 1e-12 for k in range(3)]))
        n[ax] = 1.0 if c[ax] > 0.5 else -1.0
        area = 0.5 * np.linalg.norm(np.cross(p[1] - p[0], p[2] - p[0]))
        t = P @ n
        if space.order == 1:
            for a in f:
                out[a] += t * area / 3
        else:
            for a, b in ((f[0], f[1]), (f[1], f[2]), (f[0], f[2])):
                out[len(space.nodes) + key[tuple(sorted((int(a), int(b))))]] += t * area / 3
    return out


def _edges(space):
    from sim.models.fem.p2 import mesh

    return mesh(space.nodes, space.tets)[2]


@pytest.mark.parametrize("order, mean", ELEMENTS)
@pytest.mark.parametrize("law", LAWS, ids=lambda law: f"{law.law}{len(law.mu)}")
def test_cube_in_simple_shear(order, mean, law):
    gamma = 0.3
    nodes, tets = _cube()
    space0 = TetSpace(nodes, tets, np.isclose(nodes[:, 1], 0.0), order)
    X = space0.all_nodes
    fixed = np.isclose(nodes[:, 1], 0.0)  # the face Y = 0 does not move in simple shear
    space = TetSpace(nodes, tets, fixed, order)
    boundary = np.flatnonzero(np.any(np.isclose(X, 0.0) | np.isclose(X, 1.0), axis=1) & ~np.isclose(X[:, 1], 0.0))
    dofs = (3 * boundary[:, None] + np.arange(3)).ravel()
    exact = np.zeros_like(X)
    exact[:, 0] = gamma * X[:, 1]
    W = _rows(space, dofs)
    res = hold(FiniteStrain(space, law, mean), W, exact[boundary].ravel(), tol=1e-10)
    assert res.report.converged
    assert np.abs(res.u.reshape(-1, 3) - exact).max() <= 1e-6 * gamma
    # the reactions at the prescribed nodes are the consistent loads of the closed form's traction
    loads = _boundary_loads(space, simple_shear(law, gamma))
    reactions = res.forces[-1].reshape(-1, 3)
    on_top = np.isclose(X[boundary, 1], 1.0)
    assert reactions[on_top].sum(axis=0) == pytest.approx(loads[boundary][on_top].sum(axis=0), rel=1e-6,
                                                          abs=1e-6 * np.abs(loads).max())
    assert np.abs(reactions - loads[boundary]).max() <= 1e-6 * np.abs(loads).max()


# -- convergence on a non-homogeneous problem --------------------------------------------------------

def _bend(order: int, n: int) -> float:
    """The force (N) holding the mean displacement of the free end of a 100 x 20 x 20 mm cortex
    cantilever 20 mm sideways (finite strain: the beam bends and stretches)."""
    L, h = 0.1, 0.02
    nodes, tets = grid_tets(np.ones((5 * n, n, n), bool), np.zeros(3), h / n)
    space = TetSpace(nodes, tets, nodes[:, 0] < 1e-12, order)
    end = np.flatnonzero(np.isclose(space.all_nodes[:, 0], L))
    col = -np.ones(3 * space.n_all, dtype=np.int64)
    col[space.free] = np.arange(len(space.free))
    W = sp.csr_matrix((np.full(len(end), 1.0 / len(end)), (np.zeros(len(end), int), col[3 * end + 1])), shape=(1, len(space.free)))
    res = hold(FiniteStrain(space, CORTEX, mean_dilatation=False), W, [0.02])
    assert res.report.converged
    return float(res.forces[-1][0])


def test_p2_converges_on_a_finite_strain_bending_where_p1_does_not_yet():
    p2 = [_bend(2, n) for n in (1, 2, 3)]
    p1 = _bend(1, 2)
    e1, e2 = abs(p2[0] - p2[1]), abs(p2[1] - p2[2])
    assert e2 < 0.5 * e1  # the differences shrink: converging
    assert abs(p2[2] - p2[1]) / p2[2] < 0.05  # 4.84, 4.12, 4.00 mN: differences 15%, 3%
    assert p1 > 3 * p2[2]  # linear tetrahedra lock at kappa = 50 mu: 7.5x too stiff at two elements through the thickness


# -- where a state rests on the law's data (support) --------------------------------------------

@pytest.mark.parametrize("order", [1, 2])
def test_point_states_store_the_energy_the_compiled_pass_does_and_support_reads_homogeneous_stretches(order):
    """`point_states` (NumPy) against `FiniteStrain.evaluate` (the compiled element pass) on a
    random state: the same stored energy; and on homogeneous deformations, whose every point has
    the stretches and J of F: a stretch of 1.2 (isochoric) puts all the energy outside
    0.9..1.1, one of 1.05 none, and a dilatation of 1.1 gives |J - 1| = 0.331."""
    import numpy as np

    from sim.hyperelastic import ogden
    from sim.models.fem import TetSpace
    from sim.models.fem.finite_strain import FiniteStrain, point_states, support

    nodes, tets = grid_tets(np.ones((2, 2, 2), bool), np.zeros(3), 0.01)
    space = TetSpace(nodes, tets, nodes[:, 2] < 1e-12, order=order)
    system = FiniteStrain(space, ogden([1500.0], [-18.0]))
    u = np.random.default_rng(1).normal(scale=5e-4, size=3 * space.n_all)
    s = point_states(system, u)
    assert float(np.sum(s["psi"] * s["weights"])) == pytest.approx(system.evaluate(u, tangent=False)["energy"], rel=1e-12)

    def homogeneous(F):
        return ((np.asarray(F) - np.eye(3)) @ space.all_nodes.T).T.ravel()

    for lam, share in ((1.2, 1.0), (1.05, 0.0)):
        out = support(system, homogeneous(np.diag([lam, lam**-0.5, lam**-0.5])), (0.9, 1.1))
        assert out["energy_share_outside"] == share
        assert out["max_abs_j_minus_1"] < 1e-12
        assert out["principal_stretch_max"] == pytest.approx(lam, rel=1e-12)
        assert out["principal_stretch_min"] == pytest.approx(lam**-0.5, rel=1e-12)
    assert support(system, homogeneous(np.eye(3) * 1.1), (0.9, 1.2))["max_abs_j_minus_1"] == pytest.approx(0.331, rel=1e-12)
