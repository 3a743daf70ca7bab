"""The results of the statistics beyond yes/no (`analysis.statistics.kinds.kind_stats`): the protocol's
primary analysis, and per rating item, score and choice question what reports, plots and
`report stats --json` read (docs/analysis.md).

Each is complete when built (Holm over the study's family computed first) and never changed
after; its tests are the frozen records of analysis/statistics/result_records.py, its other containers
read-only. `as_dict()` is for the JSON writers only."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

from analysis.statistics.result_records import (
    ChoicePair,
    ChoiceShare,
    ChoiceTest,
    DifferencePair,
    EndRate,
    EndSummary,
    Friedman,
    MixedModelFit,
    OrdinalGeeFit,
    RankPair,
    RatingSummary,
    Record,
    Summary,
)


@dataclass(frozen=True)
class PrimaryAnalysis(Record):
    """The protocol's primary analysis (`analysis.statistics.kinds.primary`): what `plan` powers and
    reports lead with.

    - analysis: "ordinal_gee", "logistic_gee", "mixed_model", "choice" or "none";
    - items: the ids it analyses (rating items, yes/no questions, one score or one choice);
    - text: what it is, as a phrase ("proportional-odds GEE across the rating items ...")."""

    analysis: str
    items: tuple[str, ...]
    text: str


@dataclass(frozen=True)
class RatingStats(Record):
    """A rating (Likert) item asked after each condition.

    - question: its text; points: its scale's points; anchors: the scale's anchor labels;
    - n: participants with an answer for every condition;
    - conditions: per condition its median [IQR], mean and counts per point (RatingSummary);
    - friedman: Friedman across the conditions with Kendall's W [95% CI], or why not run
      (`reason`);
    - pairs: the Wilcoxon signed-rank pairs with the rank-biserial r [95% CI] (RankPair)."""

    question: str
    points: int
    anchors: tuple[str, ...]
    n: int
    conditions: Mapping[str, RatingSummary]
    friedman: Friedman
    pairs: tuple[RankPair, ...]


@dataclass(frozen=True)
class ScoreStats(Record):
    """A score: a VAS item, an instrument's score, or a question's mean over trials.

    - label: what reports call it; n: participants with a value for every condition;
    - conditions: per condition its mean [95% CI] (with `ci_reason` when there is none) and
      median [IQR] (Summary);
    - mixed_model: the linear mixed model (analysis.statistics.scales.mixed_model: `model_test`,
      `means`, `pairs`, `converged`, `problems`);
    - friedman: Friedman as the non-parametric check;
    - pairs: the mixed model's pairwise differences as Holm's family holds them (a
      mixed-model primary's also carry `p_holm_primary`)."""

    label: str
    n: int
    conditions: Mapping[str, Summary]
    mixed_model: MixedModelFit
    friedman: Friedman
    pairs: tuple[DifferencePair, ...]


@dataclass(frozen=True)
class ChoiceStats(Record):
    """A choice question asked at the end (one condition picked), from
    analysis.statistics.scales.choice_analysis.

    - question: its text; n: participants who chose; k: conditions; n_missing: no answer;
    - shares: per condition its count and share [Wilson 95%] (ChoiceShare);
    - overall: the test of equal chances {test, statistic, df, p_value, n, ...};
    - pairs: exact binomial tests between two conditions' counts (ChoicePair)."""

    question: str
    n: int
    k: int
    n_missing: int
    shares: Mapping[str, ChoiceShare]
    overall: ChoiceTest
    pairs: tuple[ChoicePair, ...]


@dataclass(frozen=True)
class KindStats(Record):
    """Every kind of answer beyond yes/no of a study; `as_dict()` is `report stats --json`'s
    `kinds`.

    - primary: the protocol's primary analysis;
    - ratings, scores, choices: per item id (score name) its statistics;
    - session: the other questions asked once at the end, described only: per id a yes/no
      question's rate with its Wilson interval (EndRate), or a mean [95% CI] and median [IQR] (EndSummary);
    - ordinal_gee: the proportional-odds GEE across the rating items (analysis.statistics.scales.ordinal_gee),
      None without rating items or with one condition."""

    primary: PrimaryAnalysis
    ratings: Mapping[str, RatingStats]
    scores: Mapping[str, ScoreStats]
    choices: Mapping[str, ChoiceStats]
    session: Mapping[str, EndRate | EndSummary]
    ordinal_gee: OrdinalGeeFit | None

    def family_pairs(self) -> list[tuple]:
        """Every pairwise test here, a tuple per question or score, as Holm over the study's
        whole family counts them: the ratings' Wilcoxon pairs, the scores' mixed-model pairs, the choices'
        binomial pairs."""
        return [v.pairs for part in (self.ratings, self.scores, self.choices) for v in part.values()]
