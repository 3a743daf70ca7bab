"""The surface membrane (the pia-arachnoid): its forces and tangent against finite differences, a
flat membrane's uniaxial tension against the closed form, the composite with the body."""

import json
import re

import numpy as np
import pytest
import scipy.sparse as sp

from analysis.verification import tissue_pulls
from sim.errors import ParameterError, SceneError
from sim.hyperelastic import ogden
from sim.models.fem import FiniteStrain, TetSpace, hold
from sim.models.fem.membrane import Membrane, MembraneLaw, WithMembrane, boundary_faces, ogden_stress
from sim.pulls import make_pulls
from sim.scene import Scene, load_scene
from tests.conftest import ROOT
from tests.helpers import box, localise

SCENE = ROOT / "protocols/scenes/brain_pull.toml"
PAC = ROOT / "protocols/materials/pia_arachnoid_human.toml"


def _space(order=2, h=1e-3):
    nodes, tets = box(2, 2, 1, h)
    fixed = nodes[:, 2] <= 1e-12
    return TetSpace(nodes, tets, fixed, order=order)


def _random_u(space, scale, seed=0):
    rng = np.random.default_rng(seed)
    u = np.zeros(3 * space.n_all)
    u[space.free] = scale * rng.standard_normal(len(space.free))
    return u


def test_boundary_faces_of_a_box_cover_its_surface():
    nodes, tets = box(2, 2, 1, 1e-3)
    space = TetSpace(nodes, tets, nodes[:, 2] <= 0, order=2)
    faces = boundary_faces(space)
    X = space.all_nodes[faces[:, :3]]
    area = 0.5 * np.linalg.norm(np.cross(X[:, 1] - X[:, 0], X[:, 2] - X[:, 0]), axis=1).sum()
    assert area == pytest.approx(2 * (4 + 2 + 2) * 1e-6, rel=1e-12)


def test_boundary_face_mid_nodes_are_their_edges_midpoints():
    space = _space()
    faces = boundary_faces(space)
    P = space.all_nodes
    mids = 0.5 * (P[faces[:, [0, 1, 0]]] + P[faces[:, [1, 2, 2]]])
    assert np.abs(P[faces[:, 3:]] - mids).max() < 1e-15


@pytest.mark.parametrize("alpha", [2.0, 36.97, -4.0])
def test_force_is_the_energys_gradient(alpha):
    space = _space()
    mem = Membrane(space, MembraneLaw(3e5, alpha, 4e-4))
    u = _random_u(space, 2e-5)
    du = _random_u(space, 1.0, seed=1)
    eps = 1e-9
    fd = (mem.evaluate(u + eps * du, tangent=False)["energy"] - mem.evaluate(u - eps * du, tangent=False)["energy"]) / (2 * eps)
    assert mem.evaluate(u, tangent=False)["f"] @ du == pytest.approx(fd, rel=1e-5)


@pytest.mark.parametrize("alpha", [2.0, 36.97, -4.0])
@pytest.mark.parametrize("scale", [0.0, 2e-5])
def test_tangent_is_the_forces_derivative(alpha, scale):
    """At rest too (equal stretches: the divided differences' limit)."""
    space = _space()
    mem = Membrane(space, MembraneLaw(3e5, alpha, 4e-4))
    u = _random_u(space, scale)
    du = _random_u(space, 1e-9, seed=1)  # strains of 1e-6: alpha = 37 is strongly nonlinear
    K = mem.evaluate(u)["K"]
    fd = (mem.evaluate(u + du, tangent=False)["f"] - mem.evaluate(u - du, tangent=False)["f"])[space.free] / 2
    exact = K @ du[space.free]
    assert np.abs(exact - fd).max() < 1e-5 * np.abs(exact).max()


def test_stress_tangent_matches_finite_differences_of_the_stress_near_equal_stretches():
    C = np.array([[1.1, 0.02], [0.02, 1.1 + 1e-9]])
    _, S, D = ogden_stress(C, 1.0, 36.97)
    E = np.array([[0.3, 0.1], [0.1, -0.2]])
    eps = 1e-7
    fd = (ogden_stress(C + eps * E, 1.0, 36.97, False)[1] - ogden_stress(C - eps * E, 1.0, 36.97, False)[1]) / (2 * eps)
    assert np.abs(np.einsum("IJKL,KL->IJ", D, E) - fd).max() < 1e-6 * np.abs(fd).max()


@pytest.mark.parametrize("alpha", [2.0, 36.97])
def test_flat_membrane_in_uniaxial_stretch_carries_the_closed_form_tension(alpha):
    """x = l X, y = l^-1/2 Y on the top face of a slab: the edge forces of the top face's
    membrane sum to the plane-stress incompressible tension times the width, and the lateral
    edges carry none."""
    L, n, lam = 1e-2, 3, 1.08
    nodes, tets = box(n, n, 1, L / n)
    fixed = np.zeros(len(nodes), bool)
    fixed[0] = True  # a clamp the space requires; the membrane's forces are on every dof
    space = TetSpace(nodes, tets, fixed, order=2)
    top = L / n
    faces = boundary_faces(space)
    on_top = np.all(np.abs(space.all_nodes[faces][:, :, 2] - top) < 1e-12, axis=1)
    law = MembraneLaw(3e5, alpha, 4e-4)
    mem = Membrane(space, law, faces=faces[on_top])
    P = space.all_nodes
    u = np.zeros_like(P)
    u[:, 0] = (lam - 1.0) * P[:, 0]
    u[:, 1] = (lam**-0.5 - 1.0) * P[:, 1]
    f = mem.evaluate(u.ravel(), tangent=False)["f"].reshape(-1, 3)
    on_face = np.zeros(len(P), bool)
    on_face[faces[on_top].ravel()] = True
    right = on_face & (np.abs(P[:, 0] - L) < 1e-12)
    far = on_face & (np.abs(P[:, 1] - L) < 1e-12)
    tension = float(uniaxial_tension(law, lam)) * L
    assert f[right, 0].sum() == pytest.approx(tension, rel=1e-10)
    assert abs(f[far, 1].sum()) < 1e-10 * tension


def test_membrane_law_refuses_a_non_positive_thickness():
    with pytest.raises(ParameterError, match="thickness"):
        MembraneLaw(3e5, 36.97, 0.0)


def _pull(system, space):
    top = np.flatnonzero(np.abs(space.all_nodes[:, 2] - space.all_nodes[:, 2].max()) < 1e-12)
    free_pos = np.full(3 * space.n_all, -1)
    free_pos[space.free] = np.arange(len(space.free))
    cols = free_pos[3 * top + 2]
    W = sp.csr_matrix((np.full(len(cols), 1.0 / len(cols)), (np.zeros(len(cols), int), cols)), shape=(1, len(space.free)))
    return hold(system, W, [1e-4], fractions=(0.5, 1.0)).forces


def test_a_membrane_on_the_body_stiffens_its_pull():
    space = _space()
    body = FiniteStrain(space, ogden((1351.0,), (-20.8,)))
    plain = _pull(body, space)
    both = _pull(WithMembrane(body, MembraneLaw(3e5, 2.0, 4e-4)), space)
    assert both[-1, 0] > 2.0 * plain[-1, 0]


def test_composite_with_a_vanishing_membrane_is_the_body():
    space = _space()
    body = FiniteStrain(space, ogden((1351.0,), (-20.8,)))
    u = _random_u(space, 2e-5)
    a, b = body.evaluate(u), WithMembrane(body, MembraneLaw(1e-300, 2.0, 1e-300)).evaluate(u)
    assert np.array_equal(a["K"].indptr, b["K"].indptr)
    assert np.array_equal(a["K"].data, b["K"].data)


def _scene_with_pac(tmp_path, pac_file) -> object:
    text = localise(SCENE.read_text()).replace("density = 1040.0", f'density = 1040.0\npia_arachnoid = "{pac_file}"', 1)
    path = tmp_path / "scene.toml"
    path.write_text(text)
    return path


def test_a_scene_puts_the_shipped_pia_arachnoid_on_its_material(tmp_path):
    spec = load_scene(_scene_with_pac(tmp_path, PAC))
    assert spec.material.pia_arachnoid == MembraneLaw(300000.0, 36.97, 0.0004, 0.39)


def test_a_scene_without_one_has_no_membrane():
    assert load_scene(SCENE).material.pia_arachnoid is None


@pytest.mark.parametrize("fields, message", [
    ("thickness = 0.4\n", r"membrane\.thickness: 0\.4 is out of range; allowed: \[1e-06, 0\.005\] m"),
    ("thickness = 4e-4\nmu_spread = 1.5\n", r"membrane\.mu_spread: 1\.5 is out of range; allowed: \[0, 0\.9\]"),
])
def test_a_membrane_field_out_of_range_is_refused_naming_the_file_the_field_and_the_range(tmp_path, fields, message):
    bad = tmp_path / "pac.toml"
    bad.write_text('[membrane]\nlaw = "ogden"\nmu = 3e5\nalpha = 36.97\n' + fields)
    with pytest.raises(SceneError) as exc:
        load_scene(_scene_with_pac(tmp_path, bad))
    assert len(exc.value.problems) == 1, exc.value.problems
    assert re.fullmatch(rf"{re.escape(str(bad))}:\d+: {message}", exc.value.problems[0]), exc.value.problems[0]


def test_the_membrane_is_in_the_solve_key_and_its_absence_leaves_the_key_as_it_was(tmp_path):
    plain = Scene(load_scene(SCENE))
    pac = Scene(load_scene(_scene_with_pac(tmp_path, PAC)))
    pull = make_pulls(plain)[0]
    law = plain.spec.material.law
    a = tissue_pulls.pull_key_inputs("mesh", plain, law, 0.005, pull)
    b = tissue_pulls.pull_key_inputs("mesh", pac, law, 0.005, pull)
    assert b[:-1] == a
    assert json.dumps(b[-1]) == json.dumps(["pia-arachnoid", tissue_pulls.key_digits(300000.0 * 0.0004 / law.shear_modulus), 36.97])


def test_the_membranes_measured_spread_is_two_members_of_the_band_each_its_own_solve(tmp_path):
    """The shipped PAC's spread (0.39 of mu) gives the band two bodies, the membrane at 0.61 and
    1.39 times mu under the scene's law; their solves' keys differ from the scene's only in the
    membrane's mu t, and the scene's own (scale 1) is the membrane's key as before. No PAC, no members."""
    from analysis.verification.regions import scene_regions
    from analysis.verification.truth_band import scene_pac_spread

    assert scene_pac_spread(Scene(load_scene(SCENE))) == []
    pac = Scene(load_scene(_scene_with_pac(tmp_path, PAC)))
    members = scene_pac_spread(pac)
    assert [m["pac_scale"] for m in members] == pytest.approx([0.61, 1.39])
    pull = make_pulls(pac)[0]
    law = pac.spec.material.law
    own = tissue_pulls.pull_key_inputs("mesh", pac, law, 0.005, pull, regional=scene_regions(pac))
    plain = tissue_pulls.pull_key_inputs("mesh", pac, law, 0.005, pull)  # the body without its regions
    # the shipped brain's white matter is in the regional key, and the membrane at scale 1 is the key as before
    assert own[-2][0] == "white"
    assert own[:-2] + own[-1:] == plain
    for m in members:
        key = tissue_pulls.pull_key_inputs("mesh", pac, law, 0.005, pull, regional=m["law"])
        assert key[:-1] == own[:-1]
        assert key[-1] == ["pia-arachnoid", tissue_pulls.key_digits(300000.0 * 0.0004 * m["pac_scale"] / law.shear_modulus), 36.97]
        assert tissue_pulls.body_membrane(pac, law, m["pac_scale"]).mu == pytest.approx(300000.0 * m["pac_scale"])


def test_the_small_strain_stiffness_carries_the_membrane_as_the_pull_does():
    """`small_strain_factor` with a membrane (the observer truth's transfer, the located field): the
    condensed stiffness at rest equals the slope of the composite's own finite-strain pull at a tiny
    displacement (`hold`, Newton), per pascal of the body's mu, and is stiffer than the body's."""
    from types import SimpleNamespace

    space = _space()
    law, pac = ogden((1351.0,), (-20.8,)), MembraneLaw(3e5, 36.97, 4e-4)
    top = np.flatnonzero(np.abs(space.all_nodes[:, 2] - space.all_nodes[:, 2].max()) < 1e-12)
    free_pos = np.full(3 * space.n_all, -1)
    free_pos[space.free] = np.arange(len(space.free))
    cols = free_pos[3 * top + 2]
    W = sp.csr_matrix((np.full(len(cols), 1.0 / len(cols)), (np.zeros(len(cols), int), cols)), shape=(1, len(space.free)))
    problem = SimpleNamespace(space=space)

    def stiffness(membrane):
        C = W @ tissue_pulls.small_strain_factor(problem, law, membrane=membrane).solve(np.ascontiguousarray(W.T.toarray()))
        return 1.0 / float(C[0, 0])

    d = 1e-8
    slope = hold(WithMembrane(FiniteStrain(space, law), pac), W, [d]).forces[-1, 0] / d / law.shear_modulus
    assert abs(stiffness(pac)) == pytest.approx(abs(slope), rel=1e-4)
    assert abs(stiffness(pac)) > 2.0 * abs(stiffness(None))


def uniaxial_tension(law, stretch) -> np.ndarray:
    """The nominal tension (N/m) of a flat membrane stretched `stretch` in one direction, free
    in the other (there the stretch is stretch^-1/2): t (2 mu / alpha)(l^(alpha-1) - l^(-alpha/2-1))."""
    s = np.asarray(stretch, dtype=np.float64)
    return law.thickness * 2.0 * law.mu / law.alpha * (s ** (law.alpha - 1.0) - s ** (-0.5 * law.alpha - 1.0))
