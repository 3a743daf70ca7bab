"""Table 1 of the seed paper from a study (analysis.study.study_snapshot.Study: the database read once),
with the statistics it left out.

Tidy DataFrames with stable column names (documented in docs/analysis.md):

- `rates(study)`: one row per item and model: ``item, question, model, yes, no, n, rate,
  wilson_low, wilson_high`` (Wilson 95% interval);
- `cochran(study)`: one row per item: ``item, cochran_q, df, p_value, n_complete`` (participants
  who answered the item for every model);
- `deformation(study)`: one row per model: ``model, n_trials, mean_ms, sd_ms, median_ms, p95_ms``.
"""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
from statsmodels.stats.contingency_tables import cochrans_q

from analysis.statistics.facts import ConditionRun, IncompleteParticipant, ModelSource, StudyFacts
from analysis.statistics.faults import ConditionEvents, condition_events, involving, withheld
from analysis.statistics.stats import wilson
from analysis.statistics.withhold import binary_across_reason
from analysis.study.questions import Kind
from analysis.study.study_snapshot import Study, data_flag
from sim.text import counted


def answers_wide(answers: pd.DataFrame, item: str, models: list[str]) -> pd.DataFrame:
    """0/1 answers to one item: a row per participant who answered it for every model."""
    wide = answers[answers["item"] == item].pivot(index="code", columns="model", values="answer")
    return wide.reindex(columns=models).dropna()


def complete_answers(study: Study) -> tuple[pd.DataFrame, list[dict]]:
    """The one N rule (analysis.study.completeness): a participant counts when they answered every
    analysed question for every condition (complete cases). Returns their answers (code,
    model, item, trial, answer: each in its kind's type) and the others, each as {code,
    answers, of}: everything in a report is computed on the complete ones."""
    done = study.completeness
    return done.counted(study.answers).reset_index(drop=True), list(done.incomplete)


def binary_items(protocol) -> list[str]:
    """The yes/no questions asked after each condition: the rows of the paper-style Table 1."""
    return [q.id for q in protocol.asked("condition") if q.kind == Kind.YES_NO]


def binary_answers(study: Study, answers: pd.DataFrame | None = None) -> pd.DataFrame:
    """The complete participants' answers to `binary_items`, as 0/1 integers (from `answers`,
    complete_answers' when the caller has them)."""
    answers = complete_answers(study)[0] if answers is None else answers
    sel = answers[answers["item"].isin(binary_items(study.protocol)) & (answers["trial"] < 0)]
    return sel.astype({"answer": int}).reset_index(drop=True)


def rates(study: Study) -> pd.DataFrame:
    protocol = study.protocol
    answers = binary_answers(study)
    counts = answers.groupby(["item", "model"])["answer"].agg(yes="sum", n="count").reset_index()
    text = {q.id: q.text for q in protocol.questions}
    rows = []
    for q in binary_items(protocol):
        for m in protocol.conditions:
            c = counts[(counts["item"] == q) & (counts["model"] == m)]
            yes = int(c["yes"].iloc[0]) if len(c) else 0
            n = int(c["n"].iloc[0]) if len(c) else 0
            lo, hi = wilson(yes, n)
            rows.append({"item": q, "question": text[q], "model": m, "yes": yes, "no": n - yes, "n": n,
                         "rate": yes / n if n else float("nan"), "wilson_low": lo, "wilson_high": hi})
    return pd.DataFrame(rows, columns=["item", "question", "model", "yes", "no", "n", "rate", "wilson_low", "wilson_high"])


def events(study: Study) -> tuple[ConditionEvents, ...]:
    """Each condition's faults and safety events over its stored trials (analysis/statistics/faults.py)."""
    return condition_events(list(study.protocol.conditions), study.trial_events)


def cochran(study: Study) -> pd.DataFrame:
    protocol = study.protocol
    answers = binary_answers(study)
    held = withheld(events(study))
    rows = []
    for q in binary_items(protocol):
        wide = answers_wide(answers, q, list(protocol.conditions))
        # a withheld condition's reason first: the test would compare its fault, whatever the answers
        reason = (involving(protocol.conditions, held)
                  or binary_across_reason(len(wide), len(protocol.conditions), wide.to_numpy(dtype=int) if len(wide) else None))
        q_stat = p = float("nan")
        if reason is None:
            r = cochrans_q(wide.to_numpy(dtype=int))
            q_stat, p = float(r.statistic), float(r.pvalue)
        rows.append({"item": q, "test": "Cochran's Q", "cochran_q": q_stat, "df": len(protocol.conditions) - 1, "p_value": p,
                     "n_complete": len(wide), "reason": reason})
    return pd.DataFrame(rows, columns=["item", "test", "cochran_q", "df", "p_value", "n_complete", "reason"])


# what the row times (sim/run.py: every frame computes its surface, drawn or not)
DEFORMATION_WORK = "per visual frame, the model's deformation with the surface a participant's view draws"
DEFORMATION_LABEL = f"benchmark of this machine (wall-clock time {DEFORMATION_WORK}), not a measure of the participants"


def deformation(study: Study) -> pd.DataFrame:
    """Deformation time per frame, one value per participant (the mean of their trials) for
    the complete participants: a benchmark of the machine the sessions ran on, summarised
    over participants (no test: CPU timings are not about people)."""
    protocol = study.protocol
    answers, _ = complete_answers(study)
    lat = study.latency[study.latency["code"].isin(set(answers["code"]))]
    rows = []
    for m in protocol.conditions:
        sel = lat["model"] == m
        v = lat.loc[sel, "value"].to_numpy()
        rows.append({"model": m, "n_participants": len(v), "n_trials": int(lat.loc[sel, "trials"].sum()),
                     "mean_ms": float(v.mean()) if len(v) else float("nan"),
                     "sd_ms": float(v.std(ddof=1)) if len(v) > 1 else float("nan"),
                     "median_ms": float(np.median(v)) if len(v) else float("nan"),
                     "p95_ms": float(np.percentile(v, 95)) if len(v) else float("nan")})
    return pd.DataFrame(rows, columns=["model", "n_participants", "n_trials", "mean_ms", "sd_ms", "median_ms", "p95_ms"])


def study_facts(study: Study) -> StudyFacts:
    """N, the incomplete, and the complete participants counted by kind (analysis.study.completeness):
    a complete mixed-source participant counts as synthetic (their data are partly simulated);
    the reports' warning names every mixed-source participant."""
    protocol = study.protocol
    done = study.completeness
    n = len(done.complete)
    persons = done.count("person")
    synthetic = done.count("synthetic") + done.count("mixed")
    mixed = list(study.mixed_source_participants)  # the warning names every one, complete or not
    return StudyFacts(study=protocol.name, participants=n, incomplete_participants=tuple(IncompleteParticipant(**x) for x in done.incomplete),
                      synthetic_participants=synthetic, person_participants=persons, mixed_source_participants=mixed,
                      synthetic=synthetic > 0, mixed=synthetic > 0 and persons > 0, flag=data_flag(persons, synthetic),
                      design=f"within-subject, {counted(len(protocol.conditions), 'condition')}, {protocol.counterbalancing} counterbalancing",
                      conditions=conditions(study))


def conditions(study: Study) -> list[ConditionRun]:
    """What each condition ran: its resolved configuration (studyctl/conditions.py) and hash,
    with the sessions that ran it. A condition that ran under two configurations (its scene or
    protocol changed mid-study) has two rows; sessions before schema 5 recorded none."""
    rows = study.configurations
    order = study.protocol.conditions
    out = []  # the protocol's order; a stable sort keeps each condition's configurations by first session
    for r in sorted(rows.to_dict(orient="records"), key=lambda r: order.index(r["condition"]) if r["condition"] in order else len(order)):
        text = r["config"] if isinstance(r["config"], str) else None
        config = json.loads(text) if text else None
        out.append(ConditionRun(condition=r["condition"], model=config["model"] if config else None, config_json=text if config else None,
                                config_sha256=r["config_sha256"] if config else None, sessions=int(r["sessions"]),
                                source=model_source(config, r.get("software_versions"))))
    return out


def model_source(config: dict | None, software_versions: str | None = None) -> ModelSource | None:
    """Where a condition's model came from, as its stored configuration says: a plugin's
    distribution, version and source hash (`plugin`, studyctl/conditions.py), else built into
    brainsim-study, whose version is that of the sessions that ran it (`software_versions`: their
    stored software versions, "brainsim-study X", comma-separated; None: unknown); None: no configuration."""
    if not config:
        return None
    plugin = config.get("plugin")
    if not plugin:
        return ModelSource.of({"package": "brainsim-study", "version": _builtin_version(software_versions), "builtin": True, "source_sha256": None})
    return ModelSource(package=plugin.get("distribution"), version=plugin.get("version"), builtin=False,
                       source_sha256=plugin.get("source_sha256"), target=plugin.get("target"))


def _builtin_version(software_versions: str | None) -> str | None:
    """brainsim-study's version from the sessions' software versions: "0.9.0", or several sorted
    and comma-separated when sessions ran under more than one; None when none was stored."""
    if not isinstance(software_versions, str) or not software_versions:
        return None
    found = {v.strip().removeprefix("brainsim-study ").strip() for v in software_versions.split(",") if v.strip()}
    return ", ".join(sorted(found)) or None



