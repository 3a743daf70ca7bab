"""Report documents: LaTeX Table 1, and one self-contained HTML file with tables and plots, of
a study read once (analysis.study.study_snapshot.Study)."""

from __future__ import annotations

import html as _html
import tempfile
from dataclasses import replace
from pathlib import Path

from analysis.reports import plots
from analysis.reports.accuracy_tables import intro, pareto_rows
from analysis.reports.accuracy_tables import tables as accuracy_tables
from analysis.reports.fault_tables import events_table
from analysis.reports.figure_size import FigureSize, figure_size
from analysis.reports.formatting import PAGE_END, drawn_png, figure_html, page_head, png_base64
from analysis.reports.kind_tables import gee_line, kind_tables, primary_line
from analysis.reports.plots import pareto_plot, stability_heatmap
from analysis.reports.stability_report import counts_text, near_chatter_text, unstable_table
from analysis.reports.study_tables import (
    condition_text,
    deformation_table,
    holm_text,
    incomplete_text,
    plugin_note,
    table,
)
from analysis.reports.table import html as table_html
from analysis.reports.table import html_grid, html_text, latex_tables
from analysis.statistics import table1
from analysis.statistics.kind_results import KindStats
from analysis.statistics.kinds import kind_stats, measures
from analysis.statistics.study_stats import study_stats
from analysis.study.study_snapshot import Study
from analysis.verification.paper import deformation_words
from analysis.verification.stability import outcome_grid
from sim.text import counted


def write_plots(study: Study, out_dir, traces: dict | None = None, size: str | FigureSize = "screen",
                kinds: KindStats | None = None) -> list[Path]:
    """rates, ratings, scores, choices, deformation and force plots in `out_dir`, at `size`
    (analysis/reports/figure_size.py): "screen" (PNG and SVG, each figure's own size, as the HTML report
    inlines them) or "single"/"double" (PDF, SVG and 600-dpi PNG, 85/175 mm wide). `kinds`: the
    study's `kind_stats` when the caller has them (the figures show no p-value, so any Holm scope
    does). Returns the files written, figure by figure."""
    size = figure_size(size)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)

    facts = table1.study_facts(study)
    synthetic = "mixed" if facts.mixed else facts.synthetic  # the titles' kind of data (plots._kind)
    r = table1.rates(study)
    protocol = study.protocol
    models = list(protocol.conditions)
    answers, _ = table1.complete_answers(study)
    kinds = kind_stats(study, answers) if kinds is None else kinds
    meas = measures(protocol, answers, study.periods)
    figures = []
    if len(r):
        figures.append(("rates", lambda: plots.rates_figure(r, synthetic, size=size, models=models)))
    if kinds.ratings:
        figures.append(("ratings", lambda: plots.likert_figure(kinds.ratings, models, synthetic, size=size)))
    if kinds.scores:
        figures.append(("scores", lambda: plots.scores_figure(kinds.scores, meas, models, synthetic, size=size)))
    for item, choice in kinds.choices.items():
        figures.append((f"choice_{item}", lambda choice=choice: plots.choice_figure(choice, models, synthetic, size=size)))
    figures.append(("deformation", lambda: plots.deformation_figure(study.latency_trials, synthetic, size=size, models=models)))
    if traces is not None:
        figures.append(("force", lambda: plots.force_figure(traces, size=size)))
    written = []
    for name, draw in figures:
        written += plots.save(draw(), out_dir / name, size)
    return written


def latex(study: Study, holm_scope: str = "family") -> str:
    """Table 1 and each answer kind's table as LaTeX (analysis/reports/table.py: booktabs, wrapping
    columns that fit the text block, escaped text, proper symbols): the tables the Markdown and
    HTML render, the study's facts in each caption."""
    st = study_stats(study, holm_scope=holm_scope)
    facts = st.facts
    models = [x.model for x in st.deformation.rows]
    scope = holm_text(st)
    listed = incomplete_text(facts)
    caption = ((f"{facts.flag} " if facts.flag else "")
               + f"{facts.study}: N = {counted(facts.participants, 'participant')} with every answer; {facts.design}."
               + (f" Left out (incomplete): {listed}." if listed else "")
               + f" Deformation time: {table1.DEFORMATION_WORK}.")
    origins = plugin_note(facts.conditions)
    tables = [replace(table(st), notes=f"{caption} {origins}".strip())] if st.items else []
    tables += [replace(t, notes=f"{caption} {t.notes}") for t in kind_tables(st.kinds, models, scope)]
    if not st.items:  # the deformation row had no yes/no table to sit in
        tables.append(replace(deformation_table(st), notes=caption))
    faults = events_table(st.faults)
    tables += [faults] if faults is not None else []
    return latex_tables(tables, "tab:" + facts.study)


FIGURES = ("rates", "ratings", "scores", "choice", "deformation", "force")


def _figure_order(path: Path) -> int:
    return next((k for k, name in enumerate(FIGURES) if path.stem.startswith(name)), len(FIGURES))


def accuracy_html(result: dict) -> str:
    """The accuracy bench's table and Pareto plot (analysis/verification/accuracy.py) as an HTML section."""
    img = drawn_png(lambda path: pareto_plot(pareto_rows(result), path, reference=result["meta"]["reference"]["setting"]))
    every = accuracy_tables(result)[0]
    return (f"<h2>{html_text(every.title)}</h2><p>{html_text(intro(result))} Simulated pulls, not participants. "
            f"Seed paper (its 2014 PC): {deformation_words()} per deformation.</p>"
            f"{html_grid(every)}" + figure_html("pareto", img))


def stability_html(result: dict) -> str:
    """The stability sweep's heat map and the cases that were not stable, as an HTML section."""
    img = drawn_png(lambda path: stability_heatmap(outcome_grid(result["cases"]), path))
    near = near_chatter_text(result)
    return (f"<h2>Numerical stability</h2><p>{html_text(counts_text(result))}</p>" + figure_html("stability", img)
            + html_grid(unstable_table(result)) + (f"<p>{html_text(near)}</p>" if near else ""))


def html(study: Study, traces: dict | None = None, accuracy: dict | None = None, stability: dict | None = None, holm_scope: str = "family") -> str:
    """One self-contained HTML file: facts, Table 1, statistics, plots (PNG inlined), and the
    accuracy bench's table and Pareto plot and the stability sweep's heat map when given."""
    st = study_stats(study, holm_scope=holm_scope)
    facts = st.facts
    with tempfile.TemporaryDirectory() as tmp:
        write_plots(study, tmp, traces, kinds=st.kinds)
        images = {f.stem: png_base64(f) for f in sorted(Path(tmp).glob("*.png"), key=_figure_order)}
    esc = _html.escape
    listed = incomplete_text(facts)
    incomplete = f" Left out (incomplete): {listed}." if listed else ""
    banner = f'<p class="synthetic">{esc(facts.flag)}</p>' if facts.flag else ""
    models = [x.model for x in st.deformation.rows]
    gee = esc(gee_line(st.gee, st.kinds.primary.analysis == "logistic_gee").replace("`", ""))
    primary = (f"<p>{esc(primary_line(st))}</p>" if st.kinds.primary.analysis in ("mixed_model", "choice") else "")
    scope = holm_text(st)
    binary = f"{table_html(table(st))}<p>{gee}</p>" if st.items else ""
    faults = events_table(st.faults)
    binary += table_html(faults) if faults is not None else ""
    kind_html = "".join(table_html(t) for t in kind_tables(st.kinds, models, scope))
    deformation = "" if st.items else table_html(deformation_table(st))  # else a row of Table 1
    figs = "".join(figure_html(k, v) for k, v in images.items())
    return f"""{page_head(f"{facts.study}: Table 1")}
<h1>{esc(facts.study)}: Table 1</h1>
{banner}
<p>N = {counted(facts.participants, 'participant')} with every answer; {esc(facts.design)}.{esc(incomplete)} {esc(scope)}.</p>
{binary}
{kind_html}
{primary}{deformation}
<h2>Conditions</h2><p>What each condition ran (participants saw only their labels; the full configuration is in the export's conditions.csv):</p>
<ul>{"".join(f"<li>{esc(condition_text(c))}</li>" for c in facts.conditions)}</ul>
{figs}
{accuracy_html(accuracy) if accuracy else ""}
{stability_html(stability) if stability else ""}
{PAGE_END}"""
