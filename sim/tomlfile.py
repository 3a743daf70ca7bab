"""Reading TOML input files with problems named as ``FILE:LINE``.

`read_toml` turns a missing or unreadable file, bytes that are not UTF-8 and TOML syntax
errors into one-line `TomlFileError`s; `Locator` finds the line of a table or key (a dotted
field such as ``models.fem.resolution`` or ``hands[1].pull``) for error messages.
"""

from __future__ import annotations

import re
import tomllib
from pathlib import Path

_PART = r'(?:[A-Za-z0-9_-]+|"[^"\\]*"|\'[^\']*\')'  # bare, or quoted (a model named "package.module:Class")
_NAME = rf"{_PART}(?:\s*\.\s*{_PART})*"
_ARRAY_TABLE = re.compile(rf"^\[\[\s*({_NAME})\s*\]\]")
_TABLE = re.compile(rf"^\[\s*({_NAME})\s*\]")
_KEY = re.compile(rf"^({_NAME})\s*=")


class TomlFileError(Exception):
    """A file that cannot be read as TOML; the message is one line naming the file (and line)."""


def _unquote(name: str) -> str:
    """A dotted TOML name as the readers spell it: spaces around dots dropped, quotes removed
    (the quoted part's own dots then read as the readers join them)."""
    return "".join(p.strip("\"'") if p[:1] in "\"'" else re.sub(r"\s+", "", p) for p in re.split(r"(\"[^\"]*\"|'[^']*')", name))


class Locator:
    """Line numbers of tables and keys in a TOML text (1-based; for error messages).

    Tables are named as in the file (``models.fem``), the k-th ``[[hands]]`` as ``hands[k]``,
    keys as ``TABLE.KEY``. `line` falls back to the enclosing table, then to line 1."""

    def __init__(self, text: str):
        self.lines: dict[str, int] = {}
        table = ""
        counts: dict[str, int] = {}
        in_string = None  # the delimiter of a multi-line string being skipped
        for n, raw in enumerate(text.splitlines(), start=1):
            if in_string is not None:
                if raw.count(in_string) % 2 == 1:
                    in_string = None
                continue
            line = raw.split("#", 1)[0].strip()
            m = _ARRAY_TABLE.match(line)
            if m:
                name = re.sub(r"\s+", "", m.group(1))
                k = counts.get(name, 0)
                counts[name] = k + 1
                table = f"{name}[{k}]"
                self.lines.setdefault(name, n)
                self.lines.setdefault(table, n)
                continue
            m = _TABLE.match(line)
            if m:
                table = _unquote(m.group(1))
                parts = table.split(".")
                for i in range(len(parts) - 1, 0, -1):  # [hands.target] after the k-th [[hands]]: hands[k].target
                    head = ".".join(parts[:i])
                    if head in counts:
                        table = f"{head}[{counts[head] - 1}]." + ".".join(parts[i:])
                        break
                self.lines.setdefault(table, n)
                continue
            m = _KEY.match(line)
            if m:
                parts = _unquote(m.group(1)).split(".")
                for i in range(1, len(parts) + 1):  # a dotted key also locates its parents
                    key = ".".join(parts[:i])
                    self.lines.setdefault(f"{table}.{key}" if table else key, n)
            for delim in ('"""', "'''"):
                if raw.count(delim) % 2 == 1:
                    in_string = delim
                    break

    def line(self, field: str) -> int:
        while field:
            if field in self.lines:
                return self.lines[field]
            if field.endswith("]") and "[" in field:
                field = field[: field.rindex("[")]
            else:
                field = field.rsplit(".", 1)[0] if "." in field else ""
        return 1


def read_toml(path: str | Path) -> tuple[dict, Locator]:
    """Parse a TOML file; raises `TomlFileError` naming the file and, where known, the line."""
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise TomlFileError(f"{path}: cannot read: {exc.strerror or exc}") from None
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = raw.count(b"\n", 0, exc.start) + 1
        column = exc.start - (raw.rfind(b"\n", 0, exc.start) + 1) + 1
        raise TomlFileError(f"{path}:{line}: not UTF-8: byte 0x{raw[exc.start]:02x} at column {column}; "
                            "TOML files must be UTF-8") from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        m = re.search(r"line (\d+)", str(exc))
        raise TomlFileError(f"{path}:{m.group(1) if m else 1}: invalid TOML: {exc}") from None
    return data, Locator(text)
