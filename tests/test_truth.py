"""`studyctl calibrate truth` (analysis/verification/truth_table.py) end to end on two coarse meshes (20 and 16 mm,
meshed and solved on first use, then cached): the table it writes is read by `load_truth` for
the scene it was made for, follows the reference's paths, and its transfer to a grasp place off
the hand's vertex is checked against a direct solve there."""

import json

import numpy as np
import pytest
from click.testing import CliRunner

from analysis.verification.tissue_pulls import RECORD_XS, combined_sample, pull_references
from analysis.verification.truth import hand_sets, load_truth
from sim.pulls import hand_pulls, scene_with
from studyctl.cli import cli
from tests.conftest import SCENE


@pytest.fixture(scope="module")
def coarse_truth(tmp_path_factory, monkeypatch_module):
    import analysis.verification.truth_table

    scene = scene_with(SCENE)
    left = hand_sets(scene)[0]
    out = tmp_path_factory.mktemp("truth") / "t.npz"
    original = analysis.verification.truth_table.build_truth

    def coarse(*a, **kw):
        return original(*a, **(kw | {"sizes_mm": (20.0, 16.0)}))

    monkeypatch_module.setattr(analysis.verification.truth_table, "build_truth", coarse)
    vertices = ",".join(str(int(v)) for v in left[:: max(1, len(left) // 4)])
    res = CliRunner().invoke(cli, ["calibrate", "truth", "--vertices", vertices, "--out", str(out), "--jobs", "1", "--json"])
    assert res.exit_code == 0, res.output
    return scene, out, json.loads(res.stdout)


@pytest.fixture(scope="module")
def monkeypatch_module():
    mp = pytest.MonkeyPatch()
    yield mp
    mp.undo()


def test_the_table_follows_the_reference_paths_and_transfers_within_its_check(coarse_truth):
    scene, out, rep = coarse_truth
    truth = load_truth(scene, out)
    mu = scene.spec.material.law.shear_modulus
    pulls = hand_pulls(scene)
    refs = pull_references(SCENE, pulls, RECORD_XS, (20.0, 16.0), jobs=1)["pulls"]  # cached by the build: read
    p = pulls[0]
    want = np.array([combined_sample(refs[p.name]["force_per_pa"][:, k] * mu, refs[p.name]["h_m"])["force"] for k in range(len(RECORD_XS))])
    assert np.allclose(truth.force(p.vertex, np.outer(RECORD_XS, p.direction)), want, rtol=1e-9)
    assert rep["vertices"] == len(truth.vertices)
    assert rep["paths"] == [q.name for q in pulls]
    (check,) = [c for c in rep["transfer_checks"] if c["hand"] == p.name]
    # a grasp a few mm off the hand's vertex: near rest the transfer is the small-strain ratio (exact in
    # the limit); the stiffening differs by place, so the error grows along the pull (docs/synthetic.md)
    assert check["converged"]
    assert check["error_at_mm"]["2"] < 0.15
    assert check["error_at_mm"]["2"] < check["error_at_mm"]["8"] < 1.0
    # the transfer maps the hand's own small-strain stiffness to each place's
    z = np.load(out)
    for k, v in enumerate(truth.vertices):
        h = int(truth.path[k])
        assert np.allclose(truth.K(int(v)), mu * z["K0_per_pa"][k], rtol=1e-8)
        assert h == (1 if int(v) == pulls[1].vertex else 0)  # the left hand's places follow its path; the right hand's vertex (always in) its own


def test_a_table_for_another_law_is_refused(coarse_truth, tmp_path):
    from analysis.errors import InputError

    _, out, _ = coarse_truth
    other = tmp_path / "s.toml"
    other.write_text(SCENE.read_text().replace('file = "../materials/human_cortex.toml"', 'law = "ogden"\nmu = [1500.0]\nalpha = [-10.0]')
                     .replace('"../../data/', f'"{SCENE.parents[2]}/data/').replace('"../models/', f'"{SCENE.parents[1]}/models/')
                     .replace('"../materials/', f'"{SCENE.parents[1]}/materials/'))
    with pytest.raises(InputError, match="made for another scene \\(law"):
        load_truth(scene_with(other), out)


def test_between_records_and_off_the_pull_it_is_the_reference_solved_there(coarse_truth):
    """At 2.75 mm (between the 2.5 and 3 mm records: the Hermite interpolant) and at 6 mm with 0.5 mm
    sideways (the path's tangent), against the reference solved directly to that displacement
    (the law is hyperelastic: the state does not depend on the path to it)."""
    from sim.pulls import Pull

    scene, out, _ = coarse_truth
    truth = load_truth(scene, out)
    mu = scene.spec.material.law.shear_modulus
    p = hand_pulls(scene)[0]
    e = np.asarray(p.direction)
    side = np.cross(scene.mesh.vertex_normals[p.vertex], e)
    side /= np.linalg.norm(side)
    for d, tol in ((0.00275 * e, 0.01), (0.006 * e + 0.0005 * side, 0.03)):
        x = float(np.linalg.norm(d))
        probe = Pull("probe", p.vertex, p.point, tuple(d / x), p.hemisphere)
        # followed whole on both meshes, as the table's own paths are (not cut where the support ends)
        r = pull_references(SCENE, [probe], [x], (20.0, 16.0), jobs=1, stiffness_for={"probe"})["pulls"]["probe"]
        want = combined_sample(r["force_per_pa"][:, 0] * mu, r["h_m"])["force"]
        got = truth.force(p.vertex, [d])[0]
        assert np.linalg.norm(got - want) < tol * np.linalg.norm(want)
