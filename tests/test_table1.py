"""Table 1 statistics against published values, and a synthetic study through to the report."""

import pytest
from click.testing import CliRunner

from analysis.table1 import wilson
from studyctl.cli import cli
from studyctl.synthetic import run_synthetic_study
from tests.test_study import fast_protocol


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
    assert r.statistic == pytest.approx(q, abs=5e-5) and r.pvalue == pytest.approx(p, abs=5e-5)


def test_small_synthetic_study_through_to_table1(tmp_path):
    db = tmp_path / "s.db"
    run_synthetic_study(db, 6, seed=2, protocol_path=fast_protocol(tmp_path, trials=1))
    res = CliRunner().invoke(cli, ["report", "table1", "--db", str(db)])
    assert res.exit_code == 0, res.output
    text = res.output
    assert "SYNTHETIC DATA" in text and "N = 6 participants" in text and "williams counterbalancing" in text
    assert text.count("| ") >= 11 and "Time for real-time deformation" in text
    import json

    out = json.loads(CliRunner().invoke(cli, ["report", "table1", "--db", str(db), "--format", "json"]).output)
    assert out["facts"]["synthetic"] is True and len(out["rates"]) == 27
    for r in out["rates"]:
        assert r["yes"] + r["no"] == 6 and r["wilson_low"] <= r["rate"] <= r["wilson_high"]
    assert {c["item"] for c in out["cochran"]} == {r["item"] for r in out["rates"]}


def test_mcnemar_with_continuity_correction_matches_the_published_example():
    from statsmodels.stats.contingency_tables import mcnemar

    r = mcnemar([[48, 86], [150, 510]], exact=False, correction=True)
    assert round(r.statistic, 3) == 16.818 and r.pvalue == pytest.approx(4.115e-05, rel=1e-3)


def test_friedman_with_and_without_tie_correction_matches_nag_g08aef():
    import numpy as np

    from analysis.stats import friedman

    t1 = [1, 2, 1, 1, 3, 2, 3, 1, 3, 3, 2, 2, 3, 2, 2.5, 3, 3, 2]
    t2 = [3, 3, 3, 2, 1, 3, 2, 3, 1, 1, 3, 3, 2, 3, 2.5, 2, 2, 3]
    t3 = [2, 1, 2, 3, 2, 1, 1, 2, 2, 2, 1, 1, 1, 1, 1, 1, 1, 1]
    f = friedman(np.array([t1, t2, t3]).T)
    assert round(f["statistic_uncorrected"], 3) == 8.583 and round(f["p_value_uncorrected"], 4) == 0.0137
    assert round(f["statistic"], 3) == 8.704 and round(f["p_value"], 4) == 0.0129


def test_wilcoxon_signed_rank_matches_hollander_and_wolfe():
    from scipy import stats

    x = [1.83, 0.50, 1.62, 2.48, 1.68, 1.88, 1.55, 3.06, 1.30]
    y = [0.878, 0.647, 0.598, 2.05, 1.06, 1.29, 1.06, 3.14, 1.29]
    r = stats.wilcoxon(x, y, alternative="greater")
    assert r.statistic == 40 and round(r.pvalue, 5) == 0.01953


def test_published_table_is_flagged_exactly_where_counts_and_rates_disagree():
    import json

    from tests.conftest import ROOT

    res = CliRunner().invoke(cli, ["report", "published", "--table", str(ROOT / "data" / "paper_table1.csv"), "--json"])
    out = json.loads(res.output)
    assert [(f["item"], f["model"], f["printed"], f["computed"]) for f in out["flags"]] == [("realtime", "mass_spring", "8.6%", "68.6%")]
    assert len(out["homogeneity"]) == 9 and all("ignores" in h["note"] for h in out["homogeneity"])
    assert "paired" in out["not_computable"]


def test_report_stats_json_keys(tmp_path):
    import json

    db = tmp_path / "s.db"
    run_synthetic_study(db, 6, seed=4, protocol_path=fast_protocol(tmp_path, trials=1))
    out = json.loads(CliRunner().invoke(cli, ["report", "stats", "--db", str(db), "--json"]).output)
    item = out["items"]["natural"]
    assert {"cochran_q", "p_value", "rates", "pairs"} <= set(item)
    assert {"yes", "no", "rate", "wilson_low", "wilson_high"} <= set(item["rates"]["fem"])
    assert len(item["pairs"]) == 3 and {"a", "b", "p_value", "p_holm"} <= set(item["pairs"][0])
    assert all(p["p_holm"] >= p["p_value"] for p in item["pairs"])
    lat = out["latency"]
    assert {"statistic", "p_value", "kendall_w", "pairs"} <= set(lat) and len(lat["pairs"]) == 3


def test_latex_html_and_plots(small_study, tmp_path):
    db = small_study
    tex = CliRunner().invoke(cli, ["report", "table1", "--db", str(db), "--format", "latex"]).output
    assert tex.startswith("\\begin{table}") and "SYNTHETIC DATA" in tex and tex.count("\\\\") == 10
    res = CliRunner().invoke(cli, ["report", "table1", "--db", str(db), "--format", "html", "--out", str(tmp_path / "r.html")])
    assert res.exit_code == 0, res.output
    page = (tmp_path / "r.html").read_text()
    assert "SYNTHETIC DATA" in page and page.count("data:image/png;base64,") == 3 and "Friedman" in page
    assert "http" not in page.split("<body>")[1]  # self-contained: nothing fetched
    res = CliRunner().invoke(cli, ["report", "plots", "--db", str(db), "--out", str(tmp_path / "plots")])
    assert res.exit_code == 0
    names = sorted(p.name for p in (tmp_path / "plots").iterdir())
    assert names == ["deformation.png", "deformation.svg", "force.png", "force.svg", "rates.png", "rates.svg"]


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
