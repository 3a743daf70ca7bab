"""The results of the statistics beyond yes/no (`analysis.kinds.kind_stats`): the protocol's
primary analysis, and per rating item, score and choice question what reports, plots and
`report stats --json` read (docs/analysis.md).

The tests' own results stay the plain records analysis/scales.py and analysis/stats.py return
(`friedman`, `mixed_model`, `overall`, per-condition summaries), and pairwise tests are lists of
tidy records (`a, b, p_value, p_holm, ...`): `analysis.study_stats.study_stats` sets their Holm
p-values, and the test's name where one was not run, after `kind_stats`."""

from __future__ import annotations

from dataclasses import dataclass, fields


def _record(obj) -> dict:
    return {f.name: getattr(obj, f.name) for f in fields(obj)}


@dataclass(frozen=True)
class PrimaryAnalysis:
    """The protocol's primary analysis (`analysis.kinds.primary`): what `plan` powers and
    reports lead with.

    - analysis: "ordinal_gee", "logistic_gee", "mixed_model", "choice" or "none";
    - items: the ids it analyses (rating items, yes/no questions, one score or one choice);
    - text: what it is, as a phrase ("proportional-odds GEE across the rating items ...")."""

    analysis: str
    items: tuple[str, ...]
    text: str

    def as_dict(self) -> dict:
        return {"analysis": self.analysis, "items": list(self.items), "text": self.text}


@dataclass(frozen=True)
class RatingStats:
    """A rating (Likert) item asked after each condition.

    - question: its text; points: its scale's points; anchors: the scale's anchor labels;
    - n: participants with an answer for every condition;
    - conditions: per condition {n, median, q1, q3, iqr, mean, counts (per point)};
    - friedman: Friedman across the conditions with Kendall's W [95% CI], or why not run
      (`reason`);
    - pairs: the Wilcoxon signed-rank pairs with the rank-biserial r [95% CI], tidy records."""

    question: str
    points: int
    anchors: list[str]
    n: int
    conditions: dict[str, dict]
    friedman: dict
    pairs: list[dict]

    def as_dict(self) -> dict:
        return _record(self)


@dataclass(frozen=True)
class ScoreStats:
    """A score: a VAS item, an instrument's score, or a question's mean over trials.

    - label: what reports call it; n: participants with a value for every condition;
    - conditions: per condition its mean [95% CI] (with `ci_reason` when there is none) and
      median [IQR];
    - mixed_model: the linear mixed model (analysis.scales.mixed_model: `model_test`,
      `means`, `pairs`, `converged`, `problems`);
    - friedman: Friedman as the non-parametric check;
    - pairs: copies of the mixed model's pairwise differences, the ones in Holm's family (a
      mixed-model primary's also carry `p_holm_primary`)."""

    label: str
    n: int
    conditions: dict[str, dict]
    mixed_model: dict
    friedman: dict
    pairs: list[dict]

    def as_dict(self) -> dict:
        return _record(self)


@dataclass(frozen=True)
class ChoiceStats:
    """A choice question asked at the end (one condition picked), from
    analysis.scales.choice_analysis.

    - question: its text; n: participants who chose; k: conditions; n_missing: no answer;
    - shares: per condition {count, share, wilson_low, wilson_high};
    - overall: the test of equal chances {test, statistic, df, p_value, n, ...};
    - pairs: exact binomial tests between two conditions' counts, tidy records."""

    question: str
    n: int
    k: int
    n_missing: int
    shares: dict[str, dict]
    overall: dict
    pairs: list[dict]

    def as_dict(self) -> dict:
        return _record(self)


@dataclass(frozen=True)
class KindStats:
    """Every kind of answer beyond yes/no of a study; `as_dict()` is `report stats --json`'s
    `kinds`.

    - primary: the protocol's primary analysis;
    - ratings, scores, choices: per item id (score name) its statistics;
    - session: the other questions asked once at the end, described only: per id a record
      {question, kind, ...} (a rate with its Wilson interval, or a mean [95% CI] and median [IQR]);
    - ordinal_gee: the proportional-odds GEE across the rating items (analysis.scales.ordinal_gee),
      None without rating items or with one condition."""

    primary: PrimaryAnalysis
    ratings: dict[str, RatingStats]
    scores: dict[str, ScoreStats]
    choices: dict[str, ChoiceStats]
    session: dict[str, dict]
    ordinal_gee: dict | None

    def as_dict(self) -> dict:
        return {"primary": self.primary.as_dict(),
                "ratings": {k: v.as_dict() for k, v in self.ratings.items()},
                "scores": {k: v.as_dict() for k, v in self.scores.items()},
                "choices": {k: v.as_dict() for k, v in self.choices.items()},
                "session": self.session, "ordinal_gee": self.ordinal_gee}

    def family_pairs(self) -> list[list[dict]]:
        """Every pairwise test here, a list per question or score, for Holm over the study's
        whole family: the ratings' Wilcoxon pairs, the scores' mixed-model pairs, the choices'
        binomial pairs."""
        return [v.pairs for part in (self.ratings, self.scores, self.choices) for v in part.values()]
