"""The one definition of a complete participant, and of a participant's kind, that every count
uses (`studyctl status`, Table 1's N, the reports' banners and their lists of the incomplete).

A participant is complete when they answered every analysed question for every condition:
each question asked after a condition once per condition, after a trial once per trial, at the
end once. Free text is never analysed, so it is neither needed nor counted; a participant with
any answer (text included) who is not complete is incomplete, listed as {code, answers, of}.

A participant's kind comes from their answers' own source: ``person`` (no synthetic answer),
``synthetic`` (only synthetic answers) or ``mixed`` (both; the reports warn about these).
"""

from __future__ import annotations

from dataclasses import dataclass

import pandas as pd

from analysis.study.protocol_view import StudyProtocol

KINDS = ("person", "synthetic", "mixed")


def expected_answers(protocol) -> int:
    """How many analysed answers a complete participant gives."""
    per = {"condition": len(protocol.conditions), "trial": len(protocol.conditions) * protocol.trials_per_condition, "end": 1}
    return sum(per[q.when] for q in protocol.questions if q.analysed)


def analysed_rows(protocol, answers: pd.DataFrame) -> pd.Series:
    """Which of `answers` (code, model, item, ...) are analysed answers the protocol asks for:
    a question asked at the end has no model, every other one names one of the conditions."""
    when = {q.id: q.when for q in protocol.questions if q.analysed}
    w = answers["item"].map(when)
    return w.notna() & ((w == "end") == (answers["model"] == "")) & ((w == "end") | answers["model"].isin(protocol.conditions))


@dataclass(frozen=True)
class Completeness:
    """`complete`: the complete participants' codes, sorted; `incomplete`: every other
    participant with an answer, each {code, answers, of}, by code; `kinds`: code -> kind of
    every participant with an answer; `protocol`: the protocol it was counted under."""

    complete: tuple[str, ...]
    incomplete: tuple[dict, ...]
    kinds: dict[str, str]
    protocol: StudyProtocol

    def count(self, kind: str) -> int:
        """How many complete participants are of `kind`."""
        return sum(1 for c in self.complete if self.kinds.get(c) == kind)

    def counted(self, answers: pd.DataFrame) -> pd.DataFrame:
        """The rows of `answers` every statistic is computed on: the complete participants'
        analysed answers."""
        return answers[analysed_rows(self.protocol, answers) & answers["code"].isin(set(self.complete))]


def kinds_of(sources: pd.DataFrame) -> dict:
    """code -> kind from ``code, source`` rows (one per answer, or per distinct pair)."""
    out = {}
    for code, s in sources.groupby("code")["source"]:
        synth = set(s) == {"synthetic"}
        out[str(code)] = "synthetic" if synth else "mixed" if "synthetic" in set(s) else "person"
    return out


def completeness(protocol, answers: pd.DataFrame, sources: pd.DataFrame, only: set[str] | None = None) -> Completeness:
    """Who is complete in `answers` (``code, model, item``, one row per answer) under `protocol`,
    with the kinds from `sources` (``code, source``); `only`: count these codes alone (e.g.
    those who have not withdrawn)."""
    if only is not None:
        answers = answers[answers["code"].isin(only)]
    need = expected_answers(protocol)
    counts = answers[analysed_rows(protocol, answers)].groupby("code").size()
    every = sorted(str(c) for c in set(answers["code"]))
    complete = tuple(c for c in every if int(counts.get(c, 0)) == need)
    incomplete = tuple({"code": c, "answers": int(counts.get(c, 0)), "of": need} for c in every if c not in complete)
    return Completeness(complete, incomplete, kinds_of(sources), protocol)
