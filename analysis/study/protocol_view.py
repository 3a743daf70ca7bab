"""The protocol as the analyses read it: a structural type (`typing.Protocol`) of what a
`studyctl.protocol.Protocol` gives them, so the layer boundary is typed without the analyses
importing the study layer (studyctl/protocol.py reads the file and checks it)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Protocol

from analysis.study.questions import Question


class StudyProtocol(Protocol):
    """A study's protocol: its design, questions, instruments, tasks and participant fields."""

    name: str
    target_participants: int
    scene: Path
    conditions: tuple[str, ...]
    counterbalancing: str
    training_minutes: float
    trials_per_condition: int
    trial_seconds: float
    rest_seconds: float
    age_min: int
    age_max: int
    latency_measures: tuple[str, ...]
    questions: tuple[Question, ...]
    instruments: tuple[tuple[str, str], ...]  # (name, when) of each instrument given
    tasks: tuple  # studyctl.tasks.TaskSpec: kind, parameter, method, trials, question, interval_seconds, low, high
    fields: tuple  # studyctl.fields.Field: name, kind (analysis.study.fields.FieldKind), values, ...
    groups: str | None
    trial_end: str

    def asked(self, when: str) -> Sequence[Question]: ...

    def field_named(self, name: str): ...

    @property
    def group_field(self): ...
