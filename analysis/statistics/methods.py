"""A study's methods as data: who took part, the design, the apparatus (devices, models and their
resolved configurations, rates, the rig's measured latencies), the procedure (trials, questions,
instruments with their sources) and the analysis (tests, corrections, software versions). It is
the `methods` object of `studyctl report stats --json` (`StudyMethods.as_dict()`), and `report
text` writes its paragraphs from it, so every number in the text is one the JSON holds."""

from __future__ import annotations

import platform
from collections.abc import Mapping
from dataclasses import dataclass
from importlib.metadata import PackageNotFoundError, version

from analysis.statistics.facts import IncompleteParticipant, ModelSource, StudyFacts
from analysis.statistics.kind_results import KindStats
from analysis.statistics.result_records import Record
from analysis.statistics.stats import tests_run
from analysis.study.instruments import SOURCES, TITLES
from analysis.study.questions import Kind
from analysis.study.study_snapshot import Study
from sim.models.registry import ModelLoadError, model_class


@dataclass(frozen=True, kw_only=True)
class GroupCounts(Record):
    """The design's group field and how many complete participants are in each of its values."""

    field: str
    counts: Mapping[str, int]


@dataclass(frozen=True, kw_only=True)
class Participants(Record):
    """Who took part: N (complete), the target, whose data they are, who was excluded and why
    (incomplete answers), the eligible ages, the groups."""

    n: int
    target: int | None
    synthetic: bool
    synthetic_participants: int
    person_participants: int
    excluded: tuple[IncompleteParticipant, ...]
    age_min: int | None
    age_max: int | None
    groups: GroupCounts | None


@dataclass(frozen=True, kw_only=True)
class Design(Record):
    """The within-subject design: the conditions and their counterbalancing, trials, rest, training."""

    within_subject: bool
    conditions: tuple[str, ...]
    n_conditions: int
    counterbalancing: str
    trials_per_condition: int
    trial_seconds: float
    rest_seconds: float
    training_minutes: float
    trial_end: str


@dataclass(frozen=True, kw_only=True)
class Device(Record):
    """A device the sessions ran with, how many sessions, and whether they were synthetic."""

    device: str
    sessions: int
    synthetic: bool


@dataclass(frozen=True, kw_only=True)
class ModelRun(Record):
    """What a condition's model was as a methods section names it: its options (a plate-spring's
    variant and parameter file among them), mesh, law and only the material values the model
    reads; a condition without a stored configuration has none of these."""

    condition: str
    model: str | None
    options: Mapping[str, str | float | int | bool] | None = None
    mesh: str | None = None
    law: str | None = None
    young_pa: float | None = None
    poisson: float | None = None
    source: ModelSource | None


@dataclass(frozen=True, kw_only=True)
class Latency(Record):
    """A latency measure of the rig (docs/rig.md) with one condition: mean and range over its trials."""

    measure: str
    model: str
    trials: int
    mean: float
    lowest: float
    highest: float


@dataclass(frozen=True, kw_only=True)
class Apparatus(Record):
    """The devices, software versions, loop rates, each condition's model and the rig's latencies."""

    devices: tuple[Device, ...]
    software_versions: tuple[str, ...]
    servo_rate_hz: tuple[float, ...]
    visual_rate_hz: tuple[float, ...]
    models: tuple[ModelRun, ...]
    latency: tuple[Latency, ...]


@dataclass(frozen=True, kw_only=True)
class QuestionAsked(Record):
    """A question asked (not an instrument's item): its text, kind, when, scale."""

    id: str
    text: str
    kind: str
    when: str
    points: int | None
    anchors: tuple[str, ...] | None
    instrument: str | None


@dataclass(frozen=True, kw_only=True)
class InstrumentUsed(Record):
    """A standard instrument given (SUS, NASA-TLX), its source and how many items."""

    name: str
    title: str
    when: str
    source: str
    items: int


@dataclass(frozen=True, kw_only=True)
class TaskRun(Record):
    """A discrimination task: its parameter, method, trials, question, intervals and range."""

    kind: str
    parameter: str
    method: str
    trials: int
    question: str
    interval_seconds: float
    low: float
    high: float


@dataclass(frozen=True, kw_only=True)
class Procedure(Record):
    """What participants did: the questions asked, the instruments given, the discrimination tasks."""

    questions: tuple[QuestionAsked, ...]
    instruments: tuple[InstrumentUsed, ...]
    tasks: tuple[TaskRun, ...]


@dataclass(frozen=True, kw_only=True)
class KindAnalysis(Record):
    """How one kind of answer is tested: across the conditions, between pairs, and described."""

    kind: str
    omnibus: str
    pairs: str
    describe: str


@dataclass(frozen=True, kw_only=True)
class Analysis(Record):
    """The primary analysis, the tests per kind of answer, Holm's scope and family, the interval
    level, the software and its versions."""

    primary: str | None
    primary_text: str | None
    complete_cases: bool
    kinds: tuple[KindAnalysis, ...]
    holm: str
    holm_family: int
    ci_level: float
    software: Mapping[str, str]


@dataclass(frozen=True, kw_only=True)
class StudyMethods(Record):
    """A study's methods, as its report's Methods section writes them."""

    participants: Participants
    design: Design
    apparatus: Apparatus
    procedure: Procedure
    analysis: Analysis


CI_LEVEL = 0.95  # every interval the reports print
ANALYSIS_PACKAGES = ("numpy", "scipy", "pandas", "statsmodels", "scikit-learn")
# what each kind of answer is tested with (analysis/statistics/kinds.py, analysis/statistics/table1.py)
KIND_TESTS = {
    Kind.YES_NO: ("Cochran's Q across the conditions", "exact McNemar tests", "Wilson score intervals of each rate"),
    Kind.LIKERT: ("the Friedman test (tie-corrected) with Kendall's W", "Wilcoxon signed-rank tests with the rank-biserial correlation",
               "medians and interquartile ranges"),
    Kind.VAS: ("a linear mixed model (condition and period fixed, participant random)", "t contrasts of the mixed model",
            "means with t intervals"),
    Kind.CHOICE: ("an exact multinomial test against equal shares", "exact binomial tests between two conditions' counts",
               "shares with Wilson intervals"),
}


def material_keys(model: str) -> tuple:
    """The material keys model `model` reads (its declaration); none when it no longer loads."""
    try:
        return model_class(model).material_keys
    except ModelLoadError:
        return ()


def _versions() -> dict[str, str]:
    out = {"python": platform.python_version()}
    for name in ("brainsim-study", *ANALYSIS_PACKAGES):
        try:
            out[name] = version(name)
        except PackageNotFoundError:
            continue
    return out


def _groups(study: Study, complete: set[str]) -> GroupCounts | None:
    """The design's group field and how many of the `complete` participants are in each value."""
    field = study.protocol.groups
    if not field:
        return None
    f = study.fields
    rows = f[(f["field"] == field) & f["code"].isin(complete)]
    counts = rows["value"].astype(str).value_counts()
    values = next((x.values for x in study.protocol.fields if x.name == field), tuple(counts.index))
    return GroupCounts(field=field, counts={v: int(counts.get(v, 0)) for v in values})


def _model(config: dict | None) -> dict:
    """A condition's resolved configuration as a methods section names it: its options (a
    plate-spring's variant and parameter file among them) and only the material values the
    model reads (a plate-spring stack has its own stiffness; a mass-spring reads E alone)."""
    if not config:
        return {}
    options = dict(config.get("options") or {}) | ({"variant": config["variant"]} if "variant" in config else {})
    # an unset option (None: the model's own default applies) is left out, never printed as None
    options = {k: v["file"] if isinstance(v, dict) and "file" in v else v for k, v in options.items() if v is not None}
    material = config.get("material") or {}
    keys = material_keys(config["model"])
    # the hyperelastic law only where the formulation solves it (the linear FEM reads E and nu)
    finite = options.get("formulation") in ("finite-strain", "nodal-pressure")
    law = material.get("law") if isinstance(material.get("law"), dict) and finite else None
    return {"options": options, "mesh": (config.get("mesh") or {}).get("file"), "law": law.get("law") if law else None,
            "young_pa": material.get("young") if "young" in keys else None, "poisson": material.get("poisson") if "poisson" in keys else None}


def study_methods(study: Study, facts: StudyFacts, items: dict | None = None, kinds: KindStats | None = None,
                  holm: str = "family") -> StudyMethods:
    """The methods of `study` (`facts`: analysis.statistics.table1.study_facts, or the discrimination
    report's N in its place; `items` and `kinds`: the yes/no and other kinds' statistics the
    results come from, for the primary analysis and the size of the Holm family, None for a
    study without questions; `holm`: its scope)."""
    items = items or {}
    protocol = study.protocol
    # the participants the results count: those who answered everything, or who discriminated
    answered = set(study.answers["code"]) or set(study.discrimination["code"])
    complete = answered - {r.code for r in facts.incomplete_participants}
    configs = facts.conditions
    rates = {(c.config or {}).get("servo_rate_hz") for c in configs}
    visual = {(c.config or {}).get("visual_rate_hz") for c in configs}
    setups = study.setups.to_dict(orient="records")
    latencies = [r for r in study.latencies.to_dict(orient="records") if r["measure"] in protocol.latency_measures]
    asked = sorted({q.kind for q in protocol.questions if q.analysed}, key=list(KIND_TESTS).index)
    # the Holm family: the pairwise tests actually run, as Table 1 and the JSON count them
    family = tests_run([p for v in items.values() for p in v.pairs] + ([p for g in kinds.family_pairs() for p in g] if kinds else []))
    return StudyMethods(
        participants=Participants(
            n=facts.participants, target=protocol.target_participants, synthetic=facts.synthetic,
            synthetic_participants=facts.synthetic_participants, person_participants=facts.person_participants,
            excluded=facts.incomplete_participants, age_min=protocol.age_min, age_max=protocol.age_max, groups=_groups(study, complete),
        ),
        design=Design(
            within_subject=True, conditions=tuple(protocol.conditions), n_conditions=len(protocol.conditions),
            counterbalancing=protocol.counterbalancing, trials_per_condition=protocol.trials_per_condition,
            trial_seconds=protocol.trial_seconds, rest_seconds=protocol.rest_seconds,
            training_minutes=protocol.training_minutes, trial_end=protocol.trial_end,
        ),
        apparatus=Apparatus(
            devices=tuple(Device(device=r["device"], sessions=int(r["sessions"]), synthetic=bool(r["synthetic"])) for r in setups),
            software_versions=tuple(sorted({r["software_version"] for r in setups if r["software_version"]})),
            servo_rate_hz=tuple(sorted(x for x in rates if x is not None)), visual_rate_hz=tuple(sorted(x for x in visual if x is not None)),
            models=tuple(ModelRun.of({"condition": c.condition, "model": c.model, **_model(c.config), "source": c.source}) for c in configs),
            latency=tuple(Latency.of({k: (float(v) if isinstance(v, float) else v) for k, v in r.items()}) for r in latencies),
        ),
        procedure=Procedure(
            questions=tuple(QuestionAsked(id=q.id, text=q.text, kind=q.kind, when=q.when, points=q.points,
                                          anchors=tuple(q.anchors) if q.anchors else None, instrument=q.instrument)
                            for q in protocol.questions if not q.instrument),
            instruments=tuple(InstrumentUsed(name=name, title=TITLES[name], when=when, source=SOURCES[name],
                                             items=sum(1 for q in protocol.questions if q.instrument == name))
                              for name, when in protocol.instruments),
            tasks=tuple(TaskRun(kind=t.kind, parameter=t.parameter, method=t.method, trials=t.trials, question=t.question,
                                interval_seconds=t.interval_seconds, low=t.low, high=t.high) for t in protocol.tasks),
        ),
        analysis=Analysis(
            primary=kinds.primary.analysis if kinds else None, primary_text=kinds.primary.text if kinds else None,
            complete_cases=True, kinds=tuple(KindAnalysis(kind=k, omnibus=KIND_TESTS[k][0], pairs=KIND_TESTS[k][1], describe=KIND_TESTS[k][2])
                                             for k in asked),
            holm=holm, holm_family=family, ci_level=CI_LEVEL, software=_versions(),
        ),
    )
