"""Whole tables as rows: for export (studyctl/export.py) and for moving a participant's session
between studies (the synthetic study's scratch databases, studyctl/synthetic/bundles.py)."""

from __future__ import annotations

from studyctl.store.database import Store


def table_rows(store: Store, table: str, code: str | None = None) -> list[dict]:
    """Every row of `table` as stored (a name from the schema, never text from outside), or only
    participant `code`'s."""
    if code is None:
        return store.rows(f"select * from [{table}]")
    return store.rows(f"select * from [{table}] where code = ?", (code,))
