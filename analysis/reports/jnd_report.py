"""The discrimination task's report in each format (md, latex, html, json): what `report jnd`
writes, and the section `report table1` adds (analysis/reports/study_report.py). Light: it loads
the discrimination analysis only (matplotlib only for the html's figures, there). Every table and
sentence of the task's results is drawn here from `jnd.jnd_results`."""

from __future__ import annotations

import dataclasses
import html as _html
import json
import math

from analysis.discrimination import jnd
from analysis.discrimination.jnd import trials
from analysis.discrimination.pooled import POOLED_MIN
from analysis.reports.fault_tables import events_table
from analysis.reports.formatting import PAGE_END, drawn_png, figure_html, p_value, page_head
from analysis.reports.table import Table, latex_tables
from analysis.reports.table import html as table_html
from analysis.reports.table import markdown as table_markdown
from sim.jsonable import jsonable
from sim.text import counted


def jnd_text(study, fmt: str) -> str:
    """The discrimination task's section in `fmt` (md, latex, html, json)."""
    res = jnd.jnd_results(study)
    if fmt == "json":
        return json.dumps(jsonable(res), indent=2) + "\n"
    return html(res, study) if fmt == "html" else latex(res) if fmt == "latex" else markdown(res)


def _pct(x) -> str:
    if x is None or not math.isfinite(float(x)):
        return "-"
    v = 100 * float(x)
    return f"{v:.1f}%" if abs(v) >= 0.1 or v == 0 else f"{v:.2g}%"


def _interval(lo, hi, why: str = "no interval") -> str:
    return f"[{_pct(lo)}, {_pct(hi)}]" if lo is not None and math.isfinite(float(lo)) and math.isfinite(float(hi)) else f"({why})"


FLAG_TEXT = {"all_correct": "every answer right: below the range tested", "at_chance": "at chance: above the range tested",
             "one_level": "one level: not identified", "location_at_bound": "threshold beyond the range tested",
             "shallow": "no trend", "optimizer": "the optimiser stopped", "steep": "slope at its bound"}


def tables(res: dict) -> list[Table]:
    """The report's tables, one source for Markdown, LaTeX and HTML:
    per condition (geometric mean [95% CI], median, recovery when synthetic) and per participant
    (the fit, its flag, the pooled estimate, QUEST+'s own estimate where it ran, the generating
    value when synthetic)."""
    recovery = any("recovery_coverage" in c for c in res["conditions"])
    rows = []
    for c in res["conditions"]:
        gm = (c["reason"].replace("withheld:", "WITHHELD:", 1) if c.get("reason")
              else f"{_pct(c['geometric_mean'])} {_interval(c['gm_low'], c['gm_high'], c.get('gm_reason') or 'no interval')}" if c["n"]
              else "n/a (no fit)")
        if c.get("gm_warning"):
            gm += f" ({c['gm_warning']})"
        pooled_rec = (f"; pooled {_pct(c['recovery_pooled_median_abs_rel_error'])}, {_pct(c['recovery_pooled_coverage'])}"
                      if "recovery_pooled_coverage" in c else "")
        rows.append([c["condition"], str(c["n"]), gm, _pct(c["median"])]
                    + ([f"{_pct(c.get('recovery_median_abs_rel_error'))}, {_pct(c.get('recovery_coverage'))}{pooled_rec}"] if recovery else []))
    out = [Table(title="Weber fraction per condition", columns=["Condition", "N", "geometric mean [95% CI]", "median"]
                 + (["recovery: median abs. error, CI coverage (own fit; pooled)"] if recovery else []), rows=rows,
                 notes="Geometric mean over participants with a t interval on ln Weber fraction (n - 1 df)."
                    + (" A - marks a recovery figure there is none of (no participant's fit to compare)." if recovery else ""))]
    quest = any("quest_estimate" in r for r in res["weber"])
    generating = any("generating_weber" in r for r in res["weber"])
    rows = []
    for r in res["weber"]:
        flag = FLAG_TEXT.get(r.get("flag") or "", "")
        rows.append([r["code"], r["condition"], str(r["n_trials"]), _pct(r["p_correct"]),
                     f"{_pct(r['weber'])} {_interval(r['ci_low'], r['ci_high'], 'no interval: ' + flag if flag else 'no interval')}",
                     _pct(r["lapse"]), flag or "none",
                     f"{_pct(r.get('weber_pooled'))} {_interval(r.get('pooled_low'), r.get('pooled_high'), 'too few to pool')}"
                     if r.get("weber_pooled") == r.get("weber_pooled") and r.get("weber_pooled") is not None else "(too few to pool)"]
                    + ([_pct(r.get("quest_estimate"))] if quest else []) + ([_pct(r.get("generating_weber"))] if generating else []))
    out.append(Table(title="Per participant", columns=["Participant", "Condition", "trials", "% correct", "Weber [95% CI]", "lapse", "fit flag",
                                                        "pooled [95% CrI]"]
                + (["QUEST+ estimate"] if quest else []) + (["generating"] if generating else []), rows=rows,
                notes="The Weber fraction with its parametric-bootstrap 95% interval: the increment picked out 75% of the time by the "
                        "two-interval observer fitted on the log stiffness ratio (analysis/discrimination/psychometric.py); lapse: the fit's. Pooled: the "
                        f"same observer, each participant pooled with the condition's others (hierarchical, {POOLED_MIN} or more participants), "
                        "posterior median and 95% credible interval: the better estimate of one person from 40 trials (docs/study.md). "
                        "A - marks a value there is none of: the fit gave none (it did not converge), or the run recorded none "
                        "(no QUEST+ estimate, no generating value)."))
    return out


def faults_table(res: dict) -> Table | None:
    """The faults and safety events per condition (analysis.reports.fault_tables.events_table), None where no
    trial had one (the report then is as it was)."""
    return events_table(res["faults"]) if res.get("faults") else None


def _heading(res: dict) -> tuple[str, str]:
    """(the report's title, what it holds): the study, the synthetic flag, N and the task."""
    f = res["facts"]
    task = f["task"]
    flag = f"{f['flag']} " if f["flag"] else ""
    method = task["method"] + (f" ({task['rule']})" if task["rule"] else "")
    return (f"Stiffness discrimination: {f['study']}", f"{flag}N = {counted(f['participants'], 'participant')}; two-interval forced choice "
            f"\"{task['question']}\", {task['trials']} {method} trials per condition around {task['reference']:g} times each condition's stiffness.")


def markdown(res: dict) -> str:
    title, head = _heading(res)
    lines = [f"**{title}.** {head}", ""]
    if not res["weber"]:
        return "\n".join(lines + ["No discrimination trials yet.", ""])

    first, per = tables(res)
    lines += table_markdown(first)
    faults = faults_table(res)
    lines += table_markdown(faults) if faults is not None else []
    if res["group"]:
        lines += [_group_text(res["group"]), ""]
    lines += table_markdown(per)
    return "\n".join(lines)


def latex(res: dict) -> str:
    """The report's tables as LaTeX (analysis/reports/table.py), the study's heading and the group test in
    the first table's caption."""
    title, head = _heading(res)
    if not res["weber"]:
        return f"% {title}. {head} No discrimination trials yet.\n"
    first, per = tables(res)
    group = f" {_group_text(res['group'])}" if res["group"] else ""
    first = dataclasses.replace(first, title=f"{title}: {first.title}", notes=f"{head} {first.notes}{group}")
    faults = faults_table(res)
    return latex_tables([first, per] + ([faults] if faults is not None else []), "tab:jnd")


def _group_text(g: dict) -> str:
    """The group test in one paragraph (keys of analysis.discrimination.weber_groups.group_test)."""
    parts = [f"Mixed model and {'Friedman' if len(g['conditions']) > 2 else 'Wilcoxon'} across the conditions: not tested ({why})."
             for why in (g.get("withheld") or {}).values()]
    mm = g.get("mixed_model") or {}
    if mm and mm.get("converged") is False:
        parts.append("Mixed model of log Weber fraction on condition: not tested (the fit did not converge"
                     + (f": {mm['problem']}" if mm.get("problem") else "") + ").")
    elif mm:
        parts.append(f"Mixed model of log Weber fraction on condition (participant as random intercept): likelihood-ratio chi2({mm.get('df')}) = "
                     f"{p_value(mm.get('chi2'))}, p = {p_value(mm.get('p'))}.")
    fr = g.get("friedman") or {}
    if fr:
        parts.append(f"{fr.get('test', 'Friedman')}: statistic {p_value(fr.get('statistic'))}, p = {p_value(fr.get('p'))}.")
    pairs = g.get("pairs") or []
    why = "; ".join(g.get("problems") or []) or "no ratio"
    if pairs:
        parts.append("Pairs (paired t on log Weber fractions, Holm): " + "; ".join(
            f"{p['a']} vs {p['b']}: ratio {p_value(p.get('ratio'))} [{p_value(p.get('ratio_low'))}, {p_value(p.get('ratio_high'))}], p_holm {p_value(p.get('p_holm'))}"
            if p_value(p.get("ratio")) != "-" else f"{p['a']} vs {p['b']}: not tested ({p.get('reason') or why})" for p in pairs) + ".")
    return " ".join(parts)


def html_section(res: dict, study) -> str:
    """The report's section as HTML (escaped), with one psychometric plot per condition."""
    esc = _html.escape
    body = [f'<p class="synthetic">{esc(res["facts"]["flag"])}</p>' if res["facts"]["flag"] else ""]
    task = res["facts"]["task"]
    body.append(f"<p>N = {res['facts']['participants']}; two-interval forced choice &ldquo;{esc(task['question'])}&rdquo;, "
                f"{task['trials']} {esc(task['method'])} trials per condition.</p>")
    first, per = tables(res) if res["weber"] else (None, None)
    if first:
        body.append(table_html(first, "h3"))
    faults = faults_table(res)
    if faults is not None:
        body.append(table_html(faults, "h3"))
    if res["group"]:
        body.append(f"<p>{esc(_group_text(res['group']))}</p>")
    if res["weber"]:
        from analysis.reports.plots import psychometric_plot  # lazy: matplotlib, only for the HTML page's figures

        t = trials(study)
        for c in res["conditions"]:
            img = drawn_png(lambda path, c=c: psychometric_plot(t[t["condition"] == c["condition"]], [r for r in res["weber"] if r["condition"] == c["condition"]],
                                                                   c["condition"], path, res["facts"]["synthetic"]))
            body.append(figure_html(f'psychometric {esc(c["condition"])}', img))
        body.append(table_html(per, "h3"))
    return "<h2>Stiffness discrimination</h2>" + "".join(body)


def html(res: dict, study) -> str:
    esc = _html.escape
    return f"""{page_head(f"{res['facts']['study']}: stiffness discrimination")}
<h1>{esc(res['facts']['study'])}</h1>
{html_section(res, study)}
{PAGE_END}"""
