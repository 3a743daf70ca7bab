"""Registering a study's participants: one at a time or from a CSV (codes, ages, a protocol's fields), each with its counterbalanced order."""

from __future__ import annotations

from pathlib import Path

from analysis.errors import InputError
from analysis.study.csvfiles import read_csv
from sim.text import NAME_MOST, TITLE_MOST, text_problem
from studyctl.fields import field_rows, parse_fields
from studyctl.store import Store, now, roster

CODE_CHARS = set("ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789-_")


def _check_code(code: str, where: str) -> str:
    code = (code or "").strip()
    if not code or len(code) > 32 or not set(code) <= CODE_CHARS:
        raise InputError(f"{where}: code {code!r} must be 1-32 letters, digits, '-' or '_' (a pseudonym, not a name)")
    return code


def _check_age(age, protocol, where: str):
    if age is None or age == "":
        return None
    try:
        age = int(age)
    except (TypeError, ValueError):
        raise InputError(f"{where}: age {age!r} is not an integer") from None
    if not protocol.age_min <= age <= protocol.age_max:
        raise InputError(f"{where}: age {age} is outside the inclusion range {protocol.age_min}..{protocol.age_max}")
    return age


def add_participant(db: str | Path, code: str, age=None, name: str | None = None, contact: str | None = None,
                    synthetic: bool = False, dry_run: bool = False, fields: dict[str, str] | None = None) -> dict:
    """Register a participant; `fields` their values of the protocol's [fields.NAME] (text as
    given, e.g. {"experience": "resident"}), each checked against its field."""
    with Store(db) as store:
        protocol = store.protocol()
        code = _check_code(code, "participant")
        age = _check_age(age, protocol, f"participant {code}")
        values = parse_fields(protocol, fields or {}, f"participant {code}")
        if roster.person(store, code) is not None:
            raise InputError(f"participant {code}: already registered")
        if synthetic and (name or contact):
            raise InputError(f"participant {code}: a synthetic participant has no name or contact")
        for option, text, most in (("--name", name, NAME_MOST), ("--contact", contact, TITLE_MOST)):
            if text and (problem := text_problem(text, most, one_line=True)) is not None:
                raise InputError(f"{option}: {problem}")
        _insert(store, [{"code": code, "age": age, "synthetic": int(synthetic), "created_at": now()}],
                [{"code": code, "name": name, "contact": contact}] if name or contact else [], dry_run, {code: values})
        return {"code": code, "age": age, "synthetic": synthetic, "fields": values, "dry_run": dry_run}


def _insert(store: Store, people: list[dict], identities: list[dict], dry_run: bool, fields: dict | None = None) -> None:
    """Participants, their fields, and their identifying details (kept apart; never exported or
    reported), all or none."""
    with store.transaction(dry_run) as conn:
        roster.insert_participants(conn, people, identities,
                                   [r for code, values in (fields or {}).items() for r in field_rows(code, values)])


def import_participants(db: str | Path, csv_path: str | Path, dry_run: bool = False) -> dict:
    """CSV with a `code` column, then optional `age`, `name`, `contact` and a column per field the
    protocol declares ([fields.NAME]; a required field's column must be there): all rows or none."""
    csv_path = Path(csv_path)
    with Store(db) as store:
        protocol = store.protocol()
        names = tuple(f.name for f in protocol.fields)
        required = ("code",) + tuple(f.name for f in protocol.fields if f.required)
        rows = read_csv(csv_path, ("code", "age", "name", "contact") + names, required)
        existing = roster.participant_codes(store)
        people, identities, fields, seen = [], [], {}, set()
        for line, row in rows:
            where = f"{csv_path}: line {line}"
            code = _check_code(row.get("code"), where)
            if code in seen or code in existing:
                raise InputError(f"{where}: code {code!r} appears twice or is already registered")
            seen.add(code)
            people.append({"code": code, "age": _check_age(row.get("age"), protocol, where), "synthetic": 0, "created_at": now()})
            fields[code] = parse_fields(protocol, {k: row[k] for k in names if k in row}, where)
            for column, most in (("name", NAME_MOST), ("contact", TITLE_MOST)):  # as `participants add` checks them
                if row.get(column) and (problem := text_problem(row[column], most, one_line=True)) is not None:
                    raise InputError(f"{where}: {column}: {problem}")
            if row.get("name") or row.get("contact"):
                identities.append({"code": code, "name": row.get("name") or None, "contact": row.get("contact") or None})
        if not people:
            raise InputError(f"{csv_path}: no participants (only a header)")
        _insert(store, people, identities, dry_run, fields)
        return {"imported": len(people), "dry_run": dry_run}
