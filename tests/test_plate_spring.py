"""The plate-spring model against hand calculations of the paper's equations, and properties."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sim.errors import ParameterError
from sim.models.plate_spring import PlateSpring, PlateSpringParams

# Set A: equal plate lengths (q = 1), thickness doubling (alpha = 2), three layers.
A = PlateSpringParams(b=0.01, h1=0.002, l1=0.01, alpha=2.0, q=1.0, layers=3, B=0.01, E=1e6, x_c1=0.001, delta=1.0, t1=1e-4, omega=2.0)
# Set B: growing lengths (q = 1.5), equal thickness, two layers, delta = 2.
B = PlateSpringParams(b=0.005, h1=0.001, l1=0.004, alpha=1.0, q=1.5, layers=2, B=0.005, E=2e5, x_c1=0.0005, delta=2.0, t1=3e-4, omega=1.0)


def test_set_a_layer_table_by_hand():
    s = PlateSpring(A, "continuous")
    # Eq. (2) with q = 1: every plate has length l1
    assert s.L == pytest.approx([0.01, 0.01, 0.01])
    # Eq. (5): H_i = h1 * alpha**(i-1)
    assert s.H == pytest.approx([0.002, 0.004, 0.008])
    # Eq. (4): I = b H^3 / 12 ; Eq. (3): P = 3 E I / L^3 = 3e6 * I / 1e-6
    i1 = 0.01 * 0.002**3 / 12  # 6.6667e-12
    assert s.P == pytest.approx([3e12 * i1, 3e12 * i1 * 8, 3e12 * i1 * 64])
    assert s.P == pytest.approx([20.0, 160.0, 1280.0])
    # Eq. (1): correction (2L / (2L - 0.6 B))^3 = (0.02 / 0.014)^3 = 2.915452
    corr = (0.02 / 0.014) ** 3
    assert s.Pc == pytest.approx([20.0 * corr, 160.0 * corr, 1280.0 * corr])
    # Eq. (18): T_i = t1 (1 - omega^i) / (1 - omega) = 0.1, 0.3, 0.7 ms
    assert s.T == pytest.approx([1e-4, 3e-4, 7e-4])
    assert s.layers_in_budget() == 3


def test_set_a_deformation_by_hand_both_variants():
    corr = (0.02 / 0.014) ** 3
    pc1, pc2, pc3 = 20.0 * corr, 160.0 * corr, 1280.0 * corr
    cont, paper = PlateSpring(A, "continuous"), PlateSpring(A, "paper")
    # F = 1 N: layer 1 consumes F_1 = x_c1 Pc_1 = 0.0583 N (Eq. 6); DCL = 2 in both variants
    f1 = 0.001 * pc1
    x2 = (1.0 - f1) / pc2  # Eq. (12)
    for s in (cont, paper):
        sol = s.deformation(1.0)
        assert sol.dcl == 2
        assert sol.deformation == pytest.approx(0.001 + x2)  # Eq. (19): n_1 x_c1 + X_2
        assert sol.layer_deformation == pytest.approx((0.001, x2, 0.0))
        assert sol.plate_deformation == pytest.approx(x2 / 3)  # Eq. (13)
        assert not sol.overstretched
        assert not sol.saturated
    # F = 3 N: continuous layer 2 consumes n_2 x_c1 Pc_2 = 1.3994 N -> DCL 3
    f2_cont = 3 * 0.001 * pc2
    sol = cont.deformation(3.0)
    assert sol.dcl == 3
    assert sol.deformation == pytest.approx(0.001 + 0.003 + (3.0 - f1 - f2_cont) / pc3)
    # paper: Eq. (9) F_2 = 48 E I_2 x_c1 / (delta L^3) = 48e6 * 5.3333e-11 * 1e-3 / 1e-6 = 2.56 N
    f2_paper = 48e6 * (0.01 * 0.004**3 / 12) * 1e-3 / 1e-6
    assert f2_paper == pytest.approx(2.56)
    assert paper.F[1] == pytest.approx(2.56)
    sol = paper.deformation(3.0)
    assert sol.dcl == 3
    assert sol.deformation == pytest.approx(0.004 + (3.0 - f1 - 2.56) / pc3)
    # and just below the transition the paper's X is past the jump: 0.001 + 2.56 / Pc_2
    below = paper.deformation(f1 + 2.56 - 1e-9).deformation
    assert below == pytest.approx(0.001 + 2.56 / pc2, rel=1e-6)


def test_set_a_paper_jump_is_backward_and_reported():
    corr = (0.02 / 0.014) ** 3
    pc2 = 160.0 * corr
    s = PlateSpring(A, "paper")
    assert len(s.jumps) == 1  # 1 -> 2 never jumps: Eq. (6) and Eq. (9) agree there
    j = s.jumps[0]
    assert j.layer == 2
    assert j.x_before == pytest.approx(0.001 + 2.56 / pc2)  # 0.006488 m
    assert j.x_after == pytest.approx(0.004)  # C_3 = x_c1 (1 + 3)
    assert j.kind == "backward"
    assert j.size == pytest.approx(0.004 - 0.001 - 2.56 / pc2)
    assert PlateSpring(A, "continuous").jumps == ()


def test_set_b_by_hand():
    # Eq. (2): L_2 = l1 (q + q^2 + q^3) / 3 = 0.004 * 7.125 / 3 = 0.0095
    s = PlateSpring(B, "paper")
    assert s.L == pytest.approx([0.004, 0.0095])
    i = 0.005 * 0.001**3 / 12
    p1, p2 = 3 * 2e5 * i / 0.004**3, 3 * 2e5 * i / 0.0095**3
    assert (p1, p2) == pytest.approx((3.90625, 0.2915878))
    pc1 = p1 * (0.008 / (0.008 - 0.003)) ** 3  # 1.6^3 = 4.096 -> 16.0
    pc2 = p2 * (0.019 / (0.019 - 0.003)) ** 3
    assert pc1 == pytest.approx(16.0)
    assert s.Pc == pytest.approx([pc1, pc2])
    # paper F_2 = 48 E I x_c1 / (delta L^3) with delta = 2
    assert s.F == pytest.approx([0.0005 * 16.0, 48 * 2e5 * i * 0.0005 / (2 * 0.0095**3)])
    for variant in ("paper", "continuous"):
        s = PlateSpring(B, variant)
        sol = s.deformation(0.005)  # below F_1 = 0.008: layer 1 only, X = F / Pc_1
        assert sol.dcl == 1
        assert sol.deformation == pytest.approx(0.005 / 16.0)
        sol = s.deformation(0.0085)
        assert sol.dcl == 2
        assert sol.deformation == pytest.approx(0.0005 + 0.0005 / pc2)
        assert not sol.overstretched
        sol = s.deformation(0.01)  # X_2 = 0.002 / Pc_2 = 4.1 mm > n_2 x_c1 = 1.5 mm
        assert sol.overstretched
        assert sol.saturated
        assert s.layers_in_budget() == 2  # T = 0.3, 0.6 ms


def test_inverse_by_hand_set_a():
    corr = (0.02 / 0.014) ** 3
    pc1, pc2 = 20.0 * corr, 160.0 * corr
    s = PlateSpring(A, "continuous")
    assert s.force(0.0005) == pytest.approx(0.0005 * pc1)
    assert s.force(0.002) == pytest.approx(0.001 * pc1 + 0.001 * pc2)
    # paper: X in [C_3, x_before) is reached inside layer 2 already (backward jump)
    p = PlateSpring(A, "paper")
    assert p.force(0.005) == pytest.approx(0.001 * pc1 + 0.004 * pc2)
    # and past x_before the force jumps to layer 3's branch
    x = 0.0066
    assert p.force(x) == pytest.approx(0.001 * pc1 + 2.56 + (x - 0.004) * 1280.0 * corr)


def test_zero_force_and_negative():
    s = PlateSpring(A)
    sol = s.deformation(0.0)
    assert sol.deformation == 0.0
    assert sol.dcl == 1
    assert s.force(0.0) == 0.0
    with pytest.raises(ParameterError, match="force: -1 is out of range; allowed: >= 0 N"):
        s.deformation(-1.0)
    with pytest.raises(ParameterError, match="displacement"):
        s.force(-0.001)
    with pytest.raises(ParameterError, match="not a number"):
        s.deformation("1")
    with pytest.raises(ParameterError, match="finite"):
        s.deformation(math.nan)


@pytest.mark.parametrize(
    "change, message",
    [
        ({"alpha": 2.5}, r"alpha: 2.5 is out of range; allowed: \[1, 2\]"),
        ({"q": 0.9}, r"q: 0.9 is out of range; allowed: \[1, 1.5\]"),
        ({"layers": 0}, r"layers: 0 is out of range; allowed: an integer in 1..1000"),
        ({"B": 0.02}, r"B: 0.02 is out of range; allowed: \[0.01, 0.0101\] m"),
        ({"l1": 0.003}, r"B: .* 2\*L_i > 0.6\*B .* B < 0.01 m"),
        ({"E": -1.0}, r"E: -1.0 is out of range; allowed: a finite number > 0 Pa"),
        ({"x_c1": 0.0}, r"x_c1: 0.0 is out of range"),
    ],
)
def test_bad_parameters(change, message):
    values = A.as_dict() | change
    with pytest.raises(ParameterError, match=message):
        PlateSpringParams(**values)


def test_overflowing_layer_count_names_the_limit():
    values = A.as_dict() | {"q": 1.5, "layers": 60, "alpha": 1.0}
    with pytest.raises(ParameterError, match=r"layers: 60 is out of range for these parameters; allowed: 1\.\.(\d+)") as exc:
        PlateSpring(PlateSpringParams(**values))
    top = int(exc.value.args[0].split("allowed: 1..")[1].split()[0])
    assert 10 < top < 60
    PlateSpring(PlateSpringParams(**(values | {"layers": top})))  # the limit itself works
    with pytest.raises(ParameterError):
        PlateSpring(PlateSpringParams(**(values | {"layers": top + 1})))


def test_extreme_modulus_stays_finite():
    for E in (1.0, 1e12):
        s = PlateSpring(PlateSpringParams(**(A.as_dict() | {"E": E})))
        sol = s.deformation(1.0)
        assert math.isfinite(sol.deformation)
        assert math.isfinite(s.force(0.01))


# -- properties -----------------------------------------------------------------------------

params_strategy = st.builds(
    lambda b, h1, l1, alpha, q, layers, E, xc, delta: PlateSpringParams(
        b=b, h1=h1, l1=max(l1, 0.31 * b + 1e-4), alpha=alpha, q=q, layers=layers, B=b, E=E, x_c1=xc, delta=delta
    ),
    b=st.floats(1e-3, 2e-2),
    h1=st.floats(1e-4, 1e-2),
    l1=st.floats(1e-3, 3e-2),
    alpha=st.floats(1.0, 2.0),
    q=st.floats(1.0, 1.5),
    layers=st.integers(1, 8),
    E=st.floats(1e2, 1e7),
    xc=st.floats(1e-4, 5e-3),
    delta=st.floats(0.2, 5.0),
)


def _tol(s, m):
    """Rounding of X = C + (F - S_M) / Pc_M: a few ulps of S_M, amplified by 1 / Pc."""
    return 1e-13 * float(s.S[m]) * (1 / float(s.Pc[m - 1]) + 1 / float(s.Pc[m]))


def _left_limit(s, m):
    """lim X(F) for F -> S_m from below: X is linear with slope 1/Pc_{m-1} just below S_m."""
    h = 1e-6 * float(s.F[m - 1])
    return s.deformation(float(s.S[m]) - h).deformation + h / float(s.Pc[m - 1])


@settings(max_examples=150, deadline=None)
@given(p=params_strategy, frac=st.floats(0.0, 2.0))
def test_continuous_inverse_round_trip(p, frac):
    s = PlateSpring(p, "continuous")
    F = frac * s.capacity_f
    x = s.deformation(F).deformation
    assert s.force(x) == pytest.approx(F, rel=1e-9, abs=1e-12 * s.capacity_f)


@settings(max_examples=150, deadline=None)
@given(p=params_strategy)
def test_continuous_curve_is_continuous_and_increasing(p):
    s = PlateSpring(p, "continuous")
    forces = np.sort(np.concatenate((np.linspace(0, 1.5 * s.capacity_f, 200), s.S, s.S * (1 - 1e-12))))
    xs = np.array([s.deformation(f).deformation for f in forces])
    assert np.all(np.diff(xs) >= 0)
    assert np.all(np.diff(xs)[np.diff(forces) > 0] > 0)
    for m in range(1, p.layers):  # no jump at any layer transition
        assert s.deformation(float(s.S[m])).deformation == pytest.approx(_left_limit(s, m), rel=1e-9, abs=_tol(s, m))
    assert s.jumps == ()


@settings(max_examples=150, deadline=None)
@given(p=params_strategy)
def test_paper_jumps_detected_exactly_where_the_curve_jumps(p):
    s = PlateSpring(p, "paper")
    found = {j.layer: j for j in s.jumps}
    for m in range(1, p.layers):
        if _tol(s, m) > 1e-7 * s.capacity_x:
            continue  # a layer so soft that X(F) near S_m is not resolvable in float64
        at = s.deformation(float(s.S[m])).deformation
        below = _left_limit(s, m)
        size = at - below
        if abs(size) > 1e-6 * max(s.capacity_x, 1e-12) + _tol(s, m):
            assert m in found
            assert found[m].size == pytest.approx(size, rel=1e-5, abs=_tol(s, m))
        else:
            assert m not in found or abs(found[m].size) <= 1e-6 * s.capacity_x
    # the inverse is monotone in both variants
    xs = np.linspace(0, 1.2 * s.capacity_x, 300)
    fs = np.array([s.force(x) for x in xs])
    # monotone up to rounding: a stiff stack's forces reach 1e4 N, where one ulp is 2e-12 N
    assert np.all(np.diff(fs) >= -1e-12 * max(1.0, float(fs.max())))
