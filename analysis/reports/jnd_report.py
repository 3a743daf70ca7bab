"""The discrimination task's report in each format (md, latex, html, json): what `report jnd`
writes, and the section `report table1` adds (analysis/reports/study_report.py). Light: it loads
the discrimination analysis only (matplotlib only for the html's figures, there)."""

from __future__ import annotations

import json

from analysis.discrimination import jnd
from sim.jsonable import jsonable


def jnd_text(study, fmt: str) -> str:
    """The discrimination task's section in `fmt` (md, latex, html, json)."""
    res = jnd.jnd_results(study)
    if fmt == "json":
        return json.dumps(jsonable(res), indent=2) + "\n"
    return jnd.html(res, study) if fmt == "html" else jnd.latex(res) if fmt == "latex" else jnd.markdown(res)
