"""The statistics that fit each kind of answer (docs/analysis.md), beside the yes/no Table 1:

- ratings (Likert items asked after each condition): median [IQR] and the distribution per
  condition; Friedman with Kendall's W [95% CI]; Wilcoxon signed-rank pairs with the
  rank-biserial correlation [95% CI]; across the items, a proportional-odds GEE;
- scores (VAS items, the SUS and raw NASA-TLX scores, and every question asked after each
  trial, as each participant's mean over the trials): mean [95% CI] per condition; a linear
  mixed model with condition and period (its pairs in the Holm family); Friedman as the
  non-parametric check;
- choices (one condition picked at the end): counts and shares [Wilson 95%], the exact
  multinomial test of equal chances, exact binomial pairs;
- other questions asked once at the end: described, not tested (there is no condition to compare).

Instrument items are not tested one by one: they enter through their instrument's score. Free
text is exported, never analysed. Complete cases only (analysis.statistics.table1.complete_answers).
"""

from __future__ import annotations

import numpy as np
import pandas as pd
from scipy.stats import wilcoxon

from analysis.statistics import scales
from analysis.statistics.faults import condition_events, involving, withheld, withhold_fit, withhold_pairs
from analysis.statistics.kind_results import ChoiceStats, KindStats, PrimaryAnalysis, RatingStats, ScoreStats
from analysis.statistics.result_records import (
    ChoicePair,
    ChoiceShare,
    ChoiceTest,
    DifferencePair,
    EndRate,
    EndSummary,
    Friedman,
    MixedModelFit,
    ModelMean,
    ModelTest,
    OddsRatioPair,
    OrdinalGeeFit,
    RankPair,
    RatingSummary,
    Summary,
)
from analysis.statistics.stats import friedman, holm, holm_family, named, records, wilson
from analysis.statistics.withhold import across_reason
from analysis.study import instruments
from analysis.study.questions import VAS_RANGE, Kind
from analysis.study.study_snapshot import Study

TRIAL_MEAN = " (mean over trials)"


def _rating_items(protocol) -> list:
    return [q for q in protocol.asked("condition") if q.kind == Kind.LIKERT and q.instrument is None]


def _score_questions(protocol) -> list:
    return [q for q in protocol.asked("condition") if q.kind == Kind.VAS and q.instrument is None]


def _per_trial_items(protocol) -> list:
    """The questions asked after every trial that are analysed as a mean over trials (an
    instrument's items enter through its score)."""
    return [q for q in protocol.asked("trial") if q.analysed and q.kind != Kind.CHOICE and q.instrument is None]


def score_scale(item: str, protocol) -> tuple[float, float] | None:
    """The range a score lies in (its interval stays inside): a VAS item's 0-100, an
    instrument's 0-100, a per-trial mean's question's own scale."""
    base = item.removesuffix(TRIAL_MEAN)
    if base in instruments.SCORES:
        return instruments.SCORE_RANGE[base]
    q = next((q for q in protocol.questions if q.id == base), None)
    if q is None:
        return None
    return {Kind.VAS: tuple(VAS_RANGE), Kind.YES_NO: (0.0, 1.0), Kind.LIKERT: (1.0, float(q.points or 0))}.get(q.kind)


def score_names(protocol) -> list[str]:
    """The scores beside the VAS items (`measures`' names): each instrument's asked after every
    condition, and the mean over trials of each question and instrument asked per trial."""
    return ([name for name, when in protocol.instruments if when == "condition"]
            + [q.id + TRIAL_MEAN for q in _per_trial_items(protocol)]
            + [name + TRIAL_MEAN for name, when in protocol.instruments if when == "trial"])


def primary(protocol) -> PrimaryAnalysis:
    """The protocol's primary analysis (what `plan` powers and reports lead with): the
    proportional-odds GEE across its rating items, else the logistic GEE across its yes/no
    questions, else the mixed model of its first score, else the test of its choice."""
    ratings = _rating_items(protocol)
    if ratings:
        return PrimaryAnalysis("ordinal_gee", tuple(q.id for q in ratings),
                               "proportional-odds GEE " + ("across the rating items (answer ~ condition + period + item)" if len(ratings) > 1
                                                           else f"of {ratings[0].text!r} (answer ~ condition + period)"))
    binary = [q.id for q in protocol.asked("condition") if q.kind == Kind.YES_NO]
    if binary:
        return PrimaryAnalysis("logistic_gee", tuple(binary), "logistic GEE across the yes/no questions (answer ~ condition + period + item)")
    scores = [q.id for q in _score_questions(protocol)] + score_names(protocol)
    if scores:
        return PrimaryAnalysis("mixed_model", tuple(scores[:1]),
                               f"linear mixed model of {_label(scores[0], protocol)} (answer ~ condition + period + (1 | participant))")
    choice = [q.id for q in protocol.asked("end") if q.kind == Kind.CHOICE]
    if choice:
        return PrimaryAnalysis("choice", tuple(choice[:1]), "exact multinomial test of the final choice")
    return PrimaryAnalysis("none", (), "no question compares the conditions")


def measures(protocol, answers: pd.DataFrame, per: pd.DataFrame | None = None) -> pd.DataFrame:
    """Each participant's value per condition and measure (tidy: code, model, item, kind,
    answer, period): rating items (kind ordinal); VAS items and instrument scores, and the
    mean over trials of every question asked after each trial (kind continuous)."""
    rows = []
    cond = answers[answers["model"].isin(protocol.conditions)]
    for q in _rating_items(protocol):
        sel = cond[(cond["item"] == q.id) & (cond["trial"] < 0)]
        rows += [(r.code, r.model, q.id, "ordinal", float(r.answer)) for r in sel.itertuples()]
    for q in _score_questions(protocol):
        sel = cond[(cond["item"] == q.id) & (cond["trial"] < 0)]
        rows += [(r.code, r.model, q.id, "continuous", float(r.answer)) for r in sel.itertuples()]
    for name, when in protocol.instruments:
        if when == "end":  # about the whole session: described with the end questions
            continue
        items = [q.id for q in instruments.questions(name)]
        sel = cond[cond["item"].isin(items)]
        scored = []  # (code, model, score) per condition, or per trial of a condition
        for (code, model, _trial), g in sel.groupby(["code", "model", "trial"], sort=False):
            by_item = dict(zip(g["item"], g["answer"].astype(float)))
            if len(by_item) == len(items):
                scored.append((code, model, instruments.score(name, by_item)))
        label = name if when == "condition" else name + TRIAL_MEAN
        for (code, model), g in pd.DataFrame(scored, columns=["code", "model", "score"]).groupby(["code", "model"], sort=False):
            rows.append((code, model, label, "continuous", float(g["score"].mean())))
    for q in _per_trial_items(protocol):
        sel = cond[cond["item"] == q.id]
        for (code, model), g in sel.groupby(["code", "model"], sort=False):
            rows.append((code, model, q.id + TRIAL_MEAN, "continuous", float(g["answer"].astype(float).mean())))
    out = pd.DataFrame(rows, columns=["code", "model", "item", "kind", "answer"])
    if per is not None and len(out):
        out = out.merge(per, on=["code", "model"], how="left")
    return out


def _wide(df: pd.DataFrame, item: str, models: list[str]) -> pd.DataFrame:
    return df[df["item"] == item].pivot(index="code", columns="model", values="answer").reindex(columns=models).dropna()


def _label(item: str, protocol) -> str:
    base = item.removesuffix(TRIAL_MEAN)
    text = instruments.SCORES.get(base) or next((q.text for q in protocol.questions if q.id == base), item)
    return text + (TRIAL_MEAN if item.endswith(TRIAL_MEAN) else "")


def ratings(protocol, meas: pd.DataFrame) -> dict[str, dict]:
    """Per rating item (RatingStats' fields, its pairs before Holm): each condition's median
    [IQR], mean and distribution (count per point); Friedman with Kendall's W [95% CI]; Wilcoxon
    pairs with rank-biserial [95% CI]."""
    models = list(protocol.conditions)
    out = {}
    for q in _rating_items(protocol):
        wide = _wide(meas, q.id, models)
        per_model = {}
        for m in models:
            v = wide[m].to_numpy() if len(wide) else np.zeros(0)
            per_model[m] = scales.median_iqr(v) | {"mean": float(v.mean()) if len(v) else float("nan"),
                                                   "counts": [int(np.sum(v == k)) for k in range(1, q.points + 1)]}
        tests = _tests(wide, len(models))
        out[q.id] = {"question": q.text, "points": q.points, "anchors": list(q.anchors), "n": int(len(wide)), "conditions": per_model,
                     "friedman": tests["friedman"], "pairs": tests["pairs"]}
    return out


def _tests(wide: pd.DataFrame, k: int) -> dict:
    """Friedman [W with CI] and Wilcoxon pairs [rank-biserial with CI] on a complete wide table;
    each withheld with its `reason` where its prerequisites fail (analysis/statistics/withhold.py)."""
    nan = float("nan")
    reason = across_reason(len(wide), k, wide.to_numpy() if len(wide) else None)
    if reason is None:
        fr = scales.friedman_with_ci(wide.to_numpy()) | {"test": "Friedman (tie-corrected chi2)", "reason": None}
    else:
        fr = {"test": "Friedman (tie-corrected chi2)", "statistic": nan, "p_value": nan, "df": k - 1, "n": int(len(wide)),
              "kendall_w": nan, "kendall_w_low": nan, "kendall_w_high": nan, "reason": reason}
    pairs = records(scales.wilcoxon_with_ci(wide)) if k >= 2 else []
    return {"friedman": fr, "pairs": pairs}


def scores(protocol, meas: pd.DataFrame) -> dict[str, dict]:
    """Per score (VAS items, instrument scores, per-trial means; ScoreStats' fields, its pairs
    before Holm): mean [95% CI] per condition; the linear mixed model (condition + period) with
    its pairs; Friedman as the check."""
    models = list(protocol.conditions)
    out = {}
    cont = meas[meas["kind"] == "continuous"] if len(meas) else meas
    for item in dict.fromkeys(cont["item"]) if len(cont) else []:
        data = cont[cont["item"] == item]
        wide = _wide(data, item, models)
        with_period = "period" in data and bool(data["period"].notna().all())
        mm = scales.mixed_model(data.assign(period=data["period"].astype(int)) if with_period else data.drop(columns="period", errors="ignore"),
                                models, with_period)
        _clip_means(mm, score_scale(item, protocol))
        fr = _tests(wide, len(models))["friedman"]
        out[item] = {"label": _label(item, protocol), "n": int(len(wide)),
                     "conditions": {m: scales.mean_ci(wide[m], scale=score_scale(item, protocol)) | scales.median_iqr(wide[m]) for m in models},
                     "mixed_model": mm, "friedman": fr, "pairs": mm["pairs"]}
    return out


def _clip_means(mm: dict, scale: tuple[float, float] | None) -> None:
    """Keep the mixed model's per-condition mean intervals (normal theory, unbounded) inside the
    score's scale, saying so in its notes where one reached past an end."""
    if scale is None:
        return
    lo, hi = scale
    clipped = False
    for c in mm.get("means", {}).values():
        for key in ("ci_low", "ci_high"):
            v = c.get(key)
            if v is not None and np.isfinite(v) and not lo <= v <= hi:
                c[key], clipped = min(max(v, lo), hi), True
    if clipped:
        mm.setdefault("notes", []).append(f"the model-based means' 95% intervals reached past the {lo:g}-{hi:g} scale "
                                          "and are clipped to it (the normal-theory interval is not bounded)")


def choices(protocol, answers: pd.DataFrame) -> dict[str, dict]:
    """Per choice question asked at the end: ChoiceStats' fields, its pairs before Holm."""
    out = {}
    for q in protocol.asked("end"):
        if q.kind == Kind.CHOICE:
            sel = answers[answers["item"] == q.id].set_index("code")["answer"]
            res = scales.choice_analysis(sel, list(protocol.conditions))
            out[q.id] = {"question": q.text} | res
    return out


def session_questions(protocol, answers: pd.DataFrame) -> dict[str, EndRate | EndSummary]:
    """Questions asked once at the end, other than choices: described only."""
    out = {}
    for name, when in protocol.instruments:
        if when == "end":  # one score per participant
            items = [q.id for q in instruments.questions(name)]
            sel = answers[answers["item"].isin(items)]
            v = [instruments.score(name, dict(zip(g["item"], g["answer"].astype(float)))) for _, g in sel.groupby("code")
                 if g["item"].nunique() == len(items)]
            out[name] = EndSummary.of({"question": instruments.SCORES[name], "kind": "score"} | scales.mean_ci(v, scale=instruments.SCORE_RANGE[name])
                                      | scales.median_iqr(v))
    for q in protocol.asked("end"):
        if not q.analysed or q.kind == Kind.CHOICE or q.instrument is not None:
            continue
        v = answers.loc[answers["item"] == q.id, "answer"].astype(float).to_numpy()
        if q.kind == Kind.YES_NO:

            lo, hi = wilson(int(v.sum()), len(v))
            out[q.id] = EndRate(question=q.text, kind=q.kind, n=len(v), yes=int(v.sum()), rate=float(v.mean()) if len(v) else float("nan"),
                                wilson_low=lo, wilson_high=hi)
        else:
            out[q.id] = EndSummary.of({"question": q.text, "kind": q.kind} | scales.mean_ci(v, scale=score_scale(q.id, protocol)) | scales.median_iqr(v))
    return out


def ordinal_primary(protocol, meas: pd.DataFrame, held: dict[str, str] | None = None) -> OrdinalGeeFit | None:
    """The proportional-odds GEE across the rating items, Holm over its pairs; withheld when it
    involves a condition in `held` (analysis/statistics/faults.py)."""

    items = [q.id for q in _rating_items(protocol)]
    if not items or len(protocol.conditions) < 2:
        return None
    data = meas[meas["item"].isin(items)]
    with_period = "period" in data and bool(data["period"].notna().all())
    if with_period:
        data = data.assign(period=data["period"].astype(int))
    res = withhold_fit(scales.ordinal_gee(data, list(protocol.conditions), with_period=with_period, with_item=len(items) > 1),
                       held or {}, list(protocol.conditions))
    return OrdinalGeeFit.of(res, pairs=odds_ratio_pairs(res["pairs"], PAIR_TESTS["ordinal_gee"], res.get("problems") or []))


PAIR_TESTS = {"scores": "t contrast of the linear mixed model (between-within df)",
              "choices": "exact binomial test of the two conditions' counts",
              "ordinal_gee": "Wald t of the proportional-odds GEE (participants - 1 df)",
              "gee": "Wald z of the logistic GEE (robust covariance)"}


def odds_ratio_pairs(pairs: list[dict], test: str, problems=()) -> tuple[OddsRatioPair, ...]:
    """A GEE's pairs, Holm over them, each naming its test."""
    return tuple(OddsRatioPair.of(p, p_holm=h, **named(p, test, problems)) for p, h in zip(pairs, holm([p["p_value"] for p in pairs])))


def kind_tests(study: Study, answers: pd.DataFrame) -> dict:
    """The tests of every kind beyond yes/no of `study` from its complete `answers`, before
    Holm, what `kind_stats` builds its results from: {ratings, scores, choices}, per item the
    fields of its result as plain records (`ratings`, `scores`, `choices`), and `measures`, the
    values they test."""
    protocol = study.protocol
    meas = measures(protocol, answers, study.periods)
    tests = {"ratings": ratings(protocol, meas), "scores": scores(protocol, meas), "choices": choices(protocol, answers),
             "measures": meas}
    return _withhold(tests, _held(study), list(protocol.conditions))


def _held(study: Study) -> dict[str, str]:
    return withheld(condition_events(list(study.protocol.conditions), study.trial_events))


def _withhold(tests: dict, held: dict[str, str], models: list[str]) -> dict:
    """`tests` with every test involving a withheld condition (analysis/statistics/faults.py) withheld: its
    p-values NaN, its reason said where the test would be."""
    why = involving(models, held)
    if why is None:
        return tests
    nan = float("nan")

    def across(fr: dict) -> dict:
        return {"test": fr["test"], "statistic": nan, "p_value": nan, "df": fr["df"], "n": fr["n"], "kendall_w": nan,
                "kendall_w_low": nan, "kendall_w_high": nan, "reason": why}

    for v in tests["ratings"].values():
        v |= {"friedman": across(v["friedman"]), "pairs": withhold_pairs(v["pairs"], held)}
    for v in tests["scores"].values():
        mm = withhold_fit(v["mixed_model"], held, models)
        mm["model_test"] = mm["model_test"] | {k: nan for k in ("chi2", "p_value", "f", "p_value_f")} | {"reason": why}
        v |= {"mixed_model": mm, "friedman": across(v["friedman"]), "pairs": mm["pairs"]}
    for v in tests["choices"].values():
        ov = v["overall"]
        v |= {"overall": ov | {k: nan for k in ("statistic", "p_value", "p_value_chi2") if k in ov} | {"reason": why},
              "pairs": withhold_pairs(v["pairs"], held)}
    return tests


def family_pairs(tests: dict) -> list[list[dict]]:
    """The pairs of `kind_tests` in Holm's family, a list per question or score, in the order
    of KindStats.family_pairs."""
    return [v["pairs"] for part in ("ratings", "scores", "choices") for v in tests[part].values()]


def kind_stats(study: Study, answers: pd.DataFrame, tests: dict | None = None, adjusted: list[list[dict]] | None = None) -> KindStats:
    """Everything beyond yes/no of `study` (analysis.study.study_snapshot.Study) from its complete
    `answers`: ratings, scores, choices, end questions, and the ordinal primary, complete when
    built. `tests`: `kind_tests` already computed; `adjusted`: the Holm p-values of their
    family pairs (analysis.statistics.stats.holm_family over the study's whole family, in `family_pairs`
    order); by default Holm over these pairs alone."""
    protocol = study.protocol
    tests = kind_tests(study, answers) if tests is None else tests
    if adjusted is None:
        adjusted = holm_family([[p["p_value"] for p in pairs] for pairs in family_pairs(tests)])
    holm_of = iter(adjusted)
    what = primary(protocol)
    rating_stats = {k: RatingStats(**v | {"conditions": {m: RatingSummary.of(c) for m, c in v["conditions"].items()},
                                          "friedman": Friedman.of(v["friedman"]),
                                          "pairs": tuple(RankPair.of(p, **h) for p, h in zip(v["pairs"], next(holm_of)))})
                    for k, v in tests["ratings"].items()}
    score_stats = {}
    for k, v in tests["scores"].items():
        mm = v["mixed_model"]
        problems = mm.get("problems") or []
        # the primary's pairs Holm-adjusted among themselves (p_holm_primary), as plan powers it;
        # p_holm stays the whole family's
        own = ([{"p_holm_primary": p} for p in holm([p["p_value"] for p in v["pairs"]])]
               if what.analysis == "mixed_model" and what.items[0] == k else [{}] * len(v["pairs"]))
        pairs = tuple(DifferencePair.of(p, **o, **h, **named(p, PAIR_TESTS["scores"], problems))
                      for p, o, h in zip(v["pairs"], own, next(holm_of)))
        fit = MixedModelFit.of(mm, model_test=ModelTest.of(mm["model_test"]), means={m: ModelMean.of(c) for m, c in mm["means"].items()},
                               pairs=tuple(DifferencePair.of(p, **named(p, PAIR_TESTS["scores"], problems)) for p in mm["pairs"]))
        score_stats[k] = ScoreStats(**v | {"conditions": {m: Summary.of(c) for m, c in v["conditions"].items()}, "mixed_model": fit,
                                           "friedman": Friedman.of(v["friedman"]), "pairs": pairs})
    choice_stats = {k: ChoiceStats(**v | {"shares": {m: ChoiceShare.of(c) for m, c in v["shares"].items()},
                                          "overall": ChoiceTest.of(v["overall"]),
                                          "pairs": tuple(ChoicePair.of(p, **h, **named(p, PAIR_TESTS["choices"]))
                                                         for p, h in zip(v["pairs"], next(holm_of)))})
                    for k, v in tests["choices"].items()}
    return KindStats(primary=what, ratings=rating_stats, scores=score_stats, choices=choice_stats,
                     session=session_questions(protocol, answers), ordinal_gee=ordinal_primary(protocol, tests["measures"], _held(study)))



def across_p(x: np.ndarray) -> float:
    """The p-value across the conditions (columns) of paired values, for `plan`'s thousands of
    simulated studies: Friedman for three or more, the Wilcoxon signed-rank test for two (its
    normal approximation with the tie correction: with ties scipy's exact route is a
    permutation test, too slow for thousands of calls); 1 when no participant differs."""

    if np.all(x == x[:, :1]):
        return 1.0
    if x.shape[1] == 2:
        return float(wilcoxon(x[:, 0], x[:, 1], method="approx").pvalue)
    return friedman(x)["p_value"]



