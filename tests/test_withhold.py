"""One rule for every statistic (analysis/statistics/withhold.py, issue 42 item 1): printed only where its
prerequisites hold for the data, otherwise withheld with the reason; intervals inside their
scale. The sweep runs N = 0, 1, 2, 3 and a one-condition study through every report and format."""

import json
import re

import numpy as np
import pytest

from analysis.statistics.withhold import mean_ci
from tests.helpers import QUESTIONS, kinds_protocol, studyctl

PER_TRIAL = QUESTIONS.replace('id = "stable"\ntext = "Is the system stable?"', 'id = "stable"\ntext = "Is the system stable?"\nwhen = "trial"')


def test_a_bounded_mean_interval_stays_inside_its_scale_and_covers():
    # the case: a t interval 86.8 [69.7, 103.8] on a 0-100 scale
    v = [100.0, 100.0, 62.0, 85.0, 87.0]
    t = mean_ci(v)
    assert t["ci_high"] > 100.0
    assert t["ci_method"] == "t"
    b = mean_ci(v, scale=(0.0, 100.0))
    assert 0.0 < b["ci_low"] < b["mean"] < b["ci_high"] < 100.0
    assert b["ci_method"].startswith("logit t")
    # coverage of the logit t interval of a mean on a bounded scale (beta-distributed answers, mean 85)
    rng = np.random.default_rng(5)
    for n in (5, 12, 30):
        hits = [(lambda c: c["ci_low"] <= 85.0 <= c["ci_high"])(mean_ci(100 * rng.beta(8.5, 1.5, n), scale=(0.0, 100.0))) for _ in range(2000)]
        assert 0.92 <= np.mean(hits) <= 0.975, (n, np.mean(hits))
    assert mean_ci([4.0])["ci_reason"] == "no interval at N = 1"
    assert mean_ci([3.0, 3.0, 3.0], scale=(1, 7))["ci_reason"] == "no interval: every value is 3 (no variation)"


def _walk(obj, path=""):
    if isinstance(obj, dict):
        yield path, obj
        for k, v in obj.items():
            yield from _walk(v, f"{path}.{k}")
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            yield from _walk(v, f"{path}[{i}]")


SCALES = {"stiffness": (0, 100), "sus": (0, 100), "nasa_tlx": (0, 100), "stable (mean over trials)": (0, 1),
          "smooth (mean over trials)": (1, 5)}


def _check_json(st: dict, n: int) -> None:
    for path, d in _walk(st):
        if "test" in d and "p_value" in d:  # a test: a number, or null with the reason
            p = d["p_value"]
            assert (p is not None and 0.0 <= p <= 1.0 and not d.get("reason")) or (p is None and d.get("reason")), (n, path, d)
        if "rank_biserial" in d and d["rank_biserial"] is not None:
            assert -1.0 <= d["rank_biserial"] <= 1.0, (n, path)
        for lo, hi in (("wilson_low", "wilson_high"), ("kendall_w_low", "kendall_w_high")):
            if d.get(lo) is not None:
                assert 0.0 <= d[lo] <= d[hi] <= 1.0, (n, path, d)
    for item, v in st["kinds"]["scores"].items():
        lo, hi = SCALES[item]
        for m, c in v["conditions"].items():
            if c["ci_low"] is None:
                assert c["ci_reason"], (n, item, m)
            else:
                assert lo <= c["ci_low"] <= c["mean"] <= c["ci_high"] <= hi, (n, item, m, c)
        test = v["mixed_model"]["model_test"]
        assert test["f"] is not None or test["reason"], (n, item)
        if test["f"] is not None:
            assert test["df_denominator"] > 0, (n, item)
            assert v["mixed_model"]["converged"], (n, item)


def _check_text(text: str, n: int, fmt: str, bounded: bool = True) -> None:
    """No NaN or inf, no Holm over no tests, every interval ordered; with `bounded` (the study
    reports: percentages and 0-100 scores) nothing printed above 100."""
    text = re.sub(r"base64,[A-Za-z0-9+/=]+", "", text)
    bad = re.search(r"\bnan\b|\binf\b", text, re.I)
    assert not bad, (n, fmt, text[max(0, bad.start() - 300):bad.end() + 50])
    assert "over all 0 pairs" not in text, (n, fmt)
    assert "Traceback" not in text, (n, fmt)
    for lo, hi in re.findall(r"\[(-?\d+(?:\.\d+)?)%?, (-?\d+(?:\.\d+)?)%?\]", text):  # every interval printed
        assert float(lo) <= float(hi), (n, fmt, lo, hi)
        assert float(lo) >= 0.0 or "-" in text.split(f"[{lo}")[0][-12:], (n, fmt, lo)  # only differences go below 0
    # nothing above 100 (a percentage, a 0-100 score) before the list of configurations (hashes)
    if fmt == "html":
        text = re.sub(r"<[^>]+>", " ", re.sub(r"<style>.*?</style>", "", text, flags=re.S))
    text = re.sub(r"\b(?:19|20)\d\d\b", "", text)  # the years of citations
    over = None if fmt == "latex" or not bounded else re.search(r"(?<![\w.])(?:[1-9]\d{3,}|10[1-9]|1[1-9]\d|[2-9]\d\d)(?:\.\d+)?(?![\w.])", text.split("Conditions (what each ran")[0])
    assert not over, (n, fmt, over and text[over.start() - 80:over.end() + 20])


@pytest.fixture(scope="module")
def studies(tmp_path_factory):
    out = {}
    for n in (0, 1, 2, 3):
        d = tmp_path_factory.mktemp(f"n{n}")
        proto = kinds_protocol(d, questions=PER_TRIAL, trials=2)
        db = d / "s.db"
        if n:
            assert studyctl("synth", "--db", db, "--protocol", proto, "--participants", n, "--seed", 5).exit_code == 0
        else:
            assert studyctl("study", "init", "--db", db, "--protocol", proto).exit_code == 0
        out[n] = db
    d = tmp_path_factory.mktemp("one")
    db = d / "s.db"
    proto = kinds_protocol(d, questions=PER_TRIAL.split('[[questions]]\nid = "most')[0] + '[[instruments]]\nname = "sus"\n',
                           conditions=("paper",), trials=2)
    proto.write_text(proto.read_text().replace('[conditions.located]\nmodel = "plate_spring"\nvariant = "located"\n', ""))
    res = studyctl("synth", "--db", db, "--protocol", proto, "--participants", 3, "--seed", 2)
    assert res.exit_code == 0, res.output
    out["one condition"] = db
    return out


@pytest.mark.parametrize("n", [0, 1, 2, 3, "one condition"])
def test_every_report_at_small_n_prints_only_valid_statistics(studies, n):
    db = studies[n]
    for fmt in ("md", "html", "latex", "csv"):
        res = studyctl("report", "table1", "--db", db, "--format", fmt)
        assert res.exit_code == 0, (n, fmt, res.output)
        _check_text(res.output, n, fmt)
    res = studyctl("report", "stats", "--db", db)
    assert res.exit_code == 0
    _check_text(res.output, n, "stats")
    st = json.loads(studyctl("report", "stats", "--db", db, "--json").output)
    if n == 0:
        assert st["message"] == "no answers yet"
        return
    _check_json(st, n)
    if n == 1:  # one participant: no test, no interval, each cell saying why
        md = studyctl("report", "table1", "--db", db).output
        assert "not testable at N = 1" in md
        assert "no interval at N = 1" in md
        assert "no SD at N = 1" in md
        assert all(p["p_value"] is None for v in st["kinds"]["ratings"].values() for p in v["pairs"])
    if n == "one condition":
        md = studyctl("report", "table1", "--db", db).output
        assert "one condition: nothing to compare" in md
        assert "Holm: no pair tested" in md
        assert not re.search(r"Friedman[^|]*\| \d", md)
    if n == 2:  # a Wilcoxon pair is run, with the warning that it cannot reach 0.05
        pairs = [p for v in st["kinds"]["ratings"].values() for p in v["pairs"] if p["p_value"] is not None]
        assert pairs
        assert all("cannot reach p < 0.05" in p["warning"] for p in pairs)


def test_report_jnd_says_what_a_small_group_cannot_give(tmp_path):
    """Two participants: the geometric mean's interval is printed with the warning that it is wide;
    every participant's row names its fit flag and QUEST+'s own estimate, in Markdown and HTML."""
    from tests.helpers import jnd_protocol

    db = tmp_path / "s.db"
    assert studyctl("synth", "--db", db, "--protocol", jnd_protocol(tmp_path, trials=12), "--participants", 2, "--seed", 4).exit_code == 0
    md = studyctl("report", "jnd", "--db", db).output
    assert "N = 2: a t interval on 1 df is wide" in md
    assert "| fit flag | pooled [95% CrI] | QUEST+ estimate | generating |" in md
    assert "(too few to pool)" in md
    html = studyctl("report", "jnd", "--db", db, "--format", "html").output
    assert "QUEST+ estimate" in html
    assert "recovery: median abs. error, CI coverage (own fit; pooled)" in html
    assert "N = 2: a t interval" in html
    js = json.loads(studyctl("report", "jnd", "--db", db, "--format", "json").output)
    assert js["facts"]["fit"]["function"] == "thurstone"
    assert js["conditions"][0]["gm_warning"]
    _check_text(md, 2, "jnd", bounded=False)  # a Weber fraction has no upper end


def test_report_validity_with_one_participant_per_group_tests_nothing_and_says_why(tmp_path):
    from tests.helpers import field_protocol

    db = tmp_path / "s.db"
    res = studyctl("synth", "--db", db, "--protocol", field_protocol(tmp_path, conditions=("plate_spring",), trials=2), "--participants", 3, "--seed", 3)
    assert res.exit_code == 0, res.output
    for fmt in ("md", "html"):
        text = studyctl("report", "validity", "--db", db, "--format", fmt).output
        _check_text(text, 3, f"validity {fmt}", bounded=False)  # (counts of permutations and replicates)
        assert "not tested: a group has fewer than 2 participants with values" in text
        assert "classification needs 2 or more participants in every group" in text
    js = json.loads(studyctl("report", "validity", "--db", db, "--format", "json").stdout)
    _check_json_tests(js)


def _check_json_tests(js: dict) -> None:
    for path, d in _walk(js):
        if "test" in d and "p" in d:  # validity's tests: p, or null with the reason
            assert (d["p"] is not None and not d.get("reason")) or (d["p"] is None and d.get("reason")), (path, d)


def test_a_group_model_that_did_not_converge_prints_no_test():
    from analysis.reports.jnd_report import _group_text

    text = _group_text({"mixed_model": {"converged": False, "chi2": 2.72, "df": 2, "p": 0.257, "problem": "singular covariance"}})
    assert "not tested (the fit did not converge: singular covariance)" in text
    assert "2.72" not in text
    assert "0.257" not in text
    assert "chi2(2) = 2.72, p = 0.257" in _group_text({"mixed_model": {"converged": True, "chi2": 2.72, "df": 2, "p": 0.257}})
