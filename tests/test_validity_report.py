"""`studyctl report validity` (issue 32, item 4): the construct-validity report of a study with
groups. One small synthetic study (15 participants in three groups, face-validity ratings, SUS,
a text field and a free-text question) is made once; the metrics are either its own or a table
built here with a known group difference and learning curve (monkeypatched in, fast)."""

import json
import re
import sqlite3
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from analysis.reports import validity_report as report_mod
from analysis.reports import validity_report as vr
from analysis.reports.latex import document
from analysis.validity.metrics import COLUMNS
from studyctl.store import Store
from studyctl.store.snapshot import read_study
from tests.helpers import fast_protocol, field_protocol, latex_problems, studyctl

ORDER = ["student", "resident", "neurosurgeon"]
SECRET = "SECRET-REMARK-7f3a"  # a text field's value: never in a report
FAST = ("--permutations", "20", "--bootstrap", "50")

RATINGS = '''
[[questions]]
id = "tissue_realism"
text = "The brain tissue moved as real brain tissue does."
kind = "likert"
points = 7
anchors = ["Strongly disagree", "Strongly agree"]

[[questions]]
id = "remarks"
text = "Anything else?"
kind = "text"
when = "end"

[[instruments]]
name = "sus"
when = "end"
'''


@pytest.fixture(scope="module")
def db(tmp_path_factory) -> Path:
    tmp = tmp_path_factory.mktemp("validity")
    path = field_protocol(tmp, conditions=("plate_spring",), trials=2)
    path.write_text(path.read_text() + RATINGS)
    db = tmp / "study.db"
    assert studyctl("study", "init", "--protocol", path, "--db", db).exit_code == 0
    res = studyctl("synth", "--db", db, "--participants", "15", "--seed", "3")
    assert res.exit_code == 0, res.output
    con = sqlite3.connect(db)
    with con:
        for (code,) in con.execute("select code from participants").fetchall():
            con.execute("insert into participant_fields (code, field, value) values (?, 'note', ?)", (code, f"{SECRET} {code}"))
            con.execute("insert into participant_fields (code, field, value) values (?, 'years', ?)", (code, int(code[1:]) % 7))
    con.close()
    return db


def _groups(db) -> dict[str, str]:
    con = sqlite3.connect(db)
    try:
        return dict(con.execute("select code, value from participant_fields where field = 'experience'").fetchall())
    finally:
        con.close()


def built_metrics(groups: dict[str, str], conditions=("plate_spring",), trials=6, seed=0) -> pd.DataFrame:
    """path_length falls with expertise (0.08, 0.06, 0.04 m, separated) and with practice (an
    exponential, rate 0.7 per trial, 0.02 m above the plateau at the first trial); sparc does not
    differ between the groups."""
    rng = np.random.default_rng(seed)
    rows = []
    for code, g in sorted(groups.items()):
        level = 0.08 - 0.02 * ORDER.index(g) + rng.normal(0, 0.002)
        smooth = -3.0 + rng.normal(0, 0.3)
        for ci, c in enumerate(conditions):
            for t in range(trials):
                for hand in ("left", "right"):
                    rows.append([code, True, c, t, hand, "path_length", level + 0.02 * np.exp(-0.7 * t) + 0.005 * ci + rng.normal(0, 0.001), "m"])
                    rows.append([code, True, c, t, hand, "sparc", smooth + rng.normal(0, 0.1), "1"])
    return pd.DataFrame(rows, columns=COLUMNS)


@pytest.fixture
def built(db, monkeypatch):
    """The study's metrics replaced by `built_metrics` (two conditions when asked for)."""
    def use(conditions=("plate_spring",)):
        table = built_metrics(_groups(db), conditions)
        monkeypatch.setattr(report_mod, "metrics_table", lambda study, goals=None: table)  # where the report takes them from
        monkeypatch.setattr(report_mod, "study_goals", lambda study: {})
        return table
    return use


def report(db, *args):
    res = studyctl("report", "validity", "--db", db, *FAST, *args)
    assert res.exit_code == 0, res.output
    return res.stdout  # the progress bar is on stderr


def test_json_has_every_section_and_finds_the_built_in_difference(db, built):
    built()
    out = json.loads(report(db, "--format", "json"))
    assert out["synthetic"] is True
    assert out["note"].startswith("SYNTHETIC DATA")
    assert out["groups"] == ORDER
    assert out["expert"] == "neurosurgeon"
    assert out["participants_with_metrics"] == 15
    assert out["metrics"] == ["path_length", "sparc"]
    assert out["settings"] == {"permutations": 20, "group_permutations": 1000, "bootstrap": 50, "seed": 0,
                                                                           "band": [5.0, 95.0]}
    kw = {r["metric"]: r for r in out["kruskal"]}
    assert kw["path_length"]["p_holm"] < 0.01
    assert kw["sparc"]["p_holm"] > 0.05
    assert kw["path_length"]["p_wy"] == pytest.approx(1 / 1001)  # the groups separated: p_wy's floor
    assert kw["sparc"]["p_wy"] > 0.05
    assert len(out["pairs"]) == 6
    assert all({"p", "p_holm", "p_wy", "cliffs_delta", "delta_low", "delta_high"} <= set(r) for r in out["pairs"])
    sep = [r for r in out["pairs"] if r["metric"] == "path_length"]
    assert all(r["p_wy"] < 0.05 for r in sep)
    assert all(r["cliffs_delta"] == 1.0 and r["delta_low"] == 1.0 for r in sep)  # every student's path longer than every resident's ...
    assert out["mixed_model"]["reason"].startswith("one condition (plate_spring)")
    assert out["mixed_model"]["fixed"] == []
    curves = [r for r in out["learning_curves"] if r["metric"] == "path_length"]
    assert len(curves) == 3
    for r in curves:  # the built-in rate 0.7 and plateau, within the bootstrap intervals
        assert r["rate_low"] <= 0.7 <= r["rate_high"]
        assert r["plateau_low"] < r["plateau"] < r["plateau_high"]
    assert {r["group"] for r in out["learning_curves"]} == set(ORDER)
    bench = {r["metric"]: r for r in out["proficiency"]["benchmark"]}
    assert bench["path_length"]["better"] == "lower"
    assert bench["path_length"]["n_expert"] == 5
    card = out["proficiency"]["scorecard"]
    assert len(card) == 10 * 2
    assert {r["group"] for r in card} == {"student", "resident"}
    assert all(r["position"] == "worse" for r in card if r["metric"] == "path_length")  # longer paths than every expert
    c = out["classifier"]
    assert c["n"] == 15
    assert c["accuracy"] >= 0.8
    assert c["p_value"] <= 0.1
    assert c["n_permutations"] == 20
    assert c["groups"] == ORDER
    assert np.sum(c["confusion"]) == 15
    items = {r["item"] for r in out["rating_tests"]}
    assert items == {"tissue_realism", "sus"}
    assert all(r["p_holm"] >= r["p"] for r in out["rating_tests"])
    ratings = [r for r in out["ratings"] if r["item"] == "sus"]
    assert [r["group"] for r in ratings] == ORDER
    assert sum(r["n"] for r in ratings) == 15
    assert ratings[0]["condition"] == ""
    assert {r["field"] for r in out["fields"]} == {"years"}  # the integer field, described; the text field never


def test_the_mixed_model_is_fitted_with_two_conditions(db, built):
    built(conditions=("fem", "plate_spring"))
    with Store(db, mode="read") as store:
        rep = vr.validity_report(read_study(store), permutations=5, bootstrap=20)
    fixed = rep["mixed_model"]["fixed"]
    assert rep["mixed_model"]["reason"] is None
    assert set(fixed["metric"]) == {"path_length", "sparc"}
    pl = fixed[fixed["metric"] == "path_length"].set_index("term")
    assert pl.loc["group[neurosurgeon]", "coef"] == pytest.approx(-0.04, abs=0.006)
    assert pl.loc["group[neurosurgeon]", "p"] < 1e-6
    assert pl.loc["condition[plate_spring]", "coef"] == pytest.approx(0.005, abs=0.002)
    assert len(rep["kruskal"]) == 4  # Holm over metrics x conditions (x pairs)
    assert len(rep["pairs"]) == 12


def test_markdown_structure(db, built):
    built()
    md = report(db)
    lines = md.splitlines()
    assert lines[0] == "# Construct validity: brain_pull_2015 (SYNTHETIC DATA)"
    assert lines[2] == "**SYNTHETIC DATA (simulated participants): not evidence about people.** 15 synthetic participants."
    assert lines[4] == ("N = 15 participants with metrics in 3 groups of experience (student 5, resident 5, neurosurgeon 5); 1 condition "
                        "(plate_spring), up to 6 trials each; 2 metrics (docs/metrics.md). Expert group: neurosurgeon. 1000 permutations "
                        "of the group tests' labels, 20 of the classifier's, 50 bootstrap replicates, seed 0.")
    assert [ln for ln in lines if ln.startswith("## ")] == [
        "## Participants", "## Group comparisons", "## Pairwise comparisons", "## Mixed model", "## Learning curves",
        "## Proficiency benchmark", "## Scorecards", "## Expertise classification", "## Face validity ratings"]
    i = lines.index("## Group comparisons")
    assert lines[i + 4] == ("| metric | unit | condition | student: median [IQR] | resident: median [IQR] | neurosurgeon: median [IQR] "
                            "| H | p | p_holm | p_wy |")
    assert lines[i + 6].startswith("| path_length | m | plate_spring | ")
    assert lines[i + 7].startswith("| sparc | 1 | plate_spring | ")
    assert "Holm over the family of the 2 Kruskal-Wallis tests run" in lines[i + 2]
    assert "Holm over the family of the 6 pairwise tests run (metrics x conditions x pairs)" in md
    assert "p_wy: Westfall-Young step-down min-p over the same family, 1000 permutations" in lines[i + 2]
    assert "| pair | U | p | p_holm | p_wy | Cliff's delta [95% CI] |" in md
    assert "Not fitted: one condition (plate_spring): no condition effect to model" in md
    assert "| participant | group | condition | metrics at proficiency | fraction |" in md
    assert "| nan |" not in md
    assert "| path_length | plate_spring | 5 | " in md
    assert md.count(" | lower |") == 1
    assert md.count(" | higher |") == 1
    assert re.search(r"leave-one-participant-out over 15 participants: accuracy \d+\.\d% .*permutation p = [0-9.]+ \(20 permutations", md)
    face = lines[lines.index("## Face validity ratings"):]
    assert face[4] == "| question | condition | student: median [IQR] (n) | resident: median [IQR] (n) | neurosurgeon: median [IQR] (n) | H | p | p_holm |"
    assert face[6].startswith("| The brain tissue moved as real brain tissue does. | plate_spring | ")
    assert face[7].startswith("| SUS score (0-100) | whole session | ")


def test_the_latex_tables_compile_and_fit_an_a4_page(db, built, tmp_path):
    built()
    tex = report(db, "--format", "latex")
    assert "SYNTHETIC DATA" in tex
    assert tex.count("\\toprule") >= 8
    assert "Face validity ratings" in tex
    assert latex_problems(document(tex), tmp_path) == []


def test_html_has_a_figure_per_metric_and_says_synthetic(db, built, tmp_path):
    built()
    out = tmp_path / "validity.html"
    assert report(db, "--format", "html", "--out", out).strip() == f"wrote {out}"
    page = out.read_text()
    assert page.count("<img ") == 2
    assert page.count('src="data:image/png;base64,') == 2
    assert '<img alt="path_length"' in page
    assert '<img alt="sparc"' in page
    assert "<title>Construct validity: brain_pull_2015 (SYNTHETIC DATA)</title>" in page
    assert '<p class="synthetic">SYNTHETIC DATA' in page


def test_a_text_field_and_free_text_never_appear_in_any_output(db, built, tmp_path):
    built()
    texts = [report(db, "--format", fmt) for fmt in ("md", "json")]
    report(db, "--format", "html", "--out", tmp_path / "v.html")
    texts.append((tmp_path / "v.html").read_text())
    for text in texts:
        assert SECRET not in text
        assert "no comment" not in text


def test_the_study_s_own_metrics_end_to_end(db):
    """No monkeypatching: the synthetic sessions' traces through metrics_table to the report."""
    out = json.loads(report(db, "--json"))
    assert out["participants_with_metrics"] == 15
    assert len(out["metrics"]) >= 10
    assert "path_length" in out["metrics"]
    assert len(out["kruskal"]) == len(out["metrics"])
    assert len(out["pairs"]) == 3 * len(out["metrics"])
    assert "accuracy" in out["classifier"], out["classifier"]  # 5 participants in each of the 3 groups: classified


def test_rating_kruskal_wallis_and_sus_against_pingouin_and_statsmodels(db):
    pg = pytest.importorskip("pingouin")
    from statsmodels.stats.multitest import multipletests

    with Store(db, mode="read") as store:
        study = read_study(store)
    groups, order, _ = vr.study_groups(study)
    scores, text = vr.rating_scores(study.protocol, study.answers)
    desc, tests = vr.ratings_by_group(scores, text, groups, order)
    con = sqlite3.connect(db)
    ans = pd.read_sql_query("select a.code, a.item, a.answer, f.value as grp from answers a join participant_fields f "
                            "on f.code = a.code and f.field = 'experience'", con)
    con.close()
    ans = ans[(ans["item"] == "tissue_realism") | ans["item"].str.startswith("sus_")].astype({"answer": float})
    tr = ans[ans["item"] == "tissue_realism"]
    sus = ans[ans["item"].str.startswith("sus_")].pivot(index="code", columns="item", values="answer")
    odd = sum(sus[f"sus_{k}"] - 1 for k in (1, 3, 5, 7, 9))  # Brooke 1996, by hand
    even = sum(5 - sus[f"sus_{k}"] for k in (2, 4, 6, 8, 10))
    sus_df = pd.DataFrame({"answer": 2.5 * (odd + even)}).reset_index().merge(ans[["code", "grp"]].drop_duplicates(), on="code")
    for item, ref_data in (("tissue_realism", tr), ("sus", sus_df)):
        row = tests[tests["item"] == item].iloc[0]
        ref = pg.kruskal(data=ref_data, dv="answer", between="grp")
        assert row["H"] == pytest.approx(ref["H"].item(), rel=1e-10)
        assert row["p"] == pytest.approx(ref["p_unc"].item(), rel=1e-10)
        for g in ORDER:
            d = desc[(desc["item"] == item) & (desc["group"] == g)].iloc[0]
            x = ref_data.loc[ref_data["grp"] == g, "answer"]
            assert d["n"] == len(x)
            assert d["median"] == pytest.approx(x.median())
            assert d["iqr"] == pytest.approx(x.quantile(0.75) - x.quantile(0.25))
    assert tests["p_holm"].tolist() == pytest.approx(multipletests(tests["p"], method="holm")[1].tolist())


def test_a_study_without_groups_is_a_one_line_error(tmp_path):
    db = tmp_path / "study.db"
    assert studyctl("study", "init", "--protocol", fast_protocol(tmp_path), "--db", db).exit_code == 0
    res = studyctl("report", "validity", "--db", db)
    assert res.exit_code != 0
    assert len(res.output.strip().splitlines()) == 1
    assert "no participant groups" in res.output
    assert "design.groups" in res.output
    assert "Traceback" not in res.output
