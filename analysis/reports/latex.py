"""Text as LaTeX: escaped, with proper symbols (`$\\pm$`, en-dashes for ranges, a minus sign for
negative numbers, `\\%`), what every report's tables (analysis/reports/table.py) and text set.

A document needs `PREAMBLE` (booktabs, tabularx, longtable, pdflscape: what the tables use);
`document` is a whole A4 article, what the tests compile every report's tables in (they refuse
an overfull box over 1 pt)."""

from __future__ import annotations

import re

from pandas.io.formats.style_render import _escape_latex  # pandas' own escaping, as its Styler.to_latex uses

PREAMBLE = "\\usepackage[T1]{fontenc}\n\\usepackage{booktabs}\n\\usepackage{tabularx}\n\\usepackage{longtable}\n\\usepackage{pdflscape}\n"

# characters the reports write that pdflatex's utf8 input does not set up, as LaTeX
SYMBOLS = {"±": "$\\pm$", "≥": "$\\geq$", "≤": "$\\leq$", "×": "$\\times$", "°": "$^{\\circ}$", "µ": "$\\mu$", "μ": "$\\mu$",
           "−": "$-$", "–": "--", "—": "---", "²": "$^{2}$", "χ": "$\\chi$", "α": "$\\alpha$", "β": "$\\beta$", "δ": "$\\delta$",
           "κ": "$\\kappa$", "λ": "$\\lambda$", "σ": "$\\sigma$", "τ": "$\\tau$", "η": "$\\eta$", "ω": "$\\omega$", "Δ": "$\\Delta$",
           "≈": "$\\approx$", "→": "$\\rightarrow$", "…": "\\dots{}", "’": "'", "‘": "`", "“": "``", "”": "''"}
_RANGE = re.compile(r"(?<![\w.\-])(\d+(?:\.\d+)?)-(\d+(?:\.\d+)?)(?![\w\-])")  # 0-100; not a date 2026-11-27 or brain2-3.npz
_MINUS = re.compile(r"(?<![\w.)\]])-(?=\.?\d)")  # -0.5, not 1-2 or x-1


def text(value) -> str:
    """`value` as LaTeX text: escaped, with the reports' plain-text symbols made proper ('+-' is
    the plus-minus sign, a numeric range 'a-b' takes an en-dash, a leading '-' before a number
    is a minus sign); an underscore may break a line (condition names like plate_spring)."""
    s = str(value).replace("+-", "±")
    s = _RANGE.sub(r"\1–\2", s)
    s = _MINUS.sub("−", s)
    s = _escape_latex(s).replace("\\_", "\\_\\allowbreak{}")
    return "".join(SYMBOLS.get(ch, ch) for ch in s)


def document(body: str) -> str:
    """A whole A4 article around `body` (what the tests compile; an author \\input's the tables)."""
    return ("\\documentclass[a4paper]{article}\n" + PREAMBLE + "\\begin{document}\n" + body + "\n\\end{document}\n")
