"""The facts that head every report of a study (`analysis.table1.study_facts`): who counts, whose
data they are, the design, and what each condition ran."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

from analysis.result_records import Record


@dataclass(frozen=True)
class StudyFacts(Record):
    """A study's facts, never changed after (its lists and records read-only); `as_dict()` is the
    `facts` object of `report stats --json` and `report table1 --format json`.

    - study: the protocol's name;
    - participants: N, the participants with every answer (analysis.table1.complete_answers);
    - incomplete_participants: the others, left out of every statistic, each {code, answers, of};
    - synthetic_participants, person_participants: how many answered synthetically, as a person;
    - mixed_source_participants: the codes that answered both ways;
    - synthetic: any synthetic answer; mixed: people and synthetic participants pooled;
    - flag: what a report says first about whose data it holds ("" for people only);
    - design: "within-subject, K conditions, ... counterbalancing";
    - conditions: what each condition ran, each {condition, model, config, config_sha256,
      sessions} (analysis.table1.conditions)."""

    study: str
    participants: int
    incomplete_participants: tuple[Mapping, ...]
    synthetic_participants: int
    person_participants: int
    mixed_source_participants: tuple[str, ...]
    synthetic: bool
    mixed: bool
    flag: str
    design: str
    conditions: tuple[Mapping, ...]
