"""Study protocol files (TOML) -> frozen dataclasses, with every problem reported.

`load_protocol` raises `ProtocolError` listing all problems, each as ``FILE:LINE: field:
message``; `check_protocol` returns them without raising (for ``studyctl protocol validate``).
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field
from pathlib import Path
from zoneinfo import ZoneInfo, ZoneInfoNotFoundError

from analysis.errors import ProtocolError
from analysis.study import instruments
from analysis.study.questions import KINDS, LATENCY_MEASURES, LIKERT_POINTS, WHENS, Kind, Question
from sim.errors import SceneError, SimError
from sim.models import registry
from sim.scene import configure, load_scene
from sim.targets import TRIAL_ENDS
from sim.text import NAME_MOST, TEXT_MOST, TITLE_MOST, quoted, text_problem
from sim.tomlfile import Locator, TomlFileError, parse_toml, read_toml_text
from sim.tomltable import TableReader
from studyctl.fields import check_fields
from studyctl.synthetic.skill import check_skills
from studyctl.tasks import check_tasks
from studyctl.text import ID_RE

MAX_CONDITIONS = 8
DESIGNS = ("williams",)
DEFAULT_LATENCY = ("deformation_ms", "tick_interval_p99_us", "read_to_force_us")  # [latency] left out, with free trials
DEFAULT_AGES = (18, 120)  # [inclusion] left out: adults
# what to write for a missing section (the error says it)
SECTION_HINTS = {"study": 'name = "my_study", target_participants = 20, scene = "scenes/brain_pull.toml"',
                 "design": 'conditions = ["fem", "plate_spring"], counterbalancing = "williams", training_minutes = 2.0, '
                           'trials_per_condition = 3, trial_seconds = 3.0'}


@dataclass(frozen=True)
class Protocol:
    path: Path
    name: str
    title: str
    version: int
    target_participants: int
    scene: Path
    conditions: tuple[str, ...]
    counterbalancing: str
    training_minutes: float
    trials_per_condition: int
    trial_seconds: float
    rest_seconds: float  # the rest screen between trials of a person's session
    age_min: int
    age_max: int
    latency_measures: tuple[str, ...]
    questions: tuple[Question, ...]
    text: str  # the file's content, stored with every session
    consent_version: str = "1"  # the consent form a person must have signed before a session
    withdrawal: str = "keep"  # a withdrawn participant's data: "keep" (pseudonymous) or "delete"
    timezone: str | None = None  # the lab's IANA time zone (session slots); None: floating local times
    # [conditions.NAME] tables (model and options) by name; a condition not here is a model
    # name, the scene's own configuration (studyctl/conditions.py)
    condition_tables: dict = field(default_factory=dict, compare=False)
    instruments: tuple[tuple[str, str], ...] = ()  # (name, when) of each [[instruments]]; their items are in `questions`
    tasks: tuple = ()  # [[tasks]] run in every condition after its free trials (studyctl/tasks.py)
    fields: tuple = ()  # [fields.NAME]: what is recorded about each participant (studyctl/fields.py)
    groups: str | None = None  # design.groups: the choice field that is the between-participant factor
    trial_end: str = "time"  # design.trial_end: "time" (the trial's seconds) or "targets" (every hand held its target, or the time)
    skills: dict = field(default_factory=dict, compare=False)  # [synthetic.groups.NAME]: group -> studyctl.synthetic.skill.SkillProfile

    def field_named(self, name: str):
        return next((f for f in self.fields if f.name == name), None)

    @property
    def group_field(self):
        return self.field_named(self.groups) if self.groups else None

    @property
    def sha256(self) -> str:
        return hashlib.sha256(self.text.encode()).hexdigest()

    @property
    def items(self) -> tuple[str, ...]:
        return tuple(q.id for q in self.questions)

    def asked(self, when: str) -> tuple[Question, ...]:
        """The questions asked at `when` (condition, trial or end), in protocol order."""
        return tuple(q for q in self.questions if q.when == when)

    def question(self, item: str) -> Question:
        return next(q for q in self.questions if q.id == item)


def check_protocol(path: str | Path, text: str | None = None) -> tuple[Protocol | None, list[str]]:
    """Parse and validate; returns (protocol or None, problems as 'FILE:LINE: field: message').

    `text` overrides the file's content (a protocol stored in a study database). A protocol read
    from its file also has its scene validated and each condition checked against it; a stored
    one was checked when its study was made, and its reports must not fail because the scene
    file was edited since."""
    path = Path(path)
    from_file = text is None
    try:
        if text is None:
            data, loc, text = read_toml_text(path)
        else:
            data, loc = parse_toml(text, path), Locator(text)
    except TomlFileError as exc:
        return None, [str(exc)]
    c = TableReader(path, data, "", loc, [])
    _unknown_keys(data, c)
    study, design = c.table("study", hint=_hint("study")), c.table("design", hint=_hint("design"))
    inclusion, latency = c.table("inclusion", required=False), c.table("latency", required=False)
    meta = _study_fields(study, c.table("ethics", required=False), path)
    tables = _condition_tables(data.get("conditions", {}), c.error)
    conditions = _design_conditions(design, tables, c)
    scene, scene_spec = meta["scene"], None
    if from_file and scene is not None and scene.is_file():
        scene_spec, problems = _scene_problems(scene, path, text, conditions or [], tables,
                                               lambda message: c.error("design.conditions", message))
        c.problems += [(path, 0, p) for p in problems]
    cb = design.string("counterbalancing", choices=DESIGNS)
    training = design.number("training_minutes", lo=0.0, hi=120.0)
    trials = design.integer("trials_per_condition", lo=0, hi=100)
    trial_s = design.number("trial_seconds", lo=0.5, hi=600.0)
    rest_s = design.number("rest_seconds", default=5.0, lo=0.0, hi=600.0)
    trial_end = design.string("trial_end", default="time", choices=TRIAL_ENDS)
    if trial_end == "targets" and scene_spec is not None and not any(h.target is not None for h in scene_spec.hands):
        c.error("design.trial_end", f"'targets' needs a target on a hand of the scene {scene} ([hands.target]); it has none")

    age_min = inclusion.integer("age_min", default=DEFAULT_AGES[0], lo=0, hi=120)
    age_max = inclusion.integer("age_max", default=DEFAULT_AGES[1], lo=0, hi=120)
    if age_min is not None and age_max is not None and age_min > age_max:
        c.error("inclusion.age_max", f"{age_max} is below age_min {age_min}")

    # without [latency]: the three measures of the paper's study where there are free trials to time
    measures = latency.items("measures", default=list(DEFAULT_LATENCY) if trials else [])
    for m in measures or []:
        if m not in LATENCY_MEASURES:
            c.error("latency.measures", f"unknown measure {m!r}; allowed: {', '.join(LATENCY_MEASURES)}")


    tasks = check_tasks(data, c, trial_s)
    if any(t.kind == "discrimination" for t in tasks):
        _check_stiffness_scaling(conditions or [], tables, c.error)
    if trials == 0 and not tasks and "tasks" not in data:
        c.error("design.trials_per_condition", "0 is out of range without [[tasks]]; allowed: 1..100 (0 when each condition has a task)")
    questions = _questions(data, c, len(conditions or []))
    fields, groups = check_fields(data, design, c)

    skills = check_skills(data, groups, fields, c)
    if c.problems:
        return None, c.strings()
    return (
        Protocol(
            path=path, name=meta["name"], title=meta["title"], version=meta["version"], target_participants=meta["target"], scene=scene,
            conditions=tuple(conditions), counterbalancing=cb, training_minutes=training, trials_per_condition=trials,
            trial_seconds=trial_s, rest_seconds=rest_s, age_min=age_min, age_max=age_max, latency_measures=tuple(measures),
            questions=tuple(questions), text=text, consent_version=meta["consent_version"], withdrawal=meta["withdrawal"],
            timezone=meta["timezone"], condition_tables=tables,
            instruments=tuple(dict.fromkeys((q.instrument, q.when) for q in questions if q.instrument)), tasks=tuple(tasks),
            fields=tuple(fields), groups=groups, trial_end=trial_end or "time", skills=skills,
        ),
        [],
    )


def _hint(section: str) -> str:
    """What a missing [section] should hold, for its message."""
    return f"{SECTION_HINTS[section]} (docs/study.md lists every key)"


SECTIONS = {"study": ("name", "title", "version", "target_participants", "scene", "timezone"),
            "design": ("conditions", "counterbalancing", "training_minutes", "trials_per_condition", "trial_seconds", "rest_seconds", "groups",
                       "trial_end"),
            "inclusion": ("age_min", "age_max"), "latency": ("measures",), "ethics": ("consent_version", "withdrawal"),
            "questions": ("id", "text", "kind", "points", "anchors", "when"), "instruments": ("name", "when"), "conditions": None,
            "fields": None, "synthetic": ("groups",),
            "tasks": ("kind", "parameter", "reference", "method", "rule", "trials", "question", "feedback", "interval_seconds", "range", "start")}


def _unknown_keys(data: dict, c: TableReader) -> None:
    """Sections and keys a protocol may not have (a typo is named, never ignored)."""
    for key in data:
        if key not in SECTIONS:
            c.error(key, f"unknown section; allowed: {', '.join(SECTIONS)}")
    for sec, keys in SECTIONS.items():
        if keys is None:  # [conditions.NAME]: names of the protocol's choosing, checked below
            continue
        tables = data.get(sec)
        tables = [(sec, tables)] if isinstance(tables, dict) else \
            [(f"{sec}[{k}]", t) for k, t in enumerate(tables)] if isinstance(tables, list) else []
        for where, t in tables:
            for key in t if isinstance(t, dict) else ():
                if key not in keys:
                    c.error(f"{where}.{key}", f"unknown key; allowed: {', '.join(keys)}")


def _study_fields(study: TableReader, ethics: TableReader, path: Path) -> dict:
    """[ethics] and [study]: the consent form's version, withdrawal, name, title, time zone,
    version, target N and the scene (resolved beside the protocol)."""
    out = {"consent_version": ethics.string("consent_version", default="1", most=NAME_MOST, one_line=True),
           "withdrawal": ethics.string("withdrawal", default="keep", choices=("keep", "delete"))}
    if out["consent_version"] is not None and not out["consent_version"].strip():
        ethics.error("consent_version", "empty; name the consent form's version, e.g. \"1\"")
    out["name"] = study.string("name", most=NAME_MOST, one_line=True)
    out["title"] = study.string("title", default="", most=TITLE_MOST, one_line=True)
    timezone = out["timezone"] = study.string("timezone", default=None)
    if timezone is not None:
        try:
            ZoneInfo(timezone)
        except (ZoneInfoNotFoundError, ValueError):
            study.error("timezone", f"{timezone!r} is not an IANA time zone, e.g. \"Asia/Shanghai\" or \"Europe/Berlin\"")
    out["version"] = study.integer("version", default=1, lo=1, hi=10_000)
    out["target"] = study.integer("target_participants", lo=1, hi=10000)
    scene_rel = study.string("scene")
    out["scene"] = None
    if scene_rel is not None:
        out["scene"] = (path.parent / scene_rel).resolve()
        if not out["scene"].exists():
            study.error("scene", f"{out['scene']} does not exist")
        elif not out["scene"].is_file():  # a folder, a device (/dev/zero never ends), a named pipe (blocks)
            study.error("scene", f"{out['scene']} is not a regular file")
    return out


def _design_conditions(design: TableReader, tables: dict, c: TableReader) -> list | None:
    """design.conditions: each a [conditions.NAME] table or a model's name, once, and every
    table listed."""
    conditions = design.items("conditions")
    if conditions is None:
        return None
    # a model's name is spelt plate-spring or plate_spring alike; a condition's table is named with _ only
    typed = list(conditions)
    conditions = [registry.canonical(x) if isinstance(x, str) and x not in tables else x for x in conditions]
    spelt: dict[str, object] = {}  # both spellings of one model: named as written, not merged
    for cond, written in zip(conditions, typed):
        first = spelt.setdefault(str(cond), written)
        if str(first) != str(written):
            c.error("design.conditions", f"{first!r} and {written!r} are the same model (- and _ spell names alike); list it once")
    if not conditions:
        c.error("design.conditions", "at least one condition")
    if len(conditions) > MAX_CONDITIONS:
        c.error("design.conditions", f"{len(conditions)} conditions; allowed: 1..{MAX_CONDITIONS}")
    for cond in conditions:
        if not isinstance(cond, str):
            c.error("design.conditions", f"{cond!r} is not a condition's name")
        elif cond not in registry.names() and cond not in tables:
            named = f"a [conditions.NAME] table ({', '.join(tables)})" if tables else "a [conditions.NAME] table"
            c.error("design.conditions", f"unknown condition {cond!r}; allowed: {named} or a model name ({', '.join(registry.names())})")
    if len(set(map(str, typed))) != len(typed):
        c.error("design.conditions", "a condition appears twice")
    for declared in tables:
        if declared not in conditions:
            c.error(f"conditions.{declared}", "not listed in design.conditions")
    return conditions


def _questions(data: dict, c: TableReader, n_conditions: int) -> list[Question]:
    """[[questions]] and [[instruments]] as questions, in file order (instruments' items after
    the questions): a kind, when it is asked, and what the kind needs (docs/study.md)."""
    out: list[Question] = []
    seen: dict[str, str] = {}
    bad = c.error

    def add(q: Question, where: str) -> None:
        if q.id in seen:
            bad(where, f"duplicate item id {q.id!r} (also {seen[q.id].rpartition('.')[0]})")
        else:
            seen[q.id] = where
            out.append(q)

    qs = data.get("questions")
    if qs is None and "instruments" not in data and "tasks" not in data:
        bad("questions", "missing section: at least one [[questions]], [[instruments]] or [[tasks]]")
    elif qs is not None and not isinstance(qs, list):
        bad("questions", "must be an array of tables ([[questions]])")
    for k, q in enumerate(qs if isinstance(qs, list) else []):
        sec = f"questions[{k}]"
        if not isinstance(q, dict):
            bad(sec, "must be a table")
            continue
        question = _question(c.sub(q, f"{sec}."), n_conditions)
        if question is not None:
            add(question, f"{sec}.id")
    ins = data.get("instruments", [])
    if not isinstance(ins, list):
        bad("instruments", "must be an array of tables ([[instruments]] with name = ...)")
        ins = []
    named: set[str] = set()
    for k, t in enumerate(ins):
        sec = f"instruments[{k}]"
        if not isinstance(t, dict):
            bad(sec, "must be a table")
            continue
        r = c.sub(t, f"{sec}.")
        name, when = r.string("name"), r.string("when", default="condition")
        if name is not None and name not in instruments.NAMES:
            bad(f"{sec}.name", f"{name!r} is not an instrument; allowed: {', '.join(instruments.NAMES)}")
        elif when is not None and when not in WHENS:
            bad(f"{sec}.when", f"{when!r} is not allowed; allowed: {', '.join(WHENS)}")
        elif name in named:
            bad(f"{sec}.name", f"{name!r} appears twice")
        elif name is not None and when is not None:
            named.add(name)
            for q in instruments.questions(name, when):
                add(q, f"{sec}.name")
    if not any(q.analysed for q in out) and (isinstance(qs, list) or "instruments" in data):
        bad("questions", "no question to analyse: at least one [[questions]] other than free text, or an [[instruments]]")
    return out


def _question(r: TableReader, n_conditions: int) -> Question | None:
    """One [[questions]] table: its kind, when it is asked and what the kind needs; the question,
    or None when it has a problem (added to `r`'s problems)."""
    q, bad = r.data, r.error
    qid, qtext = r.string("id", most=NAME_MOST, one_line=True), r.string("text", most=TEXT_MOST)
    kind = r.string("kind", default="yes_no")
    when = r.string("when", default="condition")
    if kind is not None and kind not in KINDS:
        bad("kind", f"{kind!r} is not a kind; allowed: {', '.join(KINDS)}")
    if when is not None and when not in WHENS:
        bad("when", f"{when!r} is not allowed; allowed: {', '.join(WHENS)}")
    elif kind == Kind.CHOICE and when is not None and when != "end":
        bad("when", f"{when!r}: a choice among the conditions is asked once, after the last; allowed: end")
    if kind == Kind.CHOICE and n_conditions < 2:
        bad("kind", "a choice needs at least 2 conditions in design.conditions")
    points = anchors = None
    if kind not in KINDS:  # refused above: what the kind needs is unknown
        return None
    if kind == Kind.LIKERT:
        points = r.integer("points", lo=LIKERT_POINTS[0], hi=LIKERT_POINTS[1])
    elif "points" in q:
        bad("points", f"only a likert question has points; this one is {kind}")
    if "anchors" in q and kind not in (Kind.LIKERT, Kind.VAS):
        bad("anchors", f"only a likert or vas question has anchors; this one is {kind}")
    elif "anchors" in q:
        a = q["anchors"]
        if not (isinstance(a, list) and len(a) == 2 and all(isinstance(x, str) and x.strip() for x in a)):
            bad("anchors", f"{quoted(a)}: two non-empty texts, [low, high], e.g. [\"Not at all\", \"Completely\"]")
        elif (problem := next((f"{end}: {p}" for end, x in zip(("low", "high"), a)
                               if (p := text_problem(x, NAME_MOST, one_line=True)) is not None), None)) is not None:
            bad("anchors", problem)
        else:
            anchors = (a[0].strip(), a[1].strip())
    elif kind == Kind.LIKERT:
        bad("anchors", "missing: a likert question names its two ends, anchors = [low, high]")
    if qtext is not None and not qtext.strip():
        bad("text", "empty: the question as the participant reads it")
    if qid is not None and not ID_RE.match(qid):
        bad("id", f"{qid!r} must be lower-case letters, digits and _ (starting with a letter)")
    elif qid is not None and qtext is not None and kind in KINDS and when in WHENS:
        return Question(qid, qtext, kind=kind, when=when, points=points, anchors=anchors)
    return None


def _condition_tables(raw, bad) -> dict[str, dict]:
    """The [conditions.NAME] tables: a name as item ids are, a `model` among the known ones; the
    options are checked against the scene (`_scene_problems`)."""
    if not isinstance(raw, dict):
        bad("conditions", "must be tables, one per condition: [conditions.NAME] with model = ...")
        return {}
    tables = {}
    for name, t in raw.items():
        if not isinstance(t, dict):
            bad(f"conditions.{name}", "must be a table: [conditions.NAME] with model = ...")
        elif not ID_RE.match(name):
            bad(f"conditions.{name}", f"{name!r} must be lower-case letters, digits and _ (starting with a letter)")
        elif name in registry.names():  # a model's name alone means the scene's own configuration
            bad(f"conditions.{name}", f"{name!r} is a model's name, which means the scene's own configuration; name the condition otherwise")
        elif not registry.is_model_name(t.get("model")):
            what = "missing" if "model" not in t else f"{t['model']!r} is not a model"
            bad(f"conditions.{name}.model", f"{what}; allowed: {', '.join(registry.names())} or \"package.module:Class\"")
        elif (problem := _load_problem(t["model"])) is not None:
            bad(f"conditions.{name}.model", problem)
        else:
            tables[name] = t | {"model": registry.canonical(t["model"])}
    return tables


def _load_problem(name: str) -> str | None:
    """Why model `name` cannot be used (it does not import, declares another API...), or None."""
    try:
        registry.model_class(name)
    except registry.ModelLoadError as exc:
        return str(exc)
    return None


def _check_stiffness_scaling(conditions: list, tables: dict, bad) -> None:
    """The discrimination task scales each condition's stiffness: its model must declare it."""
    for cond in conditions:
        if not isinstance(cond, str):  # refused by the design's check
            continue
        model = tables[cond].get("model") if cond in tables else cond
        if isinstance(model, str) and _load_problem(model) is None and not registry.model_class(model).scales_stiffness:
            bad("design.conditions", f"condition {cond!r}: model {model!r} does not scale its stiffness (scales_stiffness in its "
                                     "class, docs/models.md), which the discrimination task needs")


def _scene_problems(scene: Path, path: Path, text: str, conditions: list, tables: dict, bad) -> tuple:
    """(the scene's spec, or None when it has problems; the problems, each 'FILE:LINE: field:
    message'): the scene file's own; then, for a valid scene, each condition's: a model the
    scene does not configure, an option it does not take or out of its range (named at the
    protocol's lines)."""
    try:
        spec = load_scene(scene)
    except SceneError as exc:
        return None, list(exc.problems)
    out: list[str] = []
    for c in conditions:
        if not isinstance(c, str):  # refused above
            continue
        if c in tables:
            try:
                configure(spec, tables[c], path, Locator(text), f"conditions.{c}.")
            except SceneError as exc:
                out += exc.problems
            except SimError as exc:  # e.g. plate-spring parameters that fail the paper's bounds
                out.append(f"{path}:{Locator(text).line(f'conditions.{c}')}: conditions.{c}: {exc}")
        elif c in registry.names() and (problem := _load_problem(c)) is not None:
            bad(f"condition {c!r}: {problem}")
        elif c in registry.names() and c not in spec.models:
            bad(f"{c!r} is not configured in the scene {scene}; configured: {', '.join(sorted(spec.models))}")
    return spec, out


def load_protocol(path: str | Path) -> Protocol:
    protocol, problems = check_protocol(path)
    if problems:
        raise ProtocolError(problems)
    return protocol


def protocol_from_text(text: str, path: str | Path) -> Protocol:
    """Rebuild a stored protocol; relative paths resolve against its original location."""
    protocol, problems = check_protocol(path, text)
    if problems:
        raise ProtocolError(problems)
    return protocol
