"""Accuracy bench: the pulls, the calibration, error,
JND, band and Wilson arithmetic worked by hand; the held-out pulls; a small bench end to end
through the CLI and into the report."""

import json
import re

import numpy as np
import pytest
from click.testing import CliRunner

from analysis.reports.accuracy_tables import meets_text, tables, within_text
from analysis.reports.plots import pareto
from analysis.statistics.stats import wilson
from analysis.verification import accuracy
from analysis.verification.accuracy import Setting, class_best, compare, coupling_bound
from sim.pulls import Pull, make_pulls, scene_with
from sim.scene import DEFAULT_SCENE
from studyctl.cli import cli


@pytest.fixture(scope="module")
def scene():
    return scene_with(DEFAULT_SCENE)


def test_pulls_are_three_points_two_tangent_directions(scene):
    pulls = make_pulls(scene)
    assert len(pulls) == 6
    assert len({p.vertex for p in pulls}) == 3
    for p in pulls:
        n = scene.mesh.vertex_normals[p.vertex]
        assert abs(np.linalg.norm(p.direction) - 1) < 1e-12
        assert abs(np.dot(p.direction, n)) < 1e-9


def _pull(name="p"):
    return Pull(name, 0, (0.0, 0.0, 0.0), (1.0, 0.0, 0.0), 0)


def _ref(f, half=0.0, decided=True, truth=""):
    f = np.asarray(f, dtype=float)
    n = float(np.linalg.norm(f))
    return {"force": f, "force_n": n, "band_half_n": half, "band_rel": half / n, "mesh_band_rel": half / n, "law_band_rel": 0.0,
            "support_share_outside": 0.0, "max_abs_j_minus_1": 0.0, "decided": decided, "truth": truth,
            "reason": "" if decided else "a reason"}


def test_calibration_scale_errors_verdicts_and_wilson_by_hand():
    """Calibration pull: reference 0.4 and 1.0 N, model half of it: scale 2. Test pull: model
    0.24 N against 0.4 N (raw 40% off; calibrated 0.48 N, 20%: inside the 25% band) and 0.6 N
    against 1.0 N (calibrated 1.2 N, 20%: outside the 10% band)."""
    ref = [[_ref([0.4, 0, 0]), _ref([1.0, 0, 0])],
           [_ref([0.4, 0, 0], half=0.05), _ref([1.0, 0, 0], half=0.01)]]
    model = {"model": "m", "setting": "s", "force": np.array([[[-0.2, 0, 0], [-0.5, 0, 0]], [[-0.24, 0, 0], [0.0, -0.6, 0]]]),
             "tick_us": 1.0, "frame_ms": 2.0, "frame_ms_p99": 3.0, "build_s": 0.0, "unstable": False}
    rows, samples = compare(ref, [model], [_pull("c"), _pull("t")], 1, np.array([0.01, 0.02]))
    raw, cal = rows
    assert raw["calibration"] == "raw"
    assert raw["scale"] == 1.0
    assert cal["scale"] == pytest.approx(2.0)
    assert raw["force_error"] == pytest.approx(0.4)
    assert raw["within_jnd"] == 0.0
    assert raw["n_test"] == 2
    assert cal["force_error"] == pytest.approx(0.2)
    assert cal["within_jnd"] == 0.5
    assert cal["calibration_error"] == pytest.approx(0.0)
    # 0.48 vs 0.4 +- 0.05: the band reaches past the JND on one side, not the other: undecided;
    # 1.2 vs 1.0 +- 0.01: outside for every value in the band
    assert (cal["within"], cal["outside"], cal["undecided"]) == (0, 1, 1)
    assert raw["angle_deg"] == pytest.approx(45.0)  # 0 and 90 degrees (the force on the hand is minus the tissue's)
    # Wilson's interval for 1 of 2 at 95%, worked by hand: (k + z^2/2) / (n + z^2) -+ z / (n + z^2) sqrt(k (n - k) / n + z^2 / 4)
    z = 1.959964
    centre, half = (1 + z * z / 2) / (2 + z * z), z / (2 + z * z) * np.sqrt(0.5 + z * z / 4)
    assert (cal["within_jnd_low"], cal["within_jnd_high"]) == pytest.approx((centre - half, centre + half), abs=1e-6)
    assert [s["set"] for s in samples if s["calibration"] == "raw"] == ["calibration"] * 2 + ["test"] * 2


def test_samples_where_the_truth_is_not_decided_carry_its_verdict_and_are_not_rated():
    """Test pull: 0.4 N decided, 1.0 N extrapolated, 0.2 N undecided; a model exact at the first
    and 50% off at the others is within the JND on 1 of 1 decided samples, with 1 extrapolated
    and 1 undecided beside; the calibration scale is fitted on the decided calibration sample only."""
    far = _ref([1.0, 0, 0], decided=False, truth="extrapolated")
    ref = [[_ref([0.4, 0, 0]), far, _ref([0.2, 0, 0])], [_ref([0.4, 0, 0]), far, _ref([0.2, 0, 0], decided=False, truth="undecided")]]
    model = {"model": "m", "setting": "s", "force": np.array([[[-0.2, 0, 0], [-0.1, 0, 0], [-0.1, 0, 0]],
                                                              [[-0.4, 0, 0], [-1.5, 0, 0], [-0.3, 0, 0]]]),
             "tick_us": 1.0, "frame_ms": 2.0, "frame_ms_p99": 3.0, "build_s": 0.0, "unstable": False}
    rows, samples = compare(ref, [model], [_pull("c"), _pull("t")], 1, np.array([0.01, 0.02, 0.03]))
    raw, cal = rows
    assert cal["scale"] == pytest.approx(2.0)  # the two decided calibration samples (the extrapolated one would give 10)
    assert raw["n_test"] == 1
    assert raw["within_jnd"] == 1.0
    assert raw["within"] == 1
    assert raw["extrapolated"] == 1
    assert raw["truth_undecided"] == 1
    assert raw["force_error_max"] == pytest.approx(0.0)
    test = [s for s in samples if s["set"] == "test" and s["calibration"] == "raw"]
    assert [s["verdict"] for s in test] == ["within", "extrapolated", "undecided"]
    assert [s["decided"] for s in test] == [True, False, False]
    assert test[1]["reason"] == "a reason"
    by = accuracy.breakdown(samples, "force_band")
    raw_rows = {r["force_band"]: r for r in by if r["calibration"] == "raw"}
    assert raw_rows["0.1-0.5 N"]["decided"] == 1
    assert raw_rows["0.1-0.5 N"]["within"] == 1
    assert raw_rows["0.1-0.5 N"]["undecided"] == 1
    assert raw_rows["above 0.5 N"]["decided"] == 0
    assert raw_rows["above 0.5 N"]["extrapolated"] == 1


def test_verdict_against_the_band():
    assert accuracy.verdict(0.45, 0.4, 0.0) == "within"  # 12.5% of 0.4 N, band 25%
    assert accuracy.verdict(0.45, 0.4, 0.06) == "undecided"
    assert accuracy.verdict(1.2, 1.0, 0.05) == "outside"  # 20% off, 10% band, 5% reference band
    assert accuracy.verdict(1.08, 1.0, 0.01) == "within"


def test_test_pulls_are_held_out(scene):
    calib, test = make_pulls(scene), accuracy.test_pulls(scene)
    places = {p.vertex for p in test}
    assert len(places) == 10
    assert len(test) == 20
    assert {p.hemisphere for p in test} == {0, 1}
    for p in test:
        n = scene.mesh.vertex_normals[p.vertex]
        assert abs(np.linalg.norm(p.direction) - 1) < 1e-12
        assert abs(np.dot(p.direction, n)) < 1e-9
        assert min(np.linalg.norm(np.subtract(p.point, c.point)) for c in calib) >= 0.020
        # not a site of the located model's field (the ico4 subset: first 2562 of each hemisphere)
        assert p.vertex % 10242 >= 2562
    a, b = test[0], test[1]
    assert a.vertex == b.vertex  # two orthogonal tangents
    assert abs(np.dot(a.direction, b.direction)) < 1e-9


def test_pareto_front():
    rows = [{"force_error": 0.1, "frame_ms": 10}, {"force_error": 0.2, "frame_ms": 1}, {"force_error": 0.3, "frame_ms": 5},
            {"force_error": 0.1, "frame_ms": 20}]
    assert pareto(rows) == [True, True, False, False]


def _row(model, setting, calibration, within, error, ms, p99, unstable=0, n=77):
    return {"model": model, "setting": setting, "calibration": calibration, "scale": 1.0, "within_jnd": within, "within_jnd_low": within - 0.1,
            "within_jnd_high": within + 0.1, "force_error": error, "pulls_within": 0, "n_test_pulls": 9, "frame_ms": ms, "frame_ms_p99": p99,
            "unstable_pulls": unstable, "n_test": n, "n_within_jnd": round(within * n)}


def test_the_fewest_decided_samples_is_the_smallest_n_whose_every_wilson_interval_is_narrow_enough():
    def widest(n):
        return max((wilson(k, n)[1] - wilson(k, n)[0]) / 2 for k in range(n + 1))

    assert widest(accuracy.MIN_DECIDED) <= accuracy.RATE_HALF_WIDTH
    assert widest(accuracy.MIN_DECIDED - 1) > accuracy.RATE_HALF_WIDTH


def test_a_class_with_too_few_decided_samples_gets_no_verdict():
    """A quick bench judged each model on one decided sample and printed "meets target: yes"."""
    b = class_best([_row("fem", "linear-8mm", "raw", 1.0, 0.02, 1.0, 2.0, n=1)])[0]
    assert b["meets_target"] is None
    assert b["setting"] is None
    assert b["why"] == f"too few decided samples in every configuration (1 < {accuracy.MIN_DECIDED})"
    assert b["left_out"] == {"linear-8mm": f"too few decided samples (1 < {accuracy.MIN_DECIDED})"}


def test_a_configuration_with_too_few_decided_samples_is_not_the_best():
    rows = [_row("fem", "few", "raw", 1.0, 0.01, 1.0, 2.0, n=3), _row("fem", "many", "raw", 0.5, 0.2, 1.0, 2.0)]
    assert class_best(rows)[0]["setting"] == "many"


def test_a_row_below_the_minimum_shows_its_counts_and_no_rate():
    text = within_text(_row("fem", "linear-8mm", "raw", 1.0, 0.02, 1.0, 2.0, n=1))
    assert text == f"1 of 1 within; no rate: too few decided samples (1 < {accuracy.MIN_DECIDED})"


def test_a_rate_names_its_denominator():
    assert within_text(_row("fem", "linear-8mm", "raw", 0.5, 0.02, 1.0, 2.0, n=40)).endswith("] of 40")


def test_no_verdict_is_neither_yes_nor_no():
    assert meets_text({"meets_target": None}) == "no verdict"


def _quick_rows():
    """A quick bench run with `--test-places 20`: 240 decided samples a row, 95% within."""
    return [_row("fem", "linear-8mm", "raw", 0.95, 0.02, 1.0, 2.0, n=240)]


def test_rows_past_the_minimum_meet_the_target_in_the_full_bench():
    assert class_best(_quick_rows())[0]["meets_target"] is True


def test_the_quick_bench_gives_no_verdict_even_past_the_minimum():
    assert class_best(_quick_rows(), quick=True)[0]["meets_target"] is None


def test_the_quick_bench_says_why_it_gives_no_verdict():
    assert class_best(_quick_rows(), quick=True)[0]["why"] == f"quick bench: {accuracy.QUICK_REASON}"


def _quick_result():
    ref = {"setting": "fem p2 20/16 mm", "formulation": "finite strain", "band_rel_median": 0.01, "band_rel_max": 0.02}
    meta = {"reference": ref, "calibration_pulls": [1], "test_pulls": [1] * 40, "max_pull_m": 0.012, "pull_speed_m_per_s": 0.005,
            "samples_per_pull": 6, "young_pa": 1000.0, "scene_young_pa": 1000.0, "quick": True}
    row = _quick_rows()[0] | {"force_error_max": 0.05, "extrapolated": 0, "truth_undecided": 0, "within": 228, "outside": 12, "undecided": 0,
                              "angle_deg": 1.0, "angle_deg_max": 2.0, "tick_us": 1.0}
    return {"rows": [row], "meta": meta}


def test_the_quick_bench_s_table_says_no_verdict_past_the_minimum():
    _, best = tables(_quick_result())
    assert best.rows[0][best.columns.index("meets target")] == "no verdict"


def test_the_quick_bench_s_intro_says_why_it_decides_nothing():
    every, _ = tables(_quick_result())
    assert f"The quick bench is a smoke run: it decides nothing ({accuracy.QUICK_REASON})." in every.notes


def test_each_class_at_its_best_keeps_the_budget_and_gives_up_no_pull():
    rows = [_row("fem", "fast", "raw", 0.20, 0.5, 1.0, 2.0), _row("fem", "slow", "raw", 0.96, 0.04, 30.0, 600.0),
            _row("fem", "corot", "raw", 0.30, 0.4, 5.0, 8.0, unstable=4), _row("fem", "tie", "raw", 0.20, 0.5, 0.5, 0.9),
            _row("mass_spring", "lg", "raw", 0.85, 0.08, 3.0, 9.0), _row("mass_spring", "lg", "calibrated", 0.10, 0.4, 3.0, 9.0),
            _row("plate_spring", "only-slow", "raw", 0.9, 0.05, 40.0, 50.0)]
    best = {(b["model"], b["calibration"]): b for b in class_best(rows)}
    fem = best[("fem", "raw")]
    # the accurate row is over the 33 ms budget and the corotational one gave up: of the two
    # left at 20%, the faster wins the tie
    assert fem["setting"] == "tie"
    assert not fem["meets_target"]
    assert fem["left_out"] == {"slow": "frame p99 600 ms over the 33 ms budget", "corot": "gave up on a pull"}
    assert best[("mass_spring", "raw")]["meets_target"]
    assert not best[("mass_spring", "calibrated")]["meets_target"]
    assert best[("plate_spring", "raw")]["setting"] is None
    assert "no configuration" in best[("plate_spring", "raw")]["why"]
    assert class_best(rows, frame_budget_ms=1000.0)[0]["setting"] == "slow"


def test_coupling_bound_of_a_linear_tissue_is_the_series_springs():
    """Behind a coupling k a linear tissue K gives F = K k / (K + k) d: relative error K / (K + k)."""
    xs = np.array([0.004, 0.008, 0.012])
    ref = [[{"force_n": 50.0 * x} for x in xs] for _ in range(3)]
    assert coupling_bound(ref, 1, xs, 10000.0) == 1.0  # 0.5% off
    assert coupling_bound(ref, 1, xs, 100.0) == 0.0  # 33% off
    ref[2][2]["force_n"] = float("nan")  # a sample without a reference is not judged
    assert coupling_bound(ref, 1, xs, 10000.0) == 1.0


def test_the_pareto_plots_legend_covers_no_point():
    """Issue 28: inside the axes (lower left) the legend covered the located plate-spring's
    point, the best one: fast and accurate lies in that corner."""
    from analysis.reports.plots import _plt, pareto_figure

    rows = [{"model": m, "setting": s, "frame_ms": ms, "force_error": e} for m, s, ms, e in (
        ("plate_spring", "located", 0.05, 0.03), ("plate_spring", "scene-fit", 0.04, 0.3), ("fem", "linear-4mm", 2.0, 0.05),
        ("fem", "p2-4mm", 30.0, 0.02), ("mass_spring", "lg-4mm", 28.0, 0.2))]
    fig = pareto_figure(rows)
    fig.canvas.draw()
    ax = fig.axes[0]
    box = (ax.get_legend() or fig.legends[0]).get_window_extent()  # below the axes since issue 46 (a figure legend)
    points = ax.transData.transform([(r["frame_ms"], r["force_error"]) for r in rows])
    _plt().close(fig)
    assert not [p for p in points if box.x0 - 5 <= p[0] <= box.x1 + 5 and box.y0 - 5 <= p[1] <= box.y1 + 5]


@pytest.fixture(scope="module")
def small_bench(tmp_path_factory, monkeypatch_module):
    """Three settings, 20/16 mm reference (the finite-strain law), samples at 1 and 2 mm (where the truth is decided), two test
    places: the bench end to end in a minute or two (the reference solves are cached after)."""
    tiny = accuracy.AccuracyConfig(samples=2, max_pull=0.002, reference_sizes_mm=(20.0, 16.0), test_places=2,
                                   quick=True, settings=(
        Setting("plate_spring", "scene-fit", (("variant", "continuous"), ("params", "scene"))),
        Setting("fem", "linear-8mm", (("formulation", "linear"), ("resolution", 0.008))),
        Setting("mass_spring", "local-global-8mm", (("integrator", "local-global"), ("resolution", 0.008)))))
    monkeypatch_module.setattr(accuracy, "quick_config", lambda **kw: tiny)
    out = tmp_path_factory.mktemp("acc")
    res = CliRunner().invoke(cli, ["bench", "accuracy", "--quick", "--json", "--jobs", "1", "--out", str(out)])
    assert res.exit_code == 0, res.output
    small_bench_stderr.append(res.stderr)
    return json.loads(res.stdout), out  # stdout: the JSON alone


small_bench_stderr: list[str] = []


def test_bench_accuracy_says_where_it_is_on_stderr_off_a_terminal(small_bench):
    """`bench accuracy` in a log was silent for minutes."""
    assert re.search(r"^accuracy: reference, then models: \d+ of \d+$", small_bench_stderr[0], flags=re.M)


@pytest.fixture(scope="module")
def monkeypatch_module():
    mp = pytest.MonkeyPatch()
    yield mp
    mp.undo()


def test_bench_accuracy_cli_rows_and_files(small_bench):
    out, d = small_bench
    every = {(r["setting"], r["speed"], r["calibration"]): r for r in out["rows"]}
    assert set(every) == {(s, v, c) for s in ("scene-fit", "linear-8mm", "local-global-8mm") for v in ("quasi-static", "typical", "fast")
                          for c in ("raw", "calibrated")}
    # at the hands' speeds the viscoelastic truth rests on rates far beyond the data's: nothing decided, no error given
    for (setting, speed, cal), r in every.items():
        if speed != "quasi-static":
            assert r["n_test"] == 0 and r["force_error"] is None  # NaN, as JSON carries it
            assert r["extrapolated"] + r["truth_undecided"] == 4 * 2  # the 2 samples of each test pull
            assert r["no_reference"] == 4 * 4  # the 4 holds: the solves hold at 12 mm, this bench stops at 2 mm
            assert r["scale"] == every[(setting, "quasi-static", cal)]["scale"]  # one stiffness scale for every speed
    rows = {(s, c): r for (s, v, c), r in every.items() if v == "quasi-static"}
    for r in rows.values():
        assert r["n_test"] > 0
        assert r["withheld"] == f"too few decided samples ({r['n_test']} < {accuracy.MIN_DECIDED})"
        assert 0.0 <= r["within_jnd_low"] <= r["within_jnd"] <= r["within_jnd_high"] <= 1.0
        assert r["within"] + r["outside"] + r["undecided"] == r["n_test"]
        assert r["n_test"] + r["extrapolated"] + r["truth_undecided"] == 4 * 2
        assert r["tick_us"] > 0
        assert r["frame_ms"] > 0
        assert 0 <= r["angle_deg"] <= 180
    ref = out["meta"]["reference"]
    assert ref["converged"]
    assert ref["sizes_mm"] == [20.0, 16.0]
    assert ref["law"]["law"] == "ogden"
    assert ref["solves"] == 10 * 2
    assert len(out["meta"]["calibration_pulls"]) == 6
    assert len(out["meta"]["test_pulls"]) == 4
    # quasi-static, then typical and fast (their holds have no truth here, so no sample: as past a stopped solve)
    assert len(out["samples"]) == 3 * 2 * 10 * 2 + 2 * 3 * 2 * 10 * 2
    # the calibrated scale is the geometric mean of reference over model force on the decided calibration samples
    for (setting, cal), r in rows.items():
        if cal == "calibrated":
            c = [s for s in out["samples"] if s["setting"] == setting and s["calibration"] == "raw" and s["set"] == "calibration" and s["decided"]]
            assert r["scale"] == pytest.approx(np.exp(np.mean([np.log(s["reference_force_n"] / s["force_n"]) for s in c])))
    assert sorted(p.name for p in d.iterdir()) == ["accuracy.csv", "accuracy.json", "accuracy.md", "accuracy.tex", "pareto.png", "pareto.svg",
                                                   "samples.csv"]
    assert 0.0 <= out["meta"]["coupling_bound"]["scene"] <= out["meta"]["coupling_bound"]["omni_max"] <= 1.0
    assert {(b["model"], b["speed"], b["calibration"]) for b in out["best"]} == {(m, v, c) for m in ("plate_spring", "fem", "mass_spring")
                                                                                   for v in ("quasi-static", "typical", "fast") for c in ("raw", "calibrated")}
    assert {b["meets_target"] for b in out["best"]} == {None}  # a quick bench decides nothing
    md = (d / "accuracy.md").read_text()
    assert "Each class at its best" in md
    assert "Held-out samples per displacement (mm)" in md
    assert "| below 0.1 N |" in md
    # every sample says where the truth stands, and only decided ones carry a within/outside verdict
    for s in out["samples"]:
        assert s["verdict"] in (("within", "outside", "undecided") if s["decided"] else ("extrapolated", "undecided"))
        assert s["decided"] or s["reason"]
    assert [e["name"] for e in out["meta"]["reference"]["ensemble"]][0] == "chosen"
    # the shipped scene's truth names its pia-arachnoid's treatment: the parenchyma's force, the PAC left out, and why
    pac = out["meta"]["reference"]["pia_arachnoid"]
    assert pac["treatment"].startswith("not in this truth, which is the parenchyma's force") and "no sample would be decided" in pac["treatment"]


def test_the_quick_bench_says_it_decides_nothing(small_bench, monkeypatch):
    out, _ = small_bench
    monkeypatch.setattr(accuracy, "run_accuracy", lambda *a, **k: out)
    res = CliRunner().invoke(cli, ["bench", "accuracy", "--quick"])
    assert res.exit_code == 0, res.output
    assert accuracy.QUICK_NOTE in " ".join(res.output.split())  # rich wraps it to the terminal
    assert "meets target" in res.output
    assert " yes " not in res.output


def test_the_accuracy_tables_compile_and_fit_an_a4_page(small_bench, tmp_path):
    from analysis.reports.latex import document
    from tests.helpers import latex_problems

    _, d = small_bench
    tex = (d / "accuracy.tex").read_text()
    assert tex.count("\\begin{landscape}") == 2  # 12 and 9 columns turn the page
    assert "\\toprule" in tex
    assert "+-" not in tex
    assert latex_problems(document(tex), tmp_path) == []


def test_report_carries_the_accuracy_table_and_pareto_plot(small_bench, small_study, tmp_path):
    _, d = small_bench
    db = small_study
    res = CliRunner().invoke(cli, ["report", "table1", "--db", str(db), "--format", "html", "--accuracy", str(d / "accuracy.json"),
                                   "--out", str(tmp_path / "r.html")])
    assert res.exit_code == 0, res.output
    page = (tmp_path / "r.html").read_text()
    assert "Model error against run time" in page
    assert 'alt="pareto"' in page
    assert "linear-8mm" in page
    md = CliRunner().invoke(cli, ["report", "table1", "--db", str(db), "--accuracy", str(d / "accuracy.json")]).output
    assert "| fem | linear-8mm | raw |" in md
    assert "| fem | linear-8mm | calibrated |" in md
    assert "14.69" in md
    assert "no rate: too few decided samples" in md
    assert f"The quick bench is a smoke run: it decides nothing ({accuracy.QUICK_REASON})." in md
    tex = CliRunner().invoke(cli, ["report", "table1", "--db", str(db), "--format", "latex", "--accuracy", str(d / "accuracy.json")]).output
    assert "\\label{tab:accuracy:1}" in tex
    assert "linear-8mm" in tex
    (tmp_path / "bad.json").write_text("{}")
    res = CliRunner().invoke(cli, ["report", "table1", "--db", str(db), "--accuracy", str(tmp_path / "bad.json")])
    assert res.exit_code == 1
    assert "bad.json: not a `studyctl bench accuracy` result" in res.output


def test_a_scaled_truth_scales_every_members_force_and_decides_the_contrast_again():
    """`--young` scales the truth (forces with mu; bands and support not): the law's, the
    membrane's and the contrast's member forces too, and the verdict with the contrast is taken
    again at the new force (a 0.04 N sample with a 20% contrast spread: decided with it at 25% JND
    there, not at 0.6 N where the JND is 10%)."""
    c = {"force": np.array([0.04, 0.0, 0.0]), "force_n": 0.04, "band_half_n": 0.002, "band_rel": 0.05, "forces_n": [0.04],
         "law_forces_n": [0.04, 0.041], "membrane_forces_n": [0.03], "contrast_forces_n": [0.048], "contrast_band_rel": 0.2,
         "decided_share": 0.01, "decided_j": 0.01, "decided_on": "marginal share", "decided": True, "decided_with_contrast": True}
    out = accuracy._scaled({"pulls": {"p": [c]}}, 15.0)["pulls"]["p"][0]
    assert out["force_n"] == pytest.approx(0.6)
    assert out["law_forces_n"] == pytest.approx([0.6, 0.615])
    assert out["membrane_forces_n"] == pytest.approx([0.45])
    assert out["contrast_forces_n"] == pytest.approx([0.72])
    assert out["decided"] and out["decided_with_contrast"] is False
    assert accuracy._scaled({"pulls": {"p": [c | {"decided_with_contrast": None}]}}, 15.0)["pulls"]["p"][0]["decided_with_contrast"] is None


def test_a_speed_the_bench_does_not_know_is_refused_before_anything_runs(tmp_path):
    res = CliRunner().invoke(cli, ["bench", "accuracy", "--quick", "--speeds", "quasi-static,slow", "--out", str(tmp_path / "acc")])
    assert res.exit_code != 0 and "Traceback" not in res.output
    assert "speed 'slow'; allowed: quasi-static, typical, fast" in res.output
    assert not (tmp_path / "acc").exists()
