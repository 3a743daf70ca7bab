"""The FEM under the tissue-model contract on the brain: condensation, coupling, embedding, runs."""

import json

import numpy as np
import pytest
from click.testing import CliRunner

from sim.geometry.tetmesh import body_volume
from sim.geometry.volume import embed
from sim.models.fem import FemModel, fixed_nodes
from sim.models.fem.model import build as fem_build
from sim.run import run_scene
from sim.scene import build_scene
from studyctl.cli import cli
from tests.conftest import SCENE
from tests.helpers import patch_vertex_weights

LEFT, LEFT2, RIGHT = (-0.0313, -0.0186, 0.0723), (-0.045, 0.0, 0.06), (0.0315, -0.0172, 0.0716)


@pytest.fixture(scope="module")
def model():
    scene = build_scene(SCENE)
    volume = body_volume(scene.mesh, 0.008)
    fixed = fixed_nodes(volume, scene.mesh, scene.fixed_mask, 2)
    return FemModel(scene.mesh, volume, 3000.0, 0.45, fixed)


def test_condensed_stiffness_reproduces_a_direct_solve(model):
    c = model.grasp(LEFT, 0)
    part = model.parts[c.data.part]
    f = np.array([0.05, -0.02, 0.03])  # force on the tissue, spread over the grasp patch
    u = part.solve_free(c.data.W.T @ f)
    d = c.data.W @ u  # where the patch's mean point goes
    assert np.allclose(model.force(c, tuple(d)), -f, rtol=1e-9, atol=1e-12)
    # and the deformation field of the frame is that solution, embedded on the surface
    field = model.deformation([c], [d])
    nodal = np.zeros((model.n_model_nodes, 3))
    start = model.offsets[c.data.part]
    nodal[start : start + part.n_all] = part.from_free(u, corners=False)
    assert np.allclose(field, model.surface_matrix @ nodal, atol=1e-15)
    patch, share = patch_vertex_weights(model.surface, c.vertex, model.grasp_radius)  # the area mean on the vertices
    assert np.allclose(share @ field[patch], d, atol=1e-3 * np.linalg.norm(d))


def test_two_grasps_on_one_hemisphere_are_coupled_and_on_two_are_not(model):
    a, b, r = model.grasp(LEFT, 0), model.grasp(LEFT2, 1), model.grasp(RIGHT, 1)
    part = model.parts[a.data.part]
    fa, fb = np.array([0.03, 0.0, 0.01]), np.array([-0.02, 0.01, 0.0])
    u = part.solve_free(a.data.W.T @ fa + b.data.W.T @ fb)
    da, db = a.data.W @ u, b.data.W @ u
    got = model.forces([a, b], [tuple(da), tuple(db)])
    assert np.allclose(got[0], -fa, atol=1e-9)
    assert np.allclose(got[1], -fb, atol=1e-9)
    # pulling b alone moves a's grasp point: the 6x6 coupling is not block diagonal
    alone = model.forces([a, b], [(0.0, 0.0, 0.0), (0.01, 0.0, 0.0)])
    assert np.linalg.norm(alone[0]) > 1e-4
    # different hemispheres share no node: no coupling
    sep = model.forces([a, r], [(0.0, 0.0, 0.0), (0.01, 0.0, 0.0)])
    assert sep[0] == (0.0, 0.0, 0.0)


def test_a_second_grasp_at_a_vertex_reuses_its_condensation_as_a_new_contact(model):
    """Grasps at one vertex share the condensed responses (computed once, read-only) but are new
    contacts (caches keyed by a contact's identity see a new grasp); a model with another
    stiffness condenses afresh."""
    a, b = model.grasp(LEFT, 0), model.grasp(LEFT, 1)
    assert a.data is not b.data
    assert b.data.U is a.data.U
    assert b.data.K == a.data.K
    assert a.vertex == b.vertex
    assert not a.data.U.flags.writeable
    stiff = model.with_stiffness(2.0)
    c = stiff.grasp(LEFT, 0)
    assert c.data.U is not a.data.U
    assert np.allclose(c.data.K, 2.0 * np.asarray(a.data.K), rtol=1e-9)


def test_embedding_reproduces_linear_fields(model):
    vol = model.volume
    A = np.array([[1e-3, 2e-3, 0.0], [0.0, 1e-3, -1e-3], [5e-4, 0.0, 2e-3]])
    nodal = vol.nodes @ A.T
    emb = embed(vol, model.surface.vertices, model.surface.labels)
    assert np.allclose(emb.matrix @ nodal, model.surface.vertices @ A.T, atol=1e-12)
    assert np.allclose(emb.weights.sum(axis=1), 1.0)
    assert emb.weights.min() > -1.0  # outside vertices are close to their element


def test_sim_run_with_fem_lockstep():
    scene = build_scene(SCENE, "fem")
    r = run_scene(scene, duration=2.0, time_scale=0)
    fmag = np.linalg.norm(r.forces, axis=2)
    assert 0.03 < fmag.max() < 1.0
    assert fmag.max() <= 3.3
    assert [e.kind for e in r.events].count("grasp") == 2
    k = 1900  # end of the pull: force against the displacement, for each hand
    for i in range(2):
        grasp = next(e for e in r.events if e.kind == "grasp" and e.hand == i)
        d = r.positions[k, i] - scene.mesh.vertices[int(grasp.detail.split()[1])]
        assert np.dot(d, r.forces[k, i]) < 0
    s = r.stats()
    assert s["deformation_ms"]["p50"] is not None


def test_cli_model_fem_json_and_errors():
    res = CliRunner().invoke(cli, ["model", "fem", "--resolution", "8", "--order", "1", "--grasp", ",".join(map(str, LEFT)), "--displacement", "-0.005,0,0", "--json"])
    assert res.exit_code == 0, res.output
    out = json.loads(res.output)
    assert out["force_n"][0] > 0  # linear tetrahedra at Poisson 0.45
    assert out["converged"]
    assert out["locking"]
    assert {"mesh", "assembly", "factorisation", "grasp", "tick", "frame"} <= set(out["times_ms"])
    res = CliRunner().invoke(cli, ["model", "fem", "--resolution", "9", "--grasp", "0,0,0", "--displacement", "0,0,0"])
    assert res.exit_code == 1
    assert "resolution: 9 mm is out of range; allowed: 3..8 mm" in res.output
    res = CliRunner().invoke(cli, ["model", "fem", "--grasp", "0,0", "--displacement", "0,0,0"])
    assert res.exit_code == 2
    assert "three comma-separated numbers" in res.output


@pytest.mark.parametrize("formulation", ["corotational", "finite-strain"])
def test_cli_nonlinear_formulations_converge_and_agree_for_small_pulls(formulation, tmp_path):
    from sim.scene import load_scene

    # the linear FEM at the law's own small-strain moduli (its Poisson ratio, young derived): the finite-strain law's limit
    nu = load_scene(SCENE).material.law.poisson
    scene = tmp_path / "s.toml"
    scene.write_text(SCENE.read_text().replace("poisson = 0.45", f"poisson = {nu!r}").replace('"../../data/', f'"{SCENE.parents[2]}/data/')
                     .replace('"../', f'"{SCENE.parents[1]}/'))
    args = ["model", "fem", "--scene", str(scene), "--resolution", "8", "--order", "1", "--grasp", ",".join(map(str, LEFT)), "--json"]
    lin = json.loads(CliRunner().invoke(cli, [*args, "--displacement", "-0.0002,0,0"]).output)
    res = CliRunner().invoke(cli, [*args, "--displacement", "-0.0002,0,0", "--formulation", formulation, "--steps", "1"])
    out = json.loads(res.output)
    assert out["converged"]
    assert out["final_residuals"][-1] < 1e-7
    assert np.allclose(out["force_n"], lin["force_n"], rtol=0.02, atol=0.02 * lin["force_magnitude_n"])
    if formulation == "finite-strain":  # a small pull rests on measured tissue: every point within the data's stretches
        sup = out["support"]
        assert out["support_data"] == "brain_tissue_uniaxial_budday2017.csv, brain_tissue_shear_budday2017.csv, region cortex"
        assert sup["stretch_range"] == pytest.approx([0.9, 1.104987562])  # shear's l1 at gamma 0.2 widens the uniaxial 0.9-1.1
        assert sup["energy_share_outside"] == 0.0
        assert 0.9 < sup["principal_stretch_min"]
        assert sup["principal_stretch_max"] < 1.1
        assert 0.0 < sup["max_abs_j_minus_1"] < 0.01
        assert sup["marginal_share_outside"] == 0.0  # and none of the force's energy rate comes from outside
        assert sup["max_abs_j_minus_1_fine"] >= sup["max_abs_j_minus_1"]  # the nodes and 64 points include more of the P2 field
        assert sup["energy_rate"] == pytest.approx(out["force_n"][0], rel=1e-4)  # dE/dd: the force holding the pull, along it


def test_corotational_haptic_frames_converge_to_the_static_corotational_solution():
    from sim.models.fem import corotational_solve

    scene = build_scene(SCENE)
    volume = body_volume(scene.mesh, 0.008)
    fixed = fixed_nodes(volume, scene.mesh, scene.fixed_mask, 2)
    model = FemModel(scene.mesh, volume, 3000.0, 0.45, fixed, formulation="corotational")
    c = model.grasp(LEFT, 0)
    d = np.array([-0.012, 0.0, 0.0])
    for k in range(60):  # frames: the hand arrives over 4 frames, then holds still
        model.deformation([c], [d * min(1.0, (k + 1) / 4)])
    haptic = -np.asarray(model.force(c, tuple(d)))
    part = model.parts[c.data.part]
    _, static, rep = corotational_solve(part, c.data.W, c.data.U, d, steps=4)
    assert rep.converged
    # the haptic update corotates only the elements that move (5% of the largest displacement)
    assert np.linalg.norm(haptic - static) < 0.005 * np.linalg.norm(static)
    assert model.restarts == 0
    assert model.inverted_frames == 0
    # between frames the servo uses the frame's state plus the linear tangent: continuous in d
    f1 = np.asarray(model.force(c, tuple(d)))
    f2 = np.asarray(model.force(c, tuple(d + 1e-4)))
    assert np.linalg.norm(f2 - f1) < 1e-4 * np.abs(np.asarray(c.data.K)).max() * 2


def test_corotational_fem_pulls_through_inverted_elements_and_still_catches_a_runaway(monkeypatch):
    """Measured by the accuracy bench: pulled 24 mm along the surface at an occipital place,
    the 6 mm corotational FEM inverts elements after about 20 mm. Its full step (which omits
    the rotations' derivative) then overshot and the force ran to 1e4 N, so the model gave up.
    The line search on the corotational energy halves such steps: the pull completes with a
    force that grows smoothly. The runaway check stays as the servo's safety net."""
    import sim.models.fem.model as fem_model
    from analysis.verification.accuracy import Setting
    from analysis.verification.bench_pulls import HANDSET_PARAMS, build_model
    from sim.pulls import scene_with, test_pulls
    from sim.scene import DEFAULT_SCENE

    scene = scene_with(DEFAULT_SCENE)
    pull = next(p for p in test_pulls(scene) if p.name == "test1-anterior")
    model = build_model(scene, Setting("fem", "c", (("formulation", "corotational"), ("resolution", 0.006), ("order", 1))), HANDSET_PARAMS, 1.0)
    c = model.grasp(pull.point, 0)
    forces = []
    for f in range(1, 73):
        d = tuple(float(x) for x in np.asarray(pull.direction) * 0.024 * f / 72)
        model.deformation([c], [d])
        forces.append(np.linalg.norm(model.force(c, d)))
    diag = model.diagnostics()
    assert not diag["unstable"]
    assert diag["restarts"] == 0
    assert diag["inverted_frames"] > 0  # the case the line search is for
    assert diag["halvings"] > 0
    steps = np.diff(forces)
    assert 0.5 < forces[-1] < 2.0  # no jump
    assert steps.min() > -0.02 * forces[-1]
    assert steps.max() < 0.1 * forces[-1]

    # a runaway (here: a step that returns ten times the force) is still caught: no force, then
    # a fresh start at the next grasp
    model.deformation([], [])
    step = fem_model.corotational_step
    monkeypatch.setattr(fem_model, "corotational_step", lambda *a, **k: (lambda out: (out[0], 10 * out[1], *out[2:]))(step(*a, **k)))
    c = model.grasp(pull.point, 0)
    for f in range(1, 10):
        d = tuple(float(x) for x in np.asarray(pull.direction) * 0.024 * f / 72)
        model.deformation([c], [d])
    assert model.unstable
    assert model.diagnostics()["unstable"]
    assert np.linalg.norm(model.force(c, d)) == 0.0
    monkeypatch.setattr(fem_model, "corotational_step", step)
    model.deformation([], [])
    assert not model.unstable
    c = model.grasp(pull.point, 0)
    model.deformation([c], [(0.0, 0.001, 0.0)])
    assert 0 < np.linalg.norm(model.force(c, (0.0, 0.001, 0.0))) < 0.1


def test_compiled_polar_rotations_equal_the_svd_ones():
    pytest.importorskip("numba")
    from sim.models.fem.corotational import _svd_rotations
    from sim.models.fem.corotational_kernels import polar_rotations

    rng = np.random.default_rng(1)
    F = np.eye(3) + 0.4 * rng.normal(size=(5000, 3, 3))
    R, det = np.empty_like(F), np.empty(len(F))
    left = polar_rotations(F, R, det)
    assert np.array_equal(left, np.linalg.det(F) <= 0)
    assert left.any()
    assert np.allclose(det, np.linalg.det(F), rtol=1e-12, atol=1e-14)
    assert np.allclose(R[~left], _svd_rotations(F[~left]), atol=1e-12)
    assert np.allclose(np.einsum("mji,mjk->mik", R[~left], R[~left]), np.eye(3), atol=1e-12)  # orthonormal


def test_cli_nodal_pressure_pull_converges_softer_than_the_locking_p1_and_refuses_p2():
    args = ["model", "fem", "--resolution", "8", "--grasp", ",".join(map(str, LEFT)), "--displacement", "-0.004,0,0", "--json", "--steps", "2"]
    plain = json.loads(CliRunner().invoke(cli, [*args, "--order", "1", "--formulation", "finite-strain"]).output)
    nodal = json.loads(CliRunner().invoke(cli, [*args, "--formulation", "nodal-pressure"]).output)
    assert plain["converged"]
    assert nodal["converged"]
    assert nodal["order"] == 1
    assert nodal["force_magnitude_n"] < 0.8 * plain["force_magnitude_n"]
    res = CliRunner().invoke(cli, [*args, "--formulation", "nodal-pressure", "--order", "2"])
    assert res.exit_code != 0
    assert "runs on linear tetrahedra (order 1) only" in res.output
    assert "Traceback" not in res.output


def test_reset_brings_a_model_that_gave_up_back_to_rest():
    """The accuracy bench resets between pulls: a corotational model that gave up on one pull
    rendered zero on every later one (12 of its 18 bench pulls instead of 4)."""
    scene = build_scene(SCENE)
    volume = body_volume(scene.mesh, 0.008)
    model = FemModel(scene.mesh, volume, 3000.0, 0.45, fixed_nodes(volume, scene.mesh, scene.fixed_mask, 2), formulation="corotational")
    c = model.grasp(LEFT, 0)
    d = (-0.002, 0.0, 0.0)
    model.deformation([c], [np.array(d)])
    model.unstable = True  # as its runaway check sets it
    assert model.tick_laws([c]) is None
    model.reset()
    assert not model.unstable
    assert model.tick_laws([c]) is not None
    c = model.grasp(LEFT, 0)
    model.deformation([c], [np.array(d)])
    assert np.linalg.norm(model.force(c, d)) > 0.0


def test_the_built_model_keeps_each_parts_centroid_tree(model):
    """A grasp's search tree, built with the model: each grasp built it again (part of 300 ms)."""
    assert len(model.centroid_trees) == len(model.parts)


def test_the_build_condenses_the_grasps_where_the_scenes_hands_start():
    """A run's first grasps (2 of 2 over the 250 ms budget) did the work of a new grasp site."""
    scene = build_scene(SCENE)
    model = fem_build(scene.mesh, {"resolution": 0.008}, scene)
    assert model.condensed_vertices == {scene.mesh.nearest_vertex(h.start) for h in scene.spec.hands}
