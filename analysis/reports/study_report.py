"""A study's Table 1 report in each format (md, csv, latex, html, json), with the accuracy
bench's and the stability sweep's sections where given, and the discrimination task's section
(`jnd_report`). The command (`studyctl report table1`) reads the
study and the benches' files and writes what this returns."""

from __future__ import annotations

import json

from analysis.discrimination import jnd
from analysis.reports.accuracy_tables import markdown as accuracy_markdown
from analysis.reports.accuracy_tables import tables as accuracy_tables
from analysis.reports.formatting import spreadsheet_frame
from analysis.reports.jnd_report import html_section, jnd_text
from analysis.reports.report import html, latex
from analysis.reports.stability_report import markdown as stability_markdown
from analysis.reports.study_tables import table1_markdown
from analysis.reports.table import latex_tables
from analysis.statistics import table1
from analysis.statistics.faults import rates_with_events
from analysis.statistics.study_stats import study_stats
from sim.jsonable import jsonable


def table1_text(study, fmt: str, holm_scope: str = "family", accuracy: dict | None = None, stability: dict | None = None,
                traces=None) -> str:
    """The paper's Table 1 of `study` in `fmt`, the accuracy bench's tables (md, latex, html) and
    the stability sweep's (md, html) added where given, the discrimination section where the
    protocol has a task; `traces` (html): the force traces its figures draw."""
    if fmt == "md":
        text = table1_markdown(study, holm_scope)
        if accuracy:
            text += "\n## Model error against run time\n\n" + accuracy_markdown(accuracy)
        if stability:
            text += "\n## Numerical stability\n\n" + stability_markdown(stability)
    elif fmt == "latex":
        text = latex(study, holm_scope)
        if accuracy:
            text += latex_tables(accuracy_tables(accuracy), "tab:accuracy")
    elif fmt == "html":
        text = html(study, traces, accuracy=accuracy, stability=stability, holm_scope=holm_scope)
    elif fmt == "csv":  # the flag and N travel with the table
        facts = table1.study_facts(study)
        rows = rates_with_events(table1.rates(study), table1.events(study))
        text = spreadsheet_frame(rows.assign(participants=facts.participants, synthetic=facts.synthetic)).to_csv(index=False)
    else:
        rates, cochran = table1.rates(study), table1.cochran(study)
        text = json.dumps(jsonable({"facts": table1.study_facts(study).as_dict(), "rates": rates.to_dict(orient="records"),
                                    "cochran": cochran.to_dict(orient="records"),
                                    "kinds": study_stats(study, rates, cochran, holm_scope).kinds.as_dict(),
                                    "deformation": table1.deformation(study).to_dict(orient="records"),
                                    "faults": [e.as_dict() for e in table1.events(study)]}
                                   | ({"jnd": jnd.jnd_results(study)} if study.protocol.tasks else {})), indent=2)
    if study.protocol.tasks and fmt in ("md", "latex"):
        text += ("\n## Stiffness discrimination\n\n" if fmt == "md" else "\n") + jnd_text(study, fmt)
    elif study.protocol.tasks and fmt == "html":
        text = text.replace("</body></html>", html_section(jnd.jnd_results(study), study) + "\n</body></html>")
    return text
