"""The experimenter's records (studyctl/participants.py): participants, consent, withdrawal,
corrected answers, cancelled slots, the participant and session lists, the study's status and
the contact list. Reads take an open `Store`; writes take the connection of the caller's
`store.transaction(...)`, so the caller keeps the transaction and its dry run."""

from __future__ import annotations

import sqlite3

from studyctl.store.database import Store, now
from studyctl.store.roster import participant_count


# -- reads ---------------------------------------------------------------------------------
def consent_rows(store: Store, code: str) -> list[dict]:
    """The consent recorded for a participant (given_on, version): none or one row."""
    return store.rows("select given_on, version from consent where code = ?", (code,))


def consented_codes(store: Store, version: str) -> set[str]:
    """The codes of participants whose consent to this version is recorded."""
    return {r["code"] for r in store.rows("select code from consent where version = ?", (version,))}


def has_consent(store: Store, code: str, version: str) -> bool:
    """Whether a participant's consent to this version of the form is recorded."""
    return bool(store.rows("select code from consent where code = ? and version = ?", (code, version)))


def session_ids(store: Store, code: str) -> list[int]:
    """The ids of a participant's sessions."""
    return [r["id"] for r in store.rows("select id from sessions where code = ?", (code,))]


def trace_paths(store: Store, code: str) -> list[str]:
    """The trace files (relative paths) of a participant's trials."""
    return [r["trace_path"] for r in store.rows(
        "select trace_path from trials where trace_path is not null and session_id in (select id from sessions where code = ?)", (code,))]


def data_counts(store: Store, code: str) -> dict[str, int]:
    """How many answers and sessions a participant has: {"answers": n, "sessions": n}."""
    return {t: store.rows(f"select count(*) as n from {t} where code = ?", (code,))[0]["n"] for t in ("answers", "sessions")}


def slot_start(store: Store, code: str) -> str | None:
    """The start of a participant's scheduled slot, or None if they have none."""
    rows = store.rows("select slot_start from schedule where code = ? and slot_start is not null", (code,))
    return rows[0]["slot_start"] if rows else None


def stored_answer(store: Store, key: tuple) -> dict | None:
    """The row ({"answer": value}) of one answer by (code, model, item, trial), or None if none is stored."""
    rows = store.rows("select answer from answers where code = ? and model = ? and item = ? and trial = ?", key)
    return rows[0] if rows else None


def participant_list(store: Store) -> list[dict]:
    """One row per participant by code: code, kind, age, consent, slot, session (the last one's status), answers, withdrawn."""
    return store.rows(
        "select p.code, case when p.synthetic = 1 then 'synthetic' else 'person' end as kind, p.age, "
        "c.version as consent, s.slot_start as slot, "
        "(select status from sessions x where x.code = p.code order by x.id desc limit 1) as session, "
        "(select count(*) from answers a where a.code = p.code) as answers, p.withdrawn_at as withdrawn "
        "from participants p left join consent c on c.code = p.code left join schedule s on s.code = p.code order by p.code")


def session_list(store: Store) -> list[dict]:
    """One row per session by id: session, code, status, device, kind, started_at, finished_at, trials, answers."""
    return store.rows(
        "select x.id as session, x.code, x.status, x.device, case when x.synthetic = 1 then 'synthetic' else 'person' end as kind, "
        "x.started_at, x.finished_at, (select count(*) from trials t where t.session_id = x.id) as trials, "
        "(select count(*) from answers a where a.session_id = x.id) as answers from sessions x order by x.id")


def _count(store: Store, sql: str) -> int:
    return store.rows(sql)[0]["n"]


def people_counts(store: Store) -> dict[str, int]:
    """How many persons and synthetic participants the study holds (withdrawn ones included), how
    many of them withdrew (`withdrawn`: everyone, as `complete_withdrawn` counts; of these,
    `withdrawn_synthetic`), and its consent records."""
    return {
        "persons": participant_count(store, synthetic=False),
        "synthetic": participant_count(store, synthetic=True),
        "withdrawn": _count(store, "select count(*) as n from participants where withdrawn_at is not null"),
        "withdrawn_synthetic": _count(store, "select count(*) as n from participants where synthetic = 1 and withdrawn_at is not null"),
        "consented": _count(store, "select count(*) as n from consent"),
    }


def sessions_by_status(store: Store) -> dict[str, int]:
    """status -> number of sessions."""
    return {r["status"]: r["n"] for r in store.rows("select status, count(*) as n from sessions group by status")}


def upcoming_slots(store: Store, moment: str) -> list[dict]:
    """The next five scheduled slots from `moment` on (code, slot_start, slot_end), earliest first."""
    return store.rows("select code, slot_start, slot_end from schedule where slot_start >= ? order by slot_start limit 5", (moment,))


def answer_count(store: Store) -> int:
    """How many answers the study holds."""
    return _count(store, "select count(*) as n from answers")


def contacts(store: Store) -> list[dict]:
    """The identifying details (code, name, contact) of the participants who have not withdrawn, by code."""
    return store.rows("select i.code, i.name, i.contact from identities i join participants p on p.code = i.code "
                      "where p.withdrawn_at is null order by i.code")


# -- writes, inside the caller's transaction -------------------------------------------------
def record_consent(conn: sqlite3.Connection, row: dict, detail: str) -> None:
    """Store a consent row (code, version, given_on, recorded_at, recorded_by, in that order) and its event."""
    conn.execute("insert or replace into consent (code, version, given_on, recorded_at, recorded_by) values (?, ?, ?, ?, ?)",
                 tuple(row.values()))
    conn.execute("insert into events (session_id, at, kind, detail) values (null, ?, 'consent', ?)", (now(), detail))


def withdraw_rows(conn: sqlite3.Connection, code: str, session_ids: list[int], delete: bool, detail: str) -> None:
    """Withdraw a participant: delete their data (`delete`) or stop their open sessions, drop their slot and
    contact details, mark them withdrawn and log the event."""
    ids = ",".join(str(i) for i in session_ids) or "null"  # integers from the database, safe to inline
    if delete:
        for table in ("latency", "trials", "conditions"):
            conn.execute(f"delete from {table} where session_id in ({ids})")
        conn.execute(f"delete from events where session_id in ({ids})")
        conn.execute("delete from answers where code = ?", (code,))
        conn.execute("delete from corrections where code = ?", (code,))
        conn.execute("delete from observer_features where code = ?", (code,))
        conn.execute("delete from participant_fields where code = ?", (code,))
        conn.execute("delete from sessions where code = ?", (code,))
    else:  # an interrupted session will not be resumed
        conn.execute("update sessions set status = 'withdrawn' where code = ? and status in ('running', 'interrupted')", (code,))
    conn.execute("delete from schedule where code = ?", (code,))
    conn.execute("delete from identities where code = ?", (code,))
    conn.execute("update participants set withdrawn_at = ?, withdrawal = ? where code = ?",
                 (now(), "deleted" if delete else "kept", code))
    conn.execute("insert into events (session_id, at, kind, detail) values (null, ?, 'withdrawn', ?)", (now(), detail))


def cancel_slot(conn: sqlite3.Connection, code: str, detail: str) -> None:
    """Free a participant's slot (their condition order stays) and log the event."""
    conn.execute("update schedule set slot_start = null, slot_end = null where code = ?", (code,))
    conn.execute("insert into events (session_id, at, kind, detail) values (null, ?, 'slot_cancelled', ?)", (now(), detail))


def correct_answer(conn: sqlite3.Connection, key: tuple, old, new, reason: str, by: str) -> None:
    """Change one answer by (code, model, item, trial) and keep the old value, reason and who in `corrections`."""
    conn.execute("update answers set answer = ? where code = ? and model = ? and item = ? and trial = ?", (new, *key))
    conn.execute("insert into corrections (code, model, item, trial, old_answer, new_answer, reason, corrected_at, corrected_by) "
                 "values (?, ?, ?, ?, ?, ?, ?, ?, ?)", (*key, old, new, reason, now(), by))
