"""The facts that head every report of a study (`analysis.statistics.table1.study_facts`): who counts, whose
data they are, the design, and what each condition ran."""

from __future__ import annotations

import json
from dataclasses import dataclass

from analysis.statistics.result_records import Record


@dataclass(frozen=True, kw_only=True)
class IncompleteParticipant(Record):
    """A participant left out of every statistic: their answers of the `of` a complete one gives."""

    code: str
    answers: int
    of: int


@dataclass(frozen=True, kw_only=True)
class ModelSource(Record):
    """Where a condition's model came from (analysis.statistics.table1.model_source): built into
    brainsim-study (`builtin`, its `version` the sessions' own) or a plugin's distribution and
    version with its source's SHA-256 (`target`: its entry point, for a plugin only)."""

    package: str | None
    version: str | None
    builtin: bool
    source_sha256: str | None
    target: str | None = None


@dataclass(frozen=True, kw_only=True)
class ConditionRun(Record):
    """What one condition ran under one configuration (analysis.statistics.table1.conditions): its model,
    its resolved configuration as the store keeps it (`config_json`, canonical JSON, whose
    SHA-256 is `config_sha256`; None before schema 5) and the sessions that ran it.

    The configuration is the model's own document (its options are the model's to declare), so it
    stays the stored text; `config` reads it."""

    condition: str
    model: str | None
    config_json: str | None
    config_sha256: str | None
    sessions: int
    source: ModelSource | None

    @property
    def config(self) -> dict | None:
        return None if self.config_json is None else json.loads(self.config_json)

    def as_dict(self) -> dict:
        out = super().as_dict()
        return {("config" if k == "config_json" else k): (self.config if k == "config_json" else v) for k, v in out.items()}


@dataclass(frozen=True)
class StudyFacts(Record):
    """A study's facts, never changed after (its lists and records read-only); `as_dict()` is the
    `facts` object of `report stats --json` and `report table1 --format json`.

    - study: the protocol's name;
    - participants: N, the participants with every answer (analysis.statistics.table1.complete_answers);
    - incomplete_participants: the others, left out of every statistic;
    - synthetic_participants, person_participants: how many answered synthetically, as a person;
    - mixed_source_participants: the codes that answered both ways;
    - synthetic: any synthetic answer; mixed: people and synthetic participants pooled;
    - flag: what a report says first about whose data it holds ("" for people only);
    - design: "within-subject, K conditions, ... counterbalancing";
    - conditions: what each condition ran (analysis.statistics.table1.conditions)."""

    study: str
    participants: int
    incomplete_participants: tuple[IncompleteParticipant, ...]
    synthetic_participants: int
    person_participants: int
    mixed_source_participants: tuple[str, ...]
    synthetic: bool
    mixed: bool
    flag: str
    design: str
    conditions: tuple[ConditionRun, ...]
