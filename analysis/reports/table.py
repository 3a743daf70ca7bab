"""The one table of every report: `Table` (a title, columns, rows of text, notes) and its
renderers, Markdown, HTML, LaTeX and CSV. A report builds its tables as `Table`s and renders them
here; no other module writes a table's rows.

- Markdown: a pipe table, `|` in a cell escaped, a line break in a cell a space.
- HTML: every text escaped (`html.escape`), '+-' as the plus-minus sign.
- LaTeX: booktabs rules, wrapping `tabularx` columns sized to the A4 text block, a `longtable`
  that breaks across pages when the table is too tall for a float, landscape when it has more
  than LANDSCAPE_COLUMNS columns; every text through `analysis.reports.latex.text` (escaped,
  proper symbols), the title and notes as the caption. A document needs `PREAMBLE`.
- CSV: the columns and rows (the `csv` module's quoting); a CSV has no place for the notes."""

from __future__ import annotations

import csv as _csv
import html as _html
import io
import math
import re
from dataclasses import dataclass

from analysis.reports.latex import PREAMBLE
from analysis.reports.latex import text as latex_text

# a table taller than this share of the page (estimated from its text) breaks across pages (longtable)
# instead of a float that would run off the page
FLOAT_SHARE = 0.8
# the A4 article text block (pt) and the small type's line height and mean character width (pt)
TEXT_WIDTH, TEXT_HEIGHT, LINE_PT, CHAR_PT = 345.0, 592.0, 9.5, 4.3
# more columns than this wrap too narrowly in portrait on an A4 text block: the table turns
LANDSCAPE_COLUMNS = 7


@dataclass(frozen=True)
class Table:
    """A report's table: `columns` (their headings) and `rows` (one text per column each; cells
    are kept as text, `str` of what was given), a `title` and `notes` (a sentence or a few under
    it; the caption in LaTeX). A table without columns is a titled paragraph (a report section
    that has text and no grid)."""

    columns: tuple[str, ...]
    rows: tuple[tuple[str, ...], ...] = ()
    title: str = ""
    notes: str = ""

    def __post_init__(self) -> None:
        columns = tuple(str(c) for c in self.columns)
        rows = tuple(tuple(str(c) for c in r) for r in self.rows)
        for k, r in enumerate(rows):
            if len(r) != len(columns):
                raise ValueError(f"table {self.title!r}: row {k} has {len(r)} cells; the table has {len(columns)} columns")
        object.__setattr__(self, "columns", columns)
        object.__setattr__(self, "rows", rows)


# ---------------------------------------------------------------- Markdown

def _md_cell(x: str) -> str:
    return x.replace("|", "\\|").replace("\n", " ")


def _md_row(cells) -> str:
    return "|" + "|".join(f" {_md_cell(c)} " if c else " " for c in cells) + "|"


def markdown_grid(t: Table) -> list[str]:
    """The table's header, rule and rows as Markdown lines (no title, no notes)."""
    return [_md_row(t.columns), "|" + "---|" * len(t.columns), *(_md_row(r) for r in t.rows)]


def markdown(t: Table) -> list[str]:
    """The table as Markdown lines: its title in bold, the grid, its notes below, each followed by a blank line."""
    return [f"**{t.title}**", "", *markdown_grid(t), "", t.notes, ""]


# ---------------------------------------------------------------- HTML

def html_text(x: str) -> str:
    """Text as HTML: escaped, '+-' the plus-minus sign."""
    return _html.escape(x).replace("+-", "&plusmn;")


def html_grid(t: Table) -> str:
    """The table as one HTML <table> (no title, no notes)."""
    head = "".join(f"<th>{html_text(c)}</th>" for c in t.columns)
    rows = "".join("<tr>" + "".join(f"<td>{html_text(c)}</td>" for c in r) + "</tr>" for r in t.rows)
    return f"<table><tr>{head}</tr>{rows}</table>"


def html(t: Table, heading: str = "h2") -> str:
    """The table as an HTML section: its title under a `heading`, the grid, its notes as a paragraph."""
    return f"<{heading}>{html_text(t.title)}</{heading}>{html_grid(t)}<p>{html_text(t.notes)}</p>"


# ---------------------------------------------------------------- CSV

def csv(t: Table) -> str:
    """The columns and rows as CSV (quoted where a cell needs it)."""
    out = io.StringIO()
    writer = _csv.writer(out, lineterminator="\n")
    writer.writerow(t.columns)
    writer.writerows(t.rows)
    return out.getvalue()


# ---------------------------------------------------------------- LaTeX

def _weights(t: Table, width: float) -> list[float]:
    """Each column's share of the `width` (pt): by the square root of its cells' mean length (a
    column of long lists gets more room than one of short numbers, as a browser lays out a
    table), never narrower than its longest word (split at spaces and underscores) in small
    bold type."""
    cols = list(zip(t.columns, *t.rows))
    share = [math.sqrt(sum(len(c) for c in col) / len(col) + 1.0) for col in cols]
    total = sum(share)
    # a word breaks after an underscore (latex.text allows it); bold header letters are ~35% wider
    floor = [(max((len(w) for c in col for w in re.split(r"\s+|(?<=_)", c)), default=1) * CHAR_PT * 1.35 + 8.0) / width
             for col in cols]
    w = [max(x / total, f) for x, f in zip(share, floor)]
    return [x / sum(w) for x in w]


def _height(t: Table, caption: str, weights: list[float], width: float) -> float:
    """A rough height (pt) of the table set in small type, its columns `weights` of `width`: each
    row as tall as its most wrapped cell, with the caption; enough to tell a table that fits a
    page from one that does not."""
    per_col = [max(w * width - 6.0, 10.0) / CHAR_PT for w in weights]

    def lines(row) -> int:
        return max(-(-len(c) // int(n)) for c, n in zip(row, per_col)) if len(row) else 1

    return LINE_PT * (sum(lines(r) for r in [t.columns, *t.rows]) + len(caption) * CHAR_PT / width + 3)


def latex(t: Table, label: str | None = None) -> str:
    """The table in LaTeX: the title and notes as its caption, booktabs rules, columns filling
    the text width and wrapping their text (each as wide as its text needs), small type. A
    `table` float with `tabularx` where it fits a page; else a `longtable` that breaks across
    pages with its head repeated; more than LANDSCAPE_COLUMNS columns turn the page."""
    n = len(t.columns)
    caption = latex_text(t.title) + (f". {latex_text(t.notes)}" if t.notes else "")
    head = " & ".join(f"\\textbf{{{latex_text(c)}}}" for c in t.columns) + " \\\\"
    body = [" & ".join(latex_text(c) for c in row) + " \\\\" for row in t.rows]
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


def latex_tables(ts: list[Table], prefix: str) -> str:
    """Several tables in LaTeX, labelled `prefix`:1, :2, ..., headed by the packages they need."""
    head = "% needs in the preamble: " + " ".join(PREAMBLE.split("\n")).strip() + "\n"
    return head + "\n".join(latex(t, f"{prefix}:{k}") for k, t in enumerate(ts, start=1))
