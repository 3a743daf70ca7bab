"""Everything `studyctl report stats --json` prints for a study (its tables and text are
analysis/reports/study_tables.py's): the yes/no questions' rates, Cochran's Q and McNemar pairs (analysis/statistics/table1.py), each answer kind's
statistics (analysis/statistics/kinds.py), the logistic GEE across questions, and Holm over the family of
pairwise tests (analysis/statistics/stats.py)."""

from __future__ import annotations

import pandas as pd

from analysis.statistics.faults import withheld, withhold_fit, withhold_pairs
from analysis.statistics.kinds import (
    PAIR_TESTS,
    family_pairs,
    kind_stats,
    kind_tests,
    odds_ratio_pairs,
)
from analysis.statistics.methods import study_methods
from analysis.statistics.result_records import ConditionRate, GeeFit, McNemarPair, OddsRatioPair
from analysis.statistics.stats import HOLM_SCOPES, gee_fit, holm, holm_family, named, pairwise_mcnemar, records
from analysis.statistics.study_results import DeformationBenchmark, DeformationRow, LogisticGee, StudyStats, YesNoItem
from analysis.statistics.table1 import (
    DEFORMATION_LABEL,
    answers_wide,
    binary_answers,
    cochran,
    complete_answers,
    deformation,
    events,
    rates,
    study_facts,
)
from analysis.study.study_snapshot import Study


def study_stats(study: Study, rates_frame: pd.DataFrame | None = None, cochran_frame: pd.DataFrame | None = None,
                holm_scope: str = "family") -> StudyStats:
    """Everything `studyctl report stats --json` prints (`StudyStats.as_dict()`; `rates_frame`, `cochran_frame`:
    `rates` and `cochran` of the study already computed by the caller, so a report does not compute them twice) of `study`
    (analysis.study.study_snapshot.Study: the database read once). Complete cases only
    (`analysis.statistics.table1.complete_answers`). `holm_scope`: "family" (default: Holm over every
    pairwise test of every question and kind) or "question" (within each question's pairs).
    Every test is run and Holm computed before a result is built: each is complete when built."""
    if holm_scope not in HOLM_SCOPES:
        raise ValueError(f"holm_scope: {holm_scope!r}; allowed: {', '.join(HOLM_SCOPES)}")
    r = rates(study) if rates_frame is None else rates_frame  # a row per question and condition
    q = cochran(study) if cochran_frame is None else cochran_frame  # a row per question
    protocol = study.protocol
    every, _ = complete_answers(study)
    answers = binary_answers(study, every)
    protocol_models = list(protocol.conditions)
    faults = events(study)
    held = withheld(faults)
    mcnemar = {}
    for item, _g in r.groupby("item", sort=False):
        wide = answers_wide(answers, item, protocol_models)
        mcnemar[item] = withhold_pairs(records(pairwise_mcnemar(wide)), held) if len(wide) else []
    tests = kind_tests(study, every)
    # Holm over the family: the yes/no questions' McNemar pairs and every other kind's pairs
    adjusted = holm_family([[p["p_value"] for p in pairs] for pairs in [*mcnemar.values(), *family_pairs(tests)]], holm_scope)
    items = {}
    for (item, g), holm_of in zip(r.groupby("item", sort=False), adjusted):
        qrow = q[q["item"] == item].iloc[0]
        items[item] = YesNoItem(
            question=g["question"].iloc[0],
            cochran_q=qrow["cochran_q"], df=int(qrow["df"]), p_value=qrow["p_value"], n_complete=int(qrow["n_complete"]),
            rates={row["model"]: ConditionRate(**{k: row[k] for k in ("yes", "no", "rate", "wilson_low", "wilson_high")}) for _, row in g.iterrows()},
            pairs=tuple(McNemarPair.of(p, **h) for p, h in zip(mcnemar[item], holm_of)),
            reason=qrow.get("reason") if isinstance(qrow.get("reason"), str) else None,
        )
    kinds = kind_stats(study, every, tests, adjusted[len(mcnemar):])
    gee = study_gee(study, answers, protocol_models, held)
    facts = study_facts(study)
    return StudyStats(facts=facts, holm=holm_scope, items=items, gee=gee, kinds=kinds, faults=faults,
                      deformation=DeformationBenchmark(DEFORMATION_LABEL, tuple(DeformationRow(**r) for r in deformation(study).to_dict(orient="records"))),
                      methods=study_methods(study, facts, items, kinds, holm_scope))


def study_gee(study: Study, answers: pd.DataFrame, models: list[str], held=None) -> LogisticGee:
    """The primary analysis across questions: a logistic GEE with model and period (the
    condition's position in the participant's session, `study.periods`) and, for the composite
    over all questions, item as factors; then one per question, with Holm over the family of
    their pairwise contrasts. `held`: the withheld conditions and why (analysis/statistics/faults.py): a
    fit over one of them is withheld."""
    held = held or {}
    if answers.empty or len(models) < 2:
        return LogisticGee(composite=None, items={})
    df = answers.merge(study.periods, on=["code", "model"], how="left")
    with_period = bool(df["period"].notna().all())
    if with_period:
        df["period"] = df["period"].astype(int)
    composite = withhold_fit(gee_fit(df, models, with_period, with_item=True), held, models)
    fits = {item: withhold_fit(gee_fit(g, models, with_period), held, models) for item, g in df.groupby("item", sort=False)}
    test = PAIR_TESTS["gee"]
    # Holm over every question's pairs together; a pair not made says why in its own fit's words
    together = iter(holm([pair["p_value"] for v in fits.values() for pair in v["pairs"]]))
    items = {item: GeeFit.of(v, pairs=tuple(OddsRatioPair.of(p, p_holm=next(together), **named(p, test, v.get("problems") or []))
                                            for p in v["pairs"]))
             for item, v in fits.items()}
    return LogisticGee(composite=GeeFit.of(composite, pairs=odds_ratio_pairs(composite["pairs"], test, composite.get("problems") or [])),
                       items=items, period_factor=with_period)


