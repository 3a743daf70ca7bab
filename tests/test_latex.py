"""analysis/reports/latex.py and the LaTeX of analysis/reports/table.py: every report's tables as
LaTeX that compiles with pdflatex and fits an A4 text block (no overfull box over 1 pt), with
escaped text and proper symbols."""

from __future__ import annotations

import pytest

from analysis.reports import latex, table
from analysis.reports.table import Table
from tests.helpers import latex_problems


@pytest.mark.parametrize("raw, want", [
    ("12.3 +- 4.5", "12.3 $\\pm$ 4.5"),
    ("a 0-100 scale", "a 0--100 scale"),
    ("r -0.31 [-0.76, 0.40]", "r $-$0.31 [$-$0.76, 0.40]"),
    ("on 2026-11-27", "on 2026-11-27"),  # a date keeps its hyphens
    ("mesh brain2-3.npz", "mesh brain2-3.npz"),  # so does a name
    ("50% & more_than #1 {x}", "50\\% \\& more\\_\\allowbreak{}than \\#1 \\{x\\}"),
    ("χ²(2) ≥ 3 µs, 45°", "$\\chi$$^{2}$(2) $\\geq$ 3 $\\mu$s, 45$^{\\circ}$"),
])
def test_text_is_escaped_with_proper_symbols(raw, want):
    assert latex.text(raw) == want


def _table(n_conditions: int, n_rows: int) -> Table:
    names = [f"plate_spring_located_variant_{k}" for k in range(n_conditions)]
    return Table(title="Ratings", columns=["Question", *[f"{m}: median [IQR]" for m in names], "Friedman chi2 (p)", "Wilcoxon p, Holm"],
                 rows=[[f"Question {i}: did the interaction feel like retracting real brain tissue, with the force you expected?",
                       *["4.5 [3, 6.75]"] * n_conditions, "2.55 (0.28), W 0.07 [0.00, 0.36]",
                       "; ".join(f"{a}-{b} 1 (r 0.39 [-0.27, 0.83])" for a in names[:2] for b in names[2:4])] for i in range(n_rows)],
                 notes="SYNTHETIC DATA (simulated participants): not evidence about people. 7-point ratings, 0-100 scores, 12.3 +- 4.5 ms.")


@pytest.mark.parametrize("n_conditions, n_rows", [(2, 3), (3, 9), (6, 3), (3, 60), (6, 40)])
def test_a_table_fits_the_page_whatever_its_shape(n_conditions, n_rows, tmp_path):
    tex = table.latex_tables([_table(n_conditions, n_rows)], "tab:t")
    assert ("\\begin{landscape}" in tex) == (n_conditions + 3 > table.LANDSCAPE_COLUMNS)
    if n_rows <= 3 and n_conditions <= 3:  # a short table is a float; a long one breaks across pages, its head repeated
        assert "\\begin{table}" in tex
        assert tex.count("\\toprule") == 1
    if n_rows >= 40:
        assert "\\begin{longtable}" in tex
        assert tex.count("\\toprule") == 2
    assert latex_problems(latex.document(tex), tmp_path) == []


def test_the_checker_sees_a_table_that_does_not_fit(tmp_path):
    """The compile check itself: a plain tabular of long unbroken cells runs off the page."""
    wide = "\\begin{tabular}{lll}\n" + " & ".join(["x" * 60] * 3) + " \\\\\n\\end{tabular}\n"
    assert any("Overfull" in p for p in latex_problems(latex.document(wide), tmp_path))
