"""Text from people: identifiers checked, control characters refused, long values quoted by a short prefix, cells
made safe to open in a spreadsheet (the OWASP CSV-injection rule)."""

from __future__ import annotations

import re

from sim.text import LINE_BREAKS, NAME_MOST, TEXT_MOST, TITLE_MOST, control_character, control_problem, text_problem

ID_RE = re.compile(r"^[a-z][a-z0-9_]*$")  # a name a protocol gives (question, condition, field): also a column and a key
QUOTE_LIMIT = 40  # characters of a refused value an error line quotes
FORMULA_START = ("=", "+", "-", "@", "\t", "\r")  # a spreadsheet reads a cell starting so as a formula


def quoted(value, limit: int = QUOTE_LIMIT) -> str:
    """`value` quoted for an error line: whole when short, else its first `limit` characters
    and its length."""
    text = str(value)
    if len(text) <= limit:
        return repr(text)
    return f"{text[:limit]!r}... ({len(text)} characters)"


def spreadsheet_safe(value):
    """A text cell a spreadsheet would run as a formula, prefixed with ' (shown, not run); any
    other value as it is."""
    if isinstance(value, str) and value.startswith(FORMULA_START):
        return "'" + value
    return value


def spreadsheet_frame(df):
    """A pandas DataFrame whose text cells are `spreadsheet_safe` (numbers stay numbers)."""
    from pandas.api.types import is_object_dtype, is_string_dtype

    out = df.copy()
    for col in out.columns:
        if is_object_dtype(out[col]) or is_string_dtype(out[col]):
            out[col] = out[col].map(spreadsheet_safe)
    return out


__all__ = ["ID_RE", "LINE_BREAKS", "NAME_MOST", "TEXT_MOST", "TITLE_MOST", "control_character", "control_problem", "quoted",
           "spreadsheet_frame", "spreadsheet_safe", "text_problem"]
