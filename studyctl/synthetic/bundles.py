"""A synthetic participant's session run away from the study's database and brought back whole.

`synth` runs each participant's session in a scratch study of their own (a temporary folder
of whichever process or Dask worker runs it); the process that called `synth` then stores the
result in the study in one transaction. So one process alone writes the study database
(SQLite's write-ahead log needs every writer on one host: a database on a shared disk cannot
take writers from several machines), a worker needs no path to the study, and a Dask worker
that dies loses only the participant it was running, which the cluster runs again from the
start: every participant is stored exactly once. The scratch study has the study's name and rows, so its
trace paths and everything computed from them are the study's own.
"""

from __future__ import annotations

import hashlib
import tempfile
from dataclasses import dataclass
from pathlib import Path

from analysis.errors import StoreError
from analysis.study.trace_files import home, trace_dir, write_durably
from studyctl.session.run import run_session
from studyctl.store import Store
from studyctl.store.tables import table_rows
from studyctl.store.trials import session_exists

SEEDED = ("study", "rig_profile")  # the study's rows a synthetic session reads
OWN = ("participants", "participant_fields", "schedule", "synthetic_traits")  # the participant's own rows, written by `synth` before the run
NEW_IDS = ("events", "corrections")  # rowid tables: the study gives imported rows their ids
FIRST = ("sessions",)  # imported before the rows that reference them


@dataclass(frozen=True)
class Seed:
    """What a worker needs to run one participant's synthetic session (picklable)."""

    db_name: str  # the study database's file name: trace paths are relative to it
    code: str
    seed: int
    session_id: int
    rows: dict  # table -> the rows the scratch study starts with


@dataclass(frozen=True)
class Bundle:
    """One participant's finished session: every row it wrote and its trace files."""

    code: str
    session_id: int
    tables: dict  # table -> rows (dicts)
    traces: dict  # path relative to the database's folder -> bytes


def seed_for(store, code: str, seed: int, session_id: int) -> Seed:
    rows = {t: table_rows(store, t) for t in SEEDED}
    rows |= {t: table_rows(store, t, code) for t in OWN}
    return Seed(store.file.name, code, seed, session_id, rows)


def run_away(task: Seed) -> Bundle:
    """Run the participant's synthetic session in a scratch study; return what it wrote."""
    with tempfile.TemporaryDirectory(prefix="studyctl-synth-") as folder:
        db = Path(folder) / task.db_name
        with Store(db, create=True) as scratch, scratch.transaction():
            for table, rows in task.rows.items():
                scratch.db[table].insert_all(rows)
        run_session(db, task.code, synthetic=True, seed=task.seed, time_scale=0.0, session_id=task.session_id)
        with Store(db, mode="read") as scratch:
            tables = {t: table_rows(scratch, t) for t in scratch.db.table_names()
                      if t not in ("meta", *SEEDED, *OWN)}
        traces = {str(p.relative_to(home(db))): p.read_bytes() for p in sorted(trace_dir(db).rglob("*.npz"))}
    return Bundle(task.code, task.session_id, {t: rows for t, rows in tables.items() if rows}, traces)


def store_bundle(store, bundle: Bundle) -> None:
    """Write a bundle into the study: its traces durably, checked against the SHA-256s its rows
    hold, then all its rows in one transaction. A session already stored is refused (a
    participant stored twice would be a bug, never a second sample)."""
    if session_exists(store, bundle.session_id):
        raise StoreError(f"session {bundle.session_id} of {bundle.code} is already in {store.path}; not stored twice")
    named = {}
    for table in ("trials", "discrimination"):
        for row in bundle.tables.get(table, []):
            for key in ("trace_path", "trace_path_1", "trace_path_2"):
                if row.get(key):
                    named[row[key]] = row[key.replace("path", "sha256")]
    for rel, data in bundle.traces.items():
        if rel in named and hashlib.sha256(data).hexdigest() != named[rel]:
            raise StoreError(f"{rel}: the trace of {bundle.code} came back changed (SHA-256 differs); nothing stored")
    missing = sorted(set(named) - set(bundle.traces))
    if missing:
        raise StoreError(f"{missing[0]}: the trace of {bundle.code} did not come back; nothing stored")
    try:
        for rel, data in bundle.traces.items():  # before the rows: a crash leaves at worst unreferenced files
            write_durably(store.file.parent / rel, data)
    except OSError as exc:
        raise StoreError(f"{store.file.parent}: cannot write the traces of {bundle.code}: {exc.strerror}") from None
    order = [t for t in FIRST if t in bundle.tables] + sorted(t for t in bundle.tables if t not in FIRST)
    with store.transaction():
        for table in order:
            rows = bundle.tables[table]
            if table in NEW_IDS:
                rows = [{k: v for k, v in r.items() if k != "id"} for r in rows]
            store.db[table].insert_all(rows)
