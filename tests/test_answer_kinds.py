"""Question kinds, standard instruments, their statistics and reports, synthetic answers of
every kind, power for the primary analysis and rig profiles (issue 26, items 2-7)."""

import csv
import json
import math
import re
import sqlite3

import numpy as np
import pytest

from analysis.reports.latex import document
from analysis.study import instruments
from analysis.study.questions import Question
from studyctl.protocol import check_protocol, load_protocol
from studyctl.synthetic.observer import likert_answer, likert_thresholds
from studyctl.synthetic.synth_run import run_synthetic_study
from tests.conftest import ROOT
from tests.helpers import QUESTIONS, kinds_protocol, latex_problems, studyctl


def test_the_shipped_example_validates():
    p = load_protocol(ROOT / "protocols/plate_spring_variants.toml")
    assert p.conditions == ("paper", "located", "fem_linear")
    likert = [q for q in p.questions if q.kind == "likert" and q.instrument is None]
    assert [q.id for q in likert] == list(load_protocol(ROOT / "protocols/brain_pull_2015.toml").items)
    assert all(q.points == 7 and q.when == "condition" for q in likert)
    assert p.instruments == (("sus", "condition"),)
    assert [q.id for q in p.questions if q.instrument] == [f"sus_{k}" for k in range(1, 11)]
    assert [(q.id, q.kind, q.when) for q in p.asked("end")] == [("most_like_tissue", "choice", "end")]
    res = studyctl("protocol", "validate", ROOT / "protocols/plate_spring_variants.toml")
    assert res.exit_code == 0, res.output


REFUSED = {
    "points = 1": ("points = 7\n", "points = 1\n", r":(\d+): questions\[0\]\.points: 1 is out of range; allowed: 3\.\.11"),
    "a likert item without anchors": ('anchors = ["Not at all", "Completely"]\n\n[[questions]]\nid = "realtime"',
                                      '\n[[questions]]\nid = "realtime"',
                                      r":(\d+): questions\[0\]\.anchors: missing: a likert question names its two ends, anchors = \[low, high\]"),
    "a choice asked per trial": ('kind = "choice"\nwhen = "end"', 'kind = "choice"\nwhen = "trial"',
                                 r":(\d+): questions\[6\]\.when: 'trial': a choice among the conditions is asked once, after the last; allowed: end"),
    "an unknown kind": ('kind = "vas"', 'kind = "slider"', r":(\d+): questions\[2\]\.kind: 'slider' is not a kind; allowed: yes_no, likert, vas, choice, text"),
    "points on a vas": ('kind = "vas"\n', 'kind = "vas"\npoints = 5\n', r":(\d+): questions\[2\]\.points: only a likert question has points"),
    "an unknown instrument": ('name = "nasa_tlx"', 'name = "tlx"', r":(\d+): instruments\[1\]\.name: 'tlx' is not an instrument; allowed: sus, nasa_tlx"),
    "an instrument item clashing": ('id = "stable"', 'id = "sus_3"', r":(\d+): instruments\[0\]\.name: duplicate item id 'sus_3' \(also questions\[3\]\)"),
    "an unknown when": ('when = "end"\n\n[[questions]]\nid = "most', 'when = "later"\n\n[[questions]]\nid = "most',
                        r":(\d+): questions\[5\]\.when: 'later' is not allowed; allowed: condition, trial, end"),
}


@pytest.mark.parametrize("case", sorted(REFUSED))
def test_bad_questions_are_refused_at_their_line_with_the_allowed_values(tmp_path, case):
    old, new, pattern = REFUSED[case]
    assert old in QUESTIONS
    path = kinds_protocol(tmp_path, QUESTIONS.replace(old, new, 1))
    _, problems = check_protocol(path)
    hits = [m for p in problems if (m := re.search(pattern, p))]
    assert hits, problems
    line = int(hits[0].group(1))
    assert path.read_text().splitlines()[line - 1].strip(), "the line named is not blank"
    res = studyctl("protocol", "validate", path)
    assert res.exit_code == 1
    assert re.search(pattern, res.output + (res.stderr if hasattr(res, "stderr") else ""))


def test_sus_scoring_follows_brookes_worked_rule():
    # Brooke (1996): odd items score answer - 1, even items 5 - answer, the sum times 2.5
    assert instruments.sus_score([3] * 10) == 50.0  # every answer neutral
    assert instruments.sus_score([5, 1] * 5) == 100.0
    assert instruments.sus_score([1, 5] * 5) == 0.0
    # worked by hand: odd (4-1)+(4-1)+(4-1)+(5-1)+(4-1) = 16, even (5-2)+(5-1)+(5-2)+(5-1)+(5-2) = 17; 33 x 2.5
    assert instruments.sus_score([4, 2, 4, 1, 4, 2, 5, 1, 4, 2]) == 82.5
    with pytest.raises(ValueError):
        instruments.sus_score([6] + [3] * 9)


def test_raw_tlx_is_the_mean_of_its_six_subscales():
    # Hart (2006): RTLX, the unweighted mean; worked by hand: (70 + 20 + 55 + 30 + 65 + 40) / 6 = 46.666...
    assert instruments.raw_tlx([70, 20, 55, 30, 65, 40]) == pytest.approx(280 / 6, abs=1e-12)
    qs = instruments.questions("nasa_tlx")
    assert [q.id for q in qs] == ["tlx_mental", "tlx_physical", "tlx_temporal", "tlx_performance", "tlx_effort", "tlx_frustration"]
    assert all(q.kind == "vas" for q in qs)
    assert qs[3].anchors == ("Perfect", "Failure")
    assert instruments.score("nasa_tlx", {q.id: v for q, v in zip(qs, [70, 20, 55, 30, 65, 40])}) == pytest.approx(280 / 6)


@pytest.mark.parametrize("points", [3, 4, 7, 11])
def test_a_rating_is_an_ordered_logit_of_the_yes_no_judgement(points):
    # the ordered logit's defining property, P(rating > k) = logistic(eta - tau_k), checked on a
    # fine grid of u (likert_answer's inverse-CDF draw): exact to the grid's resolution
    u = (np.arange(4000) + 0.5) / 4000
    t = likert_thresholds(points)
    for eta in (-2.0, -0.3, 0.0, 1.1, 2.5):
        r = np.array([likert_answer(eta, points, x) for x in u])
        assert r.min() >= 1
        assert r.max() <= points
        for k in range(1, points):
            assert np.mean(r > k) == pytest.approx(1 / (1 + math.exp(-(eta - t[k - 1]))), abs=1e-3)
    assert np.allclose(t, -t[::-1])
    assert np.all(np.diff(t) > 0)
    if points % 2 == 0:  # an even scale's middle cut is the yes/no boundary: P(upper half) = P(yes)
        assert t[points // 2 - 1] == 0.0


def test_a_synthetic_study_answers_every_kind_in_its_type_and_reports_each(tmp_path):
    db = tmp_path / "s.db"
    run_synthetic_study(db, 6, seed=1, protocol_path=kinds_protocol(tmp_path))
    con = sqlite3.connect(db)
    kinds = dict(con.execute("select item, group_concat(distinct typeof(answer)) from answers group by item").fetchall())
    assert kinds["natural"] == "integer"
    assert kinds["stiffness"] == "real"
    assert kinds["stable"] == "integer"
    assert kinds["most_like_tissue"] == "text"
    assert kinds["comment"] == "text"
    assert kinds["sus_1"] == "integer"
    assert kinds["tlx_mental"] == "real"
    assert con.execute("select count(*) from answers where item = 'smooth'").fetchone()[0] == 6 * 2 * 2  # after every trial
    assert set(con.execute("select distinct trial from answers where item = 'smooth'").fetchall()) == {(0,), (1,)}
    end = con.execute("select model, trial, answer from answers where item = 'most_like_tissue'").fetchall()
    assert all(m == "" and t == -1 and a in ("paper", "located") for m, t, a in end)
    assert {r[0] for r in con.execute("select answer from answers where item = 'comment'")} == {"(synthetic participant: no comment)"}
    likert = [r[0] for r in con.execute("select answer from answers where item in ('natural', 'realtime')")]
    assert all(1 <= v <= 7 for v in likert)
    vas = [r[0] for r in con.execute("select answer from answers where item like 'tlx_%' or item = 'stiffness'")]
    assert all(0 <= v <= 100 for v in vas)
    con.close()

    st = json.loads(studyctl("report", "stats", "--json", "--db", db).output)
    k = st["kinds"]
    assert k["primary"]["analysis"] == "ordinal_gee"
    assert k["primary"]["items"] == ["natural", "realtime"]
    assert set(k["ratings"]) == {"natural", "realtime"}
    assert "friedman" in k["ratings"]["natural"]
    assert {"kendall_w", "kendall_w_low", "kendall_w_high"} <= set(k["ratings"]["natural"]["friedman"])
    assert {"rank_biserial", "rb_ci_low", "p_holm", "p_holm_family"} <= set(k["ratings"]["natural"]["pairs"][0])
    assert set(k["scores"]) == {"stiffness", "sus", "nasa_tlx", "smooth (mean over trials)"}
    assert k["scores"]["sus"]["mixed_model"]["formula"].startswith("answer ~ C(model) + C(period)")
    assert k["ordinal_gee"]["pairs"][0]["a"] == "paper"
    assert "odds_ratio" in k["ordinal_gee"]["pairs"][0]
    assert k["choices"]["most_like_tissue"]["n"] == 6
    assert k["choices"]["most_like_tissue"]["overall"]["test"].startswith("exact multinomial")
    assert "comment" not in json.dumps(k)  # free text is never analysed
    # Holm over the whole family: the yes/no McNemar pair, every rating's and score's pairs, the choice's
    family = [p for v in st["items"].values() for p in v["pairs"]] + [p for part in ("ratings", "scores", "choices") for v in k[part].values()
                                                                        for p in v["pairs"]]
    assert len(family) == 1 + 2 + 4 + 1
    from statsmodels.stats.multitest import multipletests

    ps = [p["p_value"] if p["p_value"] == p["p_value"] else 1.0 for p in family]
    assert np.allclose([p["p_holm_family"] for p in family], multipletests(ps, method="holm")[1])

    md = studyctl("report", "table1", "--db", db).output
    assert "SYNTHETIC DATA" in md
    assert "**Ratings**" in md
    assert "**Scores**" in md
    assert "SUS score (0-100)" in md
    assert "Choice: Which condition felt most like real brain tissue?" in md
    assert "Holm over all 8 pairs" in md
    assert "Primary analysis, all rating items: proportional-odds GEE" in md
    html = studyctl("report", "table1", "--format", "html", "--db", db).output
    assert "<h2>Ratings</h2>" in html
    assert 'alt="ratings"' in html
    assert 'alt="scores"' in html
    assert 'alt="choice_most_like_tissue"' in html
    for fmt in ("html", "latex"):  # --holm reaches every format
        assert "Holm within each question" in studyctl("report", "table1", "--format", fmt, "--holm", "question", "--db", db).output
    latex = studyctl("report", "table1", "--format", "latex", "--db", db).output
    # yes/no, ratings, scores, choice (free text is not analysed), each a float or, when taller than the page, a longtable
    assert latex.count("\\begin{table}") + latex.count("\\begin{longtable}") == 4
    assert latex.count("\\toprule") >= 4
    assert latex_problems(document(latex), tmp_path) == []  # compiles, nothing wider than the A4 text block
    js = json.loads(studyctl("report", "table1", "--format", "json", "--db", db).output)
    assert set(js["kinds"]["scores"]) == set(k["scores"])
    assert js["rates"][0]["item"] == "stable"
    out = tmp_path / "export"
    assert studyctl("export", "--db", db, "--out", out).exit_code == 0
    with open(out / "conditions.csv", newline="") as f:
        conds = list(csv.DictReader(f))
    assert list(conds[0]) == ["session_id", "position", "model", "status", "label", "config", "config_sha256"]
    assert {r["model"]: json.loads(r["config"])["variant"] for r in conds} == {"paper": "paper", "located": "located"}


def test_answers_import_and_correct_follow_the_kinds(tmp_path):
    db = tmp_path / "s.db"
    proto = kinds_protocol(tmp_path)
    assert studyctl("study", "init", "--db", db, "--protocol", proto).exit_code == 0
    assert studyctl("participants", "add", "P01", "--db", db, "--age", "24").exit_code == 0
    assert studyctl("participants", "consent", "P01", "--db", db).exit_code == 0
    good = tmp_path / "good.csv"
    good.write_text("participant,model,item,answer,trial\nP01,paper,natural,6,\nP01,paper,stiffness,42.5,\nP01,paper,stable,yes,\n"
                    "P01,paper,smooth,4,1\nP01,,most_like_tissue,located,\nP01,,comment,felt fine,\n")
    res = studyctl("answers", "import", "--db", db, good)
    assert res.exit_code == 0, res.output
    con = sqlite3.connect(db)
    got = {r[0]: (r[1], r[2], r[3]) for r in con.execute("select item, answer, typeof(answer), trial from answers")}
    assert got == {"natural": (6, "integer", -1), "stiffness": (42.5, "real", -1), "stable": (1, "integer", -1), "smooth": (4, "integer", 1),
                   "most_like_tissue": ("located", "text", -1), "comment": ("felt fine", "text", -1)}
    for row, message in [
        ("P01,located,natural,8,", "answer '8' to natural (likert) is not allowed; allowed: an integer 1..7"),
        ("P01,located,stiffness,101,", "answer '101' to stiffness (vas) is not allowed; allowed: a number 0..100"),
        ("P01,located,stiffness,nan,", "answer 'nan' to stiffness (vas) is not allowed"),
        ("P01,,most_like_tissue,fem,", "answer 'fem' to most_like_tissue (choice) is not allowed; allowed: paper, located"),
        ("P01,paper,most_like_tissue,paper,", "item most_like_tissue is asked once at the end, about no one condition; leave the model empty"),
        ("P01,located,smooth,3,", "item smooth is asked after every trial; trial '' is not allowed; allowed: 0..1"),
        ("P01,located,natural,3,0", "item natural is not asked per trial; leave trial empty"),
    ]:
        bad = tmp_path / "bad.csv"
        bad.write_text("participant,model,item,answer,trial\n" + row + "\n")
        res = studyctl("answers", "import", "--db", db, bad)
        assert res.exit_code != 0, (row, res.output)
        assert message in res.output, (row, res.output)
    assert con.execute("select count(*) from answers").fetchone()[0] == 6  # nothing half-written
    res = studyctl("answers", "correct", "--db", db, "--participant", "P01", "--model", "paper", "--item", "stiffness",
                   "--answer", "40", "--reason", "typo on the form")
    assert res.exit_code == 0
    assert "stiffness: 42.5 -> 40" in res.output
    res = studyctl("answers", "correct", "--db", db, "--participant", "P01", "--item", "most_like_tissue", "--answer", "paper", "--reason", "r")
    assert res.exit_code == 0
    assert "most_like_tissue: located -> paper" in res.output
    res = studyctl("answers", "correct", "--db", db, "--participant", "P01", "--model", "paper", "--item", "natural", "--answer", "0",
                   "--reason", "r")
    assert res.exit_code != 0
    assert "allowed: an integer 1..7" in res.output
    assert con.execute("select old_answer, new_answer from corrections order by id").fetchall() == [(42.5, 40.0), ("located", "paper")]
    con.close()


def test_plan_powers_the_primary_analysis_and_its_null_is_at_alpha(tmp_path):
    from studyctl.synthetic.plan import null_table, pilot_summaries, power_table

    protocol = load_protocol(kinds_protocol(tmp_path, trials=1))
    summaries = pilot_summaries(protocol, pilots=2, seed=0)
    t = power_table(protocol, [6], simulations=8, seed=1, summaries=summaries)
    assert list(t["item"]) == ["natural", "realtime", "stiffness", "stable", "most_like_tissue", "sus", "nasa_tlx", "smooth (mean over trials)",
                               "primary"]
    assert t["power"].between(0, 1).all()
    own = pilot_summaries(protocol, pilots=2, seed=0, mapping={c: "paper" for c in protocol.conditions})
    # one model under every label: each test rejects at most at alpha, within 4 Monte Carlo errors
    # (the primary's GEE fits are the slow part: fewer of them)
    null = null_table(protocol, participants=12, simulations=200, seed=2, summaries=own, primary=False).set_index("item")
    assert (null["false_positive_rate"] <= 0.05 + 4 * null["mc_error"]).all(), null
    null = null_table(protocol, participants=10, simulations=40, seed=3, summaries=own).set_index("item")
    assert null.loc["primary", "false_positive_rate"] <= 0.05 + 4 * null.loc["primary", "mc_error"], null
    res = studyctl("plan", "--protocol", protocol.path, "--participants", "6", "--simulations", "10", "--pilots", "1", "--json")
    out = json.loads(res.stdout)
    assert out["synthetic"]
    assert out["primary"]["analysis"] == "ordinal_gee"
    assert "primary" in {r["item"] for r in out["rows"]}


def test_a_rig_profile_sets_the_latency_synthetic_participants_perceive(tmp_path):
    from studyctl.synthetic.rig import condition_keys

    proto = kinds_protocol(tmp_path, trials=1)
    protocol = load_protocol(proto)
    keys = condition_keys(protocol)
    profile = tmp_path / "rig.json"
    profile.write_text(json.dumps({"machine": "test rig", "conditions": [
        {"key": keys["paper"], "condition": "paper", "frame_ms_p50": 37.5, "frame_ms_p95": 40.0, "frames": 10},
        {"key": keys["located"], "condition": "located", "frame_ms_p50": 2.25, "frame_ms_p95": 3.0, "frames": 10}]}))
    db = tmp_path / "s.db"
    assert studyctl("study", "init", "--db", db, "--protocol", proto).exit_code == 0
    res = studyctl("calibrate", "rig", "--db", db, "--profile", profile)
    assert res.exit_code == 0
    assert "paper: 37.500 ms per frame" in res.output
    run_synthetic_study(db, 2, seed=1)
    con = sqlite3.connect(db)
    lat = dict(con.execute("select model, value from observer_features where feature = 'latency_ms' and code = 'S001'").fetchall())
    assert lat == {"paper": 37.5, "located": 2.25}
    con.close()
    profile.write_text(json.dumps({"conditions": [{"key": keys["paper"], "frame_ms_p50": float("nan"), "frame_ms_p95": 1.0}]}))
    res = studyctl("calibrate", "rig", "--db", db, "--profile", profile)
    assert res.exit_code != 0
    assert "conditions[0].frame_ms_p50: nan is out of range" in res.output
    assert "Traceback" not in res.output


def test_the_shipped_rig_profile_covers_the_shipped_protocols():
    from studyctl.synthetic.rig import frame_times

    for name in ("brain_pull_2015", "plate_spring_variants"):
        p = load_protocol(ROOT / f"protocols/{name}.toml")
        assert set(frame_times(p)) == set(p.conditions), name


def test_question_dataclass_defaults_are_the_papers_yes_no():
    q = Question("x", "X?")
    assert (q.kind, q.when, q.points, q.anchors, q.instrument, q.analysed) == ("yes_no", "condition", None, None, None, True)


END_AND_TRIAL = """
[[questions]]
id = "natural"
text = "Is interaction real and natural?"

[[questions]]
id = "again"
text = "Would you use the simulator again?"
when = "end"

[[questions]]
id = "overall"
text = "How realistic was the simulator overall?"
kind = "vas"
when = "end"

[[instruments]]
name = "nasa_tlx"
when = "trial"

[[instruments]]
name = "sus"
when = "end"
"""


def test_end_questions_and_instruments_per_trial_or_at_the_end_are_answered_and_scored(tmp_path):
    db = tmp_path / "s.db"
    run_synthetic_study(db, 5, seed=2, protocol_path=kinds_protocol(tmp_path, END_AND_TRIAL))
    con = sqlite3.connect(db)
    assert con.execute("select count(*) from sessions where status = 'done'").fetchone()[0] == 5
    end = con.execute("select item, model, trial, typeof(answer) from answers where item in ('again', 'overall', 'sus_1')").fetchall()
    assert sorted(set(end)) == [("again", "", -1, "integer"), ("overall", "", -1, "real"), ("sus_1", "", -1, "integer")]
    assert con.execute("select count(*) from answers where item = 'tlx_mental'").fetchone()[0] == 5 * 2 * 2
    con.close()
    k = json.loads(studyctl("report", "stats", "--json", "--db", db).output)["kinds"]
    # the TLX per trial is one score (the mean over trials of each trial's raw TLX), not six subscales
    assert set(k["scores"]) == {"nasa_tlx (mean over trials)"}
    assert k["primary"]["analysis"] == "logistic_gee"
    # the SUS at the end is one score per participant, described with the end questions, not ten items
    assert set(k["session"]) == {"sus", "again", "overall"}
    assert k["session"]["sus"]["n"] == 5
    assert 0 <= k["session"]["sus"]["mean"] <= 100
    md = studyctl("report", "table1", "--db", db).output
    assert "raw NASA-TLX (0-100) (mean over trials)" in md
    assert "Holm over all 2 pairs" in md
    assert "nan" not in md.lower()
    assert "Primary analysis, all questions: logistic GEE" in md


def test_two_conditions_print_no_nan_and_a_score_can_be_the_primary(tmp_path):
    qs = """
[[questions]]
id = "stiffness"
text = "How stiff did the tissue feel?"
kind = "vas"

[[questions]]
id = "rating"
text = "How real was it?"
kind = "likert"
points = 5
anchors = ["Not at all", "Completely"]
when = "trial"
"""
    db = tmp_path / "s.db"
    run_synthetic_study(db, 6, seed=1, protocol_path=kinds_protocol(tmp_path, qs))
    out = studyctl("report", "stats", "--db", db).output
    st = json.loads(studyctl("report", "stats", "--json", "--db", db).output)
    assert st["kinds"]["primary"]["analysis"] == "mixed_model"
    assert st["kinds"]["primary"]["items"] == ["stiffness"]
    assert out.splitlines()[1].startswith("Primary analysis: linear mixed model of How stiff did the tissue feel?")
    for fmt in ("md", "html", "latex"):
        text = re.sub(r"base64,[A-Za-z0-9+/=]+", "", studyctl("report", "table1", "--format", fmt, "--db", db).output)  # the pictures
        assert not re.search(r"\bnan\b", text.lower()), fmt
        assert "two conditions: the pair is the test" in text, fmt
    pairs = st["kinds"]["scores"]["stiffness"]["pairs"]
    assert len(pairs) == 1  # one pair: Holm leaves it
    assert pairs[0]["p_holm_primary"] == pytest.approx(pairs[0]["p_value"])


def test_a_rig_profile_covers_every_condition_or_none_and_is_fixed_once_sessions_ran(tmp_path):
    from studyctl.synthetic.rig import condition_keys, frame_times

    proto = kinds_protocol(tmp_path, trials=1)
    protocol = load_protocol(proto)
    keys = condition_keys(protocol)
    db = tmp_path / "s.db"
    assert studyctl("study", "init", "--db", db, "--protocol", proto).exit_code == 0
    profile = tmp_path / "rig.json"
    profile.write_text(json.dumps({"conditions": [{"key": "0" * 64, "frame_ms_p50": 1.0, "frame_ms_p95": 2.0}]}))
    res = studyctl("calibrate", "rig", "--db", db, "--profile", profile)
    assert res.exit_code != 0
    assert "the profile has no entry for the configurations" in res.output
    profile.write_text(json.dumps({"conditions": [{"key": keys["paper"], "frame_ms_p50": 5.0, "frame_ms_p95": 6.0}]}))
    assert studyctl("calibrate", "rig", "--db", db, "--profile", profile).exit_code == 0
    from studyctl.store import Store

    store = Store(db, mode="read")
    try:
        assert frame_times(protocol, store) == {}  # one condition of two: none (one latency scale for all)
    finally:
        store.close()
    run_synthetic_study(db, 1, seed=1)
    res = studyctl("calibrate", "rig", "--db", db, "--profile", profile)
    assert res.exit_code != 0
    assert "calibrate before the first session" in res.output
