"""Tasks a protocol may give in each condition besides its free pulls (`[[tasks]]`).

One kind so far, ``discrimination``: two-interval forced choice on a parameter of the tissue
model (``stiffness``: Young's modulus for the FEM and the mass-spring, the plates' E for the
plate-spring; `sim.scene.Scene.with_stiffness`). Each trial pulls the tissue twice, once at the
reference and once stiffer by a relative increment ``delta`` chosen by an adaptive procedure
(studyctl/session/procedures.py), in a random order; the participant says which was stiffer. The
Weber fraction is the delta at 75% correct (analysis/discrimination/psychometric.py). docs/study.md.
"""

from __future__ import annotations

from dataclasses import dataclass

from sim.tomltable import TableReader
from studyctl.session.procedures import METHODS, RULES, ProcedureSpec

KINDS = ("discrimination",)
PARAMETERS = ("stiffness",)
TRIALS = (10, 500)
REFERENCE_MAX = 100.0  # times the condition's own stiffness
DELTA_RANGE = (0.001, 10.0)  # the increments a procedure may try: 0.1% to eleven times the reference


@dataclass(frozen=True)
class DiscriminationTask:
    """One `[[tasks]]` table of kind "discrimination" (defaults as documented)."""

    index: int  # its place among the protocol's tasks: stored with each trial
    parameter: str = "stiffness"
    reference: float = 1.0  # the reference's scale of the parameter (1: the condition's own)
    method: str = "quest+"
    rule: str = "1-up-2-down"  # staircase only
    trials: int = 40
    question: str = "Which one was stiffer?"
    feedback: bool = False
    interval_seconds: float = 3.0  # each interval's pull (default: design.trial_seconds)
    low: float = 0.02  # the increments tried: delta in [low, high]
    high: float = 1.0
    start: float = 0.4  # a staircase's first delta

    kind = "discrimination"

    def procedure_spec(self):
        return ProcedureSpec(method=self.method, rule=self.rule, start=self.start, low=self.low, high=self.high)

    def scales(self, delta: float) -> tuple[float, float]:
        """The parameter's scale in the reference and the comparison interval."""
        return self.reference, self.reference * (1.0 + delta)


DEFAULT = DiscriminationTask(index=0)  # what a [[tasks]] table leaves out


def check_tasks(data: dict, checker: TableReader, trial_seconds: float | None) -> list[DiscriminationTask]:
    """The protocol's `[[tasks]]`: each checked, its problems added to `checker` (the protocol
    file's reader: FILE:LINE: field: message), the valid ones returned."""
    bad = checker.error
    raw = data.get("tasks", [])
    if not isinstance(raw, list):
        bad("tasks", "must be an array of tables ([[tasks]] with kind = \"discrimination\")")
        return []
    out = []
    for k, t in enumerate(raw):
        sec = f"tasks[{k}]"
        if not isinstance(t, dict):
            bad(sec, "must be a table")
            continue
        before = len(checker.problems)
        r = checker.sub(t, f"{sec}.")
        kind = r.string("kind")
        if kind is not None and kind not in KINDS:
            bad(f"{sec}.kind", f"{kind!r} is not a task; allowed: {', '.join(KINDS)}")
        parameter = r.string("parameter", default=DEFAULT.parameter)
        if parameter is not None and parameter not in PARAMETERS:
            bad(f"{sec}.parameter", f"{parameter!r} is not a parameter; allowed: {', '.join(PARAMETERS)}")
        method = r.string("method", default=DEFAULT.method)
        if method is not None and method not in METHODS:
            bad(f"{sec}.method", f"{method!r} is not a method; allowed: {', '.join(METHODS)}")
        rule = r.string("rule", default=DEFAULT.rule)
        if rule is not None and rule not in RULES:
            bad(f"{sec}.rule", f"{rule!r} is not a rule; allowed: {', '.join(RULES)}")
        elif "rule" in t and method != "staircase":
            bad(f"{sec}.rule", f"only a staircase has a rule; this task's method is {method!r}")
        reference = r.number("reference", default=DEFAULT.reference)
        if reference is not None and not 0.0 < reference <= REFERENCE_MAX:
            bad(f"{sec}.reference", f"{reference!r} is out of range; allowed: 0 < reference <= {REFERENCE_MAX:g}")
            reference = None
        trials = r.integer("trials", default=DEFAULT.trials, lo=TRIALS[0], hi=TRIALS[1])
        question = r.string("question", default=DEFAULT.question)
        if question is not None and not question.strip():
            bad(f"{sec}.question", "empty: the question as the participant reads it")
        feedback = r.boolean("feedback", default=DEFAULT.feedback)
        seconds = r.number("interval_seconds", default=trial_seconds, lo=0.5, hi=600.0)
        low, high = _range(t, sec, bad)
        start = r.number("start", default=min(max(DEFAULT.start, low or DEFAULT.start), high or DEFAULT.start))
        if "start" in t and method != "staircase":
            bad(f"{sec}.start", f"only a staircase has a start; QUEST+ chooses its own (this task's method is {method!r})")
        elif start is not None and low is not None and high is not None and not low <= start <= high:
            bad(f"{sec}.start", f"{start!r} is out of range; allowed: {low:g}..{high:g} (the task's range)")
        if len(checker.problems) == before:
            out.append(DiscriminationTask(index=k, parameter=parameter, reference=reference, method=method, rule=rule, trials=trials,
                                          question=question.strip(), feedback=feedback, interval_seconds=seconds, low=low, high=high,
                                          start=start))
    return out


def _range(t: dict, sec: str, bad) -> tuple[float | None, float | None]:
    """`range = [low, high]`: the relative increments the procedure may try."""
    if "range" not in t:
        return DEFAULT.low, DEFAULT.high
    r = t["range"]
    ok = isinstance(r, list) and len(r) == 2 and all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in r)
    if ok and DELTA_RANGE[0] <= r[0] < r[1] <= DELTA_RANGE[1]:
        return float(r[0]), float(r[1])
    bad(f"{sec}.range", f"{r!r}: two increments [low, high] with {DELTA_RANGE[0]:g} <= low < high <= {DELTA_RANGE[1]:g} "
                        "(0.1 = 10% stiffer than the reference)")
    return None, None
