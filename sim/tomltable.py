"""`TableReader`: typed, range-checked reads of a parsed TOML table, for `sim.scene` (a scene
file, the plate-spring parameter file it names, a protocol's condition on top of it)."""

from __future__ import annotations

import math
from pathlib import Path

from sim.models.base import Vec3
from sim.tomlfile import Locator

REQUIRED = object()  # the default of a key that must be given


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

    def table(self, key: str, required: bool = True, allowed: tuple[str, ...] | None = None) -> TableReader:
        value, refused = self.data.get(key, REQUIRED), self.refused
        if value is REQUIRED:
            if required and not refused:
                self.error(key, "missing section")
            value, refused = {}, refused or required
        elif not isinstance(value, dict):
            self.error(key, "must be a table")
            value, refused = {}, True
        table = TableReader(self.path, value, f"{self.prefix}{key}.", self.loc, self.problems, refused)
        if allowed is not None:
            table.keys(allowed)
        return table

    def _value(self, key: str, default):
        value = self.data.get(key, default)
        if value is REQUIRED:
            if not self.refused:
                self.error(key, "missing")
            return None
        return value  # None: absent, and its default depends on a value already refused

    def number(self, key: str, default=REQUIRED, lo: float = -math.inf, hi: float = math.inf, lo_open=False,
               hi_open=False) -> float | None:
        value = self._value(key, default)
        if value is None:
            return None
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            return self.error(key, f"{value!r} is not a finite number")
        below = value <= lo if lo_open else value < lo
        above = value >= hi if hi_open else value > hi
        if below or above:
            left, right = "(" if lo_open else "[", ")" if hi_open else "]"
            return self.error(key, f"{value!r} is out of range; allowed: {left}{lo:g}, {hi:g}{right}")
        return float(value)

    def integer(self, key: str, default=REQUIRED, lo: int = 1, hi: int = 1 << 30) -> int | None:
        value = self._value(key, default)
        if value is None:
            return None
        if isinstance(value, bool) or not isinstance(value, int):
            return self.error(key, f"{value!r} is not an integer")
        if not lo <= value <= hi:
            return self.error(key, f"{value!r} is out of range; allowed: {lo}..{hi}")
        return value

    def string(self, key: str, default=REQUIRED, choices: tuple[str, ...] | None = None) -> str | None:
        value = self._value(key, default)
        if value is None:
            return None
        if not isinstance(value, str):
            return self.error(key, f"{value!r} is not a string")
        if choices is not None and value not in choices:
            return self.error(key, f"{value!r} is not one of {', '.join(choices)}")
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

    def vector(self, key: str, default=REQUIRED) -> Vec3 | None:
        value = self._value(key, default)
        if value is None:
            return None
        ok = isinstance(value, list) and len(value) == 3
        ok = ok and all(not isinstance(c, bool) and isinstance(c, (int, float)) and math.isfinite(c) for c in value)
        if not ok:
            return self.error(key, f"{value!r} is not a list of three numbers (metres)")
        return (float(value[0]), float(value[1]), float(value[2]))

    def path_value(self, key: str) -> Path | None:
        s = self.string(key)
        if s is None:
            return None
        p = Path(s)
        return p if p.is_absolute() else (self.path.parent / p).resolve()

