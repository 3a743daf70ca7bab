"""Tables as LaTeX that compiles and fits the page: booktabs rules, wrapping `tabularx` columns
sized to the text block (A4 or letter, one column or two), landscape for tables too wide to
wrap legibly, every text escaped, and proper symbols (`$\\pm$`, en-dashes for ranges, a minus
sign for negative numbers, `\\%`). Every report's LaTeX (Table 1 and each answer kind, the
discrimination report, construct validity, the accuracy bench) is written here, from the same
table dicts {title, columns, rows, note} the Markdown and HTML use.

A document needs `\\usepackage{booktabs, tabularx, pdflscape}` (`PREAMBLE`); tests compile
every report's tables with pdflatex on A4 and refuse an overfull box over 1 pt."""

from __future__ import annotations

import re

from pandas.io.formats.style_render import _escape_latex  # pandas' own escaping, as its Styler.to_latex uses

PREAMBLE = "\\usepackage[T1]{fontenc}\n\\usepackage{booktabs}\n\\usepackage{tabularx}\n\\usepackage{pdflscape}\n"
# more columns than this wrap too narrowly in portrait on an A4 text block: the table turns
LANDSCAPE_COLUMNS = 7
FIRST_WEIGHT = 1.6  # the first column (a question, a metric) gets this share of an even column's width

# characters the reports write that pdflatex's utf8 input does not set up, as LaTeX
SYMBOLS = {"±": "$\\pm$", "≥": "$\\geq$", "≤": "$\\leq$", "×": "$\\times$", "°": "$^{\\circ}$", "µ": "$\\mu$", "μ": "$\\mu$",
           "−": "$-$", "–": "--", "—": "---", "²": "$^{2}$", "χ": "$\\chi$", "α": "$\\alpha$", "β": "$\\beta$", "δ": "$\\delta$",
           "κ": "$\\kappa$", "λ": "$\\lambda$", "σ": "$\\sigma$", "τ": "$\\tau$", "η": "$\\eta$", "ω": "$\\omega$", "Δ": "$\\Delta$",
           "≈": "$\\approx$", "→": "$\\rightarrow$", "…": "\\dots{}", "’": "'", "‘": "`", "“": "``", "”": "''"}
_RANGE = re.compile(r"(?<![\d.\-])(\d+(?:\.\d+)?)-(\d+(?:\.\d+)?)(?![\d\-])")  # 0-100, not a date 2026-11-27
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


def table(t: dict, label: str | None = None) -> str:
    """A table {title, columns, rows, note} as a LaTeX `table` float: the title and note as its
    caption, booktabs rules, `tabularx` columns filling the text width and wrapping their text
    (the first column wider), small type; more than LANDSCAPE_COLUMNS columns turn the page."""
    n = len(t["columns"])
    other = (n - FIRST_WEIGHT) / (n - 1) if n > 1 else 1.0
    spec = "".join(f">{{\\raggedright\\arraybackslash\\hsize={w:.3f}\\hsize}}X"
                   for w in [FIRST_WEIGHT if n > 1 else 1.0] + [other] * (n - 1))
    caption = text(t["title"]) + (f". {text(t['note'])}" if t.get("note") else "")
    lines = ["\\begin{table}[htbp]", "\\centering\\footnotesize\\setlength{\\tabcolsep}{3pt}",
             f"\\caption{{{caption}}}"]
    if label:
        lines.append(f"\\label{{{label}}}")
    lines += [f"\\begin{{tabularx}}{{\\linewidth}}{{{spec}}}", "\\toprule",
              " & ".join(f"\\textbf{{{text(c)}}}" for c in t["columns"]) + " \\\\", "\\midrule"]
    lines += [" & ".join(text(c) for c in row) + " \\\\" for row in t["rows"]]
    lines += ["\\bottomrule", "\\end{tabularx}", "\\end{table}"]
    if n > LANDSCAPE_COLUMNS:
        lines = ["\\begin{landscape}", *lines, "\\end{landscape}"]
    return "\n".join(lines) + "\n"


def tables(ts: list[dict], prefix: str) -> str:
    """Several tables, labelled `prefix`:1, :2, ..., headed by the packages they need."""
    head = "% needs in the preamble: " + " ".join(PREAMBLE.split("\n")).strip() + "\n"
    return head + "\n".join(table(t, f"{prefix}:{k}") for k, t in enumerate(ts, start=1))


def document(body: str) -> str:
    """A whole A4 article around `body` (what the tests compile; an author \\input's the tables)."""
    return ("\\documentclass[a4paper]{article}\n" + PREAMBLE + "\\begin{document}\n" + body + "\n\\end{document}\n")
