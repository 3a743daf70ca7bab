"""A condition's model faults reach every report: a study with a condition whose model always
renders NaN (zeroed by the servo) says so in Table 1 (every format), the text and the stats, and
withholds every test involving it with the reason; synth warns; a study without faults shows no
fault section."""

from __future__ import annotations

import json
import math

import pandas as pd
import pytest

from analysis.statistics.faults import FAULT_SHARE_MAX, condition_events, withhold_fit, withhold_pairs
from studyctl.synthetic.synth_run import fault_warnings
from tests.helpers import BAD, fast_protocol, studyctl


def _events(*trials: dict) -> pd.DataFrame:
    return pd.DataFrame([{"code": "P1", "model": "m", "trial": k, "events": json.dumps(e)} for k, e in enumerate(trials)])


def test_a_fault_counts_its_trial_once_whatever_its_count():
    (e,) = condition_events(["m"], _events({"nan_force": 8, "grasp": 2}, {"grasp": 2}))
    assert (e.trials, e.fault_trials, e.affected_trials) == (2, 1, 1)


def test_force_clamping_is_a_safety_event_not_a_fault():
    (e,) = condition_events(["m"], _events({"force_clamped": 3}, {"force_clamped": 1}))
    assert (e.affected_trials, e.fault_trials, e.withheld) == (2, 0, False)


def test_a_condition_is_withheld_past_half_of_its_trials_faulty():
    (e,) = condition_events(["m"], _events({"nan_force": 1}, {"model_fault": 1}, {}))
    assert e.withheld


def test_a_condition_with_half_its_trials_faulty_is_not_withheld():
    """Exactly FAULT_SHARE_MAX: the rule is 'more than'."""
    (e,) = condition_events(["m"], _events({"nan_force": 1}, {}))
    assert (e.fault_share, e.withheld) == (FAULT_SHARE_MAX, False)


def test_the_kinds_name_the_trials_of_each():
    (e,) = condition_events(["m"], _events({"nan_force": 5, "force_clamped": 1}, {"nan_force": 2}))
    assert dict(e.kinds) == {"nan_force": 2, "force_clamped": 1}


def test_workflow_events_and_an_early_end_are_neither_faults_nor_safety_events():
    (e,) = condition_events(["m"], _events({"grasp": 2, "release": 1, "grasp_missed": 1, "ended_early": "escape"}))
    assert e.affected_trials == 0


def test_a_pair_involving_a_withheld_condition_is_not_tested_and_says_why():
    (p,) = withhold_pairs([{"a": "x", "b": "m", "p_value": 0.01, "reason": None}], {"m": "withheld: m is broken"})
    assert math.isnan(p["p_value"]) and p["reason"] == "withheld: m is broken"


def _fit_of_three() -> dict:
    """A model fit over x, y and m whose pair of the two sound conditions looks significant."""
    pair = {"difference": 1.0, "se": 0.2, "ci_low": 0.6, "ci_high": 1.4, "p_value": 0.01, "estimable": True}
    return {"converged": True, "estimable": True, "problems": [],
            "pairs": [{"a": a, "b": b} | pair for a, b in (("x", "y"), ("x", "m"), ("y", "m"))]}


def test_a_withheld_fit_reports_no_p_value_even_between_two_sound_conditions():
    fit = withhold_fit(_fit_of_three(), {"m": "withheld: m is broken"}, ["x", "y", "m"])
    assert math.isnan(fit["pairs"][0]["p_value"])


def test_a_withheld_fit_reports_no_difference_even_between_two_sound_conditions():
    fit = withhold_fit(_fit_of_three(), {"m": "withheld: m is broken"}, ["x", "y", "m"])
    assert math.isnan(fit["pairs"][0]["difference"])


def test_a_withheld_fit_gives_its_reason_on_every_pair():
    fit = withhold_fit(_fit_of_three(), {"m": "withheld: m is broken"}, ["x", "y", "m"])
    assert [p["reason"] for p in fit["pairs"]] == ["withheld: m is broken"] * 3


def test_a_withheld_fit_marks_every_pair_not_estimable():
    fit = withhold_fit(_fit_of_three(), {"m": "withheld: m is broken"}, ["x", "y", "m"])
    assert [p["estimable"] for p in fit["pairs"]] == [False] * 3


def test_a_fit_over_sound_conditions_keeps_its_p_values():
    fit = withhold_fit(_fit_of_three(), {"z": "withheld: z is broken"}, ["x", "y", "m"])
    assert [p["p_value"] for p in fit["pairs"]] == [0.01] * 3


def test_synth_warns_only_of_a_condition_whose_trials_are_mostly_faults():
    events = pd.concat([_events({"nan_force": 3}), _events({"force_clamped": 2}).assign(model="ok")])
    assert fault_warnings(["m", "ok"], events) == [
        "condition m: 1 of 1 trials had a model fault (nan_force 1); the reports withhold every test involving it"]


@pytest.fixture(scope="module")
def nan_study(tmp_path_factory):
    """Three synthetic participants, one 1 s trial per condition: plate_spring and a model whose
    force is NaN whenever pulled (zeroed by the servo, a nan_force event in every trial)."""
    tmp = tmp_path_factory.mktemp("nan_study")
    proto = fast_protocol(tmp, conditions=("plate_spring", "nan"), trials=1)
    proto.write_text(proto.read_text().replace("[inclusion]", f'[conditions.nan]\nmodel = "{BAD}:NanForce"\n\n[inclusion]', 1))
    db = tmp / "s.db"
    res = studyctl("synth", "--protocol", proto, "--db", db, "--participants", 3, "--seed", 1)
    return db, res


@pytest.fixture(scope="module")
def clean_study(tmp_path_factory):
    """plate_spring and a plugin spring that keeps the contract: no fault, no safety event."""
    tmp = tmp_path_factory.mktemp("clean_study")
    proto = fast_protocol(tmp, conditions=("plate_spring", "own"), trials=1)
    proto.write_text(proto.read_text().replace("[inclusion]", f'[conditions.own]\nmodel = "{BAD}:Spring"\n\n[inclusion]', 1))
    db = tmp / "s.db"
    res = studyctl("synth", "--protocol", proto, "--db", db, "--participants", 2, "--seed", 1)
    assert res.exit_code == 0, res.output
    return db


WITHHELD = "withheld: condition nan had a model fault in 3 of its 3 trials (nan_force), more than 50%"


def test_synth_of_a_nan_model_succeeds(nan_study):
    assert nan_study[1].exit_code == 0, nan_study[1].output


def test_synth_of_a_nan_model_warns_once_naming_the_condition_and_the_fault(nan_study):
    lines = [ln for ln in nan_study[1].output.splitlines() if ln.startswith("warning:")]
    assert lines == ["warning: condition nan: 3 of 3 trials had a model fault (nan_force 3); the reports withhold every test involving it"]


def test_table1_md_shows_each_condition_s_faults(nan_study):
    out = studyctl("report", "table1", "--db", nan_study[0]).output
    assert "| nan | 3 of 3 trials (nan_force 3) | 3 of 3 (100%) | WITHHELD: condition nan had a model fault" in out


def test_table1_md_withholds_cochran_s_q_with_the_reason(nan_study):
    out = studyctl("report", "table1", "--db", nan_study[0]).output
    assert f"| n/a ({WITHHELD}) | plate_spring-nan not tested: {WITHHELD} |" in out


def test_table1_md_says_the_gee_is_withheld(nan_study):
    gee = next(ln for ln in studyctl("report", "table1", "--db", nan_study[0]).output.splitlines() if "logistic GEE" in ln)
    assert WITHHELD in gee


@pytest.mark.parametrize("fmt,expected", [
    ("latex", "WITHHELD: condition nan had a model fault in 3 of its 3 trials (nan\\_\\allowbreak{}force)"),
    ("html", "WITHHELD: condition nan had a model fault in 3 of its 3 trials (nan_force)"),
])
def test_table1_latex_and_html_show_the_faults_table(nan_study, fmt, expected):
    out = studyctl("report", "table1", "--db", nan_study[0], "--format", fmt).output
    assert expected in out


def test_table1_csv_carries_each_condition_s_events(nan_study):
    rows = pd.read_csv(pd.io.common.StringIO(studyctl("report", "table1", "--db", nan_study[0], "--format", "csv").output), keep_default_na=False)
    assert set(rows.loc[rows["model"] == "nan", "event_kinds"]) == {"nan_force 3"}


def test_table1_json_carries_each_condition_s_faults(nan_study):
    faults = json.loads(studyctl("report", "table1", "--db", nan_study[0], "--format", "json").output)["faults"]
    assert [(f["condition"], f["fault_trials"], f["withheld"]) for f in faults] == [("plate_spring", 0, False), ("nan", 3, True)]


def test_report_text_says_the_condition_was_withheld(nan_study):
    out = studyctl("report", "text", "--db", nan_study[0]).output
    assert "WITHHELD: nan's trials were mostly model faults (3 of 3)" in out


def test_report_text_reports_no_test_of_a_withheld_condition_as_made(nan_study):
    out = studyctl("report", "text", "--db", nan_study[0]).output
    assert "Cochran's Q(" not in out


def test_report_stats_json_carries_the_faults_per_condition(nan_study):
    st = json.loads(studyctl("report", "stats", "--db", nan_study[0], "--json").output)
    assert [f["kinds"] for f in st["faults"]] == [{}, {"nan_force": 3}]


def test_report_stats_json_withholds_every_mcnemar_pair_with_the_reason(nan_study):
    st = json.loads(studyctl("report", "stats", "--db", nan_study[0], "--json").output)
    assert {p["reason"] for v in st["items"].values() for p in v["pairs"]} == {WITHHELD}


def test_a_study_without_faults_has_no_fault_table(clean_study):
    assert "Faults and safety events" not in studyctl("report", "table1", "--db", clean_study).output


def test_a_study_without_faults_keeps_its_csv_columns(clean_study):
    head = studyctl("report", "table1", "--db", clean_study, "--format", "csv").output.splitlines()[0]
    assert head == "item,question,model,yes,no,n,rate,wilson_low,wilson_high,participants,synthetic"


def test_a_study_without_faults_says_nothing_of_them_in_its_text(clean_study):
    assert "Faults and safety events" not in studyctl("report", "text", "--db", clean_study).output


def test_a_study_without_faults_lists_none_per_condition_in_its_stats(clean_study):
    st = json.loads(studyctl("report", "stats", "--db", clean_study, "--json").output)
    assert [f["affected_trials"] for f in st["faults"]] == [0, 0]


@pytest.fixture(scope="module")
def nan_ratings(tmp_path_factory):
    """The ratings example (Likert items, the SUS, a choice) with its FEM replaced by the NaN model."""
    from tests.helpers import variants_protocol

    tmp = tmp_path_factory.mktemp("nan_ratings")
    proto = variants_protocol(tmp)
    text = proto.read_text().replace('conditions = ["paper", "located", "fem_linear"]', 'conditions = ["paper", "located", "nan"]')
    proto.write_text(text.replace('[conditions.fem_linear]\nmodel = "fem"\nformulation = "linear"', f'[conditions.nan]\nmodel = "{BAD}:NanForce"'))
    db = tmp / "s.db"
    res = studyctl("synth", "--protocol", proto, "--db", db, "--participants", 3, "--seed", 2)
    assert res.exit_code == 0, res.output
    return json.loads(studyctl("report", "stats", "--db", db, "--json").output)


def test_a_rating_s_friedman_test_is_withheld_with_the_reason(nan_ratings):
    assert {v["friedman"]["reason"] for v in nan_ratings["kinds"]["ratings"].values()} == {
        "withheld: condition nan had a model fault in 3 of its 3 trials (nan_force), more than 50%"}


def test_a_rating_pair_without_the_withheld_condition_is_not_withheld(nan_ratings):
    pairs = [p for v in nan_ratings["kinds"]["ratings"].values() for p in v["pairs"] if "nan" not in (p["a"], p["b"])]
    assert not [p for p in pairs if (p.get("reason") or "").startswith("withheld")]


def test_a_rating_pair_with_the_withheld_condition_is_withheld(nan_ratings):
    pairs = [p for v in nan_ratings["kinds"]["ratings"].values() for p in v["pairs"] if "nan" in (p["a"], p["b"])]
    assert {p["reason"].split(":")[0] for p in pairs} == {"withheld"}


def test_the_score_s_mixed_model_is_withheld(nan_ratings):
    assert all(v["mixed_model"]["model_test"]["reason"].startswith("withheld: condition nan") for v in nan_ratings["kinds"]["scores"].values())


def test_a_choice_s_test_of_equal_chances_is_withheld(nan_ratings):
    assert {v["overall"]["reason"] for v in nan_ratings["kinds"]["choices"].values()} == {
        "withheld: condition nan had a model fault in 3 of its 3 trials (nan_force), more than 50%"}


def test_a_withheld_rating_pair_reports_no_effect_size(nan_ratings):
    pairs = [p for v in nan_ratings["kinds"]["ratings"].values() for p in v["pairs"] if "nan" in (p["a"], p["b"])]
    assert {p["rank_biserial"] for p in pairs} == {None}


def test_synth_json_carries_the_warning(tmp_path):
    proto = fast_protocol(tmp_path, conditions=("nan",), trials=1)
    proto.write_text(proto.read_text().replace("[inclusion]", f'[conditions.nan]\nmodel = "{BAD}:NanForce"\n\n[inclusion]', 1))
    res = studyctl("synth", "--protocol", proto, "--db", tmp_path / "s.db", "--participants", 1, "--seed", 1, "--json")
    out = json.loads(res.stdout)
    assert out["warnings"] == ["condition nan: 1 of 1 trials had a model fault (nan_force 1); the reports withhold every test involving it"]


def test_a_withheld_mixed_model_s_pair_of_two_sound_conditions_has_no_p_value(nan_ratings):
    pairs = [p for v in nan_ratings["kinds"]["scores"].values() for p in v["pairs"] if "nan" not in (p["a"], p["b"])]
    assert [(p["p_value"], p["p_holm"]) for p in pairs] == [(None, None)]


def test_holm_s_family_holds_no_pair_of_a_withheld_mixed_model(nan_ratings):
    """The family is the tested rating and choice pairs: the withheld SUS model adds none."""
    tested = [p for part in ("ratings", "choices") for v in nan_ratings["kinds"][part].values() for p in v["pairs"] if p["p_value"] is not None]
    assert nan_ratings["methods"]["analysis"]["holm_family"] == len(tested)
