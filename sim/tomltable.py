"""`TableReader`: typed, range-checked reads of a parsed TOML table, the one reader of every
TOML file the project takes: a scene, the plate-spring parameter file it names, a material,
a protocol (`studyctl.protocol`) and its conditions on top of the scene. One wording for each
problem, so a user reads the same message whichever file it is in."""

from __future__ import annotations

import math
from pathlib import Path

from brainsim_assets import path as _asset
from sim.models.base import Vec3
from sim.text import VALUE_MOST, text_problem
from sim.tomlfile import Locator

INT64_MAX = 2**63 - 1
REQUIRED = object()  # the default of a key that must be given
# a path of a file that comes with the package ("shipped:data/brain_fsaverage5.npz"): found
# wherever it is installed, so a lab's scene that names it holds when the venv moves or is shared
SHIPPED = "shipped:"
# what a value of the wrong type should have been, in a TOML writer's words
WHAT = {"integer": "an integer", "number": "a finite number", "string": "a text in quotes", "boolean": "true or false",
        "list": "a list in [ ]"}


class TableReader:
    """Typed access to a TOML table. A problem is recorded as 'FILE:LINE: field: message' (the
    line of the key, else of its table) and the accessor returns None (a section: empty), so
    loading goes on and finds every problem; `sim.scene.load_scene` raises them together."""

    def __init__(self, path: Path, data: dict, prefix: str, loc: Locator, problems: list, refused: bool = False):
        self.path, self.data, self.prefix, self.loc, self.problems = path, data, prefix, loc, problems
        self.refused = refused  # the table itself is missing or not a table (reported once): not its keys

    def error(self, key: str, message: str) -> None:
        field = f"{self.prefix}{key}" if key else self.prefix.rstrip(".")
        line = self.loc.line(field)
        where = f"{self.path}:{line}"
        self.problems.append((self.path, line, f"{where}: {field}: {message}" if field else f"{where}: {message}"))

    def keys(self, allowed: tuple[str, ...]) -> None:
        for key in self.data:
            if key not in allowed:
                self.error(key, f"unknown key; allowed: {', '.join(allowed)}")

    def strings(self) -> list[str]:
        """The problems as 'FILE:LINE: field: message', in the order they were found."""
        return [text for _, _, text in self.problems]

    def table(self, key: str, required: bool = True, allowed: tuple[str, ...] | None = None, hint: str | None = None) -> TableReader:
        """Section `key`; `hint`: what a missing one should hold (added to its message)."""
        value, refused = self.data.get(key, REQUIRED), self.refused
        if value is REQUIRED:
            if required and not refused:
                self.error(key, "missing section" + (f"; write [{key}] with {hint}" if hint else ""))
            value, refused = {}, refused or required
        elif not isinstance(value, dict):
            self.error(key, "must be a table")
            value, refused = {}, True
        table = self.sub(value, f"{self.prefix}{key}.", refused)
        if allowed is not None:
            table.keys(allowed)
        return table

    def sub(self, data: dict, prefix: str, refused: bool = False) -> TableReader:
        """A reader of `data` (a table found by the caller: an item of an array of tables, a
        [section.NAME]) whose fields are named `prefix`KEY, its problems added to this one's."""
        return TableReader(self.path, data, prefix, self.loc, self.problems, refused)

    def _value(self, key: str, default):
        value = self.data.get(key, default)
        if value is REQUIRED:
            if not self.refused:
                self.error(key, "missing")
            return None
        return value  # None: absent, and its default depends on a value already refused

    def number(self, key: str, default=REQUIRED, lo: float = -math.inf, hi: float = math.inf, lo_open=False,
               hi_open=False, unit: str = "") -> float | None:
        value = self._value(key, default)
        if value is None:
            return None
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            return self.error(key, f"{value!r} is not {WHAT['number']}")
        below = value <= lo if lo_open else value < lo
        above = value >= hi if hi_open else value > hi
        if below or above:
            left, right = "(" if lo_open else "[", ")" if hi_open else "]"
            return self.error(key, f"{value!r} is out of range; allowed: {left}{lo:g}, {hi:g}{right}" + (f" {unit}" if unit else ""))
        return float(value)

    def integer(self, key: str, default=REQUIRED, lo: int = 1, hi: int | None = None) -> int | None:
        """An integer in lo..hi (where `hi` is None, up to TOML's own largest, 2^63 - 1, which a
        parser may not enforce and SQLite cannot store beyond)."""
        value = self._value(key, default)
        if value is None:
            return None
        if isinstance(value, bool) or not isinstance(value, int):
            return self.error(key, f"{value!r} is not {WHAT['integer']}")
        if value < lo or value > (INT64_MAX if hi is None else hi):
            return self.error(key, f"{value!r} is out of range; allowed: {lo}..{INT64_MAX if hi is None else hi}")
        return value

    def string(self, key: str, default=REQUIRED, choices: tuple[str, ...] | None = None, most: int = VALUE_MOST,
               one_line: bool = False) -> str | None:
        """A text of at most `most` characters, without control characters (tabs and line
        breaks aside unless `one_line`)."""
        value = self._value(key, default)
        if value is None:
            return None
        if not isinstance(value, str):
            return self.error(key, f"{value!r} is not {WHAT['string']}")
        if (problem := text_problem(value, most, one_line)) is not None:
            return self.error(key, problem)
        if choices is not None and value not in choices:
            return self.error(key, f"{value!r} is not one of {', '.join(choices)}")
        return value

    def boolean(self, key: str, default=REQUIRED) -> bool | None:
        value = self._value(key, default)
        if value is None:
            return None
        if not isinstance(value, bool):
            return self.error(key, f"{value!r} is not {WHAT['boolean']}")
        return value

    def items(self, key: str, default=REQUIRED) -> list | None:
        """A list, its items checked by the caller."""
        value = self._value(key, default)
        if value is None:
            return None
        if not isinstance(value, list):
            return self.error(key, f"{value!r} is not {WHAT['list']}")
        return value

    def numbers(self, key: str, default=REQUIRED, lo: float = -math.inf, hi: float = math.inf, most: int = 8) -> tuple | None:
        """A number or a list of 1..`most` numbers, each in [lo, hi]."""
        value = self._value(key, default)
        if value is None:
            return None
        items = value if isinstance(value, list) else [value]
        if not 1 <= len(items) <= most or any(isinstance(c, bool) or not isinstance(c, (int, float)) or not math.isfinite(c) for c in items):
            return self.error(key, f"{value!r} is not a number or a list of 1..{most} finite numbers")
        bad = [c for c in items if not lo <= c <= hi]
        if bad:
            return self.error(key, f"{bad[0]!r} is out of range; allowed: [{lo:g}, {hi:g}]")
        return tuple(float(c) for c in items)

    def vector(self, key: str, default=REQUIRED, bound: float = math.inf, unit: str = "m", nonzero: bool = False) -> Vec3 | None:
        """Three numbers, each in [-bound, bound] (`unit`); `nonzero`: a direction, not all 0."""
        value = self._value(key, default)
        if value is None:
            return None
        ok = isinstance(value, list) and len(value) == 3
        ok = ok and all(not isinstance(c, bool) and isinstance(c, (int, float)) and math.isfinite(c) for c in value)
        if not ok:
            return self.error(key, f"{value!r} is not a list of three numbers" + (" (metres)" if unit == "m" else ""))
        if any(abs(c) > bound for c in value):
            return self.error(key, f"{value!r} is out of range; allowed: each in [{-bound:g}, {bound:g}]" + (f" {unit}" if unit else ""))
        if nonzero and not any(value):
            return self.error(key, f"{value!r} is not a direction; allowed: three numbers, not all 0")
        return (float(value[0]), float(value[1]), float(value[2]))

    def path_value(self, key: str) -> Path | None:
        """A file: absolute, relative to this file's folder, or shipped (`SHIPPED`)."""
        s = self.string(key)
        if s is None:
            return None
        p = _asset(s.removeprefix(SHIPPED)) if s.startswith(SHIPPED) else Path(s)
        p = p if p.is_absolute() else (self.path.parent / p).resolve()
        if p.exists() and not p.is_file():  # a folder, a device (/dev/zero never ends), a named pipe (blocks)
            return self.error(key, f"{p} is not a regular file")
        return p

