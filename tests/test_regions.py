"""The brain's regions: the white surfaces, the labels of points (grey between the pial and the
white surface, white inside), a law per quadrature point in `FiniteStrain`, the scene's
`white_matter` and the regional solve's key (analysis/verification/regions.py)."""

import hashlib
import shutil

import numpy as np
import pytest
import scipy.sparse as sp

from analysis.errors import InputError
from analysis.verification.regions import RegionalLaw, contrast_members, region_key, scene_regions
from analysis.verification.tissue_pulls import key_digits, law_shape_key, pull_key_inputs
from analysis.verification.truth import truth_key
from sim.errors import MeshError, SceneError
from sim.geometry import regions
from sim.geometry.mesh import load_mesh, vertex_normals
from sim.hyperelastic import ogden
from sim.material import load_material
from sim.models.fem import TetSpace, hold, p2
from sim.models.fem.finite_strain import FiniteStrain, support
from sim.pulls import make_pulls
from sim.scene import build_scene, load_scene
from tests.conftest import ROOT, SCENE
from tests.helpers import grid_tets, localise

GREY_LAW, _ = load_material(ROOT / "protocols/materials/human_cortex.toml")
WHITE_LAW, _ = load_material(ROOT / "protocols/materials/human_white_matter.toml")
WHITE_TOML = ROOT / "protocols/materials/human_white_matter.toml"


@pytest.fixture(scope="module")
def surfaces():
    return regions.white_surfaces()


# -- the white surfaces and the labels -----------------------------------------------------------

def test_white_surfaces_are_two_closed_hemispheres_inside_the_pial_ones(surfaces):
    """Each white hemisphere encloses 60-75% of its pial hemisphere's volume (FreeSurfer's
    fsaverage5: 67%), by the divergence theorem, and every one of its edges has two triangles."""
    pial = load_mesh(ROOT / "data/brain_fsaverage5.npz")

    def volume(v, f):
        return float(np.einsum("ij,ij->i", v[f[:, 0]], np.cross(v[f[:, 1]], v[f[:, 2]])).sum() / 6.0)

    for label in (0, 1):
        v, f = surfaces[label]
        keep = np.flatnonzero(pial.labels == label)
        index = np.full(len(pial.vertices), -1)
        index[keep] = np.arange(len(keep))
        pf = index[pial.triangles[np.all(pial.labels[pial.triangles] == label, axis=1)]]
        assert 0.60 < volume(v, f) / volume(pial.vertices[keep], pf) < 0.75
        edges = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
        assert set(np.unique(edges, axis=0, return_counts=True)[1]) == {2}


def test_a_point_deep_inside_is_white_and_one_just_under_the_pia_is_grey(surfaces):
    """The left hand's grasp vertex 0.5 mm under the pial surface (the cortex there is 2-3 mm
    thick) is grey; 25 mm under it, in the centrum semiovale, white."""
    scene = build_scene(SCENE)
    pull = next(p for p in make_pulls(scene) if p.name == "left-lateral")
    mesh = scene.mesh
    x, n = mesh.vertices[pull.vertex], vertex_normals(mesh.vertices, mesh.triangles)[pull.vertex]
    labels = regions.point_regions(np.array([x - 0.0005 * n, x - 0.025 * n]), pull.hemisphere, surfaces)
    assert labels[0] == regions.GREY
    assert labels[1] == regions.WHITE


def test_labels_agree_with_open3d_occupancy_on_the_8mm_mesh_centroids(surfaces):
    """Ray parity (the library's) against open3d's occupancy (an independent method) at every
    element centroid of the shipped 8 mm left hemisphere: no point differs."""
    o3d = pytest.importorskip("open3d")
    with np.load(ROOT / "data/brain_tets_8mm.npz") as z:
        nodes, tets = z["nodes_0"], z["tets_0"]
    centroids = nodes[tets].mean(axis=1)
    v, f = surfaces[0]
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(v.astype(np.float32)), o3d.core.Tensor(f.astype(np.uint32)))
    theirs = scene.compute_occupancy(o3d.core.Tensor(centroids.astype(np.float32)), nsamples=3).numpy().astype(bool)
    ours = regions.inside(v, f, centroids)
    assert int((ours != theirs).sum()) == 0


def test_a_damaged_white_surface_file_is_refused_by_name(tmp_path, monkeypatch):
    bad = tmp_path / "brain_white_fsaverage5.npz"
    shutil.copy(regions.WHITE_SURFACE, bad)
    with open(bad, "r+b") as fh:
        fh.seek(100)
        fh.write(b"\x00\x01\x02")
    monkeypatch.setattr(regions, "WHITE_SURFACE", bad)
    with pytest.raises(MeshError, match=r"brain_white_fsaverage5.npz: SHA-256 .* differs"):
        regions.white_surfaces()


# -- a law per quadrature point ------------------------------------------------------------------

def _cube_system(laws, law_of=None):
    nodes, tets = grid_tets(np.ones((2, 2, 2), bool), np.zeros(3), 0.01)
    space = TetSpace(nodes, tets, nodes[:, 2] < 1e-12, order=2)
    return space, FiniteStrain(space, laws, law_of=law_of)


def test_one_law_given_twice_over_mixed_points_is_bit_identical_to_one_law():
    """Two copies of the cortex law (the second padded with a mu = 0 term) over alternating
    points: the same bits as the single law, forces, tangent and energy, in both volumetric forms."""
    padded = ogden([GREY_LAW.mu[0], 0.0], [GREY_LAW.alpha[0], 5.0])
    space, one = _cube_system(GREY_LAW)
    law_of = (np.arange(one.wq.size).reshape(one.wq.shape) % 2).astype(np.int64)
    u = np.random.default_rng(3).normal(scale=4e-4, size=3 * space.n_all)
    for mean in (False, True):
        a = FiniteStrain(space, GREY_LAW, mean_dilatation=mean).evaluate(u)
        b = FiniteStrain(space, [GREY_LAW, padded], mean_dilatation=mean, law_of=law_of).evaluate(u)
        assert np.array_equal(a["f"], b["f"])
        assert np.array_equal(a["K"].data, b["K"].data)
        assert a["energy"] == b["energy"]


def test_white_points_make_the_body_softer():
    """The same stretched state stores less energy and needs less force with half the points
    white matter (about half as stiff) than with all grey, and more than with all white."""
    space, grey = _cube_system(GREY_LAW)
    F = np.diag([1.04, 1.04**-0.5, 1.04**-0.5])
    u = ((F - np.eye(3)) @ space.all_nodes.T).T.ravel()
    half = (np.arange(grey.wq.size).reshape(grey.wq.shape) % 2).astype(np.int64)
    white_all = np.ones(grey.wq.shape, dtype=np.int64)
    e = {name: FiniteStrain(space, [GREY_LAW, WHITE_LAW], law_of=lo).evaluate(u, tangent=False)
         for name, lo in (("grey", None), ("half", half), ("white", white_all))}
    assert e["white"]["energy"] < e["half"]["energy"] < e["grey"]["energy"]
    assert np.linalg.norm(e["half"]["f"]) < np.linalg.norm(e["grey"]["f"])


def test_support_judges_each_point_by_its_own_laws_range():
    """An isochoric stretch of 1.08 is inside grey's 0.90-1.105 and outside a white range of
    0.95-1.05: with half the points white, exactly those are outside."""
    space, grey = _cube_system(GREY_LAW)
    half = (np.arange(grey.wq.size).reshape(grey.wq.shape) % 2).astype(np.int64)
    system = FiniteStrain(space, [GREY_LAW, WHITE_LAW], law_of=half)
    F = np.diag([1.08, 1.08**-0.5, 1.08**-0.5])
    u = ((F - np.eye(3)) @ space.all_nodes.T).T.ravel()
    out = support(system, u, [(0.90, 1.105), (0.95, 1.05)])
    assert out["points_outside"] == int(half.sum())
    assert support(system, u, (0.90, 1.105))["points_outside"] == 0


def test_law_of_with_an_index_beyond_the_laws_is_refused():
    nodes, tets = grid_tets(np.ones((2, 2, 2), bool), np.zeros(3), 0.01)
    space = TetSpace(nodes, tets, nodes[:, 2] < 1e-12, order=2)
    with pytest.raises(Exception, match=r"law_of: one law index in 0\.\.0"):
        FiniteStrain(space, GREY_LAW, law_of=np.ones((len(tets), 4), dtype=np.int64))


# -- the scene's white matter and the solve's key ------------------------------------------------

def _one_material(text: str) -> str:
    """The shipped scene's text with its white matter taken out: the brain of cortex alone."""
    return "\n".join(line for line in text.splitlines() if not line.startswith("white_matter =")) + "\n"


def _scene_with(tmp_path, line: str, name: str = "scene.toml"):
    """A copy of the shipped scene whose material names `line` instead of its own white matter
    (an empty `line`: the brain of cortex alone)."""
    text = localise(_one_material(SCENE.read_text())).replace("poisson = 0.45", f"{line}\npoisson = 0.45", 1)
    path = tmp_path / name
    path.write_text(text)
    return path


@pytest.mark.parametrize("line, message", [
    ('white_matter = "nowhere.toml"', r"scene.toml:\d+: material.white_matter: .*nowhere.toml does not exist; allowed: a material file"),
    ("white_matter = 3", r"scene.toml:\d+: material.white_matter: 3 is not a text in quotes"),
])
def test_a_bad_white_matter_field_is_one_line_naming_the_file_and_field(tmp_path, line, message):
    path = _scene_with(tmp_path, line)
    before = hashlib.sha256(path.read_bytes()).hexdigest()
    with pytest.raises(SceneError, match=message) as exc:
        load_scene(path)
    assert len(str(exc.value).splitlines()) == 1
    assert hashlib.sha256(path.read_bytes()).hexdigest() == before


def test_a_white_matter_file_with_a_bad_law_is_refused_at_its_line(tmp_path):
    bad = tmp_path / "white.toml"
    bad.write_text(WHITE_TOML.read_text().replace("alpha = [-24.", "alpha = [-240."))
    path = _scene_with(tmp_path, f'white_matter = "{bad}"')
    with pytest.raises(SceneError, match=r"white.toml:\d+: material.alpha: -240.* is out of range"):
        load_scene(path)


def test_the_regional_key_differs_and_the_homogeneous_key_is_unchanged(tmp_path):
    """A scene of cortex alone keys its solves as before regions; naming the white matter (as the
    shipped scene does) changes the key, and so does a white law of another scale."""
    shipped = build_scene(_scene_with(tmp_path, "", "one_material.toml"))
    regional_scene = build_scene(_scene_with(tmp_path, f'white_matter = "{WHITE_TOML}"'))
    pull = make_pulls(shipped)[0]
    rng = (0.9, 1.105)
    plain = pull_key_inputs("mesh", shipped, GREY_LAW, 0.005, pull, rng)
    assert pull_key_inputs("mesh", shipped, GREY_LAW, 0.005, pull, rng, scene_regions(shipped)) == plain
    reg = scene_regions(regional_scene)
    assert reg.white == WHITE_LAW
    with_white = pull_key_inputs("mesh", regional_scene, GREY_LAW, 0.005, pull, rng, reg)
    assert with_white != plain
    stiffer = RegionalLaw(reg.grey, WHITE_LAW.scaled(2.0), reg.grey_range, reg.white_range)
    assert pull_key_inputs("mesh", regional_scene, GREY_LAW, 0.005, pull, rng, stiffer) != with_white
    assert region_key(reg, law_shape_key, key_digits)[0][-1] == regions.white_sha256()


def test_the_contrast_members_span_softer_none_and_stiffer_white_matter():
    members = contrast_members(GREY_LAW, (0.9, 1.105))
    ratios = [m["law"].white.shear_modulus / GREY_LAW.shear_modulus if m["law"].white else 1.0 for m in members]
    assert ratios[0] < 0.6
    assert ratios[1] == 1.0
    assert ratios[2] > 1.0
    assert [m["chosen"] for m in members] == [True, False, False]


def test_a_regional_solve_is_softer_than_the_homogeneous_one():
    """A clamped P2 beam bent at its end (finite strain, Newton): with its points below mid-height
    white matter the force holding the end is smaller than all grey, and larger than all white."""
    h, n = 0.01, 2
    nodes, tets = grid_tets(np.ones((5 * n, n, n), bool), np.zeros(3), h / n)
    space = TetSpace(nodes, tets, nodes[:, 0] < 1e-12, order=2)
    end = np.flatnonzero(np.isclose(space.all_nodes[:, 0], 5 * h))
    col = -np.ones(3 * space.n_all, dtype=np.int64)
    col[space.free] = np.arange(len(space.free))
    W = sp.csr_matrix((np.full(len(end), 1.0 / len(end)), (np.zeros(len(end), int), col[3 * end + 1])), shape=(1, len(space.free)))
    z = np.einsum("qa,mak->mqk", p2.POINTS, nodes[tets])[..., 2]
    forces = {}
    for name, law_of in (("grey", np.zeros(z.shape, np.int64)), ("half", (z < h / 2).astype(np.int64)), ("white", np.ones(z.shape, np.int64))):
        res = hold(FiniteStrain(space, [GREY_LAW, WHITE_LAW], law_of=law_of), W, [0.005])
        assert res.report.converged
        forces[name] = abs(float(res.forces[-1][0]))
    assert forces["white"] < forces["half"] < forces["grey"]


def test_an_ensemble_shape_at_unit_mu_keeps_the_white_matters_ratio(tmp_path):
    """The ensemble's laws are solved at unit mu (forces scale with mu): the white matter is
    scaled along, so its ratio to the grey, and so the solve's key, is the scene's."""
    regional_scene = build_scene(_scene_with(tmp_path, f'white_matter = "{WHITE_TOML}"'))
    scene_law = scene_regions(regional_scene)
    unit = scene_regions(regional_scene, GREY_LAW.scaled(1.0 / GREY_LAW.shear_modulus))
    assert unit.white.shear_modulus / unit.grey.shear_modulus == pytest.approx(scene_law.white.shear_modulus / scene_law.grey.shear_modulus, rel=1e-12)
    assert region_key(unit, law_shape_key, key_digits) == region_key(scene_law, law_shape_key, key_digits)


def test_the_observer_truth_of_a_brain_with_white_matter_is_its_own(tmp_path, monkeypatch):
    """The observer's truth table is keyed by the body: a scene of cortex alone keys it as before
    (no `body`), and the two never read each other's table: the shipped one is the regional
    brain's, which a scene of cortex alone is refused by name."""
    from analysis.verification.truth import load_truth

    monkeypatch.setenv("BRAINSIM_CACHE", str(tmp_path / "cache"))  # no table of this machine's own beside the shipped one
    regional_scene = build_scene(_scene_with(tmp_path, f'white_matter = "{WHITE_TOML}"'))
    cortex_alone = build_scene(_scene_with(tmp_path, "", "one_material.toml"))
    assert "body" not in truth_key(cortex_alone)
    assert "white" in truth_key(regional_scene)["body"]
    assert len(load_truth(regional_scene).vertices) > 0  # the shipped table is the regional brain's
    with pytest.raises(InputError, match=r"observer_truth\.npz: made for another scene \(body: .*white.* there, one material here\)"):
        load_truth(cortex_alone)


def test_white_matter_on_another_surface_is_refused_naming_the_field(tmp_path):
    """The white surfaces are fsaverage5's: a scene on another surface cannot name them."""
    path = _scene_with(tmp_path, f'white_matter = "{WHITE_TOML}"')
    other = tmp_path / "other_brain.npz"
    other.write_bytes((ROOT / "data" / "brain_tets_8mm.npz").read_bytes())  # a file that is not the pial surface
    text = path.read_text()
    start = text.index("[mesh]")
    line_end = text.index("\n", text.index("path", start))
    path.write_text(text[:start] + f'[mesh]\npath = "{other}"' + text[line_end:])
    with pytest.raises(SceneError, match=r"material.white_matter: needs the shipped brain surface.*other_brain.npz; allowed: "):
        load_scene(path)


def test_the_small_strain_stiffness_sees_the_white_matter():
    """The located field's and the observer truth's small-strain stiffness (`pull_stiffness`)
    on the shipped 8 mm left hemisphere: a white law equal to the grey gives the homogeneous
    stiffness to round-off; the corona radiata's (about half the cortex) gives one between the
    all-grey and the all-white brain's, and clearly below the grey's (-25% measured)."""
    from analysis.verification.tissue_pulls import build_problem, pull_stiffness
    from sim.geometry.patch import patch_area_points
    from sim.geometry.tetmesh import hemisphere_surface, mesh_hemisphere

    scene = build_scene(SCENE)
    verts, tris, _ = hemisphere_surface(scene.mesh, 0)
    prob = build_problem(scene, 0, mesh_hemisphere(verts, tris, 8e-3))
    pull = next(p for p in make_pulls(scene) if p.name == "left-lateral")
    patch = patch_area_points(scene.mesh, pull.vertex, 0.005)
    e = np.asarray(pull.direction)

    def along(law, regional=None):
        return float(e @ pull_stiffness(prob, law, *patch, regional=regional) @ e)

    grey = along(GREY_LAW)
    rng = (0.9, 1.1)
    same = along(GREY_LAW, RegionalLaw(GREY_LAW, GREY_LAW, rng, rng))
    assert same == pytest.approx(grey, rel=1e-9)
    regional = along(GREY_LAW, RegionalLaw(GREY_LAW, WHITE_LAW, rng, rng))
    white = along(WHITE_LAW) * WHITE_LAW.shear_modulus / GREY_LAW.shear_modulus  # per pascal of the grey's mu
    assert white < regional < 0.9 * grey
