"""Table 1 of the seed paper from a study (analysis.study_snapshot.Study: the database read once),
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

from analysis.facts import ConditionRun, IncompleteParticipant, ModelSource, StudyFacts
from analysis.faults import ConditionEvents, condition_events, involving, withheld
from analysis.methods import material_keys
from analysis.reports.formatting import p_value, rate_interval
from analysis.reports.table import Table
from analysis.result_records import McNemarPair
from analysis.stats import tests_run, wilson
from analysis.study_results import StudyStats
from analysis.study_snapshot import Study, data_flag
from analysis.withhold import binary_across_reason, mean_sd
from sim.text import counted


def answers_wide(answers: pd.DataFrame, item: str, models: list[str]) -> pd.DataFrame:
    """0/1 answers to one item: a row per participant who answered it for every model."""
    wide = answers[answers["item"] == item].pivot(index="code", columns="model", values="answer")
    return wide.reindex(columns=models).dropna()


def complete_answers(study: Study) -> tuple[pd.DataFrame, list[dict]]:
    """The one N rule (studyctl.completeness): a participant counts when they answered every
    analysed question for every condition (complete cases). Returns their answers (code,
    model, item, trial, answer: each in its kind's type) and the others, each as {code,
    answers, of}: everything in a report is computed on the complete ones."""
    done = study.completeness
    return done.counted(study.answers).reset_index(drop=True), list(done.incomplete)


def binary_items(protocol) -> list[str]:
    """The yes/no questions asked after each condition: the rows of the paper-style Table 1."""
    return [q.id for q in protocol.asked("condition") if q.kind == "yes_no"]


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
    """Each condition's faults and safety events over its stored trials (analysis/faults.py)."""
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
    """N, the incomplete, and the complete participants counted by kind (studyctl.completeness):
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


def source_text(source: ModelSource | None) -> str:
    """A model's origin in words: "built in", or "from PACKAGE VERSION (source SHA-256 ...)"."""
    if source is None or source.builtin:
        return "built in"
    where = f"{source.package} {source.version}" if source.package else f"{source.target} on the Python path"
    sha = f" (source SHA-256 {source.source_sha256[:12]})" if source.source_sha256 else ""
    return f"from {where}{sha}"


def condition_text(c: ConditionRun) -> str:
    """One line of what a condition ran: model, variant and options, the tissue's modulus."""
    cfg = c.config
    if cfg is None:
        return f"{c.condition}: the scene's own configuration (not recorded before schema 5)"
    opts = {k: v for k, v in cfg["options"].items() if v is not None} | ({"variant": cfg["variant"]} if "variant" in cfg else {})
    shown = ", ".join(f"{k} {v['file'] if isinstance(v, dict) and 'file' in v else v}" for k, v in sorted(opts.items()))
    mat = cfg["material"]
    keys = material_keys(cfg["model"])
    parts = [f"{label} {mat[key]:g}{unit}" for key, label, unit in (("young", "E", " Pa"), ("poisson", "nu", "")) if key in keys]
    young = f"; {', '.join(parts)}" if parts else ""
    return (f"{c.condition}: {cfg['model']} ({shown}{young}), {source_text(c.source)}, "
            f"configuration {c.config_sha256[:12]}")


def plugin_note(conditions: list[ConditionRun]) -> str:
    """The conditions whose model came from outside brainsim-study, with its package and version,
    as a sentence for a table's note ("" when every model is built in)."""
    outside = [f"{c.condition} ran {c.model} {source_text(c.source)}" for c in conditions
               if c.source is not None and not c.source.builtin]
    return f"Models from outside brainsim-study: {'; '.join(outside)}." if outside else ""


def incomplete_text(facts: StudyFacts) -> str:
    """The participants left out of every statistic, as reports print them: "P98 (9/27), ..."."""
    return ", ".join(f"{x.code} ({x.answers}/{x.of})" for x in facts.incomplete_participants)


def item_rows(r, q, models):
    """Per question, in table order: (item, question text, its rate row for each of `models`,
    its Cochran's Q row): the rows of `table`."""
    for item, g in r.groupby("item", sort=False):
        g = g.set_index("model")
        yield item, g["question"].iloc[0], [g.loc[m] for m in models], q[q["item"] == item].iloc[0]


def cochran_cell(qrow) -> str:
    """Cochran's Q (p), or why it was not run."""
    if qrow["p_value"] != qrow["p_value"]:
        return f"n/a ({qrow.get('reason') or 'not run'})"
    return f"{qrow['cochran_q']:.2f} ({p_value(qrow['p_value'])})"


def mcnemar_cell(p: McNemarPair) -> str:
    """A McNemar pair's Holm p, or why it was not tested."""
    if p.p_value != p.p_value:
        return f"{p.a}-{p.b} not tested: {p.reason or 'not run'}"
    return f"{p.a}-{p.b} {p_value(p.p_holm)}"


def holm_text(st: StudyStats) -> str:
    """What the reports' p_holm is (`study_stats`' scope): Holm over all N pairwise tests of
    every kind, or within each question."""
    if st.holm != "family":
        return "Holm within each question"
    pairs = [p for v in st.items.values() for p in v.pairs] + [p for g in st.kinds.family_pairs() for p in g]
    tested = tests_run(pairs)
    if not tested:
        return "Holm: no pair tested"
    return "one pair tested: no Holm correction" if tested == 1 else f"Holm over all {tested} pairs tested"


def rate_cell(x) -> str:
    """One question's answers under one condition: yes/no counts, the rate [Wilson 95%]."""
    return f"{x['yes']}/{x['no']}, {rate_interval(x['rate'], x['wilson_low'], x['wilson_high'])}"


def deformation_cell(x) -> str:
    """One condition's deformation time per frame (ms): mean +- sd over participants (median, p95)."""
    if not x["n_participants"]:
        return "n/a (no trials)"
    return f"{mean_sd(x['mean_ms'], x['sd_ms'], x['n_participants'])} (median {x['median_ms']:.2f}, p95 {x['p95_ms']:.2f})"


def table(st: StudyStats, r: pd.DataFrame, q: pd.DataFrame, d: pd.DataFrame) -> Table:
    """Table 1, what the Markdown, LaTeX and HTML reports all render: per yes/no question the
    counts and rate [Wilson 95%] under each condition, Cochran's Q, the McNemar pairs with Holm
    (`st`'s scope); then the deformation-time row (a benchmark of this machine, no test). `r`,
    `q`, `d`: `rates`, `cochran`, `deformation` of the study `st` was computed on."""
    models = list(d["model"])
    scope = holm_text(st)
    rows = [[question, *map(rate_cell, rates_), cochran_cell(qrow), "; ".join(map(mcnemar_cell, st.items[item].pairs)) or "n/a (one condition)"]
            for item, question, rates_, qrow in item_rows(r, q, models)]
    rows.append(["Time for real-time deformation of the model, ms: benchmark of this machine",
                 *(deformation_cell(x) for _, x in d.iterrows()), "", ""])
    return Table(columns=["Question", *(f"{m}: yes/no, rate [95% CI]" for m in models), "Cochran's Q (p)", f"McNemar p, {scope}"],
                 rows=rows, title="Table 1",
                 notes="Rates with Wilson 95% intervals; Cochran's Q across the models; pairwise exact McNemar tests, "
                       f"{scope}. Deformation time: each participant's mean over their trials, mean +- sd over participants: "
                       f"wall-clock time of this machine {DEFORMATION_WORK}, not a measure of the participants (no test).")


def deformation_table(d: pd.DataFrame) -> Table:
    """The deformation-time row on its own, for a study with no yes/no question (no Table 1 to sit in)."""
    return Table(columns=["Time for real-time deformation, ms: benchmark of this machine", *d["model"]],
                 rows=[["mean +- sd (median, p95)", *(deformation_cell(x) for _, x in d.iterrows())]],
                 title="Deformation time (benchmark of this machine)",
                 notes=f"Each participant's mean over their trials, mean +- sd over participants: wall-clock time of this machine "
                       f"{DEFORMATION_WORK}, not a measure of the participants (no test).")
