"""Report documents: LaTeX Table 1, and one self-contained HTML file with tables and plots, of
a study read once (analysis.study_snapshot.Study)."""

from __future__ import annotations

import html as _html
import tempfile
from pathlib import Path

from analysis import table1
from analysis.kinds import gee_line, kind_stats, kind_tables, measures, primary_line
from analysis.reports import plots
from analysis.reports.figure_size import FigureSize, figure_size
from analysis.reports.formatting import PAGE_END, drawn_png, figure_html, page_head, png_base64, table_html
from analysis.reports.latex import tables as latex_tables
from analysis.reports.plots import pareto_plot, stability_heatmap
from analysis.study_snapshot import Study
from analysis.study_stats import study_stats
from analysis.verification.accuracy_tables import intro
from analysis.verification.stability import markdown, outcome_grid
from analysis.withhold import mean_sd


def write_plots(study: Study, out_dir, traces: dict | None = None, size: str | FigureSize = "screen") -> list[Path]:
    """rates, ratings, scores, choices, deformation and force plots in `out_dir`, at `size`
    (analysis/reports/figure_size.py): "screen" (PNG and SVG, each figure's own size, as the HTML report
    inlines them) or "single"/"double" (PDF, SVG and 600-dpi PNG, 85/175 mm wide). Returns the
    files written, figure by figure."""
    size = figure_size(size)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)

    facts = table1.study_facts(study)
    synthetic = "mixed" if facts.mixed else facts.synthetic  # the titles' kind of data (plots._kind)
    r = table1.rates(study)
    protocol = study.protocol
    models = list(protocol.conditions)
    answers, _ = table1.complete_answers(study)
    kinds = kind_stats(study, answers)
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
    """Table 1 and each answer kind's table as LaTeX (analysis/reports/latex.py: booktabs, wrapping
    columns that fit the text block, escaped text, proper symbols): the same columns and rows as
    the Markdown and HTML tables (rates with Wilson intervals, Cochran's Q, McNemar p with Holm,
    the deformation-time benchmark row)."""
    facts, r, q, d = table1.study_facts(study), table1.rates(study), table1.cochran(study), table1.deformation(study)
    st = study_stats(study, r, q, holm_scope=holm_scope)
    models = list(d["model"])
    scope = table1.holm_text(st)
    rows = []
    for item, question, item_rows, qrow in table1.item_rows(r, q, models):
        rows.append([question] + [f"{x['yes']}/{x['no']}, {100 * x['rate']:.1f}% [{100 * x['wilson_low']:.1f}, {100 * x['wilson_high']:.1f}]"
                                  for x in item_rows]
                    + [table1.cochran_cell(qrow), "; ".join(table1.mcnemar_cell(p) for p in st.items[item].pairs)])
    deformation_row = (["Time for real-time deformation, ms (benchmark of this machine)"]
                       + [mean_sd(x["mean_ms"], x["sd_ms"], x["n_participants"]) for _, x in d.iterrows()])
    listed = table1.incomplete_text(facts)
    caption = ((f"{facts.flag} " if facts.flag else "")
               + f"{facts.study}: N = {facts.participants} participants with every answer; {facts.design}."
               + (f" Left out (incomplete): {listed}." if listed else "")
               + f" Deformation time: {table1.DEFORMATION_WORK}.")
    columns = ["Question", *models, "Cochran's Q (p)", f"McNemar p ({scope})"]
    origins = table1.plugin_note(facts.conditions)
    tables = [{"title": "Table 1", "columns": columns, "rows": rows + [deformation_row + ["", ""]],
               "note": f"{caption} {origins}".strip()}] if len(r) else []
    tables += [t | {"note": f"{caption} {t['note']}"} for t in kind_tables(st.kinds, models, scope)]
    if not len(r):  # the deformation row had no yes/no table to sit in
        tables.append({"title": "Deformation time (benchmark of this machine)", "columns": columns[: len(models) + 1],
                       "rows": [deformation_row], "note": caption})
    return latex_tables(tables, "tab:" + facts.study)


FIGURES = ("rates", "ratings", "scores", "choice", "deformation", "force")


def _figure_order(path: Path) -> int:
    return next((k for k, name in enumerate(FIGURES) if path.stem.startswith(name)), len(FIGURES))


def accuracy_html(result: dict) -> str:
    """The accuracy bench's table and Pareto plot (analysis/verification/accuracy.py) as an HTML section."""
    esc = _html.escape
    raw = [r for r in result["rows"] if r["calibration"] == "raw"]
    img = drawn_png(lambda path: pareto_plot(raw, path, reference=result["meta"]["reference"]["setting"]))
    head = "".join(f"<th>{h}</th>" for h in ("model", "setting", "calibration", "scale", "force error (mean / max)", "within JND [95% CI]",
                                             "within / outside / undecided", "direction error", "servo tick", "deformation frame"))
    rows = "".join(
        f"<tr><td>{esc(r['model'])}</td><td>{esc(r['setting'])}</td><td>{esc(r['calibration'])}</td><td>{r['scale']:.3g}</td>"
        f"<td>{r['force_error']:.1%} / {r['force_error_max']:.1%}</td>"
        f"<td>{r['within_jnd']:.0%} [{r['within_jnd_low']:.0%}, {r['within_jnd_high']:.0%}]</td>"
        f"<td>{r['within']} / {r['outside']} / {r['undecided']}</td><td>{r['angle_deg']:.1f}&deg;</td>"
        f"<td>{r['tick_us']:.2f} &micro;s</td><td>{r['frame_ms']:.3g} ms</td></tr>"
        for r in result["rows"])
    return (f"<h2>Model error against run time</h2><p>{esc(intro(result))} Simulated pulls, not participants. "
            "Seed paper (its 2014 PC): plate-spring 14.69 ms, FEM 21.35 ms, mass-spring 23.08 ms per deformation.</p>"
            f"<table><tr>{head}</tr>{rows}</table>"
            + figure_html("pareto", img))


def stability_html(result: dict) -> str:
    """The stability sweep's heat map and the cases that were not stable, as an HTML section."""
    esc = _html.escape
    img = drawn_png(lambda path: stability_heatmap(outcome_grid(result["cases"]), path))

    def at(c):
        return "" if c["detected_at_s"] is None else f"{c['detected_at_s']:.3f} s"

    rows = "".join(f"<tr><td>{esc(c['model'])}</td><td>{esc(c['case'])}</td><td>{esc(c['outcome'])}</td><td>{at(c)}</td>"
                   f"<td>{esc(c['reason'])}</td></tr>" for c in result["cases"] if c["outcome"] != "stable")
    md = markdown(result).splitlines()
    near = "".join(f"<p>{esc(line)}</p>" for line in md if line.startswith("Stable but near"))
    return (f"<h2>Numerical stability</h2><p>{esc(md[0])}</p>"
            + figure_html("stability", img) +
            f"<table><tr><th>model</th><th>case</th><th>outcome</th><th>at</th><th>reason</th></tr>{rows}</table>{near}")


def html(study: Study, traces: dict | None = None, accuracy: dict | None = None, stability: dict | None = None, holm_scope: str = "family") -> str:
    """One self-contained HTML file: facts, Table 1, statistics, plots (PNG inlined), and the
    accuracy bench's table and Pareto plot and the stability sweep's heat map when given."""
    facts, r, q, d = table1.study_facts(study), table1.rates(study), table1.cochran(study), table1.deformation(study)
    st = study_stats(study, r, q, holm_scope=holm_scope)
    with tempfile.TemporaryDirectory() as tmp:
        write_plots(study, tmp, traces)
        images = {f.stem: png_base64(f) for f in sorted(Path(tmp).glob("*.png"), key=_figure_order)}
    esc = _html.escape
    listed = table1.incomplete_text(facts)
    incomplete = f" Left out (incomplete): {listed}." if listed else ""
    banner = f'<p class="synthetic">{esc(facts.flag)}</p>' if facts.flag else ""
    rows = []
    models = list(d["model"])
    for item, question, item_rows, qrow in table1.item_rows(r, q, models):
        cells = "".join(f"<td>{row['yes']}/{row['no']}<br>{row['rate']:.1%} [{row['wilson_low']:.1%}, {row['wilson_high']:.1%}]</td>"
                        for row in item_rows)
        pairs = "; ".join(table1.mcnemar_cell(p) for p in st.items[item].pairs)
        rows.append(f"<tr><td>{esc(question)}</td>{cells}<td>{esc(table1.cochran_cell(qrow))}</td><td>{esc(pairs)}</td></tr>")
    dcells = "".join(f"<td>{esc(mean_sd(row['mean_ms'], row['sd_ms'], row['n_participants'])).replace('+-', '&plusmn;')}<br>median "
                     f"{row['median_ms']:.2f}, p95 {row['p95_ms']:.2f}</td>" if row["n_participants"] else "<td>n/a (no trials)</td>"
                     for _, row in d.iterrows())
    lat_text = (f"benchmark of this machine ({esc(table1.DEFORMATION_WORK)}): each participant's mean, mean &plusmn; sd over participants "
                "(no test: CPU time is not about people)")

    gee = esc(gee_line(st.gee, st.kinds.primary.analysis == "logistic_gee").replace("`", ""))
    primary = (f"<p>{esc(primary_line(st))}</p>" if st.kinds.primary.analysis in ("mixed_model", "choice") else "")
    scope = table1.holm_text(st)
    head = "".join(f"<th>{esc(m)}</th>" for m in models)
    binary = (f"<h2>Yes/no questions</h2><p>Rates with Wilson 95% intervals; Cochran's Q across models; pairwise exact McNemar tests.</p>"
              f"<table><tr><th>Question</th>{head}<th>Cochran's Q (p)</th><th>McNemar p ({scope})</th></tr>"
              f"{''.join(rows)}</table><p>{gee}</p>") if len(r) else ""
    kind_html = "".join(table_html(t) for t in kind_tables(st.kinds, models, scope))
    figs = "".join(figure_html(k, v) for k, v in images.items())
    return f"""{page_head(f"{facts.study}: Table 1")}
<h1>{esc(facts.study)}: Table 1</h1>
{banner}
<p>N = {facts.participants} participants with every answer; {esc(facts.design)}.{esc(incomplete)} {esc(scope)}.</p>
{binary}
{kind_html}
{primary}
<h2>Deformation time</h2>
<table><tr><th></th>{head}<th></th></tr>
<tr><td>Time for real-time deformation of the model, ms</td>{dcells}<td>{lat_text}</td></tr></table>
<h2>Conditions</h2><p>What each condition ran (participants saw only their labels; the full configuration is in the export's conditions.csv):</p>
<ul>{"".join(f"<li>{esc(table1.condition_text(c))}</li>" for c in facts.conditions)}</ul>
{figs}
{accuracy_html(accuracy) if accuracy else ""}
{stability_html(stability) if stability else ""}
{PAGE_END}"""
