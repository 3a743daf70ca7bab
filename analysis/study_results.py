"""What `analysis.study_stats.study_stats` returns: everything `studyctl report stats --json`
prints (`StudyStats.as_dict()`), and what Table 1 and the reports read (docs/analysis.md).

Pairwise tests stay lists of tidy records (`a, b, p_value, p_holm, p_holm_family,
p_holm_question, test, ...`), and model fits the plain records analysis/stats.py returns."""

from __future__ import annotations

from dataclasses import dataclass, fields

from analysis.facts import StudyFacts
from analysis.kind_results import KindStats


@dataclass(frozen=True)
class YesNoItem:
    """A yes/no question asked after each condition (a row of the paper's Table 1).

    - question: its text;
    - cochran_q, df, p_value, n_complete: Cochran's Q across the conditions (NaN when not run)
      and the participants who answered for every condition;
    - rates: per condition {yes, no, rate, wilson_low, wilson_high};
    - pairs: the exact McNemar pairs (`a, b, n01, n10, p_value, p_holm, odds_ratio`, ...);
    - reason: why Cochran's Q was not tested (None when it was)."""

    question: str
    cochran_q: float
    df: int
    p_value: float
    n_complete: int
    rates: dict[str, dict]
    pairs: list[dict]
    reason: str | None = None

    def as_dict(self) -> dict:
        return {f.name: getattr(self, f.name) for f in fields(self)}


@dataclass(frozen=True)
class LogisticGee:
    """The logistic GEE across the yes/no questions (`analysis.study_stats.study_gee`), each fit
    a record of analysis.stats.gee_fit (`formula, n_participants, converged, pairs, ...`).

    - composite: over all questions (item a factor); None without yes/no answers or with one
      condition;
    - items: one fit per question, Holm over their pairs together;
    - period_factor: whether the period is a factor (every answer's period known); None when
      nothing was fitted (and left out of `as_dict()`)."""

    composite: dict | None
    items: dict[str, dict]
    period_factor: bool | None = None

    def as_dict(self) -> dict:
        out = {"composite": self.composite, "items": self.items}
        return out if self.period_factor is None else out | {"period_factor": self.period_factor}


@dataclass(frozen=True)
class DeformationBenchmark:
    """The deformation-time row: `label` says it is a benchmark of the machine, not a measure of
    the participants; `rows` are analysis.table1.deformation's records (one per condition)."""

    label: str
    rows: list[dict]

    def as_dict(self) -> dict:
        return {"label": self.label, "rows": self.rows}


@dataclass(frozen=True)
class StudyStats:
    """Every statistic of a study (complete cases only).

    - facts: who counts, the design, the conditions;
    - holm: which `p_holm` the pairs carry: "family" (over every pairwise test of every
      question and kind) or "question" (within each);
    - items: per yes/no question id, its rates, Cochran's Q and McNemar pairs;
    - gee: the logistic GEE across the yes/no questions;
    - kinds: every other kind of answer, and the protocol's primary analysis;
    - deformation: the deformation-time benchmark;
    - methods: the study's methods as data (analysis/reports/methods.py), which `report text` writes out."""

    facts: StudyFacts
    holm: str
    items: dict[str, YesNoItem]
    gee: LogisticGee
    kinds: KindStats
    deformation: DeformationBenchmark
    methods: dict

    def as_dict(self) -> dict:
        """The nested dict `report stats --json` prints (through sim.jsonable.jsonable)."""
        return {"facts": self.facts.as_dict(), "holm": self.holm, "items": {k: v.as_dict() for k, v in self.items.items()},
                "gee": self.gee.as_dict(), "kinds": self.kinds.as_dict(), "deformation": self.deformation.as_dict(),
                "methods": self.methods}

