"""Table 1 statistics against published values, and a synthetic study through to the report."""

import math
import re

import numpy as np
import pytest
from click.testing import CliRunner
from scipy.stats import norm

from analysis.reports import report, table
from analysis.reports.latex import document
from analysis.reports.latex import text as latex_text
from analysis.reports.study_tables import table as table1_table
from analysis.reports.study_tables import table1_markdown
from analysis.statistics.stats import wilson
from analysis.statistics.study_stats import study_stats
from studyctl.cli import cli
from studyctl.synthetic.synth_run import run_synthetic_study
from tests.helpers import fast_protocol, latex_problems


@pytest.mark.parametrize("yes, n, lo, hi", [(81, 263, 0.2553, 0.3662), (15, 148, 0.0624, 0.1605), (0, 20, 0.0000, 0.1611)])
def test_wilson_intervals_match_newcombe_1998(yes, n, lo, hi):
    a, b = wilson(yes, n)
    assert (round(a, 4), round(b, 4)) == (lo, hi)


@pytest.mark.parametrize("rows, q, p", [
    ("111 111 010 110 000 111 111 110 001 010 111 111", 2.8000, 0.2466),  # NAG G08ALF
    ("00001 00001 00011 01011 01010 11010 11000 10000 10000", 5.56522, 0.234056),  # WaveMetrics
])
def test_cochrans_q_matches_published_examples(rows, q, p):
    import numpy as np
    from statsmodels.stats.contingency_tables import cochrans_q

    x = np.array([[int(c) for c in r] for r in rows.split()])
    r = cochrans_q(x)
    assert r.statistic == pytest.approx(q, abs=5e-5)
    assert r.pvalue == pytest.approx(p, abs=5e-5)


def test_small_synthetic_study_through_to_table1(tmp_path):
    db = tmp_path / "s.db"
    run_synthetic_study(db, 6, seed=2, protocol_path=fast_protocol(tmp_path, trials=1))
    res = CliRunner().invoke(cli, ["report", "table1", "--db", str(db)])
    assert res.exit_code == 0, res.output
    text = res.output
    assert "SYNTHETIC DATA" in text
    assert "N = 6 participants" in text
    assert "williams counterbalancing" in text
    assert text.count("| ") >= 11
    assert "Time for real-time deformation" in text
    import json

    out = json.loads(CliRunner().invoke(cli, ["report", "table1", "--db", str(db), "--format", "json"]).output)
    assert out["facts"]["synthetic"] is True
    assert len(out["rates"]) == 27
    for r in out["rates"]:
        assert r["yes"] + r["no"] == 6
        assert r["wilson_low"] <= r["rate"] <= r["wilson_high"]
    assert {c["item"] for c in out["cochran"]} == {r["item"] for r in out["rates"]}


def test_mcnemar_with_continuity_correction_matches_the_published_example():
    from statsmodels.stats.contingency_tables import mcnemar

    r = mcnemar([[48, 86], [150, 510]], exact=False, correction=True)
    assert round(r.statistic, 3) == 16.818
    assert r.pvalue == pytest.approx(4.115e-05, rel=1e-3)


def test_friedman_with_and_without_tie_correction_matches_nag_g08aef():
    import numpy as np

    from analysis.statistics.stats import friedman

    t1 = [1, 2, 1, 1, 3, 2, 3, 1, 3, 3, 2, 2, 3, 2, 2.5, 3, 3, 2]
    t2 = [3, 3, 3, 2, 1, 3, 2, 3, 1, 1, 3, 3, 2, 3, 2.5, 2, 2, 3]
    t3 = [2, 1, 2, 3, 2, 1, 1, 2, 2, 2, 1, 1, 1, 1, 1, 1, 1, 1]
    f = friedman(np.array([t1, t2, t3]).T)
    assert round(f["statistic_uncorrected"], 3) == 8.583
    assert round(f["p_value_uncorrected"], 4) == 0.0137
    assert round(f["statistic"], 3) == 8.704
    assert round(f["p_value"], 4) == 0.0129


def test_wilcoxon_signed_rank_matches_hollander_and_wolfe():
    from scipy import stats

    x = [1.83, 0.50, 1.62, 2.48, 1.68, 1.88, 1.55, 3.06, 1.30]
    y = [0.878, 0.647, 0.598, 2.05, 1.06, 1.29, 1.06, 3.14, 1.29]
    r = stats.wilcoxon(x, y, alternative="greater")
    assert r.statistic == 40
    assert round(r.pvalue, 5) == 0.01953


def test_published_table_is_flagged_exactly_where_counts_and_rates_disagree():
    import json

    from tests.conftest import ROOT

    res = CliRunner().invoke(cli, ["report", "published", "--table", str(ROOT / "data" / "paper_table1.csv"), "--json"])
    out = json.loads(res.output)
    assert [(f["item"], f["model"], f["printed"], f["computed"]) for f in out["flags"]] == [("realtime", "mass_spring", "8.6%", "68.6%")]
    assert len(out["homogeneity"]) == 9
    assert all("ignores" in h["note"] for h in out["homogeneity"])
    assert "paired" in out["not_computable"]
    # what the margins allow under any pairing (worked out in test_margin_bounds_*)
    p_min = {r["item"]: r["p_min"] for r in out["bounds"]["cochran"]}
    assert min(p_min.values()) == pytest.approx(0.0015, abs=5e-5)
    assert max(p_min.values()) == pytest.approx(0.0498, abs=5e-5)
    assert len(out["bounds"]["mcnemar"]) == 27
    assert min(p["p_min_holm"] for p in out["bounds"]["mcnemar"]) == pytest.approx(0.2109375)


def _all_pairings(yes, n):
    """Every 0/1 answer matrix (n participants x models) with these column sums, up to row order."""
    import itertools

    k = len(yes)
    rows = list(itertools.product((0, 1), repeat=k))
    for combo in itertools.combinations_with_replacement(range(len(rows)), n):
        x = np.array([rows[i] for i in combo])
        if tuple(x.sum(axis=0)) == tuple(yes):
            yield x


@pytest.mark.parametrize("yes, n", [((5, 2, 3), 6), ((4, 4, 1), 5), ((6, 1, 6), 7), ((3, 3, 3), 5)])
def test_margin_bounds_match_brute_force_over_every_pairing(yes, n):
    from scipy.stats import binomtest
    from statsmodels.stats.contingency_tables import cochrans_q

    from analysis.statistics.stats import max_cochran_q, min_mcnemar_p

    qs, mc = [], {}
    for x in _all_pairings(yes, n):
        if not np.all(x == x[:, :1]):
            qs.append(float(cochrans_q(x).statistic))
        for a, b in ((0, 1), (0, 2), (1, 2)):
            n01, n10 = int(np.sum((x[:, a] == 0) & (x[:, b] == 1))), int(np.sum((x[:, a] == 1) & (x[:, b] == 0)))
            p = float(binomtest(min(n01, n10), n01 + n10, 0.5).pvalue) if n01 + n10 else 1.0
            mc[(a, b)] = min(mc.get((a, b), 1.0), p)
    assert max_cochran_q(list(yes), n) == pytest.approx(max(qs))
    for (a, b), p in mc.items():
        assert min_mcnemar_p(yes[a], yes[b], n) == pytest.approx(p)


def _read(db):
    """The study in `db`, read once, as the report commands read it."""
    from studyctl.store import Store
    from studyctl.store.snapshot import read_study

    with Store(db, mode="read") as store:
        return read_study(store)


def _answers_db(tmp_path, answers: dict, orders: dict | None = None, protocol=None):
    """A study database holding these answers {code: {model: [0/1 per item]}} (imported, so no
    simulator runs); `orders` {code: [models]} recorded as their schedule."""
    import json

    from studyctl.store import Store, init_study
    from tests.helpers import PROTOCOL

    db = tmp_path / "a.db"
    init_study(db, protocol or PROTOCOL)
    store = Store(db)
    items = store.protocol().items
    with store.transaction() as conn:
        for code, by_model in answers.items():
            conn.execute("insert into participants (code, age, synthetic, created_at) values (?, 24, 0, 'x')", (code,))
            if orders:
                conn.execute("insert into schedule (code, conditions) values (?, ?)", (code, json.dumps(orders[code])))
            for model, values in by_model.items():
                for item, v in zip(items, values):
                    conn.execute("insert into answers (code, model, item, answer, session_id, source, answered_at) "
                                 "values (?, ?, ?, ?, null, 'import', 'x')", (code, model, item, int(v)))
    store.close()
    return db


def test_one_n_rule_complete_cases_everywhere_and_the_rest_listed(tmp_path):
    from analysis.reports.study_tables import table1_markdown as markdown
    from analysis.statistics.study_stats import study_stats
    from analysis.statistics.table1 import rates, study_facts

    rng = np.random.default_rng(1)
    models = ["fem", "mass_spring", "plate_spring"]
    answers = {f"P{i:02d}": {m: rng.integers(0, 2, 9).tolist() for m in models} for i in range(8)}
    answers["P98"] = {"fem": [1] * 9}  # stopped after one condition
    answers["P99"] = {m: [1] * 9 for m in models[:2]} | {"plate_spring": [1] * 4}  # stopped mid-questionnaire
    db = _answers_db(tmp_path, answers)
    study = _read(db)
    facts = study_facts(study)
    assert facts.participants == 8
    assert [x.as_dict() for x in facts.incomplete_participants] == [{"code": "P98", "answers": 9, "of": 27}, {"code": "P99", "answers": 22, "of": 27}]
    r = rates(study)
    assert (r["n"] == 8).all()  # the rates use the same 8 as the tests
    st = study_stats(study)
    assert all(v.n_complete == 8 for v in st.items.values())
    assert st.gee.composite.n_participants == 8
    assert "N = 8 participants" in markdown(study)
    assert "P98 (9/27), P99 (22/27)" in markdown(study)


def test_holm_over_the_family_of_27_pairs_by_default(tmp_path):
    from analysis.statistics.stats import holm
    from analysis.statistics.study_stats import study_stats

    rng = np.random.default_rng(2)
    answers = {f"P{i:02d}": {"fem": rng.binomial(1, 0.9, 9).tolist(), "mass_spring": rng.binomial(1, 0.3, 9).tolist(),
                             "plate_spring": rng.binomial(1, 0.6, 9).tolist()} for i in range(20)}
    study = _read(_answers_db(tmp_path, answers))
    fam, per = study_stats(study), study_stats(study, holm_scope="question")
    raw = [p.p_value for v in fam.items.values() for p in v.pairs]
    assert len(raw) == 27
    assert fam.holm == "family"
    assert [p.p_holm for v in fam.items.values() for p in v.pairs] == pytest.approx(holm(raw))
    for v in per.items.values():
        assert [p.p_holm for p in v.pairs] == pytest.approx(holm([p.p_value for p in v.pairs]))
    assert all(a.p_holm >= b.p_holm for va, vb in zip(fam.items.values(), per.items.values())
               for a, b in zip(va.pairs, vb.pairs))


def test_gee_matches_the_hand_built_saturated_case():
    """A balanced design with the model as the only factor is saturated: whatever the working
    correlation, the GEE's marginal log-odds are the logits of the sample proportions and its
    robust covariance is (1/N^2) D^-1 (sum_i r_i r_i^T) D^-1, D = diag(p (1 - p)) (the
    sandwich with A = N D V^-1 D, B = D V^-1 (sum r r^T) V^-1 D)."""
    import pandas as pd

    from analysis.statistics.stats import gee_fit

    rng = np.random.default_rng(3)
    n, models = 40, ["a", "b", "c"]
    person = rng.normal(0, 1.0, n)  # correlated answers within a participant
    y = (rng.random((n, 3)) < 1 / (1 + np.exp(-(np.array([1.2, -0.3, 0.4]) + person[:, None])))).astype(int)
    df = pd.DataFrame([{"code": f"P{i:02d}", "model": m, "answer": int(y[i, j])} for i in range(n) for j, m in enumerate(models)])
    out = gee_fit(df, models, with_period=False)
    p = y.mean(axis=0)
    logit = np.log(p / (1 - p))
    r = y - p
    D = np.diag(1 / (p * (1 - p)))
    cov = D @ (r.T @ r) @ D / n**2
    for pair in out["pairs"]:
        i, j = models.index(pair["a"]), models.index(pair["b"])
        est = logit[j] - logit[i]
        se = math.sqrt(cov[i, i] + cov[j, j] - 2 * cov[i, j])
        assert pair["log_odds_ratio"] == pytest.approx(est, abs=1e-6)
        assert pair["odds_ratio"] == pytest.approx(math.exp(est), rel=1e-6)
        assert pair["se"] == pytest.approx(se, rel=1e-4)
        assert pair["ci_low"] == pytest.approx(math.exp(est - 1.959963984540054 * se), rel=1e-4)
        assert pair["p_value"] == pytest.approx(2 * norm.sf(abs(est / se)), rel=1e-3)
    assert out["converged"]
    assert out["n_participants"] == n
    assert out["n_answers"] == 3 * n


def test_gee_has_the_period_factor_and_a_composite(tmp_path):
    from analysis.statistics.study_stats import study_stats

    rng = np.random.default_rng(4)
    models = ["fem", "mass_spring", "plate_spring"]
    orders = {f"P{i:02d}": [models[(i + k) % 3] for k in range(3)] for i in range(18)}
    answers = {c: {m: rng.binomial(1, 0.7, 9).tolist() for m in models} for c in orders}
    gee = study_stats(_read(_answers_db(tmp_path, answers, orders))).gee
    assert gee.period_factor is True
    assert gee.composite.formula == "answer ~ C(model) + C(period) + C(item)"
    assert gee.composite.n_answers == 18 * 27
    assert set(gee.items) == {"natural", "behaviour", "texture", "comfortable", "guidance", "realtime", "feedback", "deformation", "stable"}
    assert all(len(v.pairs) == 3 and {"odds_ratio", "ci_low", "ci_high", "p_value", "p_holm"} <= set(v.pairs[0].keys) for v in gee.items.values())


def test_report_stats_json_keys(tmp_path):
    import json

    db = tmp_path / "s.db"
    run_synthetic_study(db, 6, seed=4, protocol_path=fast_protocol(tmp_path, trials=1))
    out = json.loads(CliRunner().invoke(cli, ["report", "stats", "--db", str(db), "--json"]).output)
    item = out["items"]["natural"]
    assert {"cochran_q", "p_value", "rates", "pairs"} <= set(item)
    assert {"yes", "no", "rate", "wilson_low", "wilson_high"} <= set(item["rates"]["fem"])
    assert len(item["pairs"]) == 3
    assert {"a", "b", "p_value", "p_holm"} <= set(item["pairs"][0])
    # a pair no participant answered differently is not tested: null, with the reason
    assert all(p["p_holm"] >= p["p_value"] if p["p_value"] is not None else p["p_holm"] is None and p["reason"] for p in item["pairs"])
    assert out["holm"] == "family"
    assert {"p_holm_family", "p_holm_question"} <= set(item["pairs"][0])
    comp = out["gee"]["composite"]
    assert {"odds_ratio", "ci_low", "ci_high", "p_value", "p_holm"} <= set(comp["pairs"][0])
    assert len(comp["pairs"]) == 3
    assert "benchmark of this machine" in out["deformation"]["label"]
    assert len(out["deformation"]["rows"]) == 3
    assert out["deformation"]["rows"][0]["n_participants"] == 6


def test_latex_html_and_plots(small_study, tmp_path):
    db = small_study
    tex = CliRunner().invoke(cli, ["report", "table1", "--db", str(db), "--format", "latex"]).output
    assert tex.startswith("% needs in the preamble")
    assert "SYNTHETIC DATA" in tex
    assert "\\toprule" in tex
    assert "+-" not in tex
    assert sum(ln.startswith("Is ") or ln.startswith("Does ") or ln.startswith("Can ") or ln.startswith("Are ") for ln in tex.splitlines()) == 9
    assert re.search(r"McNemar p, Holm over all \d+ pairs tested", tex)
    assert "benchmark of this machine" in tex
    assert "$\\pm$" in tex
    assert re.search(r"\d+/\d+, \d+\.\d\\% \[\d+\.\d\\%, \d+\.\d\\%\]", tex)  # a rate and its interval as the Markdown and HTML print them
    assert latex_problems(document(tex), tmp_path) == []  # compiles with booktabs, nothing wider than the A4 text block
    res = CliRunner().invoke(cli, ["report", "table1", "--db", str(db), "--format", "html", "--out", str(tmp_path / "r.html")])
    assert res.exit_code == 0, res.output
    page = (tmp_path / "r.html").read_text()
    assert "SYNTHETIC DATA" in page
    assert page.count("data:image/png;base64,") == 3
    assert "benchmark of this machine" in page
    assert "logistic GEE" in page
    assert "http" not in page.split("<body>")[1]  # self-contained: nothing fetched
    res = CliRunner().invoke(cli, ["report", "plots", "--db", str(db), "--out", str(tmp_path / "plots")])
    assert res.exit_code == 0
    names = sorted(p.name for p in (tmp_path / "plots").iterdir())
    assert names == ["deformation.png", "deformation.svg", "force.png", "force.svg", "rates.png", "rates.svg"]


def test_a_report_reads_the_study_once(small_study, tmp_path, monkeypatch):
    """Each report command opens the database once (one Store, no other connection) and makes
    every table, statistic and plot from one snapshot (analysis.study.study_snapshot.Study)."""
    import dataclasses
    import sqlite3

    from studyctl.store import Store

    opened, others, inside = [], [], []
    store_init, connect = Store.__init__, sqlite3.connect

    def counted_init(self, *args, **kwargs):
        opened.append(args[0])
        inside.append(self)
        try:
            store_init(self, *args, **kwargs)
        finally:
            inside.pop()

    def counted_connect(*args, **kwargs):
        if not inside:  # a connection that is not a Store's own
            others.append(args[0])
        return connect(*args, **kwargs)

    monkeypatch.setattr(Store, "__init__", counted_init)
    monkeypatch.setattr(sqlite3, "connect", counted_connect)
    # the formats share one reading path (`_read`); html (with its plots) and the statistics are the heaviest readers
    for args in (["table1", "--format", "html", "--out", str(tmp_path / "r.html")], ["table1", "--format", "latex"], ["stats", "--json"]):
        opened.clear()
        res = CliRunner().invoke(cli, ["report", *args, "--db", str(small_study)])
        assert res.exit_code == 0, res.output
        assert opened == [small_study], args
        assert others == [], args
    assert "data:image/png;base64," in (tmp_path / "r.html").read_text()

    from analysis.reports.report import html

    study = _read(small_study)
    opened.clear()
    assert html(study).startswith("<!doctype html>")  # the snapshot alone
    assert opened == []
    assert others == []
    with pytest.raises(dataclasses.FrozenInstanceError):
        study.answers = None


@pytest.mark.slow
def test_html_report_renders_in_headless_chromium(small_study, tmp_path):
    import shutil
    import subprocess

    browser = shutil.which("chromium")
    if browser is None:
        pytest.skip("Debian's chromium is not installed (apt-get install chromium)")
    CliRunner().invoke(cli, ["report", "table1", "--db", str(small_study), "--format", "html", "--out", str(tmp_path / "r.html")])
    shot = tmp_path / "shot.png"
    subprocess.run([browser, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                    "--disable-background-networking", "--disable-component-update", "--disable-sync",
                    f"--user-data-dir={tmp_path / 'profile'}", "--window-size=1300,1600", f"--screenshot={shot}",
                    f"file://{tmp_path / 'r.html'}"], capture_output=True, timeout=120, check=True)
    import matplotlib.image as mpimg

    img = mpimg.imread(shot)[..., :3]
    assert img.std() > 0.05  # not blank
    red = (img[..., 0] > 0.6) & (img[..., 1] < 0.1) & (img[..., 2] < 0.2)
    assert red.sum() > 500  # the synthetic-data banner is there


def test_latex_table_escapes_every_special_character_and_has_the_other_formats_columns(tmp_path):
    import re

    from analysis.reports.report import latex
    from tests.conftest import ROOT
    from tests.helpers import PROTOCOL

    special = "Is {it} $5^2 ~ & 50% of_the #1 \\ case?"
    text = PROTOCOL.read_text().replace("Is interaction real and natural?", special.replace("\\", "\\\\"))
    text = text.replace('scene = "scenes/brain_pull.toml"', f'scene = "{ROOT}/protocols/scenes/brain_pull.toml"')
    protocol = tmp_path / "p.toml"
    protocol.write_text(text)
    rng = np.random.default_rng(5)
    answers = {f"P{i:02d}": {m: rng.integers(0, 2, 9).tolist() for m in ("fem", "mass_spring", "plate_spring")} for i in range(6)}
    tex = latex(_read(_answers_db(tmp_path, answers, protocol=protocol)))
    row = next(line for line in tex.splitlines() if line.startswith("Is \\{it"))
    question = row.split(" & ")[0]
    assert question == ("Is \\{it\\} \\$5\\textasciicircum 2 \\textasciitilde \\space \\& 50\\% of\\_\\allowbreak{}the \\#1 "
                        "\\textbackslash \\space case?")
    # nothing special is left unescaped in any cell: drop the escapes (and the symbols written as LaTeX), then look for the characters
    rows = [x for x in tex.splitlines() if x.endswith(" \\\\") and not x.startswith("\\textbf") and not x.startswith("\\caption")]
    for line in rows:
        body = line.removesuffix(" \\\\").replace("$\\pm$", "").replace("$-$", "")
        cells = re.split(r"(?<!\\)&", body)
        assert len(cells) == 6, line  # question, three models, Cochran's Q, McNemar
        rest = re.sub(r"\\(textasciicircum|textasciitilde|textbackslash|space|allowbreak\{\})|\\[{}$&%_#]", "", body.replace(" & ", " "))
        assert not re.search(r"[{}$^~%_#\\]", rest), line
    assert len(rows) == 10  # 9 questions and the deformation row
    assert "\\toprule" in tex
    assert "\\bottomrule" in tex


def test_table1_is_one_table_whatever_the_format(tmp_path):
    """Markdown, LaTeX and HTML render the same Table 1: its rows, each cell escaped for its format."""
    rng = np.random.default_rng(5)
    answers = {f"P{i:02d}": {m: rng.integers(0, 2, 9).tolist() for m in ("fem", "mass_spring", "plate_spring")} for i in range(6)}
    study = _read(_answers_db(tmp_path, answers))
    t = table1_table(study_stats(study))
    assert "\n".join(table.markdown_grid(t)) in table1_markdown(study)
    assert "\n".join(" & ".join(latex_text(c) for c in row) + " \\\\" for row in t.rows) in report.latex(study)
    assert table.html_grid(t) in report.html(study)


def test_gee_says_not_estimable_when_a_model_answers_alike_throughout(tmp_path):
    from analysis.reports.study_tables import table1_markdown as markdown
    from analysis.statistics.study_stats import study_stats

    rng = np.random.default_rng(6)
    answers = {f"P{i:02d}": {"fem": rng.integers(0, 2, 9).tolist(), "mass_spring": [0] * 9, "plate_spring": rng.integers(0, 2, 9).tolist()}
               for i in range(8)}
    study = _read(_answers_db(tmp_path, answers))
    comp = study_stats(study).gee.composite
    assert comp.estimable is False
    assert not comp.converged
    assert "mass_spring" in comp.problems[0]
    bad = [p for p in comp.pairs if "mass_spring" in (p.a, p.b)]
    assert bad
    assert all(not p.estimable and math.isnan(p.p_value) for p in bad)
    assert "not estimable" in markdown(study)
    assert "NOT ESTIMABLE" in markdown(study)


def test_holm_equals_statsmodels_with_ties_and_nan():
    from statsmodels.stats.multitest import multipletests

    from analysis.statistics.stats import holm

    rng = np.random.default_rng(1)
    for k in range(12):  # statsmodels' holm runs a full garbage collection per call: 0.25 s in the suite's heap
        p = rng.uniform(0, 1, rng.integers(1, 12)) ** 3
        if k % 3 == 0:
            p[rng.integers(p.size)] = p[0]  # a tie
        if k % 7 == 0:
            p[rng.integers(p.size)] = np.nan
        # a test not made (NaN) is not in the family: statsmodels on the others, NaN where it was
        ok = np.isfinite(p)
        expected = np.full(p.size, np.nan)
        expected[ok] = multipletests(p[ok], method="holm")[1]
        assert np.array_equal(holm(p), expected, equal_nan=True)
    assert holm([]) == []  # by hand
    assert holm([0.01, 0.04, 0.03]) == pytest.approx([0.03, 0.06, 0.06])
