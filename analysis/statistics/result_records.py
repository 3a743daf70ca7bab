"""The leaves of a study's results (analysis/statistics/study_results.py, analysis/statistics/kind_results.py): frozen
records whose fields are the keys `report stats --json` prints, and the read-only containers
that hold them. A result is complete when built: nothing sets a field or a key after.

`Record.of(d)` builds one from the plain dict a test returns (analysis/statistics/stats.py,
analysis/statistics/scales.py), keeping the order of its keys, which differs between a test that ran and
one that was withheld; `as_dict()` gives that dict back, for the JSON writers only."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from types import MappingProxyType


def frozen(obj):
    """A read-only copy: dicts as read-only mappings, lists as tuples, all the way down."""
    if isinstance(obj, Record):
        return obj
    if isinstance(obj, Mapping):
        return MappingProxyType({k: frozen(v) for k, v in obj.items()})
    if isinstance(obj, (list, tuple)):
        return tuple(frozen(v) for v in obj)
    return obj


def plain(obj):
    """The plain dicts and lists the JSON writers take, from records and read-only containers."""
    if isinstance(obj, Record):
        return obj.as_dict()
    if isinstance(obj, Mapping):
        return {k: plain(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [plain(v) for v in obj]
    return obj


@dataclass(frozen=True, kw_only=True)
class Record:
    """A frozen record; `keys`: the keys its JSON carries, in their order (by default every field,
    in field order; a field a test did not give is None and left out)."""

    keys: tuple[str, ...] = field(default=(), repr=False, compare=False)

    def __post_init__(self) -> None:
        # the containers a caller passed become read-only copies: a result is never changed after
        for f in fields(self):
            object.__setattr__(self, f.name, frozen(getattr(self, f.name)))

    @classmethod
    def of(cls, d: Mapping, **more):
        """From a test's dict (and `more` keys after it); an unknown key is a TypeError."""
        d = {**d, **more}
        return cls(**d, keys=tuple(d))

    def as_dict(self) -> dict:
        names = self.keys or tuple(f.name for f in fields(self) if f.name != "keys")
        return {k: plain(getattr(self, k)) for k in names}


# --- one condition's answers described (a leaf keyed by its condition in its result)

@dataclass(frozen=True, kw_only=True)
class ConditionRate(Record):
    """A yes/no question's answers in one condition: counts, the yes rate and its Wilson 95% interval."""

    yes: int
    no: int
    rate: float
    wilson_low: float
    wilson_high: float


@dataclass(frozen=True, kw_only=True)
class Summary(Record):
    """Values described: n, mean and SD with the mean's 95% interval or why it has none
    (analysis.statistics.withhold.mean_ci: `ci_method`, `ci_reason`), median [IQR] (analysis.statistics.scales.median_iqr)."""

    n: int
    mean: float
    sd: float
    ci_low: float
    ci_high: float
    ci_method: str | None = None
    ci_reason: str | None = None
    median: float
    q1: float
    q3: float
    iqr: float


@dataclass(frozen=True, kw_only=True)
class RatingSummary(Record):
    """A rating item's answers in one condition: median [IQR], mean, and how many chose each point
    (`counts[0]` is point 1)."""

    n: int
    median: float
    q1: float
    q3: float
    iqr: float
    mean: float
    counts: tuple[int, ...]


@dataclass(frozen=True, kw_only=True)
class ChoiceShare(Record):
    """How many chose one condition, their share of those who chose, its Wilson 95% interval."""

    count: int
    share: float
    wilson_low: float
    wilson_high: float


@dataclass(frozen=True, kw_only=True)
class ModelMean(Record):
    """A mixed model's mean of one condition with its standard error and 95% interval."""

    mean: float
    se: float
    ci_low: float
    ci_high: float


@dataclass(frozen=True, kw_only=True)
class EndRate(Record):
    """A yes/no question asked once at the end: its yes rate over the n who answered [Wilson 95%]."""

    question: str
    kind: str
    n: int
    yes: int
    rate: float
    wilson_low: float
    wilson_high: float


@dataclass(frozen=True, kw_only=True)
class EndSummary(Summary):
    """A question (or an instrument's score) asked once at the end, described (`kind`: the
    question's kind, "score" for an instrument)."""

    question: str
    kind: str


# --- pairwise tests: a pair of conditions (a, b); p_holm is Holm over the study's family or the
# question's pairs (`holm` of analysis.statistics.study_results.StudyStats), p_holm_question within the
# question, p_holm_family over every pairwise test of the study; `test` names the test and
# `reason` says why one was not made (None when it was)

@dataclass(frozen=True, kw_only=True)
class McNemarPair(Record):
    """An exact McNemar test of two conditions' yes/no answers (analysis.statistics.stats.pairwise_mcnemar):
    n01 (a no, b yes), n10, the Haldane-corrected odds ratio n10 / n01."""

    a: str
    b: str
    test: str
    n01: int
    n10: int
    p_value: float
    p_holm: float
    odds_ratio: float
    reason: str | None = None
    p_holm_question: float | None = None
    p_holm_family: float | None = None


@dataclass(frozen=True, kw_only=True)
class RankPair(Record):
    """A Wilcoxon signed-rank test of a rating's pair with the rank-biserial r [95% CI]
    (analysis.statistics.scales.wilcoxon_with_ci); `warning` when the test is weak (few pairs)."""

    a: str
    b: str
    test: str
    statistic: float
    p_value: float
    p_holm: float
    rank_biserial: float
    reason: str | None = None
    warning: str | None = None
    rb_ci_low: float | None = None
    rb_ci_high: float | None = None
    p_holm_question: float | None = None
    p_holm_family: float | None = None


@dataclass(frozen=True, kw_only=True)
class DifferencePair(Record):
    """A linear mixed model's difference b - a [95% CI] (analysis.statistics.scales.mixed_model);
    p_holm_primary: Holm among the primary score's own pairs (a mixed-model primary only)."""

    a: str
    b: str
    difference: float
    se: float
    ci_low: float
    ci_high: float
    p_value: float
    estimable: bool
    p_holm_primary: float | None = None
    p_holm_question: float | None = None
    p_holm_family: float | None = None
    p_holm: float | None = None
    test: str | None = None
    reason: str | None = None


@dataclass(frozen=True, kw_only=True)
class ChoicePair(Record):
    """An exact binomial test of two conditions' counts of a choice (analysis.statistics.scales.choice_analysis):
    b's share of the two [Wilson 95%]."""

    a: str
    b: str
    n_a: int
    n_b: int
    p_value: float
    share_b: float
    share_b_low: float
    share_b_high: float
    p_holm_question: float | None = None
    p_holm_family: float | None = None
    p_holm: float | None = None
    test: str | None = None
    reason: str | None = None


@dataclass(frozen=True, kw_only=True)
class OddsRatioPair(Record):
    """A GEE's odds ratio of b against a [95% CI] with its Wald p-value (analysis.statistics.stats.gee_fit,
    analysis.statistics.scales.ordinal_gee); Holm over the fit's own pairs."""

    a: str
    b: str
    log_odds_ratio: float
    se: float
    odds_ratio: float
    ci_low: float
    ci_high: float
    p_value: float
    estimable: bool
    p_holm: float | None = None
    test: str | None = None
    reason: str | None = None


# --- tests across the conditions and model fits ---------------------------------------------------

@dataclass(frozen=True, kw_only=True)
class Friedman(Record):
    """Friedman across the conditions with Kendall's W [95% CI] (analysis.statistics.scales.friedman_with_ci),
    or why it was not run (`reason`; then without the uncorrected statistic and the interval's method)."""

    statistic: float
    p_value: float
    statistic_uncorrected: float | None = None
    p_value_uncorrected: float | None = None
    df: int
    n: int
    kendall_w: float
    kendall_w_low: float
    kendall_w_high: float
    interval: str | None = None
    test: str
    reason: str | None = None


@dataclass(frozen=True, kw_only=True)
class ModelTest(Record):
    """The mixed model's joint Wald test of the condition, as chi2 and as F (between-within df)."""

    chi2: float
    df: int
    p_value: float
    f: float
    df_denominator: float
    p_value_f: float
    test: str
    reason: str | None = None


@dataclass(frozen=True, kw_only=True)
class ChoiceTest(Record):
    """The test of equal chances of a choice (analysis.statistics.scales.multinomial_test)."""

    test: str
    statistic: float
    df: int
    p_value: float
    n: int
    p_value_chi2: float | None = None
    reason: str | None = None


@dataclass(frozen=True, kw_only=True)
class MixedModelFit(Record):
    """A linear mixed model answer ~ condition + period + (1 | participant) (analysis.statistics.scales.mixed_model):
    per condition its model-based mean {mean, se, ci_low, ci_high}, the pairwise differences, and
    `notes` (e.g. intervals clipped to the scale) and `problems` (why not estimable)."""

    formula: str
    n_participants: int
    n_answers: int
    method: str
    notes: tuple[str, ...]
    converged: bool
    variance_participant: float
    variance_residual: float
    model_test: ModelTest
    estimable: bool
    problems: tuple[str, ...]
    means: Mapping[str, ModelMean]
    pairs: tuple[DifferencePair, ...]


@dataclass(frozen=True, kw_only=True)
class GeeFit(Record):
    """A logistic GEE answer ~ condition [+ period] [+ item], participants as clusters
    (analysis.statistics.stats.gee_fit); `working_correlation` None when the fit failed."""

    formula: str
    n_participants: int
    n_answers: int
    correlation: str
    covariance: str
    converged: bool
    estimable: bool
    problems: tuple[str, ...]
    working_correlation: float | None = None
    pairs: tuple[OddsRatioPair, ...]


@dataclass(frozen=True, kw_only=True)
class OrdinalGeeFit(Record):
    """A proportional-odds GEE across the rating items (analysis.statistics.scales.ordinal_gee);
    `fallback` says why the working dependence fell back to independence (None when it did not)."""

    formula: str
    n_participants: int
    n_answers: int
    working_dependence: str
    fallback: str | None
    covariance: str
    global_odds_ratio: float
    notes: tuple[str, ...]
    converged: bool
    estimable: bool
    problems: tuple[str, ...]
    pairs: tuple[OddsRatioPair, ...]
