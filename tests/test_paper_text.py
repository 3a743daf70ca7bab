"""`studyctl report text`: the methods and results paragraphs. Every number in them is a value of
`report stats --json` at its printed precision (APA style), and the text says synthetic first."""

from __future__ import annotations

import json
import re
from types import SimpleNamespace

import pytest

from analysis.reports import paper_text
from analysis.statistics.methods import Procedure, QuestionAsked
from sim.text import counted
from tests.helpers import unsupported_numbers


def test_the_checker_finds_a_number_the_json_does_not_hold():
    doc = {"a": 0.0655, "b": 0.375, "c": 2, "q": "Is it 3 mm?"}
    assert unsupported_numbers("Q(2) = .066, 37.5%, “Is it 3 mm?”", doc) == []
    assert unsupported_numbers("Q(2) = .067", doc) == [".067"]
    assert unsupported_numbers("37.6%", doc) == ["37.6%"]
    assert unsupported_numbers("p < .001", doc) == ["p < .001"]


def test_apa_numbers():
    assert paper_text.p_text(0.0657) == "p = .066"
    assert paper_text.p_text(0.0004) == "p < .001"
    assert paper_text.p_text(float("nan")) is None
    assert paper_text.unit(0.0708) == ".07"
    assert paper_text.unit(-0.3137) == "-.31"
    assert paper_text.sig(0.004182567) == "0.00418"
    assert paper_text.sig(6.7449) == "6.74"
    assert paper_text.sig(4502.887) == "4503"


def _text_and_json(db, *args) -> tuple[str, dict]:
    from tests.helpers import studyctl

    text = studyctl("report", "text", "--db", db, *args)
    stats = studyctl("report", "stats", "--db", db, "--json")
    assert text.exit_code == 0, text.output + stats.output
    assert stats.exit_code == 0, text.output + stats.output
    return text.output, json.loads(stats.output)


@pytest.mark.parametrize("which", ["paper", "variants"])
def test_every_number_of_the_text_is_in_the_stats_json(which, small_study, variants_study):
    db = small_study if which == "paper" else variants_study
    text, doc = _text_and_json(db)
    assert text.startswith("## Participants\n\nSYNTHETIC DATA (simulated participants)")
    assert [h for h in re.findall(r"^## (\w+)", text, re.M)] == ["Participants", "Design", "Apparatus", "Procedure", "Analysis", "Results"]
    assert unsupported_numbers(text, doc) == []
    m = doc["methods"]
    assert f"N = {m['participants']['n']} participants" in text
    assert counted(m['design']['trials_per_condition'], 'trial') in text  # "1 trial" with the fast protocol
    if which == "paper":  # the primary analysis and a yes/no item, as the JSON has them
        item = next(iter(doc["items"].values()))
        assert f"Cochran's Q({item['df']}) = {item['cochran_q']:.2f}" in text
        assert "logistic GEE across the yes/no questions" in text
    else:
        assert "proportional-odds GEE" in text
        assert "Friedman χ²(2)" in text
        assert "System Usability Scale (SUS) (Brooke, 1996" in text
        assert "Which condition felt most like real brain tissue?" in text


def test_the_latex_text_compiles(variants_study, tmp_path):
    from analysis.reports.latex import document
    from tests.helpers import latex_problems

    text, _ = _text_and_json(variants_study, "--format", "latex")
    assert "\\subsection*{Results}" in text
    assert "$\\chi$$^{2}$(2)" in text
    assert latex_problems(document(text), tmp_path) == []


def test_json_holds_the_same_paragraphs(small_study):
    from tests.helpers import studyctl

    md = studyctl("report", "text", "--db", small_study).output
    js = json.loads(studyctl("report", "text", "--db", small_study, "--json").output)
    assert [s["heading"] for s in js["sections"]] == re.findall(r"^## (\w+)", md, re.M)
    assert all(p in md for s in js["sections"] for p in s["paragraphs"])


def test_effects_name_their_direction_and_only_what_a_model_reads(variants_study):
    """A pair's effect says which condition it favours (an odds ratio and a difference are the
    second condition's relative to the first; a rank-biserial r is positive when the first is
    higher), and a condition's material is the one its model reads (a plate-spring stack has its
    own stiffness; its variant tells two plate-spring conditions apart)."""
    text, doc = _text_and_json(variants_study)
    apparatus = text.split("## Apparatus")[1].split("## Procedure")[0]
    assert "Condition paper ran the plate_spring model built into brainsim-study (variant paper)" in apparatus
    assert "Condition located ran the plate_spring model built into brainsim-study (variant located)" in apparatus
    plate = [s for s in apparatus.split(". ") if "plate_spring model" in s]
    assert plate
    assert not any("Young" in s or "law" in s for s in plate)
    for p in doc["kinds"]["ordinal_gee"]["pairs"]:
        if p["p_holm"] < 0.05:
            assert f"{p['b']} relative to {p['a']}, OR = {p['odds_ratio']:.2f}" in text
    for v in doc["kinds"]["ratings"].values():
        for p in v["pairs"]:
            if p["p_holm"] is not None and p["p_holm"] < 0.05:
                assert f"{p['a']} over {p['b']}, rank-biserial r = {paper_text.unit(p['rank_biserial'])}" in text


def test_a_vas_question_names_its_scale_once():
    """"(visual analogue scale on a visual analogue scale from ...)"."""
    asked = QuestionAsked(id="stiff", text="How stiff?", kind="vas", when="after_condition", points=None, anchors=("soft", "hard"),
                          instrument=None)
    m = SimpleNamespace(procedure=Procedure(questions=(asked,), instruments=(), tasks=()))
    assert paper_text._procedure(m).count("visual analogue scale") == 1
