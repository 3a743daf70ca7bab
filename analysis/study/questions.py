"""Questions and their answers: the kinds a protocol may ask, and one parser of a typed value
per kind (the terminal, `answers import` and `answers correct` all read answers through it).

Kinds (docs/study.md):
- ``yes_no``: stored 0/1;
- ``likert``: an integer 1..points (points 3..11) between two anchors;
- ``vas``: a visual analogue scale, a real number 0..100 (a slider in the window);
- ``choice``: one of the conditions, shown by its blind label; stored as the condition's name;
- ``text``: free text (terminal only), exported, never analysed.

When: ``condition`` (after a condition's trials), ``trial`` (after every trial) or ``end``
(once, after the last condition; stored with condition "" since it is about the session).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import StrEnum

from analysis.errors import StudyError
from sim.text import TEXT_MOST, quoted, text_problem


class Kind(StrEnum):
    """A question's kind; a member equals its name as a protocol file writes it ("likert")."""

    YES_NO = "yes_no"
    LIKERT = "likert"
    VAS = "vas"
    CHOICE = "choice"
    TEXT = "text"


KINDS = tuple(Kind)
WHENS = ("condition", "trial", "end")
LIKERT_POINTS = (3, 11)
VAS_RANGE = (0.0, 100.0)
SESSION = ""  # the condition of an answer asked once per session (when = "end")
NOT_PER_TRIAL = -1  # the trial of an answer not asked per trial
# the rig's latency measures a protocol may record (its [latency] measures), in words with their units
LATENCY_MEASURES = {"deformation_ms": "deformation time per frame (ms)", "tick_interval_p99_us": "servo tick interval, 99th percentile (µs)",
                    "read_to_force_us": "time from device read to force (µs)", "tick_compute_us": "servo tick computation (µs)"}
YES = frozenset({"yes", "y", "1", "true", "ja", "oui", "si", "sí"})  # as people type them on paper forms too
NO = frozenset({"no", "n", "0", "false", "nein", "non"})


@dataclass(frozen=True)
class Question:
    id: str
    text: str
    kind: Kind = Kind.YES_NO
    when: str = "condition"
    points: int | None = None  # likert
    anchors: tuple[str, str] | None = None  # likert (required), vas (optional): the scale's two ends
    instrument: str | None = None  # "sus" or "nasa_tlx": an item of a standard questionnaire

    def __post_init__(self) -> None:
        object.__setattr__(self, "kind", Kind(self.kind))  # a kind given by its name ("likert") becomes its member

    @property
    def analysed(self) -> bool:
        return self.kind != Kind.TEXT


class AnswerError(StudyError, ValueError):
    """A value the question's kind does not allow (the message names the allowed values)."""


def allowed(q: Question, labels: dict[str, str] | None = None) -> str:
    """The allowed values, as an error message or a prompt says them."""
    if q.kind == Kind.YES_NO:
        return "yes or no (y/n, 1/0)"
    if q.kind == Kind.LIKERT:
        return f"an integer 1..{q.points} (1 = {q.anchors[0]}, {q.points} = {q.anchors[1]})"
    if q.kind == Kind.VAS:
        ends = f" (0 = {q.anchors[0]}, 100 = {q.anchors[1]})" if q.anchors else ""
        return f"a number 0..100{ends}"
    if q.kind == Kind.CHOICE:
        return "one of " + (", ".join(sorted(labels.values())) if labels else "the conditions")
    return f"a text of at most {TEXT_MOST} characters"


def parse_answer(q: Question, raw, labels: dict[str, str] | None = None, by_name: tuple[str, ...] = ()):
    """The typed value of `raw` (text or a number) for `q`, or AnswerError naming what is allowed.
    A choice is given by a blind label (`labels`: condition -> label) or, in imports and
    corrections, by the condition's name (`by_name`); it is returned as the condition's name."""
    text = str(raw).strip()
    if q.kind == Kind.TEXT:
        if (problem := text_problem(text, TEXT_MOST)) is not None:
            raise AnswerError(problem)
        return text
    if q.kind == Kind.YES_NO:
        if text.lower() in YES:
            return 1
        if text.lower() in NO:
            return 0
    elif q.kind == Kind.LIKERT:
        try:
            v = int(text)
        except ValueError:
            v = None
        if v is not None and 1 <= v <= q.points:
            return v
    elif q.kind == Kind.VAS:
        try:
            v = float(text)
        except ValueError:
            v = math.nan
        if math.isfinite(v) and VAS_RANGE[0] <= v <= VAS_RANGE[1]:
            return v
    elif q.kind == Kind.CHOICE:
        by_label = {label.lower(): c for c, label in (labels or {}).items()}
        if text.lower() in by_label:
            return by_label[text.lower()]
        if text in by_name:
            return text
        if by_name:
            raise AnswerError(f"{quoted(text)} is not a condition; allowed: {', '.join(by_name)}")
    raise AnswerError(f"{quoted(text)} is not allowed; allowed: {allowed(q, labels)}")


def shown(q: Question, value) -> str:
    """A stored value as a person reads it (yes/no for yes_no)."""
    if value is None:
        return ""
    if q.kind == Kind.YES_NO:
        return "yes" if int(value) else "no"
    if q.kind == Kind.VAS:
        return f"{float(value):g}"
    return str(value)
