"""Stored trials read back: their traces (path and SHA-256) by session, condition and trial, a
session's trials in run order for replay, and the forced-choice trials of a discrimination task
already stored."""

from __future__ import annotations

from studyctl.store.database import Store


def session_exists(store: Store, session_id: int) -> bool:
    """Whether the study holds a session with this id."""
    return bool(store.rows("select id from sessions where id = ?", (session_id,)))


def trace_rows(store: Store, session_id: int, model: str, trial: int | None = None) -> list[dict]:
    """trace_path and trace_sha256 of one condition's traced trials (or its one `trial`), in trial order."""
    return store.rows("select trace_path, trace_sha256 from trials where session_id = ? and model = ? and trace_path is not null "
                      "and (? is null or trial = ?) order by trial", (session_id, model, trial, trial))


def all_trace_rows(store: Store) -> list[dict]:
    """Every traced trial: session_id, model, trial, trace_path, trace_sha256, in that order."""
    return store.rows("select session_id, model, trial, trace_path, trace_sha256 from trials where trace_path is not null "
                      "order by session_id, model, trial")


def session_trials(store: Store, session_id: int) -> list[dict]:
    """A session's trials in the order they were run (condition position, then trial)."""
    return store.rows(
        "select t.*, c.position, c.label, c.config_sha256 from trials t join conditions c on c.session_id = t.session_id and c.model = t.model "
        "where t.session_id = ? order by c.position, t.trial", (session_id,))


def discrimination_done(store: Store, session_id: int, model: str, task: int) -> list[dict]:
    """The forced-choice trials of one task stored so far in a session's condition, in order."""
    return store.rows("select trial, delta, correct from discrimination where session_id = ? and model = ? and task = ? order by trial",
                      (session_id, model, task))
