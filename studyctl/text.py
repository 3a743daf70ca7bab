"""Text a study names: identifiers checked (cells made safe to open in a spreadsheet are
`analysis.reports.formatting.spreadsheet_safe`'s). Control characters, lengths and quoting a
refused value are `sim.text`'s."""

from __future__ import annotations

import re

ID_RE = re.compile(r"^[a-z][a-z0-9_]*$")  # a name a protocol gives (question, condition, field): also a column and a key

