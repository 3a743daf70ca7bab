"""analysis/reports/table.py: the one table of every report, rendered as Markdown, HTML, LaTeX and
CSV (each renderer against text written by hand, escaping included), and no other module of
analysis/ or studyctl/ writing a table's rows."""

from __future__ import annotations

import ast
import math
import re
from pathlib import Path

import pytest

from analysis.reports import table
from analysis.reports.formatting import rate_interval
from analysis.reports.table import Table

ROOT = Path(__file__).resolve().parents[1]

T = Table(columns=["name", "a|b"], rows=[["x|y", "1"], ["two\nlines", ""]], title="Results", notes="Notes: 2 rows.")


def test_markdown_escapes_pipes_and_breaks_and_puts_the_notes_below():
    assert table.markdown(T) == ["**Results**", "",
                                 "| name | a\\|b |",
                                 "|---|---|",
                                 "| x\\|y | 1 |",
                                 "| two lines | |",
                                 "", "Notes: 2 rows.", ""]


def test_markdown_grid_is_the_table_alone():
    assert table.markdown_grid(Table(columns=["a"], rows=[["1"]])) == ["| a |", "|---|", "| 1 |"]


def test_html_escapes_every_text_and_sets_plus_minus():
    t = Table(columns=["<b>", "x & y"], rows=[["a < b & \"c\"", "1.5 +- 0.2"]], title="T & <u>", notes="p < 0.05 & more")
    assert table.html(t, "h3") == ("<h3>T &amp; &lt;u&gt;</h3>"
                                   "<table><tr><th>&lt;b&gt;</th><th>x &amp; y</th></tr>"
                                   "<tr><td>a &lt; b &amp; &quot;c&quot;</td><td>1.5 &plusmn; 0.2</td></tr></table>"
                                   "<p>p &lt; 0.05 &amp; more</p>")


def test_html_grid_has_no_title_or_notes():
    assert table.html_grid(Table(columns=["a"], rows=[["1"]], title="T", notes="N")) == "<table><tr><th>a</th></tr><tr><td>1</td></tr></table>"


def test_csv_quotes_commas_quotes_and_line_breaks():
    t = Table(columns=["question", "rate"], rows=[['Is it "real", or not?', "68.6% [52.0%, 81.4%]"], ["two\nlines", "1"]],
              notes="not in a CSV")
    assert table.csv(t) == ('question,rate\n'
                            '"Is it ""real"", or not?","68.6% [52.0%, 81.4%]"\n'
                            '"two\nlines",1\n')


def test_latex_escapes_every_text_and_captions_the_title_and_notes():
    t = Table(columns=["% of #1", "a_b & c"], rows=[["50% & 3_4 #2", "1.5 +- 0.2"]], title="T_1", notes="100% of {x}")
    lines = table.latex(t, "tab:x").splitlines()
    assert lines[:3] == ["\\begin{table}[htbp]", "\\centering\\footnotesize\\setlength{\\tabcolsep}{3pt}",
                         "\\caption{T\\_\\allowbreak{}1. 100\\% of \\{x\\}}\\label{tab:x}"]
    assert re.fullmatch(r"\\begin\{tabularx\}\{\\linewidth\}\{@\{\}(>\{[^}]*\\hsize=[0-9.]+\\hsize\\hspace\{0pt\}\}X){2}@\{\}\}", lines[3])
    assert lines[4:] == ["\\toprule",
                         "\\textbf{\\% of \\#1} & \\textbf{a\\_\\allowbreak{}b \\& c} \\\\",
                         "\\midrule",
                         "50\\% \\& 3\\_\\allowbreak{}4 \\#2 & 1.5 $\\pm$ 0.2 \\\\",
                         "\\bottomrule", "\\end{tabularx}", "\\end{table}"]


def test_latex_without_notes_captions_the_title_alone():
    assert "\\caption{Title}\n" in table.latex(Table(columns=["a"], rows=[["1"]], title="Title"))


def test_latex_tables_are_numbered_and_headed_by_their_packages():
    tex = table.latex_tables([Table(columns=["a"], rows=[["1"]], title="A"), Table(columns=["b"], rows=[["2"]], title="B")], "tab:s")
    assert tex.startswith("% needs in the preamble: \\usepackage[T1]{fontenc} \\usepackage{booktabs}")
    assert re.findall(r"\\label\{([^}]*)\}", tex) == ["tab:s:1", "tab:s:2"]


def test_cells_are_kept_as_text():
    assert Table(columns=["n", 2], rows=[[3, 0.5]]).rows == (("3", "0.5"),)


def test_a_row_of_the_wrong_length_is_refused():
    with pytest.raises(ValueError, match="row 1 has 1 cells; the table has 2 columns"):
        Table(columns=["a", "b"], rows=[["1", "2"], ["3"]], title="T")


def test_a_table_is_frozen():
    with pytest.raises(AttributeError):
        T.notes = "changed"


@pytest.mark.parametrize("args, want", [
    ((0.686, 0.52, 0.814), "68.6% [52.0%, 81.4%]"),
    ((0.686, 0.52, 0.814, 0), "69% [52%, 81%]"),
    ((0.5, None, None, 0), "50%"),
    ((0.5, math.nan, 0.7), "50.0%"),
])
def test_a_rate_with_its_interval_has_one_format(args, want):
    assert rate_interval(*args) == want


# ---------------------------------------------------------------- tables are built in table.py only

# what writes a table's rows by hand: a Markdown row or rule, an HTML table element, a LaTeX tabular's rules or cell joints
TABLE_TEXT = re.compile(r"\|---|^\| |^ \| $| \|$|<(table|tr|td|th)[ >]|\\(toprule|midrule|bottomrule|hline)\b|\\begin\{(tabular|longtable)|^ & $")
TABLE_MODULE = ROOT / "analysis" / "reports" / "table.py"


def _docstrings(tree: ast.AST) -> set[int]:
    """The ids of the docstring constants (a docstring may show a table; it builds none)."""
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)) and node.body:
            first = node.body[0]
            if isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant) and isinstance(first.value.value, str):
                out.add(id(first.value))
    return out


def table_text(source: str) -> list[str]:
    """The string constants of `source` (f-strings' literal parts included, docstrings not) that
    write a table's rows, in source order."""
    tree = ast.parse(source)
    skip = _docstrings(tree)
    found = [node for node in ast.walk(tree)
             if isinstance(node, ast.Constant) and isinstance(node.value, str) and id(node) not in skip and TABLE_TEXT.search(node.value)]
    return [node.value for node in sorted(found, key=lambda n: (n.lineno, n.col_offset))]


def test_the_scan_sees_a_table_built_by_hand():
    """The check itself: each kind of hand-built row is seen."""
    assert table_text('lines = ["| a | b |", "|---|---|"]') == ["| a | b |", "|---|---|"]
    assert table_text('row = "| " + " | ".join(cells) + " |"') == ["| ", " | ", " |"]
    assert table_text('html = f"<tr><td>{x}</td></tr>"') == ["<tr><td>"]
    assert table_text('tex = " & ".join(cells) + " \\\\\\\\"; rule = "\\\\toprule"') == [" & ", "\\toprule"]
    assert table_text('def f():\n    """| a | b |"""\n') == []


@pytest.mark.parametrize("path", sorted(p.relative_to(ROOT).as_posix() for package in ("analysis", "studyctl")
                                        for p in (ROOT / package).rglob("*.py") if p != TABLE_MODULE))
def test_no_module_but_table_py_builds_a_table(path):
    assert table_text((ROOT / path).read_text()) == []
