"""A discrimination condition's model faults reach `report jnd`: each trial stores its two
intervals' servo events; a condition whose model always renders NaN (zeroed by the servo) shows
in the faults table of every format, its summary and the group test are withheld with the reason;
synth warns; a study without faults reports as before; a schema-9 database migrates. And
`report validity` shows the same table and tests nothing of a withheld condition."""

from __future__ import annotations

import json
import sqlite3

import pandas as pd
import pytest

from analysis.discrimination.jnd import _group, task_events
from analysis.reports import validity_report as vr
from analysis.statistics.faults import condition_events
from studyctl.store import Store
from studyctl.store.snapshot import read_study
from tests.helpers import BAD, ROOT, jnd_protocol, studyctl

WITHHELD = "withheld: condition nan had a model fault in 20 of its 20 trials (nan_force), more than 50%"


@pytest.fixture(scope="module")
def nan_jnd(tmp_path_factory):
    """Two synthetic participants, ten 1 s two-interval trials per condition: plate_spring and a
    model whose force is NaN whenever pulled (a nan_force event in every interval)."""
    tmp = tmp_path_factory.mktemp("nan_jnd")
    proto = jnd_protocol(tmp, conditions=("plate_spring", "nan"), trials=10)
    proto.write_text(proto.read_text().replace("[inclusion]", f'[conditions.nan]\nmodel = "{BAD}:NanForceScaled"\n\n[inclusion]', 1))
    db = tmp / "s.db"
    res = studyctl("synth", "--protocol", proto, "--db", db, "--participants", 2, "--seed", 1)
    assert res.exit_code == 0, res.output
    return db, res.output


@pytest.fixture(scope="module")
def nan_json(nan_jnd):
    return json.loads(studyctl("report", "jnd", "--db", nan_jnd[0], "--json").output)


def _events(db, model: str) -> list[dict]:
    with sqlite3.connect(db) as con:
        return [json.loads(r[0]) for r in con.execute("select events from discrimination where model = ?", (model,))]


def test_every_discrimination_trial_of_the_nan_model_stores_its_nan_force_events(nan_jnd):
    assert all(e.get("nan_force", 0) > 0 for e in _events(nan_jnd[0], "nan"))


def test_a_discrimination_trial_stores_both_intervals_grasps(nan_jnd):
    """Each interval grasps with both hands: four grasps a trial, so the two are summed."""
    assert {e["grasp"] for e in _events(nan_jnd[0], "plate_spring")} == {4}


def test_synth_warns_of_the_discrimination_trials_faults(nan_jnd):
    lines = [ln for ln in nan_jnd[1].splitlines() if ln.startswith("warning:")]
    assert lines == ["warning: condition nan: 20 of 20 discrimination trials had a model fault (nan_force 20); "
                     "the reports withhold every test involving it"]


def test_report_jnd_json_carries_each_condition_s_faults(nan_json):
    assert [(f["condition"], f["fault_trials"], f["withheld"]) for f in nan_json["faults"]] == [("plate_spring", 0, False), ("nan", 20, True)]


def test_report_jnd_json_withholds_the_group_test_with_the_reason(nan_json):
    assert nan_json["group"]["problems"] == [WITHHELD]


def test_report_jnd_json_runs_no_mixed_model_on_a_withheld_condition(nan_json):
    assert nan_json["group"]["mixed_model"] is None


def test_report_jnd_json_withholds_the_pair_with_the_reason(nan_json):
    assert [p["reason"] for p in nan_json["group"]["pairs"]] == [WITHHELD]


def test_report_jnd_json_claims_no_geometric_mean_of_a_withheld_condition(nan_json):
    (c,) = [c for c in nan_json["conditions"] if c["condition"] == "nan"]
    assert (c["geometric_mean"], c["reason"]) == (None, WITHHELD)


def test_report_jnd_json_keeps_the_tested_condition_s_geometric_mean(nan_json):
    (c,) = [c for c in nan_json["conditions"] if c["condition"] == "plate_spring"]
    assert c["geometric_mean"] > 0


@pytest.mark.parametrize("fmt,expected", [
    ("md", "| nan | 20 of 20 trials (nan_force 20) | 20 of 20 (100%) | WITHHELD: condition nan had a model fault"),
    ("html", "WITHHELD: condition nan had a model fault in 20 of its 20 trials (nan_force)"),
    ("latex", "WITHHELD: condition nan had a model fault in 20 of its 20 trials (nan\\_\\allowbreak{}force)"),
])
def test_report_jnd_shows_the_faults_table_in_every_format(nan_jnd, fmt, expected):
    out = studyctl("report", "jnd", "--db", nan_jnd[0], "--format", fmt).output
    assert expected in out


@pytest.mark.parametrize("fmt", ["md", "html", "latex"])
def test_report_jnd_says_the_group_test_was_not_made_in_every_format(nan_jnd, fmt):
    out = studyctl("report", "jnd", "--db", nan_jnd[0], "--format", fmt).output
    assert "Mixed model and Wilcoxon across the conditions: not tested (withheld: condition nan" in out.replace("\\_\\allowbreak{}", "_")


def test_report_jnd_md_shows_the_withheld_condition_s_summary_as_withheld(nan_jnd):
    out = studyctl("report", "jnd", "--db", nan_jnd[0]).output
    assert f"| nan | 2 | WITHHELD: {WITHHELD.removeprefix('withheld: ')} | - |" in out


def test_report_table1_of_the_discrimination_study_shows_the_faults(nan_jnd):
    assert "| nan | 20 of 20 trials (nan_force 20) |" in studyctl("report", "table1", "--db", nan_jnd[0]).output


def test_report_text_says_the_condition_was_withheld(nan_jnd):
    out = studyctl("report", "text", "--db", nan_jnd[0]).output
    assert f"nan: no Weber fraction is reported ({WITHHELD})." in out


def test_a_discrimination_study_without_faults_has_no_faults_key(tmp_path):
    """Two conditions that keep the contract: the JSON as before (no `faults`), the md without a
    faults table."""
    proto = jnd_protocol(tmp_path, conditions=("plate_spring", "own"), trials=10)
    proto.write_text(proto.read_text().replace("[inclusion]", '[conditions.own]\nmodel = "plate_spring"\nvariant = "paper"\n\n[inclusion]', 1))
    db = tmp_path / "s.db"
    assert studyctl("synth", "--protocol", proto, "--db", db, "--participants", 1, "--seed", 1).exit_code == 0
    assert "faults" not in json.loads(studyctl("report", "jnd", "--db", db, "--json").output)


def _webers(n: int) -> pd.DataFrame:
    """n participants' Weber fractions in conditions a, b and c (b 1.5 times a, c varied)."""
    return pd.DataFrame([{"code": f"S{k}", "condition": c, "weber": w, "converged": True}
                         for k in range(n) for c, w in (("a", 0.1 + 0.01 * k), ("b", 0.15 + 0.02 * k), ("c", 0.3 - 0.03 * k))])


HELD = {"c": "withheld: condition c is broken"}


def test_the_pair_of_the_conditions_kept_is_still_tested():
    (ab, *_) = _group(_webers(4), ["a", "b", "c"], HELD)["pairs"]
    assert (ab["a"], ab["b"], ab["ratio"] > 1) == ("a", "b", True)


def test_a_pair_with_the_withheld_condition_carries_its_reason():
    pairs = _group(_webers(4), ["a", "b", "c"], HELD)["pairs"]
    assert [p.get("reason") for p in pairs] == [None, HELD["c"], HELD["c"]]


def test_a_kept_pair_too_small_to_test_says_its_own_reason_not_the_withheld_one():
    (ab, *_) = _group(_webers(2), ["a", "b", "c"], HELD)["pairs"]
    assert ab["reason"] == "fewer than 3 participants with a Weber fraction in every condition"


def _schema_9(tmp_path):
    """A discrimination study as software of schema 9 left it: one trial, no events column."""
    db = tmp_path / "s.db"
    assert studyctl("study", "init", "--protocol", jnd_protocol(tmp_path), "--db", db).exit_code == 0
    studyctl("participants", "add", "S01", "--synthetic", "--db", db)
    con = sqlite3.connect(db)
    con.execute("insert into sessions (id, code, started_at, status, synthetic, device) values (1, 'S01', '', 'done', 1, 'simulated')")
    con.execute("insert into discrimination (session_id, code, model, task, trial, delta, comparison_interval, answer, correct, state, "
                "source) values (1, 'S01', 'plate_spring', 0, 0, 0.5, 1, 1, 1, '{}', 'synthetic')")
    con.execute("alter table discrimination drop column events")
    con.execute("update meta set value = '9' where key = 'schema_version'")
    con.commit()
    con.close()
    return db


def test_a_schema_9_study_migrates_with_an_events_column(tmp_path):
    db = _schema_9(tmp_path)
    assert studyctl("study", "migrate", "--db", db).exit_code == 0
    with sqlite3.connect(db) as con:
        assert con.execute("select trial, events from discrimination").fetchall() == [(0, None)]


def test_a_migrated_study_s_trial_without_events_counts_as_a_trial_without_faults(tmp_path):
    db = _schema_9(tmp_path)
    studyctl("study", "migrate", "--db", db)
    with Store(db, mode="read") as store:
        (e,) = condition_events(["plate_spring"], task_events(read_study(store), 0))
    assert (e.trials, e.affected_trials) == (1, 0)


# -- construct validity --------------------------------------------------------------------------

CV_WITHHELD = "withheld: condition nan had a model fault in 6 of its 6 trials (nan_force), more than 50%"


@pytest.fixture(scope="module")
def nan_validity(tmp_path_factory):
    """protocols/construct_validity.toml with a second condition whose force is NaN: three
    synthetic participants (one a group), two trials a condition; the report with one
    permutation and one bootstrap replicate (what is tested here is what is withheld)."""
    tmp = tmp_path_factory.mktemp("nan_validity")
    cv = ROOT / "protocols" / "construct_validity.toml"
    text = cv.read_text().replace("trials_per_condition = 10 ", "trials_per_condition = 2 ").replace("training_minutes = 2.0", "training_minutes = 0.0")
    text = text.replace('scene = "scenes/retraction.toml"', f'scene = "{cv.parent / "scenes" / "retraction.toml"}"')
    text = text.replace('conditions = ["plate_spring"]', 'conditions = ["plate_spring", "nan"]')
    proto = tmp / "cv.toml"
    proto.write_text(text.replace("[inclusion]", f'[conditions.nan]\nmodel = "{BAD}:NanForce"\n\n[inclusion]', 1))
    db = tmp / "s.db"
    assert studyctl("synth", "--protocol", proto, "--db", db, "--participants", 3, "--seed", 1).exit_code == 0
    with Store(db, mode="read") as store:
        return vr.validity_report(read_study(store), permutations=1, group_permutations=1, bootstrap=1)


def test_report_validity_json_carries_each_condition_s_faults(nan_validity):
    faults = json.loads(vr.to_json(nan_validity))["faults"]
    assert [(f["condition"], f["fault_trials"], f["withheld"]) for f in faults] == [("plate_spring", 0, False), ("nan", 6, True)]


@pytest.mark.parametrize("render,expected", [
    (vr.markdown, f"| nan | 6 of 6 trials (nan_force 6) | 6 of 6 (100%) | WITHHELD: {CV_WITHHELD.removeprefix('withheld: ')} |"),
    (vr.latex, "WITHHELD: condition nan had a model fault in 6 of its 6 trials (nan\\_\\allowbreak{}force)"),
    (lambda rep: vr.html(rep | {"metrics": []}), f"WITHHELD: {CV_WITHHELD.removeprefix('withheld: ')}"),  # its tables, not its figures
], ids=["md", "latex", "html"])
def test_report_validity_shows_the_faults_table_in_every_format(nan_validity, render, expected):
    assert expected in render(nan_validity)


def test_report_validity_tests_no_group_difference_in_a_withheld_condition(nan_validity):
    kw = nan_validity["kruskal"]
    assert set(kw.loc[kw["condition"] == "nan", "reason"]) == {CV_WITHHELD}


def test_report_validity_gives_no_p_in_a_withheld_condition(nan_validity):
    kw = nan_validity["kruskal"]
    assert kw.loc[kw["condition"] == "nan", "p"].isna().all()


def test_report_validity_tests_no_pair_of_groups_in_a_withheld_condition(nan_validity):
    pairs = nan_validity["pairs"]
    assert set(pairs.loc[pairs["condition"] == "nan", "reason"]) == {CV_WITHHELD}


def test_report_validity_still_describes_a_withheld_condition_s_groups(nan_validity):
    desc = nan_validity["descriptives"]
    assert desc.loc[desc["condition"] == "nan", "median"].notna().any()


def test_report_validity_fits_no_mixed_model_across_a_withheld_condition(nan_validity):
    assert nan_validity["mixed_model"]["reason"] == CV_WITHHELD
