"""What `analysis.statistics.study_stats.study_stats` returns: everything `studyctl report stats --json`
prints (`StudyStats.as_dict()`), and what Table 1, the text and the reports read (docs/analysis.md).

Complete when built and never changed after: pairwise tests and model fits are the frozen
records of analysis/statistics/result_records.py, the other containers read-only. `as_dict()` is for the JSON
writers only."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

from analysis.statistics.facts import StudyFacts
from analysis.statistics.faults import ConditionEvents
from analysis.statistics.kind_results import KindStats
from analysis.statistics.methods import StudyMethods
from analysis.statistics.result_records import ConditionRate, GeeFit, McNemarPair, Record


@dataclass(frozen=True)
class YesNoItem(Record):
    """A yes/no question asked after each condition (a row of the paper's Table 1).

    - question: its text;
    - cochran_q, df, p_value, n_complete: Cochran's Q across the conditions (NaN when not run)
      and the participants who answered for every condition;
    - rates: per condition its counts and yes rate [Wilson 95%] (ConditionRate);
    - pairs: the exact McNemar pairs (`a, b, n01, n10, p_value, p_holm, odds_ratio`, ...);
    - reason: why Cochran's Q was not tested (None when it was)."""

    question: str
    cochran_q: float
    df: int
    p_value: float
    n_complete: int
    rates: Mapping[str, ConditionRate]
    pairs: tuple[McNemarPair, ...]
    reason: str | None = None


@dataclass(frozen=True)
class LogisticGee(Record):
    """The logistic GEE across the yes/no questions (`analysis.statistics.study_stats.study_gee`), each fit
    a record of analysis.statistics.stats.gee_fit (`formula, n_participants, converged, pairs, ...`).

    - composite: over all questions (item a factor); None without yes/no answers or with one
      condition;
    - items: one fit per question, Holm over their pairs together;
    - period_factor: whether the period is a factor (every answer's period known); None when
      nothing was fitted (and left out of `as_dict()`)."""

    composite: GeeFit | None
    items: Mapping[str, GeeFit]
    period_factor: bool | None = None

    def as_dict(self) -> dict:
        out = super().as_dict()
        return out if self.period_factor is not None else {k: v for k, v in out.items() if k != "period_factor"}


@dataclass(frozen=True, kw_only=True)
class DeformationRow(Record):
    """One condition's deformation time per frame (ms) over the complete participants' trial
    means (analysis.statistics.table1.deformation): mean, SD (NaN below two participants), median, 95th percentile."""

    model: str
    n_participants: int
    n_trials: int
    mean_ms: float
    sd_ms: float
    median_ms: float
    p95_ms: float


@dataclass(frozen=True)
class DeformationBenchmark(Record):
    """The deformation-time row: `label` says it is a benchmark of the machine, not a measure of
    the participants; `rows`, one per condition."""

    label: str
    rows: tuple[DeformationRow, ...]


@dataclass(frozen=True)
class StudyStats(Record):
    """Every statistic of a study (complete cases only).

    - facts: who counts, the design, the conditions;
    - holm: which `p_holm` the pairs carry: "family" (over every pairwise test of every
      question and kind) or "question" (within each);
    - items: per yes/no question id, its rates, Cochran's Q and McNemar pairs;
    - gee: the logistic GEE across the yes/no questions;
    - kinds: every other kind of answer, and the protocol's primary analysis;
    - deformation: the deformation-time benchmark;
    - methods: the study's methods as data (analysis/statistics/methods.py), which `report text` writes out;
    - faults: per condition its model faults and safety events, and whether its tests are withheld
      (analysis/statistics/faults.py)."""

    facts: StudyFacts
    holm: str
    items: Mapping[str, YesNoItem]
    gee: LogisticGee
    kinds: KindStats
    deformation: DeformationBenchmark
    methods: StudyMethods
    faults: tuple[ConditionEvents, ...] = ()

