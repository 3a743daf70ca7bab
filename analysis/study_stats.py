"""Everything `studyctl report stats --json` prints for a study, and Table 1 as Markdown: the
yes/no questions' rates, Cochran's Q and McNemar pairs (analysis/table1.py), each answer kind's
statistics (analysis/kinds.py), the logistic GEE across questions, and Holm over the family of
pairwise tests (analysis/stats.py)."""

from __future__ import annotations

import numpy as np
import pandas as pd

from analysis.kind_results import KindStats
from analysis.kinds import gee_line, kind_stats, kind_tables, primary_line
from analysis.reports.methods import study_methods
from analysis.reports.table import markdown, markdown_grid
from analysis.stats import HOLM_SCOPES, gee_fit, pairwise_mcnemar, records, set_holm
from analysis.study_results import DeformationBenchmark, LogisticGee, StudyStats, YesNoItem
from analysis.study_snapshot import Study
from analysis.table1 import (
    DEFORMATION_LABEL,
    answers_wide,
    binary_answers,
    cochran,
    complete_answers,
    condition_text,
    deformation,
    deformation_table,
    holm_text,
    incomplete_text,
    rates,
    study_facts,
    table,
)


def study_stats(study: Study, r: pd.DataFrame | None = None, q: pd.DataFrame | None = None, holm_scope: str = "family") -> StudyStats:
    """Everything `studyctl report stats --json` prints (`StudyStats.as_dict()`; `r`, `q`: rates and cochran already
    computed by the caller, so a report does not compute them twice) of `study`
    (analysis.study_snapshot.Study: the database read once). Complete cases only
    (`analysis.table1.complete_answers`). `holm_scope`: "family" (default: Holm over every
    pairwise McNemar test of every question) or "question" (within each question's pairs)."""
    if holm_scope not in HOLM_SCOPES:
        raise ValueError(f"holm_scope: {holm_scope!r}; allowed: {', '.join(HOLM_SCOPES)}")
    r = rates(study) if r is None else r
    q = cochran(study) if q is None else q
    protocol = study.protocol
    every, _ = complete_answers(study)
    answers = binary_answers(study, every)
    protocol_models = list(protocol.conditions)
    items = {}
    for item, g in r.groupby("item", sort=False):
        wide = answers_wide(answers, item, protocol_models)
        pairs = pairwise_mcnemar(wide) if len(wide) else pd.DataFrame(columns=["a", "b", "n01", "n10", "p_value", "p_holm", "odds_ratio"])
        qrow = q[q["item"] == item].iloc[0]
        items[item] = YesNoItem(
            question=g["question"].iloc[0],
            cochran_q=qrow["cochran_q"], df=int(qrow["df"]), p_value=qrow["p_value"], n_complete=int(qrow["n_complete"]),
            rates={row["model"]: {k: row[k] for k in ("yes", "no", "rate", "wilson_low", "wilson_high")} for _, row in g.iterrows()},
            pairs=records(pairs), reason=qrow.get("reason") if isinstance(qrow.get("reason"), str) else None,
        )
    kinds = kind_stats(study, every)
    _holm_family(items, holm_scope, kinds.family_pairs())
    gee = study_gee(study, answers, protocol_models)
    _name_tests(kinds, gee)
    facts = study_facts(study)
    return StudyStats(facts=facts, holm=holm_scope, items=items, gee=gee, kinds=kinds,
                      deformation=DeformationBenchmark(DEFORMATION_LABEL, deformation(study).to_dict(orient="records")),
                      methods=study_methods(study, facts, items, kinds, holm_scope))


PAIR_TESTS = {"scores": "t contrast of the linear mixed model (between-within df)",
              "choices": "exact binomial test of the two conditions' counts",
              "ordinal_gee": "Wald t of the proportional-odds GEE (participants - 1 df)",
              "gee": "Wald z of the logistic GEE (robust covariance)"}


def _name_tests(kinds: KindStats, gee: LogisticGee) -> None:
    """Every pairwise test in the JSON names itself (`test`), and one that could not be made says
    why (`reason`), as the rank and McNemar tests already do."""
    def name(pairs, test: str, problems=()) -> None:
        for p in pairs or []:
            p.setdefault("test", test)
            if p.get("p_value") is None or not np.isfinite(p["p_value"]):
                p.setdefault("reason", "; ".join(problems) or "not estimable")

    for v in kinds.scores.values():
        problems = v.mixed_model.get("problems") or []
        name(v.pairs, PAIR_TESTS["scores"], problems)
        name(v.mixed_model["pairs"], PAIR_TESTS["scores"], problems)
    for v in kinds.choices.values():
        name(v.pairs, PAIR_TESTS["choices"])
    if kinds.ordinal_gee:
        name(kinds.ordinal_gee["pairs"], PAIR_TESTS["ordinal_gee"], kinds.ordinal_gee.get("problems") or [])
    for part in [gee.composite, *gee.items.values()]:
        if part:
            name(part.get("pairs"), PAIR_TESTS["gee"], part.get("problems") or [])


def _holm_family(items: dict[str, YesNoItem], scope: str, others: list[list[dict]] = ()) -> None:
    """Set each pair's `p_holm`: over the whole family of pairwise tests (the yes/no questions'
    McNemar pairs and `others`: every other kind's pairs, a list per question or score), or per
    question (`p_holm_question` is kept either way)."""
    per_question = [v.pairs for v in items.values()] + list(others)
    for pairs in per_question:
        set_holm(pairs, "p_holm_question")
    family = [pair for pairs in per_question for pair in pairs]
    set_holm(family, "p_holm_family")
    for pair in family:
        pair["p_holm"] = pair["p_holm_family"] if scope == "family" else pair["p_holm_question"]


def study_gee(study: Study, answers: pd.DataFrame, models: list[str]) -> LogisticGee:
    """The primary analysis across questions: a logistic GEE with model and period (the
    condition's position in the participant's session, `study.periods`) and, for the composite
    over all questions, item as factors; then one per question, with Holm over the family of
    their pairwise contrasts."""
    if answers.empty or len(models) < 2:
        return LogisticGee(composite=None, items={})
    df = answers.merge(study.periods, on=["code", "model"], how="left")
    with_period = bool(df["period"].notna().all())
    if with_period:
        df["period"] = df["period"].astype(int)
    composite = gee_fit(df, models, with_period, with_item=True)
    items = {item: gee_fit(g, models, with_period) for item, g in df.groupby("item", sort=False)}
    set_holm([pair for v in items.values() for pair in v["pairs"]])
    set_holm(composite["pairs"])
    return LogisticGee(composite=composite, items=items, period_factor=with_period)


def table1_markdown(study: Study, holm_scope: str = "family") -> str:
    """Table 1 as Markdown: counts, rate [Wilson 95%] per model, Cochran's Q per item, McNemar
    pairs with Holm (over the family by default), the deformation-time row (a benchmark of
    this machine), headed by N (complete cases), the design and a synthetic-data flag; the
    GEE across questions below."""
    facts, r, q, d = study_facts(study), rates(study), cochran(study), deformation(study)
    st = study_stats(study, r, q, holm_scope=holm_scope)
    models = list(d["model"])
    flag = f"{facts.flag} " if facts.flag else ""
    if facts.mixed_source_participants:
        flag += f"WARNING: {', '.join(facts.mixed_source_participants)} answered both as a person and synthetically. "
    listed = incomplete_text(facts)
    left_out = f" Left out (incomplete): {listed}." if listed else ""
    scope = holm_text(st)
    lines = [f"**Table 1: {facts.study}.** {flag}N = {facts.participants} participants with every answer; {facts.design}.{left_out}", ""]
    if len(r):  # the yes/no questions: the paper's table
        t = table(st, r, q, d)
        lines += [*markdown_grid(t), "", t.notes, ""]
    for t in kind_tables(st.kinds, models, scope):
        lines += markdown(t)
    if not len(r):
        lines += [*markdown_grid(deformation_table(d)), ""]
    gee = gee_line(st.gee, st.kinds.primary.analysis == "logistic_gee")
    if gee:
        lines += [gee, ""]
    if st.kinds.primary.analysis in ("mixed_model", "choice"):
        lines += [primary_line(st), ""]
    if len(models) < 2:
        lines += ["One condition: there is nothing to compare between conditions (no Cochran's Q, McNemar or Friedman test); "
                  "a study with groups compares its groups instead.", ""]
    lines += ["Conditions (what each ran; participants saw only their labels): "
              + "; ".join(condition_text(c) for c in facts.conditions) + ".", ""]
    return "\n".join(lines)
