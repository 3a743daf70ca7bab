"""A study's Table 1 as the reports draw it: the yes/no questions' counts and rates with Cochran's
Q and the McNemar pairs, the deformation-time row, what each condition ran, the participants left
out, and the Markdown report that puts them together with the other kinds' tables
(analysis/reports/kind_tables.py) and the faults (analysis/reports/fault_tables.py)."""

from __future__ import annotations

from analysis.reports.fault_tables import events_table, events_text
from analysis.reports.formatting import mean_sd, p_value, rate_interval
from analysis.reports.kind_tables import gee_line, kind_tables, primary_line
from analysis.reports.table import Table, markdown, markdown_grid
from analysis.statistics.facts import ConditionRun, ModelSource, StudyFacts
from analysis.statistics.methods import material_keys
from analysis.statistics.result_records import ConditionRate, McNemarPair
from analysis.statistics.stats import tests_run
from analysis.statistics.study_results import DeformationRow, StudyStats, YesNoItem
from analysis.statistics.study_stats import study_stats
from analysis.statistics.table1 import DEFORMATION_WORK
from analysis.study.study_snapshot import Study
from sim.text import counted


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


def cochran_cell(item: YesNoItem) -> str:
    """Cochran's Q (p), or why it was not run."""
    if item.p_value != item.p_value:
        return f"n/a ({item.reason or 'not run'})"
    return f"{item.cochran_q:.2f} ({p_value(item.p_value)})"


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


def rate_cell(x: ConditionRate) -> str:
    """One question's answers under one condition: yes/no counts, the rate [Wilson 95%]."""
    return f"{x.yes}/{x.no}, {rate_interval(x.rate, x.wilson_low, x.wilson_high)}"


def deformation_cell(x: DeformationRow) -> str:
    """One condition's deformation time per frame (ms): mean +- sd over participants (median, p95)."""
    if not x.n_participants:
        return "n/a (no trials)"
    return f"{mean_sd(x.mean_ms, x.sd_ms, x.n_participants)} (median {x.median_ms:.2f}, p95 {x.p95_ms:.2f})"


def table(st: StudyStats) -> Table:
    """Table 1, what the Markdown, LaTeX and HTML reports all render: per yes/no question the
    counts and rate [Wilson 95%] under each condition, Cochran's Q, the McNemar pairs with Holm
    (`st`'s scope); then the deformation-time row (a benchmark of this machine, no test)."""
    models = [x.model for x in st.deformation.rows]
    scope = holm_text(st)
    rows = [[v.question, *(rate_cell(v.rates[m]) for m in models), cochran_cell(v), "; ".join(map(mcnemar_cell, v.pairs)) or "n/a (one condition)"]
            for v in st.items.values()]
    rows.append(["Time for real-time deformation of the model, ms: benchmark of this machine",
                 *(deformation_cell(x) for x in st.deformation.rows), "", ""])
    return Table(columns=["Question", *(f"{m}: yes/no, rate [95% CI]" for m in models), "Cochran's Q (p)", f"McNemar p, {scope}"],
                 rows=rows, title="Table 1",
                 notes="Rates with Wilson 95% intervals; Cochran's Q across the models; pairwise exact McNemar tests, "
                       f"{scope}. Deformation time: each participant's mean over their trials, mean +- sd over participants: "
                       f"wall-clock time of this machine {DEFORMATION_WORK}, not a measure of the participants (no test).")


def deformation_table(st: StudyStats) -> Table:
    """The deformation-time row on its own, for a study with no yes/no question (no Table 1 to sit in)."""
    rows = st.deformation.rows
    return Table(columns=["Time for real-time deformation, ms: benchmark of this machine", *(x.model for x in rows)],
                 rows=[["mean +- sd (median, p95)", *(deformation_cell(x) for x in rows)]],
                 title="Deformation time (benchmark of this machine)",
                 notes=f"Each participant's mean over their trials, mean +- sd over participants: wall-clock time of this machine "
                       f"{DEFORMATION_WORK}, not a measure of the participants (no test).")


def table1_markdown(study: Study, holm_scope: str = "family") -> str:
    """Table 1 as Markdown: counts, rate [Wilson 95%] per model, Cochran's Q per item, McNemar
    pairs with Holm (over the family by default), the deformation-time row (a benchmark of
    this machine), headed by N (complete cases), the design and a synthetic-data flag; the
    GEE across questions below."""
    st = study_stats(study, holm_scope=holm_scope)
    facts = st.facts
    models = [x.model for x in st.deformation.rows]
    flag = f"{facts.flag} " if facts.flag else ""
    if facts.mixed_source_participants:
        flag += f"WARNING: {', '.join(facts.mixed_source_participants)} answered both as a person and synthetically. "
    listed = incomplete_text(facts)
    left_out = f" Left out (incomplete): {listed}." if listed else ""
    scope = holm_text(st)
    lines = [f"**Table 1: {facts.study}.** {flag}N = {counted(facts.participants, 'participant')} with every answer; {facts.design}.{left_out}", ""]
    if st.items:  # the yes/no questions: the paper's table
        t = table(st)
        lines += [*markdown_grid(t), "", t.notes, ""]
    faults = events_table(st.faults)  # only where a trial had one: a study without keeps its table as it was
    if faults is not None:
        lines += [f"**{faults.title}.**", "", *markdown_grid(faults), "", faults.notes, ""]
    for t in kind_tables(st.kinds, models, scope):
        lines += markdown(t)
    if not st.items:
        lines += [*markdown_grid(deformation_table(st)), ""]
    gee = gee_line(st.gee, st.kinds.primary.analysis == "logistic_gee")
    if gee:
        lines += [gee, ""]
    if st.kinds.primary.analysis in ("mixed_model", "choice"):
        lines += [primary_line(st), ""]
    if len(models) < 2:
        lines += ["One condition: there is nothing to compare between conditions (no Cochran's Q, McNemar or Friedman test); "
                  "a study with groups compares its groups instead.", ""]
    lines += ["Conditions (what each ran; participants saw only their labels): "
              + "; ".join(condition_text(c) for c in facts.conditions) + ".", ""]
    return "\n".join(lines)


def stats_summary(st: StudyStats) -> list[str]:
    """`studyctl report stats`' lines: N, the primary analysis first, then each question's tests
    (Cochran's Q and McNemar pairs, Friedman and Wilcoxon pairs, mixed models, choices), the
    participants left out, the faults, the logistic GEE where it is not the primary, the
    deformation-time benchmark."""
    facts, kinds = st.facts, st.kinds
    several = len(st.deformation.rows) > 1  # a row per protocol condition
    flag = f" {facts.flag}" if facts.flag else ""
    lines = [f"{facts.study}: N = {facts.participants}.{flag}", primary_line(st)]
    if not several:
        lines.append("one condition: there is nothing to compare between conditions (no Cochran's Q, McNemar or Friedman test)")

    def pair(p) -> str:
        if p.p_value != p.p_value:
            return f"{p.a}-{p.b} not tested ({p.reason or 'not estimable'})"
        return f"{p.a}-{p.b} p_holm {p.p_holm:.3g}" + (f" ({p.warning})" if getattr(p, "warning", None) else "")

    for item, v in st.items.items() if several else ():
        pairs = ", ".join(pair(p) for p in v.pairs)
        cochran = (f"Q = {v.cochran_q:.2f}, p = {v.p_value:.3g}" if v.p_value == v.p_value
                   else f"Cochran's Q not tested ({v.reason or 'not estimable'})")
        lines.append(f"{item}: {cochran}; {pairs}")
    for item, v in kinds.ratings.items():
        fr = v.friedman
        pairs = ", ".join(pair(p) for p in v.pairs)
        friedman = (f"Friedman chi2 = {fr.statistic:.2f}, p = {fr.p_value:.3g}, W = {fr.kendall_w:.2f}"
                    if fr.statistic == fr.statistic else f"Friedman not tested ({fr.reason})")
        lines.append(f"{item}: {friedman}; {pairs}")
    for v in kinds.scores.values():
        t = v.mixed_model.model_test
        means = ", ".join(f"{m} {c.mean:.1f}" for m, c in v.conditions.items())
        test = (f"mixed model F({t.df}, {t.df_denominator}) = {t.f:.2f}, p = {t.p_value_f:.3g}" if t.f == t.f
                else f"mixed model: not tested ({t.reason or 'no fit'})")
        lines.append(f"{v.label}: {means}; {test}")
    for item, v in kinds.choices.items():
        shares = ", ".join(f"{m} {s.count}" for m, s in v.shares.items())
        overall = f"{v.overall.test} not tested ({v.overall.reason})" if v.overall.reason else f"{v.overall.test} p = {v.overall.p_value:.3g}"
        lines.append(f"{item}: {shares}; {overall}")
    if facts.incomplete_participants:
        lines.append("left out (incomplete): " + incomplete_text(facts))
    if events_text(st.faults):
        lines.append(events_text(st.faults))
    gee = gee_line(st.gee, kinds.primary.analysis == "logistic_gee")
    if gee and kinds.primary.analysis != "logistic_gee":  # the primary's own line is printed first
        lines.append(gee.replace("`", ""))
    for row in st.deformation.rows:
        lines.append(f"deformation time, {row.model}: {mean_sd(row.mean_ms, row.sd_ms, row.n_participants)} ms over "
                     f"{counted(row.n_participants, 'participant')} ({st.deformation.label})")
    return lines
