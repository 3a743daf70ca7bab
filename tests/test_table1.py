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
