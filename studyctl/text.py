"""Text a study names or exports: identifiers checked, cells made safe to open in a spreadsheet (the OWASP
CSV-injection rule). Control characters, lengths and quoting a refused value are `sim.text`'s."""

from __future__ import annotations

import re

ID_RE = re.compile(r"^[a-z][a-z0-9_]*$")  # a name a protocol gives (question, condition, field): also a column and a key
FORMULA_START = ("=", "+", "-", "@", "\t", "\r")  # a spreadsheet reads a cell starting so as a formula


def spreadsheet_safe(value):
    """A text cell a spreadsheet would run as a formula, prefixed with ' (shown, not run); any
    other value as it is."""
    if isinstance(value, str) and value.startswith(FORMULA_START):
        return "'" + value
    return value
