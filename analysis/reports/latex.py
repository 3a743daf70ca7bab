"""Tables as LaTeX that compiles and fits the page: booktabs rules, wrapping `tabularx` columns
sized to the text block (A4 or letter, one column or two), landscape for tables too wide to
wrap legibly, every text escaped, and proper symbols (`$\\pm$`, en-dashes for ranges, a minus
sign for negative numbers, `\\%`). Every report's LaTeX (Table 1 and each answer kind, the
discrimination report, construct validity, the accuracy bench) is written here, from the same
table dicts {title, columns, rows, note} the Markdown and HTML use.

A document needs `\\usepackage{booktabs, tabularx, longtable, pdflscape}` (`PREAMBLE`); tests
compile every report's tables with pdflatex on A4 and refuse an overfull box over 1 pt."""

from __future__ import annotations

import math
import re

from pandas.io.formats.style_render import _escape_latex  # pandas' own escaping, as its Styler.to_latex uses

PREAMBLE = "\\usepackage[T1]{fontenc}\n\\usepackage{booktabs}\n\\usepackage{tabularx}\n\\usepackage{longtable}\n\\usepackage{pdflscape}\n"
# a table taller than this share of the page (estimated from its text) breaks across pages (longtable)
# instead of a float that would run off the page
FLOAT_SHARE = 0.8
# the A4 article text block (pt) and the small type's line height and mean character width (pt)
TEXT_WIDTH, TEXT_HEIGHT, LINE_PT, CHAR_PT = 345.0, 592.0, 9.5, 4.3
# more columns than this wrap too narrowly in portrait on an A4 text block: the table turns
LANDSCAPE_COLUMNS = 7

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


def _weights(t: dict, width: float) -> list[float]:
    """Each column's share of the `width` (pt): by the square root of its cells' mean length (a
    column of long lists gets more room than one of short numbers, as a browser lays out a
    table), never narrower than its longest word (split at spaces and underscores) in small
    bold type."""
    cols = list(zip(t["columns"], *t["rows"]))
    share = [math.sqrt(sum(len(str(c)) for c in col) / len(col) + 1.0) for col in cols]
    total = sum(share)
    # a word breaks after an underscore (text() allows it); bold header letters are ~35% wider
    floor = [(max((len(w) for c in col for w in re.split(r"\s+|(?<=_)", str(c))), default=1) * CHAR_PT * 1.35 + 8.0) / width
             for col in cols]
    w = [max(x / total, f) for x, f in zip(share, floor)]
    return [x / sum(w) for x in w]


def _height(t: dict, caption: str, weights: list[float], width: float) -> float:
    """A rough height (pt) of the table set in small type, its columns `weights` of `width`: each
    row as tall as its most wrapped cell, with the caption; enough to tell a table that fits a
    page from one that does not."""
    per_col = [max(w * width - 6.0, 10.0) / CHAR_PT for w in weights]

    def lines(row) -> int:
        return max(-(-len(str(c)) // int(n)) for c, n in zip(row, per_col)) if len(row) else 1

    return LINE_PT * (sum(lines(r) for r in [t["columns"], *t["rows"]]) + len(caption) * CHAR_PT / width + 3)


def table(t: dict, label: str | None = None) -> str:
    """A table {title, columns, rows, note} in LaTeX: the title and note as its caption, booktabs
    rules, columns filling the text width and wrapping their text (each as wide as its text needs), small
    type. A `table` float with `tabularx` where it fits a page; else a `longtable` that breaks
    across pages with its head repeated; more than LANDSCAPE_COLUMNS columns turn the page."""
    n = len(t["columns"])
    caption = text(t["title"]) + (f". {text(t['note'])}" if t.get("note") else "")
    head = " & ".join(f"\\textbf{{{text(c)}}}" for c in t["columns"]) + " \\\\"
    body = [" & ".join(text(c) for c in row) + " \\\\" for row in t["rows"]]
    mark = f"\\label{{{label}}}" if label else ""
    landscape = n > LANDSCAPE_COLUMNS
    page = TEXT_WIDTH if landscape else TEXT_HEIGHT
    width = TEXT_HEIGHT if landscape else TEXT_WIDTH
    weights = _weights(t, width)
    if _height(t, caption, weights, width) > FLOAT_SHARE * page:
        # p{} widths: the text width less the columns' padding, shared by weight
        spec = "".join(f">{{\\raggedright\\arraybackslash\\hspace{{0pt}}}}p{{\\dimexpr({w:.4f}\\linewidth-{w * 2 * n:.4f}\\tabcolsep)\\relax}}"
                       for w in weights)
        lines = ["\\begingroup\\footnotesize\\setlength{\\tabcolsep}{3pt}", f"\\begin{{longtable}}{{@{{}}{spec}@{{}}}}",
                 f"\\caption{{{caption}}}{mark}\\\\", "\\toprule", head, "\\midrule", "\\endfirsthead",
                 "\\toprule", head, "\\midrule", "\\endhead", "\\bottomrule", "\\endlastfoot", *body, "\\end{longtable}",
                 "\\endgroup"]
    else:
        spec = "".join(f">{{\\raggedright\\arraybackslash\\hsize={w * n:.3f}\\hsize\\hspace{{0pt}}}}X" for w in weights)
        lines = ["\\begin{table}[htbp]", "\\centering\\footnotesize\\setlength{\\tabcolsep}{3pt}", f"\\caption{{{caption}}}"
                 + mark, f"\\begin{{tabularx}}{{\\linewidth}}{{@{{}}{spec}@{{}}}}", "\\toprule", head, "\\midrule", *body,
                 "\\bottomrule", "\\end{tabularx}", "\\end{table}"]
    if landscape:
        lines = ["\\begin{landscape}", *lines, "\\end{landscape}"]
    return "\n".join(lines) + "\n"


def tables(ts: list[dict], prefix: str) -> str:
    """Several tables, labelled `prefix`:1, :2, ..., headed by the packages they need."""
    head = "% needs in the preamble: " + " ".join(PREAMBLE.split("\n")).strip() + "\n"
    return head + "\n".join(table(t, f"{prefix}:{k}") for k, t in enumerate(ts, start=1))


def document(body: str) -> str:
    """A whole A4 article around `body` (what the tests compile; an author \\input's the tables)."""
    return ("\\documentclass[a4paper]{article}\n" + PREAMBLE + "\\begin{document}\n" + body + "\n\\end{document}\n")
