"""Standard questionnaires as protocol entries (``[[instruments]] name = "sus" | "nasa_tlx"``),
expanded into ordinary questions, and their scoring.

- SUS, the System Usability Scale: Brooke, J. (1996). SUS: a "quick and dirty" usability
  scale. In Jordan et al. (eds), Usability Evaluation in Industry, 189-194. Ten 5-point items
  (1 strongly disagree .. 5 strongly agree), odd items positive, even items negative; score
  = 2.5 x (sum over odd items of (answer - 1) + sum over even items of (5 - answer)), 0..100.
- NASA-TLX, raw (RTLX): Hart, S. G. and Staveland, L. E. (1988). Development of NASA-TLX.
  In Hancock and Meshkati (eds), Human Mental Workload, 139-183; the unweighted mean of the
  six subscales (Hart, 2006, NASA-TLX: 20 years later, Proc. HFES 50, 904-908). Each
  subscale 0..100 (a VAS here; the paper form's 21 ticks are steps of 5); performance runs
  from perfect (0) to failure (100), so every subscale's high end is more workload.
"""

from __future__ import annotations

import numpy as np

from analysis.study.questions import Kind, Question

NAMES = ("sus", "nasa_tlx")
# each instrument's source, as a methods section cites it
SOURCES = {"sus": "Brooke, 1996", "nasa_tlx": "Hart & Staveland, 1988; unweighted, as in Hart, 2006"}
TITLES = {"sus": "System Usability Scale (SUS)", "nasa_tlx": "NASA Task Load Index (raw NASA-TLX)"}

SUS_ITEMS = (
    "I think that I would like to use this system frequently.",
    "I found the system unnecessarily complex.",
    "I thought the system was easy to use.",
    "I think that I would need the support of a technical person to be able to use this system.",
    "I found the various functions in this system were well integrated.",
    "I thought there was too much inconsistency in this system.",
    "I would imagine that most people would learn to use this system very quickly.",
    "I found the system very cumbersome to use.",
    "I felt very confident using the system.",
    "I needed to learn a lot of things before I could get going with this system.",
)
SUS_ANCHORS = ("Strongly disagree", "Strongly agree")

TLX_SUBSCALES = (  # id, question, low anchor, high anchor (Hart and Staveland 1988, the rating sheet)
    ("mental", "Mental demand: how mentally demanding was the task?", "Very low", "Very high"),
    ("physical", "Physical demand: how physically demanding was the task?", "Very low", "Very high"),
    ("temporal", "Temporal demand: how hurried or rushed was the pace of the task?", "Very low", "Very high"),
    ("performance", "Performance: how successful were you in accomplishing what you were asked to do?", "Perfect", "Failure"),
    ("effort", "Effort: how hard did you have to work to accomplish your level of performance?", "Very low", "Very high"),
    ("frustration", "Frustration: how insecure, discouraged, irritated, stressed and annoyed were you?", "Very low", "Very high"),
)

SCORES = {"sus": "SUS score (0-100)", "nasa_tlx": "raw NASA-TLX (0-100)"}
SCORE_RANGE = {"sus": (0.0, 100.0), "nasa_tlx": (0.0, 100.0)}  # where each score lies (its intervals stay inside)


def questions(name: str, when: str = "condition") -> tuple[Question, ...]:
    """The instrument's items as questions (ids sus_1..sus_10, tlx_mental..tlx_frustration)."""
    if name == "sus":
        return tuple(Question(f"sus_{k}", text, kind=Kind.LIKERT, when=when, points=5, anchors=SUS_ANCHORS, instrument="sus")
                     for k, text in enumerate(SUS_ITEMS, start=1))
    if name == "nasa_tlx":
        return tuple(Question(f"tlx_{sid}", text, kind=Kind.VAS, when=when, anchors=(lo, hi), instrument="nasa_tlx")
                     for sid, text, lo, hi in TLX_SUBSCALES)
    raise ValueError(f"unknown instrument {name!r}; allowed: {', '.join(NAMES)}")


def item_sign(q: Question) -> float:
    """Which way an instrument's item runs: +1 where agreeing is the favourable answer (SUS's
    odd, positively worded items), -1 where it is not (SUS's even items; every NASA-TLX
    subscale, where higher is more load); +1 for a question of no instrument."""
    if q.instrument == "sus":  # items sus_1..sus_10 (`questions`)
        return 1.0 if int(q.id.removeprefix("sus_")) % 2 else -1.0
    return -1.0 if q.instrument == "nasa_tlx" else 1.0


def sus_score(answers) -> float:
    """Brooke's score from the ten answers in item order (1..5 each)."""
    a = np.asarray(answers, dtype=float)
    if a.shape != (10,) or np.any((a < 1) | (a > 5)):
        raise ValueError("SUS: ten answers 1..5 in item order")
    return float(2.5 * (np.sum(a[0::2] - 1.0) + np.sum(5.0 - a[1::2])))


def raw_tlx(answers) -> float:
    """The raw TLX: the mean of the six subscales (0..100 each, any order)."""
    a = np.asarray(answers, dtype=float)
    if a.shape != (6,) or np.any((a < 0) | (a > 100)):
        raise ValueError("NASA-TLX: six subscale ratings 0..100")
    return float(a.mean())


def score(name: str, by_item: dict[str, float]) -> float:
    """An instrument's score from one participant's answers for one condition (item id -> value)."""
    items = [q.id for q in questions(name)]
    values = [by_item[i] for i in items]
    return sus_score(values) if name == "sus" else raw_tlx(values)
