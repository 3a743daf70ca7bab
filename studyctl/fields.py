"""Participant fields: what a protocol records about each participant (`[fields.NAME]`), and the
between-participant factor (`design.groups`, a choice field).

A field describes a characteristic (experience, handedness, years in training), never who the
person is: values are stored with the pseudonymous code only (`participant_fields`) and are
exported. Kinds: `choice` (one of `values`), `integer` (optional `min`/`max`), `number` and
`text` (stored, never analysed). See docs/study.md.
"""

from __future__ import annotations

import dataclasses
import math
import random
from dataclasses import dataclass

from analysis.errors import InputError
from analysis.study.fields import FieldKind
from sim.text import quoted, text_problem
from sim.tomltable import TableReader
from studyctl.text import ID_RE

FIELD_KINDS = tuple(FieldKind)
FIELD_KEYS = ("kind", "values", "required", "min", "max", "description")
UNBOUNDED = 1 << 62  # an integer field's min and max may be any integer
MAX_TEXT = 200  # a text field's longest value: a remark, not a record about someone


@dataclass(frozen=True)
class Field:
    name: str
    kind: FieldKind
    values: tuple[str, ...] = ()  # a choice's values, in the protocol's order
    required: bool = False
    min: float | None = None
    max: float | None = None
    description: str = ""

    def __post_init__(self) -> None:
        object.__setattr__(self, "kind", FieldKind(self.kind))  # a kind given by its name becomes its member

    @property
    def analysed(self) -> bool:
        return self.kind != FieldKind.TEXT

    def allowed(self) -> str:
        """The values this field takes, as an error message names them."""
        if self.kind == FieldKind.CHOICE:
            return ", ".join(self.values)
        if self.kind in (FieldKind.INTEGER, FieldKind.NUMBER):
            what = "an integer" if self.kind == FieldKind.INTEGER else "a number"
            lo = "" if self.min is None else _num(self.min)
            hi = "" if self.max is None else _num(self.max)
            return what + (f" in {lo or '-inf'}..{hi or 'inf'}" if self.min is not None or self.max is not None else "")
        return f"a text of at most {MAX_TEXT} characters"

    def parse(self, raw) -> object:
        """The typed value of `raw` (text as given on a command line or in a CSV cell); a
        ValueError when the field does not take it."""
        text = str(raw).strip()
        if self.kind == FieldKind.CHOICE:
            if text not in self.values:
                raise ValueError(text)
            return text
        if self.kind == FieldKind.INTEGER:
            try:
                v = int(text)
            except ValueError:
                raise ValueError(text) from None
        elif self.kind == FieldKind.NUMBER:
            try:
                v = float(text)
            except ValueError:
                raise ValueError(text) from None
            if not math.isfinite(v):
                raise ValueError(text)
        else:
            if not text or text_problem(text, MAX_TEXT, one_line=True) is not None:
                raise ValueError(text)
            return text
        if self.min is not None and v < self.min or self.max is not None and v > self.max:
            raise ValueError(text)
        return v


def _num(v: float) -> str:
    return str(int(v)) if float(v).is_integer() else str(v)


def check_fields(data: dict, design: TableReader, c: TableReader) -> tuple[list[Field], str | None]:
    """[fields.NAME] tables and design.groups (`design`: the protocol's [design]), each problem
    added to the protocol file's reader `c`
    (FILE:LINE: field: message, naming what is allowed)."""
    raw = data.get("fields", {})
    out: list[Field] = []
    if not isinstance(raw, dict):
        c.error("fields", "must be tables, one per field: [fields.NAME] with kind = ...")
        raw = {}
    for name, t in raw.items():
        sec = f"fields.{name}"
        if not isinstance(t, dict):
            c.error(sec, "must be a table: [fields.NAME] with kind = ...")
            continue
        if not ID_RE.match(name):
            c.error(sec, f"{name!r} must be lower-case letters, digits and _ (starting with a letter)")
            continue
        if name in ("code", "age", "name", "contact"):
            c.error(sec, f"{name!r} is a participant's own column; name the field otherwise")
            continue
        for key in t:
            if key not in FIELD_KEYS:
                c.error(f"{sec}.{key}", f"unknown key; allowed: {', '.join(FIELD_KEYS)}")
        r = c.sub(t, f"{sec}.")
        kind = r.string("kind")
        if kind is None:
            continue
        if kind not in FIELD_KINDS:
            c.error(f"{sec}.kind", f"{kind!r} is not a field kind; allowed: {', '.join(FIELD_KINDS)}")
            continue
        required = r.boolean("required", default=False)
        description = r.string("description", default="")
        values, lo, hi, ok = (), None, None, True
        if kind == FieldKind.CHOICE:
            v = r.items("values")
            if v is not None:
                if len(v) < 2 or not all(isinstance(x, str) and x.strip() for x in v):
                    c.error(f"{sec}.values", f"{v!r}: at least two non-empty texts, e.g. [\"student\", \"resident\", \"neurosurgeon\"]")
                    ok = False
                elif len(set(x.strip() for x in v)) != len(v):
                    c.error(f"{sec}.values", "a value appears twice")
                    ok = False
                else:
                    values = tuple(x.strip() for x in v)
            else:
                ok = False
        elif "values" in t:
            c.error(f"{sec}.values", f"only a choice field has values; this one is {kind}")
        if kind in (FieldKind.INTEGER, FieldKind.NUMBER):
            if kind == FieldKind.INTEGER:
                lo, hi = r.integer("min", default=None, lo=-UNBOUNDED), r.integer("max", default=None, lo=-UNBOUNDED)
            else:
                lo, hi = r.number("min", default=None), r.number("max", default=None)
            if lo is not None and hi is not None and lo > hi:
                c.error(f"{sec}.max", f"{_num(hi)} is below min {_num(lo)}")
                ok = False
        else:
            for key in ("min", "max"):
                if key in t:
                    c.error(f"{sec}.{key}", f"only an integer or number field has {key}; this one is {kind}")
        if ok:
            out.append(Field(name, kind, values, bool(required), lo, hi, description or ""))
    groups = design.string("groups", default=None)
    if groups is not None:
        by_name = {f.name: f for f in out}
        if groups not in raw:
            named = f"a [fields.NAME] choice ({', '.join(raw)})" if raw else "a [fields.NAME] table with kind = \"choice\""
            c.error("design.groups", f"{groups!r} names no field; allowed: {named}")
        elif groups in by_name and by_name[groups].kind != FieldKind.CHOICE:
            choices = [f.name for f in out if f.kind == FieldKind.CHOICE]
            c.error("design.groups", f"{groups!r} is a {by_name[groups].kind} field; the groups are a choice field's values; allowed: "
                  + (", ".join(choices) if choices else "a field with kind = \"choice\""))
        elif groups in by_name:  # every participant is in a group
            out = [dataclasses.replace(f, required=True) if f.name == groups else f for f in out]
    return out, groups


def parse_fields(protocol, given: dict[str, str], where: str) -> dict[str, object]:
    """The typed values of a participant's fields (name -> text as given), checked against the
    protocol: an unknown field, a value the field does not take, a required field missing, each
    one InputError naming the field and what it allows. Empty values count as not given."""
    out: dict[str, object] = {}
    names = [f.name for f in protocol.fields]
    for name, raw in given.items():
        f = protocol.field_named(name)
        if f is None:
            allowed = ", ".join(names) if names else "none (the protocol declares no [fields.NAME])"
            raise InputError(f"{where}: unknown field {quoted(name)}; allowed: {allowed}")
        if raw is None or str(raw).strip() == "":
            continue
        try:
            out[name] = f.parse(raw)
        except ValueError:
            raise InputError(f"{where}: {name} = {quoted(str(raw).strip())} is not allowed; allowed: {f.allowed()}") from None
    for f in protocol.fields:
        if f.required and f.name not in out:
            raise InputError(f"{where}: field {f.name} is required; allowed: {f.allowed()}")
    return out


def field_rows(code: str, values: dict[str, object]) -> list[dict]:
    """Tidy rows of `participant_fields`: one per (code, field)."""
    return [{"code": code, "field": k, "value": v} for k, v in values.items()]


def synthetic_fields(protocol, codes: list[str], seed: int, start: int = 0) -> dict[str, dict[str, object]]:
    """Field values of synthetic participants: the group field's values in turn (balanced:
    the k-th synthetic participant of the study is in group k mod the number of groups; `start`
    is how many synthetic participants the study already has), and every other required field
    a value drawn with a generator seeded by the study's seed and the code."""
    out: dict[str, dict[str, object]] = {}
    group = protocol.group_field
    for k, code in enumerate(codes):
        rng = random.Random(f"fields:{seed}:{code}")
        values: dict[str, object] = {}
        for f in protocol.fields:
            if group is not None and f.name == group.name:
                values[f.name] = f.values[(start + k) % len(f.values)]
            elif f.required:
                values[f.name] = _draw(f, rng)
        out[code] = values
    return out


def _draw(f: Field, rng: random.Random) -> object:
    if f.kind == FieldKind.CHOICE:
        return rng.choice(f.values)
    if f.kind == FieldKind.TEXT:
        return "(synthetic participant)"
    lo = f.min if f.min is not None else (f.max - 10 if f.max is not None else 0)
    hi = f.max if f.max is not None else lo + 10
    return rng.randint(int(math.ceil(lo)), int(math.floor(hi))) if f.kind == FieldKind.INTEGER else round(rng.uniform(lo, hi), 3)
