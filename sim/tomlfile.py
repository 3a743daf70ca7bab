"""Reading TOML input files with problems named as ``FILE:LINE``.

`read_toml` turns a missing or unreadable file, one that is not a regular file or is larger
than `TOML_MAX_BYTES`, bytes that are not UTF-8, TOML syntax errors and nesting deeper than
`MAX_DEPTH` into one-line `TomlFileError`s (`parse_toml`: the same for a text already read,
such as a protocol stored in a study); `Locator` finds the line of a table or key (a dotted
field such as ``models.fem.resolution`` or ``hands[1].pull``) for error messages.
"""

from __future__ import annotations

import re
import tomllib
from pathlib import Path

from sim.errors import InputFileError, SimError
from sim.files import TOML_MAX_BYTES, read_input

_PART = r'(?:[A-Za-z0-9_-]+|"[^"\\]*"|\'[^\']*\')'  # bare, or quoted (a model named "package.module:Class")
_NAME = rf"{_PART}(?:\s*\.\s*{_PART})*"
_ARRAY_TABLE = re.compile(rf"^\[\[\s*({_NAME})\s*\]\]")
_TABLE = re.compile(rf"^\[\s*({_NAME})\s*\]")
_KEY = re.compile(rf"^({_NAME})\s*=")
MAX_DEPTH = 32  # arrays, inline tables and tables nested in each other: far beyond any settings file, far within the stack
_NEXT = re.compile(r"""[\[\]{}"'#]""")  # a bracket, or the start of what can hold one that does not nest
_BASIC_END = re.compile(r'\\.|["\n]', re.S)  # in a one-line basic string: an escape, its end, or a line break (unterminated)
_MULTI_END = re.compile(r'\\.|"""', re.S)


class TomlFileError(SimError):
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


def _too_deep(text: str) -> int | None:
    """The line where brackets first nest deeper than `MAX_DEPTH`, or None. Checked before
    parsing: the standard parser recurses once per level and a deep enough file exhausts the
    stack. Brackets in strings and comments do not count; one pass, each character looked at
    once or twice (no backtracking on an unterminated string, which stops the scan: the parser
    then names it)."""
    depth, pos = 0, 0
    while (m := _NEXT.search(text, pos)) is not None:
        c, pos = m.group(), m.end()
        if c in "[{":
            depth += 1
            if depth > MAX_DEPTH:
                return text.count("\n", 0, m.start()) + 1
        elif c in "]}":
            depth = max(depth - 1, 0)
        elif c == "#":
            pos = text.find("\n", pos)
        elif text.startswith(c * 3, m.start()):
            if c == "'":
                pos = text.find("'''", pos + 2)
                pos = -1 if pos < 0 else pos + 3
            else:
                pos += 2
                while (e := _MULTI_END.search(text, pos)) is not None and e.group() != '"""':
                    pos = e.end()
                pos = -1 if e is None else e.end()
        elif c == "'":
            end = text.find("'", pos)
            pos = -1 if end < 0 or text.find("\n", pos, end) >= 0 else end + 1
        else:
            while (e := _BASIC_END.search(text, pos)) is not None and e.group().startswith("\\"):
                pos = e.end()
            pos = -1 if e is None or e.group() != '"' else e.end()
        if pos < 0:
            return None
    return None


def _data_depth(data) -> int:
    """How deep tables and arrays nest in parsed data (dotted keys and table headers nest
    without brackets), without recursion."""
    deepest, todo = 0, [(data, 1)]
    while todo:
        value, depth = todo.pop()
        deepest = max(deepest, depth)
        if depth <= MAX_DEPTH:
            todo += [(v, depth + 1) for v in (value.values() if isinstance(value, dict) else value) if isinstance(v, (dict, list))]
    return deepest


def parse_toml(text: str, path: str | Path) -> dict:
    """TOML text read from `path` (for messages); raises `TomlFileError` naming the file and,
    where known, the line."""
    line = _too_deep(text)
    if line is not None:
        raise TomlFileError(f"{path}:{line}: nested more than {MAX_DEPTH} levels deep; allowed: at most {MAX_DEPTH}")
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        m = re.search(r"line (\d+)", str(exc))
        raise TomlFileError(f"{path}:{m.group(1) if m else 1}: invalid TOML: {exc}") from None
    except RecursionError:  # a nesting the bracket scan cannot see; never expected
        raise TomlFileError(f"{path}: nested too deeply; allowed: at most {MAX_DEPTH} levels") from None
    if _data_depth(data) > MAX_DEPTH:
        raise TomlFileError(f"{path}: tables nested more than {MAX_DEPTH} levels deep; allowed: at most {MAX_DEPTH}")
    return data


def read_toml_text(path: str | Path) -> tuple[dict, Locator, str]:
    """`read_toml` and the file's text."""
    path = Path(path)
    try:
        raw = read_input(path, TOML_MAX_BYTES)
    except InputFileError as exc:
        raise TomlFileError(str(exc)) from None
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = raw.count(b"\n", 0, exc.start) + 1
        column = exc.start - (raw.rfind(b"\n", 0, exc.start) + 1) + 1
        raise TomlFileError(f"{path}:{line}: not UTF-8: byte 0x{raw[exc.start]:02x} at column {column}; "
                            "TOML files must be UTF-8") from None
    return parse_toml(text, path), Locator(text), text


def read_toml(path: str | Path) -> tuple[dict, Locator]:
    """Parse a TOML file; raises `TomlFileError` naming the file and, where known, the line."""
    data, loc, _ = read_toml_text(path)
    return data, loc
