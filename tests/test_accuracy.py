"""Accuracy bench: the neo-Hookean reference against linear FEM, the error and JND arithmetic
worked by hand, a small bench end to end through the CLI and into the report."""

import json

import numpy as np
import pytest
from click.testing import CliRunner

from analysis import accuracy
from analysis.accuracy import Setting, compare, pareto
from sim.errors import ParameterError
from sim.reference import Pull, make_pulls, reference_pull, scene_with
from sim.scene import DEFAULT_SCENE
from studyctl.cli import cli


@pytest.fixture(scope="module")
def scene():
    return scene_with(DEFAULT_SCENE)


def test_pulls_are_three_points_two_tangent_directions(scene):
    pulls = make_pulls(scene)
    assert len(pulls) == 6 and len({p.vertex for p in pulls}) == 3
    for p in pulls:
        n = scene.mesh.vertex_normals[p.vertex]
        assert abs(np.linalg.norm(p.direction) - 1) < 1e-12 and abs(np.dot(p.direction, n)) < 1e-9


def test_neo_hookean_reference_is_the_linear_fem_for_small_pulls(scene):
    """Independent check of the reference: at 0.25-0.5 mm the strains are ~1%, where the
    neo-Hookean and linear solutions on the same mesh must agree (forces per pascal)."""
    from sim.models.fem import build
    from sim.scene import ModelSpec

    pull = make_pulls(scene)[0]
    xs = np.array([0.00025, 0.0005])
    ref = reference_pull(DEFAULT_SCENE, 0.008, pull, xs, use_cache=False)
    assert ref["converged"]
    lin = build(scene.mesh, ModelSpec(name="fem", options={"resolution": 0.008}), scene_with(DEFAULT_SCENE, young=1.0))
    K = np.asarray(lin.grasp(pull.point, 0).law.K).reshape(3, 3)
    for k, x in enumerate(xs):
        f_lin = -K @ (np.asarray(pull.direction) * x)
        assert np.linalg.norm(ref["force_per_pa"][k] - f_lin) < 0.01 * np.linalg.norm(f_lin)
    # the grasp point follows the pull (the patch mean is held there; the vertex is close)
    assert np.linalg.norm(ref["grasp"][-1] - np.asarray(pull.direction) * xs[-1]) < 0.3 * xs[-1]


def test_reference_needs_equal_load_steps(scene):
    with pytest.raises(ParameterError, match="equal steps"):
        reference_pull(DEFAULT_SCENE, 0.008, make_pulls(scene)[0], [0.001, 0.005])


def _pull():
    return Pull("p", 0, (0.0, 0.0, 0.0), (1.0, 0.0, 0.0), 0)


def test_errors_and_jnd_bands_by_hand():
    """0.4 N reference, model 20% high: inside the 25% band; 1.0 N, 20% high: outside the 10%."""
    ref = {"force_per_pa": np.array([[0.4, 0, 0], [1.0, 0, 0]]), "grasp": np.zeros((2, 3)),
           "surface": np.zeros((2, 4, 3), dtype=np.float32)}
    surf = np.zeros((2, 4, 3), dtype=np.float32)
    surf[:, :, 2] = 0.002  # every vertex 2 mm off: RMS 2 mm
    model = {"model": "m", "setting": "s", "force": np.array([[[0.48, 0, 0], [0.0, 1.2, 0]]]),
             "grasp": np.array([[[0.001, 0, 0], [0, 0, 0]]]), "surface": [surf],
             "tick_us": 1.0, "frame_ms": 2.0, "frame_ms_p99": 3.0, "build_s": 0.0, "unstable": False}
    rows, samples = compare([ref], [model], [_pull()], np.array([0.01, 0.02]), young=1.0)
    r = rows[0]
    assert r["force_error"] == pytest.approx(0.2) and r["within_jnd"] == 0.5
    assert [s["within_jnd"] for s in samples] == [True, False]
    assert r["angle_deg"] == pytest.approx(45.0)  # 0 and 90 degrees
    assert r["grasp_error_mm"] == pytest.approx(0.5) and r["surface_rms_mm"] == pytest.approx(2.0, rel=1e-6)


def test_pareto_front():
    rows = [{"force_error": 0.1, "frame_ms": 10}, {"force_error": 0.2, "frame_ms": 1}, {"force_error": 0.3, "frame_ms": 5},
            {"force_error": 0.1, "frame_ms": 20}]
    assert pareto(rows) == [True, True, False, False]


@pytest.fixture(scope="module")
def small_bench(tmp_path_factory, monkeypatch_module):
    """Three settings, 8 mm reference, two 4 mm samples: the bench end to end in seconds."""
    tiny = accuracy.AccuracyConfig(samples=2, max_pull=0.008, reference_resolution=0.008, quick=True, settings=(
        Setting("plate_spring", "calibrated", (("variant", "continuous"), ("params", "scene"))),
        Setting("fem", "linear-8mm", (("formulation", "linear"), ("resolution", 0.008))),
        Setting("mass_spring", "local-global-8mm", (("integrator", "local-global"), ("resolution", 0.008)))))
    monkeypatch_module.setattr(accuracy, "quick_config", lambda **kw: tiny)
    out = tmp_path_factory.mktemp("acc")
    res = CliRunner().invoke(cli, ["bench", "accuracy", "--quick", "--json", "--jobs", "1", "--out", str(out)])
    assert res.exit_code == 0, res.output
    return json.loads(res.output), out


@pytest.fixture(scope="module")
def monkeypatch_module():
    mp = pytest.MonkeyPatch()
    yield mp
    mp.undo()


def test_bench_accuracy_cli_rows_and_files(small_bench):
    out, d = small_bench
    rows = {r["setting"]: r for r in out["rows"]}
    assert set(rows) == {"calibrated", "linear-8mm", "local-global-8mm"}
    for r in rows.values():
        assert {"model", "setting", "force_error", "within_jnd", "tick_us", "frame_ms"} <= set(r)
        assert 0.0 <= r["within_jnd"] <= 1.0 and r["tick_us"] > 0 and r["frame_ms"] > 0
    # same mesh, pulls of 4-8 mm: linear and neo-Hookean differ by a few percent only
    assert rows["linear-8mm"]["force_error"] < 0.1
    assert out["meta"]["reference"]["setting"] == "neo-hookean-8mm" and out["meta"]["reference"]["converged"]
    assert len(out["samples"]) == 3 * 6 * 2
    assert sorted(p.name for p in d.iterdir()) == ["accuracy.csv", "accuracy.json", "accuracy.md", "pareto.png", "pareto.svg", "samples.csv"]


def test_report_carries_the_accuracy_table_and_pareto_plot(small_bench, small_study, tmp_path):
    _, d = small_bench
    db = small_study
    res = CliRunner().invoke(cli, ["report", "table1", "--db", str(db), "--format", "html", "--accuracy", str(d / "accuracy.json"),
                                   "--out", str(tmp_path / "r.html")])
    assert res.exit_code == 0, res.output
    page = (tmp_path / "r.html").read_text()
    assert "Model error against run time" in page and 'alt="pareto"' in page and "linear-8mm" in page
    md = CliRunner().invoke(cli, ["report", "table1", "--db", str(db), "--accuracy", str(d / "accuracy.json")]).output
    assert "| fem | linear-8mm |" in md and "14.69" in md
    (tmp_path / "bad.json").write_text("{}")
    res = CliRunner().invoke(cli, ["report", "table1", "--db", str(db), "--accuracy", str(tmp_path / "bad.json")])
    assert res.exit_code == 1 and "bad.json: not a `studyctl bench accuracy` result" in res.output
