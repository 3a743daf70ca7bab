"""The truth's decision rule (analysis/verification/truth_band.py, sim/models/fem/finite_strain.py): the
marginal share of energy outside the data, dE_out/dE, from the state's sensitivity (against central
differences of E_out over two solved states, and dE/dd against the solver's force); |J - 1| at the
nodes and a 64-point rule; decide() on the marginal share; the ensemble's members beyond the data."""

import math
from types import SimpleNamespace

import numpy as np
import pytest
import scipy.sparse as sp

from analysis.verification import truth_band
from analysis.verification.tissue_pulls import FOLLOW_SHARE, SUPPORT_FIELDS, Problem, follow_to, solve_pull
from sim.hyperelastic import ogden, uniaxial
from sim.material import load_material
from sim.models.fem import FiniteStrain, TetSpace, hold, p2
from sim.models.fem.finite_strain import fine_jacobian_deviation, point_states, support
from tests.helpers import grid_tets

CORTEX = "protocols/materials/human_cortex.toml"
LAW = ogden([1351.45], [-20.801])
RANGE = (0.95, 1.05)  # narrower than the data's, so that a 20 mm bend has points on both sides


def _cantilever():
    """A 100 x 20 x 20 mm cortex cantilever on P2, its free end's mean sideways displacement held."""
    nodes, tets = grid_tets(np.ones((10, 2, 2), bool), np.zeros(3), 0.01)
    space = TetSpace(nodes, tets, nodes[:, 0] < 1e-12, 2)
    end = np.flatnonzero(np.isclose(space.all_nodes[:, 0], 0.1))
    col = -np.ones(3 * space.n_all, dtype=np.int64)
    col[space.free] = np.arange(len(space.free))
    W = sp.csr_matrix((np.full(len(end), 1.0 / len(end)), (np.zeros(len(end), int), col[3 * end + 1])), shape=(1, len(space.free)))
    return FiniteStrain(space, LAW), W


@pytest.fixture(scope="module")
def bent():
    system, W = _cantilever()
    d, h = 0.02, 1e-5
    res = hold(system, W, [d + h], fractions=[(d - h) / (d + h), d / (d + h), 1.0], keep_states=True, sensitivity=True, tol=1e-11)
    assert res.report.converged
    return system, res, h


def test_the_marginal_share_is_the_derivative_of_the_energy_outside_over_two_solved_states(bent):
    system, res, h = bent
    minus, mid, plus = res.states
    s = point_states(system, mid)
    outside = (s["stretches"].min(axis=-1) < RANGE[0]) | (s["stretches"].max(axis=-1) > RANGE[1])  # fixed at the state

    def energy(u, where):
        return float(np.sum((point_states(system, u)["psi"] * system.wq)[where]))

    everywhere = np.ones_like(outside)
    fd = (energy(plus, outside) - energy(minus, outside)) / (energy(plus, everywhere) - energy(minus, everywhere))
    got = support(system, mid, RANGE, res.sensitivities[1])
    assert 0.02 < got["marginal_share_outside"] < 0.5  # some of the force comes from outside, not all
    assert got["marginal_share_outside"] == pytest.approx(fd, rel=1e-6)


def test_the_energy_rate_is_the_solvers_force(bent):
    system, res, _ = bent
    got = support(system, res.states[1], RANGE, res.sensitivities[1])
    assert got["energy_rate"] == pytest.approx(float(res.forces[1][0]), rel=1e-6)


def test_without_a_sensitivity_the_marginal_share_is_unknown(bent):
    system, res, _ = bent
    assert math.isnan(support(system, res.states[1], RANGE)["marginal_share_outside"])


def test_the_conical_rule_integrates_degree_seven_exactly():
    bary, w = p2.conical_rule(4)
    assert len(w) == 64
    assert np.all(bary > 0)
    powers = (1, 2, 3, 1)  # int L0 L1^2 L2^3 L3 dV / V = 1! 2! 3! 1! 3! / 10!
    exact = 1 * 2 * 6 * 1 * 6 / math.factorial(10)
    assert float(np.sum(w * np.prod(bary ** np.array(powers), axis=1))) == pytest.approx(exact, rel=1e-12)


def _one_tet():
    nodes = np.array([[0.0, 0, 0], [0.01, 0, 0], [0, 0.01, 0], [0, 0, 0.01]])
    return FiniteStrain(TetSpace(nodes, np.array([[0, 1, 2, 3]]), np.array([True, False, False, False]), 2), LAW)


def test_the_finer_rule_is_exact_on_an_affine_field():
    system = _one_tet()
    A = np.array([[0.01, 0.02, 0.0], [0.0, -0.01, 0.003], [0.0, 0.0, 0.004]])
    u = (system.space.all_nodes @ A.T).ravel()
    assert fine_jacobian_deviation(system, u) == pytest.approx(abs(np.linalg.det(np.eye(3) + A) - 1.0), rel=1e-12)


def test_the_finer_rule_finds_more_than_the_gauss_points_on_a_distorted_element():
    system = _one_tet()
    u = np.zeros(3 * system.space.n_all)
    u[3 * 4] = 0.002  # the mid-edge node of corners 0-1 moved along the edge by a fifth of it: J varies over the element
    gauss = float(np.max(np.abs(point_states(system, u)["J"] - 1.0)))
    fine = fine_jacobian_deviation(system, u)
    assert fine > 1.5 * gauss  # at the corners J - 1 is 4 x 0.2 = 0.8; the Gauss points see much less


def test_decide_reads_the_marginal_share():
    ok, v, why = truth_band.decide(0.2, 0.10, 0.35, 0.03)  # a marginal share of 35% above the JND's 25%
    assert not ok
    assert v == "extrapolated"
    assert "dE_out/dE" in why
    assert truth_band.decide(0.2, 0.10, 0.10, 0.03)[0]


def test_the_rule_uses_the_marginal_share_where_recorded_and_the_energy_share_before():
    row = dict.fromkeys(SUPPORT_FIELDS, 0.0) | {"energy_share_outside": 0.20, "marginal_share_outside": 0.35,
                                                "max_abs_j_minus_1": 0.02, "max_abs_j_minus_1_fine": 0.06}
    sup = np.array([[row[k] for k in SUPPORT_FIELDS]])
    rule = truth_band.rule_inputs(sup)
    assert rule["decided_on"] == truth_band.MARGINAL
    assert rule["decided_share"] == 0.35
    assert rule["decided_j"] == 0.06
    old = sup.copy()
    old[0, SUPPORT_FIELDS.index("marginal_share_outside")] = math.nan
    old[0, SUPPORT_FIELDS.index("max_abs_j_minus_1_fine")] = math.nan
    rule = truth_band.rule_inputs(old)
    assert rule["decided_on"] == truth_band.ENERGY
    assert rule["decided_share"] == 0.20
    assert rule["decided_j"] == 0.02


@pytest.fixture(scope="module")
def members():
    law, _ = load_material(CORTEX)
    return law, {m["name"].split(" (")[0]: m for m in truth_band.ensemble(CORTEX, law)}


def test_the_softer_member_passes_the_bar_and_is_softer_beyond_the_data(members):
    law, by = members
    soft = by["softer beyond the data"]
    assert soft["passes"]
    h = 1e-6

    def slope(m, x):
        return float(uniaxial(m, np.array([x + h]))[0][0] - uniaxial(m, np.array([x - h]))[0][0]) / (2 * h)

    assert slope(soft["law"], 1.2) < 0.95 * slope(law, 1.2)  # its stiffness at 1.2, 0.90x the chosen law's
    for x in (1.3, 0.8, 0.7):
        assert abs(uniaxial(soft["law"], np.array([x]))[0][0]) < 0.95 * abs(uniaxial(law, np.array([x]))[0][0])


def test_the_stiffer_member_passes_the_bar_and_is_stiffer_beyond_the_data(members):
    law, by = members
    stiff = by["stiffer beyond the data"]
    assert stiff["passes"]
    for x in (1.3, 0.8):
        assert abs(uniaxial(stiff["law"], np.array([x]))[0][0]) > 1.05 * abs(uniaxial(law, np.array([x]))[0][0])
    assert stiff["beyond_data"]["0.8"]["ratio"] > 1.05


def test_the_finer_meshes_follow_while_the_share_decided_on_allows():
    xs = np.array([0.001, 0.002, 0.003])
    sup = np.zeros((3, len(SUPPORT_FIELDS)))
    sup[:, 0] = [0.1, FOLLOW_SHARE + 0.05, FOLLOW_SHARE + 0.1]  # the energy share leaves at 2 mm
    sup[:, SUPPORT_FIELDS.index("marginal_share_outside")] = [0.1, FOLLOW_SHARE - 0.05, FOLLOW_SHARE + 0.05]  # the marginal share at 3 mm
    coarse = {"force_per_pa": np.ones((3, 3)), "support": sup}
    assert follow_to(xs, coarse, whole=False) == 0.002
    assert follow_to(xs, coarse | {"support": sup[:, :4]}, whole=False) == 0.001  # a solve made before: the energy share


def test_a_solve_without_the_marginal_share_records_its_support_all_the_same():
    """The ensemble's other laws are solved without the sensitivity (only the scene's law
    decides): `solve_pull` records the support, the marginal share NaN, and nothing fails."""
    nodes, tets = grid_tets(np.ones((10, 2, 2), bool), np.zeros(3), 0.01)
    space = TetSpace(nodes, tets, nodes[:, 0] < 1e-12, 2)
    problem = Problem(label=0, mesh=SimpleNamespace(nodes=nodes, tets=tets), space=space, fixed_nodes=0, build_s=0.0)
    end = np.flatnonzero(np.isclose(space.all_nodes[:, 0], 0.1))
    r = solve_pull(problem, LAW, space.all_nodes[end], None, np.array([0.0, 1.0, 0.0]), np.array([0.002, 0.004]), stretch_range=RANGE,
                   marginal=False)
    column = SUPPORT_FIELDS.index("marginal_share_outside")
    assert r["converged"] and np.isnan(r["support"][:, column]).all() and np.isfinite(r["support"][:, 0]).all()
