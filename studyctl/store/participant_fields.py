"""The participants' protocol fields as stored (`participant_fields`: one row per code and
field), read back typed by the protocol's field kinds (studyctl/fields.py checks and writes them)."""

from __future__ import annotations

from analysis.study.fields import FieldKind
from studyctl.store.database import Store


def read_fields(store: Store, protocol) -> dict[str, dict[str, object]]:
    """code -> {field: value}, each typed by the protocol's field kind."""
    rows = store.rows("select code, field, value from participant_fields order by code, field")
    out: dict[str, dict[str, object]] = {}
    for r in rows:
        f = protocol.field_named(r["field"])
        v = r["value"]
        if f is not None and v is not None:
            v = int(v) if f.kind == FieldKind.INTEGER else float(v) if f.kind == FieldKind.NUMBER else str(v)
        out.setdefault(r["code"], {})[r["field"]] = v
    return out


def group_of(store: Store, protocol, code: str) -> str | None:
    """The participant's group (their value of the design.groups field), None without groups."""
    if not protocol.groups:
        return None
    rows = store.rows("select value from participant_fields where code = ? and field = ?", (code, protocol.groups))
    return str(rows[0]["value"]) if rows else None
