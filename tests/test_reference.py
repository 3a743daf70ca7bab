"""The converged reference (analysis/verification/reference.py): Richardson extrapolation and the GCI worked
on analytic sequences, the body-fitted (fTetWild) hemisphere mesh, P2 forces on two sizes, and
`studyctl bench reference --quick` end to end. The meshes are cached on disk: the first run of
this file meshes one hemisphere twice (about 35 s on 2 cores), later runs read them back."""

import json
import math

import numpy as np
import pytest
from click.testing import CliRunner

from analysis.verification import reference, tissue_pulls
from analysis.verification.convergence import converge, richardson, richardson2
from analysis.verification.tissue_pulls import build_problem, pull_stiffness
from sim.geometry.patch import patch_area_points
from sim.geometry.tetmesh import enclosed_volume, hemisphere_surface, mesh_hemisphere
from sim.geometry.volume import tet_volumes
from sim.pulls import make_pulls, scene_with
from sim.scene import DEFAULT_SCENE, clamp_limit
from studyctl.cli import cli
from tests.helpers import icosphere

# -- Richardson and the GCI ------------------------------------------------------------------


@pytest.mark.parametrize("hs", [(1.0, 1.5, 2.25), (1.0, 1.3, 1.9), (0.0017, 0.0021, 0.0026)])
@pytest.mark.parametrize("C", [0.7, -2.0])
def test_richardson_recovers_an_exact_second_order_sequence(hs, C):
    f0 = 3.25
    C = C / hs[0] ** 2  # differences of order 1 whatever the unit of h (else round-off limits p to ~1e-9)
    f = [f0 + C * h**2 for h in hs]
    r = richardson(*f, *hs)
    assert r["status"] == "monotone"
    assert r["extrapolated"]
    assert abs(r["p"] - 2.0) < 1e-10
    assert abs(r["f_ext"] - f0) < 1e-10
    # Roache: GCI = 1.25 |e21| / (r21^p - 1), relative to the finest value
    r21 = hs[1] / hs[0]
    assert r["gci"] == pytest.approx(1.25 * abs((f[1] - f[0]) / f[0]) / (r21**2 - 1), rel=1e-9)
    assert r["band"][0] < f0 < r["band"][1]  # the band covers the exact value (Fs = 1.25 > 1)


def test_richardson_other_orders_and_two_meshes():
    hs = (1.0, 1.4, 2.0)
    f = [1.0 + 0.3 * h**1.5 for h in hs]
    r = richardson(*f, *hs)
    assert abs(r["p"] - 1.5) < 1e-10
    assert abs(r["f_ext"] - 1.0) < 1e-10
    r2 = richardson2(1.0 + 0.3 * 1.0**2, 1.0 + 0.3 * 1.6**2, 1.0, 1.6)  # two meshes: assumed order 2, Fs = 3
    assert r2["f_ext"] == pytest.approx(1.0, abs=1e-12)
    assert r2["fs"] == 3.0
    assert r2["status"] == "two meshes"
    assert converge([3.0, 2.0, 1.5], [3e-3, 2e-3, 1.5e-3])["f1"] == 1.5  # any order in, finest first
    with pytest.raises(ValueError):
        richardson(1, 2, 3, 2.0, 1.0, 3.0)


@pytest.mark.parametrize("f, status", [((1.00, 1.02, 0.99), "oscillatory"), ((1.00, 1.03, 1.04), "diverging"),
                                       ((1.0, 1.0 + 1e-6, 1.2), "order out of range")])
def test_richardson_falls_back_to_a_conservative_band(f, status):
    hs = (1.0, 1.25, 1.5)
    r = richardson(*f, *hs)
    assert r["status"] == status
    assert not r["extrapolated"]
    assert r["f_ext"] == f[0]
    spread = max(abs(f[1] - f[0]), abs(f[2] - f[0])) / f[0]
    assert r["gci"] >= spread - 1e-15
    assert r["gci"] >= 3.0 * abs(f[1] - f[0]) / f[0] / (1.25**2 - 1) - 1e-15


def test_richardson_on_identical_values():
    r = richardson(2.0, 2.0, 2.0, 1.0, 2.0, 3.0)
    assert r["status"] == "converged"
    assert r["gci"] == 0.0


# -- meshes and P2 forces --------------------------------------------------------------------


def test_enclosed_volume_of_a_sphere():
    s = icosphere(radius=0.05, subdivisions=4)
    v = enclosed_volume(s.vertices, s.triangles)
    assert v == pytest.approx(4 / 3 * math.pi * 0.05**3, rel=0.01)


@pytest.fixture(scope="module")
def scene():
    return scene_with(DEFAULT_SCENE)


@pytest.fixture(scope="module")
def left(scene):
    verts, tris, _ = hemisphere_surface(scene.mesh, 0)
    meshes = [mesh_hemisphere(verts, tris, s * 1e-3) for s in (8.0, 6.0)]
    assert [m.source for m in meshes] == ["shipped", "shipped"]  # data/brain_tets_*mm.npz, hash-checked
    return verts, tris, meshes


def test_body_fitted_hemisphere_mesh_is_closed_and_right_sized(left):
    verts, tris, meshes = left
    surface = enclosed_volume(verts, tris)
    assert 4e-4 < surface < 6e-4  # one hemisphere: about half a litre
    for m in meshes:
        vol = tet_volumes(m.nodes, m.tets)
        assert np.all(vol > 0)
        assert abs(vol.sum() / surface - 1) < 0.03  # the envelope is 10% of the edge length
        # every node is used and every triangle face is shared by two tets or on the boundary
        assert len(np.unique(m.tets)) == len(m.nodes)
        faces = np.sort(m.tets[:, [[1, 2, 3], [0, 2, 3], [0, 1, 3], [0, 1, 2]]].reshape(-1, 3), axis=1)
        _, counts = np.unique(faces, axis=0, return_counts=True)
        assert counts.max() == 2
    assert len(meshes[1].tets) > len(meshes[0].tets)
    assert meshes[1].h < meshes[0].h


def test_p2_pull_forces_agree_between_two_mesh_sizes(scene, left):
    _, _, meshes = left
    pull = next(p for p in make_pulls(scene) if p.name == "left-lateral")
    pts, w = patch_area_points(scene.mesh, pull.vertex, 0.005)
    assert w.sum() == pytest.approx(1.0)
    assert np.all(np.linalg.norm(pts - scene.mesh.vertices[pull.vertex], axis=1) <= 0.005)
    forces = []
    for m in meshes:
        prob = build_problem(scene, 0, m)
        # the clamp: the scene's plane, and only nodes below it
        axis, limit = clamp_limit(scene)
        assert prob.fixed_nodes == int(np.sum(m.nodes[:, axis] <= limit)) > 0
        law = scene.spec.material.law
        K = pull_stiffness(prob, law, pts, w)  # the law's small-strain limit, per pascal of mu
        assert np.allclose(K, K.T)
        assert np.all(np.linalg.eigvalsh(K) > 0)
        if m is meshes[0]:  # it is linear elasticity at the law's moduli, assembled independently (LinearFem)
            from sim.models.fem import LinearFem, condense

            lin = LinearFem(m.nodes, m.tets, law.young(law.poisson) / law.shear_modulus, law.poisson, prob.space.fixed, order=2)
            assert np.allclose(condense(lin, tissue_pulls.grasp_matrix(prob, pts, w))[2], K, rtol=1e-8)
        forces.append(np.linalg.norm(K @ np.asarray(pull.direction)))
    assert abs(forces[1] / forces[0] - 1) < 0.03  # measured 0.4% (docs/reference.md)
    # the cortex's shear modulus and a 4 mm pull: hundredths of a newton
    assert 0.02 < forces[1] * scene.spec.material.law.shear_modulus * 0.004 < 0.08


def test_cli_bench_reference_quick(tmp_path):
    out = tmp_path / "ref"
    res = CliRunner().invoke(cli, ["bench", "reference", "--quick", "--json", "--out", str(out)])
    assert res.exit_code == 0, res.output
    data = json.loads(res.stdout)
    assert {s["pull"] for s in data["samples"]} == {"left-lateral", "left-anterior"}
    assert len(data["samples"]) == 4
    assert len(data["meshes"]) == 2
    for s in data["samples"]:
        assert s["status"] == "two meshes"
        assert len(s["forces_n"]) == 2
        assert all(f > 0 for f in s["forces_n"])
        assert s["band_n"][0] < s["forces_n"][-1] < s["band_n"][1]
    meta = json.loads((out / "reference.json").read_text())["meta"]
    assert meta["element"].startswith("P2")
    assert meta["law"]["law"] == "ogden"
    assert meta["formulation"].startswith("finite strain")
    assert all(s["converged"] for p in data["pulls"] for s in p["solves"])
    assert "| pull |" in (out / "reference.md").read_text()
    assert "Newton iterations" in (out / "reference.md").read_text()
    table = CliRunner().invoke(cli, ["bench", "reference", "--quick"])
    assert table.exit_code == 0
    assert "left-lateral" in table.output
    assert "GCI band" in table.output
    bad = CliRunner().invoke(cli, ["bench", "reference", "--sizes", "8"])
    assert bad.exit_code == 2


@pytest.mark.slow
def test_three_mesh_reference_band_is_within_the_jnd():
    cfg = reference.ReferenceConfig(pulls=("left-lateral",), samples=1)
    data = reference.run_reference(cfg)
    (s,) = data["samples"]
    assert len(s["forces_n"]) == 3
    assert s["status"] in ("monotone", "oscillatory", "diverging", "order out of range")
    assert s["gci"] < 0.10
    assert s["within_jnd_rel"]


def test_combined_sample_by_hand():
    """Magnitudes 1.00 / 0.95 / 0.94 N at h = 4 / 2 / 1 mm (ratio 2): R = 0.2, p = log2(5),
    extrapolated 0.94 - 0.01 / 4 = 0.9375 N, GCI 1.25 x (0.01 / 0.94) / 4; the finest mesh's
    direction, scaled to that magnitude."""
    forces = [np.array([0.0, 1.0, 0.0]), np.array([0.0, 0.95, 0.0]), np.array([0.0, 0.94 * 0.8, 0.94 * 0.6])]
    hs = [0.004, 0.002, 0.001]
    c = tissue_pulls.combined_sample(forces, hs)
    assert c["status"] == "monotone"
    assert c["order"] == pytest.approx(np.log(5) / np.log(2))
    assert c["force_n"] == pytest.approx(0.9375)
    assert np.allclose(c["force"], [0.0, 0.9375 * 0.8, 0.9375 * 0.6])
    assert c["band_rel"] == pytest.approx(1.25 * (0.01 / 0.94) / 4)


def test_the_shipped_solves_are_the_solvers_and_hash_checked(scene, tmp_path, monkeypatch):
    """A shipped entry is what the solver gives for its pull (solved again here, regional, on the
    16 mm mesh, at two of its records), and a damaged file is refused by name."""
    info = json.loads(tissue_pulls.SHIPPED_PULLS_INFO.read_text())
    assert info["law"] == scene.spec.material.law.params()
    entries = {(e["pull"], e["size_mm"]): e for e in info["entries"] if e["shape"] == 0}
    # 26 pulls x the full bench's 8, 6, 4 mm, and the quick benches' 18 (six test places) x 20, 16 mm
    assert len(entries) == 26 * 3 + 18 * 2
    # and every other law of the ensemble, and each of the literature's regional contrasts, on each group's coarsest mesh
    shapes = sorted({e["shape"] for e in info["ensemble"]})
    assert len([e for e in info["entries"] if e["shape"] > 0]) == (26 + 18) * (len(shapes) - 1 + len(info["contrast"]))
    for e in entries.values():  # a solve that stopped says why and how far it got
        assert e["converged"] or (e["reason"] and 0 <= e.get("reached_mm", 0.0) < 12.0)
    assert entries[("left-lateral", 4.0)]["converged"]  # the hands
    assert entries[("right-lateral", 4.0)]["converged"]
    # re-solved on the quick pair's 16 mm mesh (seconds; the regional 8 mm solves take minutes to
    # half an hour), with the scene's white matter: the key names the regions, the solve has them
    from analysis.verification.accuracy import quick_config as quick_accuracy
    from analysis.verification.regions import scene_regions
    from sim.pulls import test_pulls

    pull = next(p for p in test_pulls(scene, quick_accuracy().test_places) if p.name == "test2-across")
    verts, tris, _ = hemisphere_surface(scene.mesh, pull.hemisphere)
    body = mesh_hemisphere(verts, tris, 0.016)
    rng, regional = tissue_pulls.truth_range(scene), scene_regions(scene)
    assert regional.white is not None  # the shipped brain has white matter
    key = tissue_pulls.pull_key(body, scene, scene.spec.material.law, 0.005, pull, rng, regional)
    assert key != tissue_pulls.pull_key(body, scene, scene.spec.material.law, 0.005, pull, rng)  # cortex alone is another solve
    assert entries[("test2-across", 16.0)]["key"] == key
    xs = np.array([0.0005, 0.001])  # its records: the finer meshes follow a pull only while the coarsest is decided
    shipped = tissue_pulls.stored_solve(key, xs)
    again = tissue_pulls.solve_pull(build_problem(scene, pull.hemisphere, body), scene.spec.material.law,
                                    *patch_area_points(scene.mesh, pull.vertex, 0.005), np.asarray(pull.direction), xs,
                                    stretch_range=regional.ranges(), regional=regional)
    assert again["converged"]
    assert np.allclose(again["force_per_pa"], shipped["force_per_pa"], rtol=1e-6)
    assert np.isfinite(shipped["support"]).all()  # a regional solve records every field
    assert np.allclose(again["support"], shipped["support"], rtol=1e-6, atol=1e-9)
    bad = tmp_path / "reference_pulls.npz"
    bad.write_bytes(tissue_pulls.SHIPPED_PULLS.read_bytes()[:-10] + b"0123456789")
    monkeypatch.setattr(tissue_pulls, "SHIPPED_PULLS", bad)
    monkeypatch.setattr(tissue_pulls, "_SHIPPED", None)
    with pytest.raises(tissue_pulls.ReferenceDataError, match="damaged"):
        tissue_pulls.shipped_solves()


def test_the_quick_benches_and_model_check_solve_nothing_on_an_empty_cache(tmp_path, monkeypatch):
    """Every solve `--quick` asks for (the accuracy bench, hence `model check --quick`, and the
    reference bench) is shipped: an empty cache costs seconds, not minutes of finite-strain solves."""
    from analysis.verification.accuracy import quick_config as quick_accuracy
    from analysis.verification.accuracy import sample_displacements
    from sim.pulls import test_pulls

    monkeypatch.setenv("BRAINSIM_CACHE", str(tmp_path / "empty"))
    scene = scene_with(DEFAULT_SCENE)
    acc = quick_accuracy()
    pulls = make_pulls(scene) + test_pulls(scene, acc.test_places)
    assert tissue_pulls.unsolved(DEFAULT_SCENE, pulls, sample_displacements(acc), acc.reference_sizes_mm) == {20.0: 0, 16.0: 0}
    # and the ensemble's other laws on the coarsest mesh (the truth's law band)
    from analysis.verification.truth_band import scene_ensemble, shapes

    for shape in shapes(scene_ensemble(scene))[1:]:
        assert tissue_pulls.unsolved(DEFAULT_SCENE, pulls, sample_displacements(acc), (20.0,), law=shape) == {20.0: 0}
    ref = reference.quick_config()
    chosen = [p for p in make_pulls(scene) if p.name in ref.pulls]
    xs = tissue_pulls.pull_samples(ref.max_pull, ref.samples)
    assert tissue_pulls.unsolved(DEFAULT_SCENE, chosen, xs, ref.sizes_mm) == {20.0: 0, 16.0: 0}
    assert not (tmp_path / "empty").exists()  # nothing was solved, so nothing cached


def test_samples_past_a_stopped_solve_have_no_reference_and_are_not_judged():
    """A pull whose solve stopped on one mesh: its later samples carry no reference, the
    calibration scale and the rows leave them out, and the others are judged as before."""
    from analysis.verification.accuracy import calibration_scale, compare
    from sim.pulls import Pull

    xs = np.array([0.004, 0.008])
    hs = [0.0026, 0.0023, 0.0017]
    good = np.stack([np.outer(xs, [0.0, 0.0, 10.0 * k]) for k in (1.02, 1.01, 1.0)])  # (sizes, n, 3) per pascal
    stopped = good.copy()
    stopped[2, 1] = np.nan  # the finest mesh did not reach 8 mm
    refs = {"a": {"force_per_pa": good, "h_m": hs, "solves": [{"converged": True, "size_mm": s} for s in (8, 6, 4)]},
            "b": {"force_per_pa": stopped, "h_m": hs, "solves": [{"converged": True, "size_mm": 8}, {"converged": True, "size_mm": 6},
                                                                   {"converged": False, "size_mm": 4, "reason": "tangent singular"}]}}

    def cells(name):
        out = []
        for k in range(len(xs)):
            c = tissue_pulls.combined_sample(refs[name]["force_per_pa"][:, k] * 100.0, hs)
            out.append(c | {"mesh_band_rel": c["band_rel"], "law_band_rel": 0.0, "support_share_outside": 0.0, "max_abs_j_minus_1": 0.0,
                            "decided": bool(np.isfinite(c["force_n"])), "truth": "" if np.isfinite(c["force_n"]) else "undecided",
                            "reason": "" if np.isfinite(c["force_n"]) else "no reference force"})
        return out

    pulls = [Pull("a", 1, (0.0, 0.0, 0.0), (0.0, 0.0, 1.0), 0), Pull("b", 2, (0.0, 0.0, 0.0), (0.0, 0.0, 1.0), 0)]
    ref = [cells("a"), cells("b")]
    assert np.isfinite(ref[1][0]["force_n"])
    assert np.isnan(ref[1][1]["force_n"])
    assert ref[1][1]["status"] == "not solved"
    ok, why = tissue_pulls.reached(refs)["b"]
    assert ok.tolist() == [True, False]
    assert "4 mm" in why
    assert "tangent singular" in why
    R = np.array([[c["force_n"] for c in row] for row in ref])
    assert calibration_scale(np.full(4, 2.0), R.ravel() * 0 + np.array([4.0, 4.0, 4.0, np.nan])) == pytest.approx(2.0)
    model = {"model": "m", "setting": "s", "force": -np.stack([[[0.0, 0.0, R[0, k]] for k in range(2)]] * 2),
             "tick_us": 1.0, "frame_ms": 1.0, "frame_ms_p99": 1.0, "build_s": 0.0, "unstable": 0}
    model["force"][1, 1] = [0.0, 0.0, -99.0]  # far off where there is no reference: must not count
    rows, samples = compare(ref, [model], pulls, 1, xs)
    raw = rows[0]
    assert raw["n_test"] == 1
    assert raw["within"] == 1
    assert raw["force_error_max"] == pytest.approx(0.0, abs=1e-12)
    assert raw["pulls_within"] == 1
    assert raw["n_test_pulls"] == 1
    # a test pull with no reference at all is not counted as a pull within, nor as a pull judged
    refs["c"] = {**refs["b"], "force_per_pa": np.full_like(stopped, np.nan)}
    model["force"] = np.concatenate([model["force"], model["force"][:1]])
    rows, _ = compare(ref + [cells("c")], [model], pulls + [Pull("c", 3, (0.0, 0.0, 0.0), (0.0, 0.0, 1.0), 0)], 1, xs)
    assert rows[0]["n_test"] == 1
    assert rows[0]["pulls_within"] == 1
    assert rows[0]["n_test_pulls"] == 1
    assert not any(s["pull"] == "b" and s["displacement_mm"] == 8.0 for s in samples)


def test_finer_meshes_follow_a_pull_only_as_far_as_the_coarsest_got(scene, monkeypatch):
    """Where the coarsest mesh's solve stopped, the finer meshes are asked only up to its last
    record (a sample needs every mesh); and only as long as its state has at most FOLLOW_SHARE
    of its energy outside the data's stretches (beyond, no sample can be decided)."""
    pulls = [p for p in make_pulls(scene) if p.name in ("left-lateral", "left-anterior")]
    xs = np.array([0.004, 0.008, 0.012])
    asked = []

    def fake_run(tasks, jobs, progress):
        out = []
        for t in tasks:
            asked.append((t[3].name, t[2], t[6]))
            f = np.ones((len(xs), 3))
            sup = np.zeros((len(xs), 4))
            if t[3].name == "left-anterior" and t[2] == 8.0:
                f[2] = np.nan  # stopped between 8 and 12 mm on the coarsest mesh
                sup[2] = np.nan
            if t[3].name == "left-lateral" and t[2] == 8.0:
                sup[2, 0] = tissue_pulls.FOLLOW_SHARE + 0.01  # its 12 mm state rests mostly beyond the data
            out.append({"force_per_pa": f, "support": sup, "h_m": t[2] * 1e-3, "converged": not np.isnan(f).any(), "key": "k"})
        return out

    monkeypatch.setattr(tissue_pulls, "_premesh", lambda *a: set())
    monkeypatch.setattr(tissue_pulls, "_run", fake_run)
    refs = tissue_pulls.pull_references(DEFAULT_SCENE, pulls, xs, (8.0, 6.0, 4.0))
    assert asked[:2] == [("left-lateral", 8.0, 0.012), ("left-anterior", 8.0, 0.012)]  # the coarsest first
    assert sorted(asked[2:]) == sorted([(n, s, 0.008) for s in (4.0, 6.0) for n in ("left-lateral", "left-anterior")])
    assert refs["pulls"]["left-anterior"]["force_per_pa"].shape == (3, 3, 3)


def test_a_stored_solve_that_stopped_beyond_the_records_asked_serves_them_as_converged(tmp_path, monkeypatch):
    """A solve cached by a longer pull (say `bench accuracy --quick`'s 24 mm) that stopped at
    12.5 mm holds converged states up to there: a shorter request is converged, a longer not."""
    import numpy as np

    from analysis.verification import tissue_pulls

    monkeypatch.setenv("BRAINSIM_CACHE", str(tmp_path))
    xs = np.array([0.004, 0.008, 0.016])
    force = np.array([[1.0, 0.0, 0.0], [2.0, 0.0, 0.0], [np.nan, np.nan, np.nan]])
    tissue_pulls._cache("k", xs, force, None, np.zeros((3, 4)), {"converged": False, "reason": "diverging", "reached_mm": 12.5})
    short = tissue_pulls.stored_solve("k", xs[:2])
    assert short["converged"]
    assert "stopped at 12.5 mm (diverging)" in short["reason"]
    assert not tissue_pulls.stored_solve("k", xs)["converged"]
