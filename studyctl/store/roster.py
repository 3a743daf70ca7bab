"""Who takes part and when: registering participants (with their fields and, kept apart, their
identifying details), their condition orders and rig slots, the checks the study library makes
before it adds anything (which codes exist, are synthetic, withdrew, consented, already
answered), and the table dumps of an export. Reads take an open `Store`; writes take the
connection of the caller's `store.transaction(...)`, so the caller keeps the transaction."""

from __future__ import annotations

import sqlite3

from studyctl.store.database import Store

# a participant of a group (design.groups): their group field has the group's value
_IN_GROUP = " and s.code in (select code from participant_fields where field = ? and value = ?)"


# -- registration -------------------------------------------------------------------------
def person(store: Store, code: str) -> dict | None:
    """A participant's row (code, age, synthetic, withdrawn_at, withdrawal, ...), or None if not registered."""
    rows = store.rows("select * from participants where code = ?", (code,))
    return rows[0] if rows else None


def participant_codes(store: Store) -> set[str]:
    """The codes of every registered participant."""
    return {r["code"] for r in store.rows("select code from participants")}


def insert_participants(conn: sqlite3.Connection, people: list[dict], identities: list[dict], fields: list[dict]) -> None:
    """Participants (code, age, synthetic, created_at), identities (code, name, contact) and field rows (code, field, value)."""
    conn.executemany("insert into participants (code, age, synthetic, created_at) values (:code, :age, :synthetic, :created_at)", people)
    conn.executemany("insert into identities (code, name, contact) values (:code, :name, :contact)", identities)
    conn.executemany("insert into participant_fields (code, field, value) values (:code, :field, :value)", fields)


def participant_count(store: Store, synthetic: bool) -> int:
    """How many synthetic participants (or people) are registered, withdrawn ones included."""
    return store.rows("select count(*) as n from participants where synthetic = ?", (int(synthetic),))[0]["n"]


def unrun_synthetic(store: Store) -> list[dict]:
    """code and seed (None without traits) of the synthetic participants with no session who did
    not withdraw, by code: those a `synth` registered and did not run."""
    return store.rows("select p.code, (select max(t.seed) from synthetic_traits t where t.code = p.code) as seed from participants p "
                      "where p.synthetic = 1 and p.withdrawn_at is null and not exists (select 1 from sessions s where s.code = p.code) "
                      "order by p.code")


def synthetic_with_session(store: Store) -> int:
    """How many synthetic participants have a session."""
    return store.rows("select count(*) as n from participants p where p.synthetic = 1 "
                      "and exists (select 1 from sessions s where s.code = p.code)")[0]["n"]


# -- the schedule -------------------------------------------------------------------------
def stored_order(store: Store, code: str) -> str | None:
    """The participant's stored condition order (JSON), or None when they have none."""
    row = store.rows("select conditions from schedule where code = ?", (code,))
    return row[0]["conditions"] if row else None


def _among(groups: str | None, group) -> tuple[str, tuple]:
    """The clause and parameters that keep a group's members only (none without groups)."""
    return (_IN_GROUP, (groups, group)) if groups else ("", ())


def completed_orders(store: Store, groups: str | None, group) -> list[int]:
    """The order rows (order_index) of finished sessions, of `group`'s members when the design has `groups`."""
    among, args = _among(groups, group)
    return [r["order_index"] for r in store.rows(
        "select s.order_index from schedule s join sessions x on x.code = s.code where x.status = 'done'" + among, args)]


def assigned_orders(store: Store, groups: str | None, group) -> list[int]:
    """The order rows (order_index) assigned so far, of `group`'s members when the design has `groups`."""
    among, args = _among(groups, group)
    return [r["order_index"] for r in store.rows("select s.order_index from schedule s where 1" + among, args)]


def save_order(conn: sqlite3.Connection, code: str, order_index: int, conditions: str) -> None:
    """The participant's condition order (its Williams row and the JSON list), with no slot yet."""
    conn.execute("insert or replace into schedule (code, slot_start, slot_end, order_index, conditions) values (?, null, null, ?, ?)",
                 (code, order_index, conditions))


def waiting_codes(store: Store) -> list[str]:
    """People who still need the rig: no slot, not withdrawn, no finished session, no answers from paper; by code."""
    return [r["code"] for r in store.rows(
        "select p.code from participants p left join schedule s on s.code = p.code where s.slot_start is null "
        "and p.synthetic = 0 and p.withdrawn_at is null and p.code not in (select code from sessions where status = 'done') "
        "and p.code not in (select code from answers where source = 'import') order by p.code")]


def taken_slots(store: Store) -> list[dict]:
    """slot_start and slot_end (ISO text) of every slot given out."""
    return store.rows("select slot_start, slot_end from schedule where slot_start is not null")


def set_slot(conn: sqlite3.Connection, code: str, slot_start: str, slot_end: str) -> None:
    """The participant's slot (ISO text), kept with their order."""
    conn.execute("update schedule set slot_start = ?, slot_end = ? where code = ?", (slot_start, slot_end, code))


def schedule_rows(store: Store) -> list[dict]:
    """The schedule (code, slot_start, slot_end, order_index, conditions): slots in time order, then those without one, by code."""
    return store.rows("select code, slot_start, slot_end, order_index, conditions from schedule order by slot_start is null, slot_start, code")


# -- checks before answers are added ------------------------------------------------------
def synthetic_codes(store: Store) -> set[str]:
    """The codes of synthetic participants."""
    return {r["code"] for r in store.rows("select code from participants where synthetic = 1")}


def session_codes(store: Store) -> set[str]:
    """The codes of participants with a simulator session."""
    return {r["code"] for r in store.rows("select distinct code from sessions")}


def withdrawn_codes(store: Store) -> set[str]:
    """The codes of participants who withdrew."""
    return {r["code"] for r in store.rows("select code from participants where withdrawn_at is not null")}


def answer_keys(store: Store) -> set[tuple]:
    """(code, model, item, trial) of every stored answer."""
    return {(r["code"], r["model"], r["item"], r["trial"]) for r in store.rows("select code, model, item, trial from answers")}
