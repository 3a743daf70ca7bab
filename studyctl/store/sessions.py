"""A session's rows: the session itself, its conditions, trials, latency, answers and events,
and what a session reads of its participant (a finished session, answers, observer features,
synthetic traits). The statements of studyctl/session/run.py, as functions of an open
`Store`; each write commits exactly where the session committed it before (a crash loses at
most the trial in flight)."""

from __future__ import annotations

from studyctl.store.database import Store, now

# -- the participant, checked before a session runs -------------------------------------------


def has_done_session(store: Store, code: str) -> bool:
    """Whether the participant has a completed session."""
    return bool(store.rows("select id from sessions where code = ? and status = 'done'", (code,)))


def imported_answers(store: Store, code: str) -> int:
    """How many of the participant's answers were imported from another source."""
    return store.rows("select count(*) as n from answers where code = ? and source = 'import'", (code,))[0]["n"]


def answer_count(store: Store, code: str) -> int:
    """How many answers the participant has."""
    return store.rows("select count(*) as n from answers where code = ?", (code,))[0]["n"]


# -- sessions --------------------------------------------------------------------------------


def open_sessions(store: Store, code: str, statuses: tuple[str, ...]) -> list[dict]:
    """id, device and synthetic of the participant's sessions in one of `statuses`."""
    return store.rows(f"select id, device, synthetic from sessions where code = ? and status in ({', '.join('?' * len(statuses))})",
                      (code, *statuses))


def participant_sessions(store: Store, code: str) -> list[dict]:
    """Every session row of the participant, oldest first."""
    return store.rows("select * from sessions where code = ? order by id", (code,))


def has_trials_or_answers(store: Store, session_id: int) -> bool:
    """Whether the session stored a trial or an answer (trials looked at first)."""
    return any(store.rows(f"select 1 from {t} where session_id = ? limit 1", (session_id,)) for t in ("trials", "answers"))


def discard_session(store: Store, session_id: int) -> None:
    """Delete a session that never started a trial, in one transaction; its events are kept, unlinked."""
    with store.transaction() as conn:
        conn.execute("delete from latency where session_id = ?", (session_id,))
        conn.execute("delete from conditions where session_id = ?", (session_id,))
        conn.execute("update events set session_id = null where session_id = ?", (session_id,))
        conn.execute("delete from sessions where id = ?", (session_id,))
        conn.execute("insert into events (session_id, at, kind, detail) values (null, ?, 'session_discarded', ?)",
                     (now(), f"session {session_id}: stopped before its first trial"))


def open_session(store: Store, code: str, synthetic: bool, device: str, protocol_sha256: str, scene_sha256: str,
                 software_version: str, conditions: str, seed: int | None, session_id: int | None = None) -> int:
    """Write a new running session (committed now); its id."""
    store.write("sessions", {
        **({"id": session_id} if session_id is not None else {}),
        "code": code, "started_at": now(), "finished_at": None, "status": "running", "synthetic": int(synthetic),
        "device": device, "protocol_sha256": protocol_sha256, "scene_sha256": scene_sha256,
        "software_version": software_version, "conditions": conditions, "seed": seed}, pk="id")
    return store.rows("select max(id) as id from sessions where code = ?", (code,))[0]["id"]  # the row just written


def session_done(store: Store, session_id: int) -> None:
    """Mark the session done, now (committed at once)."""
    store.db.conn.execute("update sessions set status = 'done', finished_at = ? where id = ?", (now(), session_id))


def mark_interrupted(store: Store, session_id: int) -> None:
    """Mark a running session interrupted, in its own transaction."""
    with store.transaction() as conn:
        conn.execute("update sessions set status = 'interrupted' where id = ? and status = 'running'", (session_id,))


def event_kinds(store: Store, session_id: int) -> set[str]:
    """The kinds of the session's events."""
    return {r["kind"] for r in store.rows("select kind from events where session_id = ?", (session_id,))}


# -- conditions ------------------------------------------------------------------------------


def add_condition(store: Store, session_id: int, position: int, model: str, label: str, config: str, config_sha256: str) -> None:
    """Write one pending condition of the session (committed now)."""
    store.write("conditions", {"session_id": session_id, "position": position, "model": model, "status": "pending",
                               "label": label, "config": config, "config_sha256": config_sha256}, pk=("session_id", "position"))


def condition_shas(store: Store, session_id: int) -> list[dict]:
    """model and config_sha256 of each of the session's conditions."""
    return store.rows("select model, config_sha256 from conditions where session_id = ?", (session_id,))


def condition_labels(store: Store, session_id: int) -> list[dict]:
    """model, position and blind label of each of the session's conditions."""
    return store.rows("select model, position, label from conditions where session_id = ?", (session_id,))


def condition_done(store: Store, session_id: int, position: int) -> None:
    """Mark the session's condition at `position` done (committed at once)."""
    store.db.conn.execute("update conditions set status = 'done' where session_id = ? and position = ?", (session_id, position))


# -- trials ----------------------------------------------------------------------------------


def done_trials(store: Store, session_id: int, model: str) -> set[int]:
    """The trial numbers stored for the session's condition."""
    return {r["trial"] for r in store.rows("select trial from trials where session_id = ? and model = ?", (session_id, model))}


def trial_count(store: Store, session_id: int) -> int:
    """How many trials the session stored."""
    return store.rows("select count(*) as n from trials where session_id = ?", (session_id,))[0]["n"]


def record_trial(store: Store, trial: dict, latency: list[dict]) -> None:
    """A trial's latency rows (one commit), then its row (another): a trial row means the trial is complete."""
    if latency:
        store.write_many("latency", latency, pk=("session_id", "model", "trial", "measure"))
    store.write("trials", trial, pk=("session_id", "model", "trial"))


# -- answers ---------------------------------------------------------------------------------


def answered_items(store: Store, code: str, model: str, trial: int) -> set[str]:
    """The items answered for this condition (and trial)."""
    return {r["item"] for r in store.rows("select item from answers where code = ? and model = ? and trial = ?", (code, model, trial))}


def record_answer(store: Store, code: str, model: str, item: str, trial: int, answer, session_id: int, source: str) -> None:
    """One answer, committed now."""
    store.write("answers", {"code": code, "model": model, "item": item, "trial": trial, "answer": answer, "session_id": session_id,
                            "source": source, "answered_at": now()}, pk=("code", "model", "item", "trial"))


# -- the synthetic participant and the observer ----------------------------------------------


def keep_synthetic_traits(store: Store, code: str, traits: dict, seed: int) -> None:
    """A synthetic participant's generating traits, replaced in one transaction."""
    with store.transaction() as conn:
        insert_traits(conn, code, traits, seed)


def insert_traits(conn, code: str, traits: dict, seed: int) -> None:
    """A synthetic participant's generating traits (and the seed that drew them), replacing older
    rows, inside the caller's transaction."""
    conn.executemany("insert or replace into synthetic_traits (code, trait, value, seed) values (?, ?, ?, ?)",
                     [(code, k, float(v), seed) for k, v in traits.items()])


def next_session_id(store: Store) -> int:
    """One more than the largest session id (1 in a study without sessions)."""
    return (store.rows("select max(id) as m from sessions")[0]["m"] or 0) + 1


def has_observer_features(store: Store, code: str, model: str) -> bool:
    """Whether the observer's features of the participant's condition are stored."""
    return bool(store.rows("select 1 from observer_features where code = ? and model = ? limit 1", (code, model)))


def keep_observer_features(store: Store, code: str, model: str, features: dict, session_id: int, at: str) -> None:
    """What the observer perceived of a condition, replaced in one transaction."""
    with store.transaction() as conn:
        conn.executemany("insert or replace into observer_features (code, model, feature, value, session_id, computed_at) "
                         "values (?, ?, ?, ?, ?, ?)", [(code, model, k, float(v), session_id, at) for k, v in features.items()])


def observer_features(store: Store, code: str) -> list[dict]:
    """model, feature and value of every observer feature of the participant."""
    return store.rows("select model, feature, value from observer_features where code = ?", (code,))
