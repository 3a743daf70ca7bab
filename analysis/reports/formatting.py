"""How every report writes its numbers and its pages: one format per quantity (a p-value, a rate
with its interval), and the self-contained HTML page with its pictures inlined as base64 PNG.
Table 1, the statistics, the discrimination report and the construct-validity report all use
these, so a p-value or a page looks the same wherever it appears (their tables:
analysis/reports/table.py)."""

from __future__ import annotations

import base64
import html
import io
import math
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd
from pandas.api.types import is_object_dtype, is_string_dtype

from sim.text import n_text

# every HTML report's look
STYLE = """<style>
body { font-family: sans-serif; margin: 2em; color: #222; }
table { border-collapse: collapse; font-size: 13px; }
th, td { border: 1px solid #bbb; padding: 4px 8px; vertical-align: top; }
th { background: #eee; }
.synthetic { background: #b00020; color: white; padding: 6px 10px; font-weight: bold; display: inline-block; }
figure { display: inline-block; margin: 1em; }
img { max-width: 900px; }
</style>"""

PAGE_END = "</body></html>\n"


def p_value(x, missing: str = "-", decimals: bool = False) -> str:
    """A p-value as a report prints it: `missing` where there is none (None, NaN); three
    significant digits; or, with `decimals`, three decimals and "<0.001" below that."""
    if x is None or pd.isna(x) or not math.isfinite(float(x)):
        return missing
    x = float(x)
    if decimals:
        return "<0.001" if x < 0.001 else f"{x:.3f}"
    return f"{x:.3g}"


def shown(x, spec: str, missing: str = "-") -> str:
    """`x` in the format `spec` (".1%", ".3g"), or `missing` where there is none (None, NaN: a
    row with no decided sample has no error, and JSON carries NaN as null)."""
    if x is None or not math.isfinite(float(x)):
        return missing
    return format(float(x), spec)


def rate_interval(rate: float, low: float | None, high: float | None, decimals: int = 1) -> str:
    """A rate with its interval, each a percentage with `decimals`: "68.6% [52.0%, 81.4%]"; the
    rate alone where the interval is missing (None, NaN)."""
    if low is None or high is None or not (math.isfinite(low) and math.isfinite(high)):
        return f"{rate:.{decimals}%}"
    return f"{rate:.{decimals}%} [{low:.{decimals}%}, {high:.{decimals}%}]"


def page_head(title: str) -> str:
    """An HTML report's opening, up to and with <body> (the title escaped)."""
    return f'<!doctype html>\n<html lang="en"><head><meta charset="utf-8"><title>{html.escape(title)}</title>\n{STYLE}</head><body>'


def png_base64(path: Path) -> str:
    return base64.b64encode(Path(path).read_bytes()).decode()


def drawn_png(draw) -> str:
    """Base64 PNG of what `draw(path)` writes (a report is one self-contained file)."""
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "plot.png"
        draw(path)
        return png_base64(path)


def figure_png(fig, close) -> str:
    """Base64 PNG of a matplotlib figure, which `close(fig)` then closes."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    close(fig)
    return base64.b64encode(buf.getvalue()).decode()


def figure_html(alt: str, png: str) -> str:
    """An inlined picture (`png`: base64) with its alternative text (escaped by the caller)."""
    return f'<figure><img alt="{alt}" src="data:image/png;base64,{png}"></figure>'


FORMULA_START = ("=", "+", "-", "@", "\t", "\r")  # a spreadsheet reads a cell starting so as a formula


def spreadsheet_safe(value):
    """A text cell a spreadsheet would run as a formula, prefixed with ' (shown, not run; the OWASP
    CSV-injection rule); any other value as it is."""
    if isinstance(value, str) and value.startswith(FORMULA_START):
        return "'" + value
    return value


def spreadsheet_frame(df: pd.DataFrame) -> pd.DataFrame:
    """A pandas DataFrame whose text cells are `spreadsheet_safe` (numbers stay numbers)."""
    out = df.copy()
    for col in out.columns:
        if is_object_dtype(out[col]) or is_string_dtype(out[col]):
            out[col] = out[col].map(spreadsheet_safe)
    return out


def mean_sd(mean: float, sd: float, n: int, fmt: str = "{:.2f}") -> str:
    """'mean +- sd', or the mean alone with why there is no SD (fewer than 2 values)."""
    if not n:
        return "n/a (no values)"
    if not np.isfinite(sd):
        return f"{fmt.format(mean)} (no SD at {n_text(n)})"
    return f"{fmt.format(mean)} +- {fmt.format(sd)}"
