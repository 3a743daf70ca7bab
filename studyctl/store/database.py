"""The study database: SQLite through sqlite-utils, versioned schema, WAL, one commit per event.

Every answer and every trial is committed when it happens, so a crash loses at most the trial
in flight. Participants are stored under a pseudonymous code; identifying details (name,
contact) live only in the `identities` table, which no export and no report reads.
"""

from __future__ import annotations

import contextlib
import datetime as dt
import hashlib
import json
import sqlite3
from pathlib import Path

import sqlite_utils

from analysis.errors import StoreError
from studyctl.protocol import load_protocol, protocol_from_text

SCHEMA_VERSION = 9
EXPORT_TABLES = ("participants", "schedule", "sessions", "conditions", "trials", "answers", "latency", "events", "consent", "corrections",
                 "observer_features", "rig_profile",
                 "discrimination", "synthetic_traits", "participant_fields")
IDENTIFYING_TABLES = ("identities",)


def now() -> str:
    return dt.datetime.now(dt.UTC).isoformat(timespec="milliseconds")


def _migration_1(db: sqlite_utils.Database) -> None:
    db["study"].create({"id": int, "name": str, "protocol_path": str, "protocol_text": str, "protocol_sha256": str, "created_at": str}, pk="id")
    db["participants"].create({"code": str, "age": int, "synthetic": int, "created_at": str}, pk="code")
    db["identities"].create({"code": str, "name": str, "contact": str}, pk="code", foreign_keys=[("code", "participants", "code")])
    db["schedule"].create(
        {"code": str, "slot_start": str, "slot_end": str, "order_index": int, "conditions": str},
        pk="code", foreign_keys=[("code", "participants", "code")],
    )
    db["sessions"].create(
        {"id": int, "code": str, "started_at": str, "finished_at": str, "status": str, "synthetic": int,
         "device": str, "protocol_sha256": str, "scene_sha256": str, "software_version": str, "conditions": str},
        pk="id", foreign_keys=[("code", "participants", "code")],
    )
    db["conditions"].create(
        {"session_id": int, "position": int, "model": str, "status": str},
        pk=("session_id", "position"), foreign_keys=[("session_id", "sessions", "id")],
    )
    db["trials"].create(
        {"session_id": int, "model": str, "trial": int, "started_at": str, "ended_at": str, "max_force_n": float,
         "deformation_ms_mean": float, "deformation_ms_p99": float, "tick_interval_p99_us": float,
         "read_to_force_us": float, "tick_compute_us": float, "events": str},
        pk=("session_id", "model", "trial"), foreign_keys=[("session_id", "sessions", "id")],
    )
    db["answers"].create(
        {"code": str, "model": str, "item": str, "answer": int, "session_id": int, "source": str, "answered_at": str},
        pk=("code", "model", "item"), foreign_keys=[("code", "participants", "code")],
    )
    db["latency"].create(
        {"session_id": int, "model": str, "trial": int, "measure": str, "value": float},
        pk=("session_id", "model", "trial", "measure"),
    )
    db["events"].create({"id": int, "session_id": int, "at": str, "kind": str, "detail": str}, pk="id")


def _migration_2(db: sqlite_utils.Database) -> None:
    """Blind condition labels; what started each trial; the per-tick trace file of each trial."""
    db["conditions"].add_column("label", str)
    for col, kind in (("grasped", int), ("started_by", str), ("waited_s", float), ("trace_path", str), ("trace_sha256", str), ("trace_ticks", int)):
        db["trials"].add_column(col, kind)


def _migration_3(db: sqlite_utils.Database) -> None:
    """Withdrawal, consent records, and the audit trail of corrected answers."""
    db["participants"].add_column("withdrawn_at", str)
    db["participants"].add_column("withdrawal", str)  # what was done with their data: kept or deleted
    db["consent"].create({"code": str, "version": str, "given_on": str, "recorded_at": str, "recorded_by": str},
                         pk="code", foreign_keys=[("code", "participants", "code")])
    db["corrections"].create({"id": int, "code": str, "model": str, "item": str, "old_answer": int, "new_answer": int,
                              "reason": str, "corrected_at": str, "corrected_by": str}, pk="id")


def _migration_4(db: sqlite_utils.Database) -> None:
    """What the synthetic observer perceived of each participant's condition (studyctl/synthetic/observer.py)."""
    db["sessions"].add_column("seed", int)  # a synthetic session's seed: a resume must draw the same participant
    db["observer_features"].create({"code": str, "model": str, "feature": str, "value": float, "session_id": int, "computed_at": str},
                                   pk=("code", "model", "feature"), foreign_keys=[("code", "participants", "code")])


def _migration_5(db: sqlite_utils.Database) -> None:
    """Conditions are named model configurations: each session's conditions keep the resolved one
    (JSON) and its SHA-256 (studyctl/conditions.py). Older sessions ran the scene's own."""
    db["conditions"].add_column("config", str)
    db["conditions"].add_column("config_sha256", str)


def _migration_6(db: sqlite_utils.Database) -> None:
    """Question kinds (analysis/questions.py): an answer keeps its type (integer, real or text:
    the column has no type affinity) and may follow a trial (`trial`, -1 when it does not); a
    session's answers (when = "end") have condition "". Corrections likewise."""
    db.execute("create table answers_6 (code text references participants(code), model text, item text, "
               "trial integer not null default -1, answer, session_id integer, source text, answered_at text, "
               "primary key (code, model, item, trial))")
    db.execute("insert into answers_6 select code, model, item, -1, answer, session_id, source, answered_at from answers")
    db.execute("drop table answers")
    db.execute("alter table answers_6 rename to answers")
    db.execute("create table corrections_6 (id integer primary key, code text, model text, item text, trial integer not null default -1, "
               "old_answer, new_answer, reason text, corrected_at text, corrected_by text)")
    db.execute("insert into corrections_6 select id, code, model, item, -1, old_answer, new_answer, reason, corrected_at, corrected_by "
               "from corrections")
    db.execute("drop table corrections")
    db.execute("alter table corrections_6 rename to corrections")


def _migration_7(db: sqlite_utils.Database) -> None:
    """Rig profiles (studyctl/synthetic/rig.py): each configuration's measured frame time, which the
    study's synthetic participants perceive as latency."""
    db["rig_profile"].create({"key": str, "condition": str, "model": str, "frame_ms_p50": float, "frame_ms_p95": float, "frames": int,
                              "machine": str, "measured_at": str, "source": str}, pk="key")


def _migration_8(db: sqlite_utils.Database) -> None:
    """Discrimination trials (studyctl/tasks.py): per trial the increment tried, which interval
    held the comparison, the answer, the procedure's state after it and both intervals' traces;
    and each synthetic participant's generating traits (so that estimates can be checked)."""
    db["discrimination"].create(
        {"session_id": int, "code": str, "model": str, "task": int, "trial": int, "reference": float, "delta": float,
         "comparison": float, "comparison_interval": int, "answer": int, "correct": int, "state": str, "source": str,
         "started_at": str, "answered_at": str, "trace_path_1": str, "trace_sha256_1": str, "trace_path_2": str, "trace_sha256_2": str},
        pk=("session_id", "model", "task", "trial"), foreign_keys=[("session_id", "sessions", "id")])
    db["synthetic_traits"].create({"code": str, "trait": str, "value": float, "seed": int},
                                  pk=("code", "trait"), foreign_keys=[("code", "participants", "code")])


def _migration_9(db: sqlite_utils.Database) -> None:
    """Participant fields (studyctl/fields.py): one row per participant and field the protocol
    declares, the value as given (typed on read by the field's kind; the column has no type
    affinity). Never identifying: characteristics such as experience, kept with the code."""
    db.execute("create table participant_fields (code text not null references participants(code), field text not null, value, "
               "primary key (code, field))")


MIGRATIONS = {1: _migration_1, 2: _migration_2, 3: _migration_3, 4: _migration_4, 5: _migration_5, 6: _migration_6, 7: _migration_7,
              8: _migration_8, 9: _migration_9}


STUDY_TABLES = ("meta", "study")  # what makes a file a study database (with meta.schema_version)


class _Outdated(Exception):
    def __init__(self, version: int):
        self.version = version


def _tables(conn: sqlite3.Connection) -> list[str]:
    return [r[0] for r in conn.execute("select name from sqlite_master where type = 'table' order by name")]


def _open_read(path: Path) -> sqlite3.Connection:
    """A connection that only reads. Read-write with `query_only` where the file allows it, so
    closing it removes the WAL side files as a writer would (a read-only connection leaves them
    behind); read-only where the file or folder is read-only; immutable where even the WAL index
    cannot be made (a read-only mount: nobody can write there while we read)."""
    uri = path.resolve().as_uri()
    for mode in ("rw", "ro", "immutable"):
        if mode == "immutable" and _has_wal(path):  # immutable would read it without its last writes
            raise StoreError(f"{path}: its last writes are still in {path.name}-wal, which cannot be read here (a read-only "
                             "disk); copy the database with its -wal file to a writable folder")
        conn = None
        try:
            conn = sqlite3.connect(uri + ("?immutable=1" if mode == "immutable" else f"?mode={mode}"), uri=True, isolation_level=None)
            conn.execute("PRAGMA query_only = ON")
            conn.execute("select count(*) from sqlite_master").fetchone()
            return conn
        except BaseException as exc:
            if conn is not None:
                conn.close()  # opened but unusable: closed now, not left to the garbage collector
            if mode == "immutable" or not isinstance(exc, sqlite3.OperationalError):
                raise
    raise AssertionError("unreachable")


def _has_wal(path: Path) -> bool:
    wal = path.with_name(path.name + "-wal")
    return wal.exists() and wal.stat().st_size > 0


def inspect(path: str | Path) -> tuple[str, list[str]]:
    """('missing' | 'empty' | 'study' | 'foreign', tables) of a file, read without changing it.

    The first look is `immutable`: no lock, no side file, no checkpoint, so another program's
    file (even one with a WAL it has not merged) is left exactly as it was. Only a file whose
    main part shows no tables but has a WAL is looked at again, read-only."""
    path = Path(path)
    if not path.exists():
        return "missing", []
    if path.is_dir():
        raise StoreError(f"{path}: is a folder, not a study database")
    if path.stat().st_size == 0:
        return "empty", []
    uri = path.resolve().as_uri()
    try:
        conn = sqlite3.connect(uri + "?immutable=1", uri=True, isolation_level=None)
        try:
            tables = _tables(conn)
            if not tables and _has_wal(path):
                conn.close()
                conn = sqlite3.connect(uri + "?mode=ro", uri=True, isolation_level=None)
                tables = _tables(conn)
            if not tables:
                return "empty", []
            if set(STUDY_TABLES) <= set(tables) and conn.execute("select value from meta where key = 'schema_version'").fetchone():
                return "study", tables
            return "foreign", tables
        finally:
            conn.close()
    except sqlite3.DatabaseError as exc:
        raise StoreError(f"{path}: not a study database ({exc})") from None


class Store:
    """An open study database.

    mode "write" (the default) opens an existing study database for writing (WAL, migrations);
    "read" opens it read-only and changes nothing, so reports work on a read-only copy;
    "create" may also start a new one in a new or empty file. A file that is not a study
    database is never changed: it is inspected read-only first.
    """

    def __init__(self, path: str | Path, create: bool = False, mode: str = "write"):
        try:
            self._open(path, create, mode)
        except _Outdated as old:
            # a database of older software: upgrade it once (its data unchanged), then read
            try:
                Store(path).close()
            except StoreError:
                raise StoreError(f"{path}: schema version {old.version} needs an upgrade to {SCHEMA_VERSION}, which cannot be "
                                 "written here; copy it to a writable folder and run `studyctl status` there") from None
            self._open(path, create, mode)

    def _open(self, path: str | Path, create: bool, mode: str) -> None:
        self.path = Path(path)
        mode = "create" if create else mode
        self.read_only = mode == "read"
        kind, tables = inspect(self.path)
        if kind == "missing" and mode != "create":
            raise StoreError(f"{self.path}: no such study database; create it with `studyctl study init`")
        if kind == "missing" and not self.path.parent.is_dir():
            raise StoreError(f"{self.path}: cannot create: {self.path.parent} is not an existing folder")
        if kind == "empty" and mode != "create":
            raise StoreError(f"{self.path}: an empty file, not a study database; run `studyctl study init`")
        if kind == "foreign":
            shown = ", ".join(tables[:5]) + (", ..." if len(tables) > 5 else "")
            raise StoreError(f"{self.path}: not a study database (it holds other tables: {shown}); nothing was changed")
        try:
            if self.read_only:
                conn = _open_read(self.path)
            else:
                conn = sqlite3.connect(str(self.path), timeout=30.0, isolation_level=None)
            try:
                conn.execute("PRAGMA busy_timeout = 30000")  # wait for another writer rather than fail
                self.db = sqlite_utils.Database(conn)
                if self.read_only:
                    self._check_version()
                else:
                    if kind == "study" and self._version() > SCHEMA_VERSION:  # refused before WAL is switched on
                        self._check_version()
                    conn.execute("PRAGMA foreign_keys = ON")
                    self.db.enable_wal()
                    self._migrate()
            except BaseException:
                conn.close()  # now, so the WAL side files go with it
                raise
        except sqlite3.OperationalError as exc:
            if "readonly" in str(exc) or "unable to open" in str(exc):
                raise StoreError(f"{self.path}: cannot write here ({exc}); reports and exports still work on it") from None
            raise StoreError(f"{self.path}: not a study database ({exc})") from None
        except sqlite3.DatabaseError as exc:
            raise StoreError(f"{self.path}: not a study database ({exc})") from None

    def _version(self) -> int:
        row = self.db.execute("select value from meta where key = 'schema_version'").fetchone()
        return int(row[0]) if row else 0

    def _check_version(self) -> None:
        version = self._version()
        if version > SCHEMA_VERSION:
            raise StoreError(f"{self.path}: schema version {version} is newer than this software's ({SCHEMA_VERSION}); update studyctl")
        if version < SCHEMA_VERSION:
            raise _Outdated(version)

    def _migrate(self) -> None:
        db = self.db
        if "meta" not in db.table_names():
            db["meta"].create({"key": str, "value": str}, pk="key")
        row = db.execute("select value from meta where key = 'schema_version'").fetchone()
        version = int(row[0]) if row else 0
        if version > SCHEMA_VERSION:
            raise StoreError(f"{self.path}: schema version {version} is newer than this software's ({SCHEMA_VERSION})")
        for v in range(version + 1, SCHEMA_VERSION + 1):
            with self.transaction() as conn:  # one transaction per migration (DDL included)
                MIGRATIONS[v](db)
                conn.execute("insert or replace into meta (key, value) values ('schema_version', ?)", (str(v),))

    def close(self) -> None:
        self.db.conn.close()  # a second close does nothing

    def __enter__(self) -> Store:
        return self

    def __exit__(self, *exc_info) -> None:
        self.close()  # returns None: an exception in the block goes on

    # -- one committed write per event ------------------------------------------------------
    def write(self, table: str, record: dict, pk=None, replace: bool = False) -> None:
        """One row, committed now (sqlite-utils runs each insert in its own transaction)."""
        if replace:
            self.db[table].upsert(record, pk=pk)
        else:
            self.db[table].insert(record, pk=pk)

    @contextlib.contextmanager
    def transaction(self, dry_run: bool = False):
        """Everything written inside is committed together, or (on an error, or `dry_run`) none of it."""
        conn = self.db.conn
        conn.execute("BEGIN IMMEDIATE")
        try:
            yield conn
        except BaseException:
            conn.execute("ROLLBACK")
            raise
        conn.execute("ROLLBACK" if dry_run else "COMMIT")

    def write_many(self, table: str, records: list[dict], pk=None) -> None:
        """All rows or none, in one transaction."""
        with self.transaction():
            self.db[table].insert_all(records, pk=pk)

    def rows(self, sql: str, params=()) -> list[dict]:
        cur = self.db.execute(sql, params)
        cols = [c[0] for c in cur.description]
        return [dict(zip(cols, r)) for r in cur.fetchall()]

    # -- study ------------------------------------------------------------------------------
    def study(self) -> dict:
        rows = self.rows("select * from study order by id limit 1")
        if not rows:
            raise StoreError(f"{self.path}: no study in this database; run `studyctl study init`")
        return rows[0]

    def protocol(self):
        s = self.study()
        return protocol_from_text(s["protocol_text"], s["protocol_path"])

    def event(self, session_id: int | None, kind: str, detail: str = "") -> None:
        self.write("events", {"session_id": session_id, "at": now(), "kind": kind, "detail": detail}, pk="id")


def sha256_file(path: str | Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def init_study(db_path: str | Path, protocol_path: str | Path) -> dict:
    protocol = load_protocol(protocol_path)
    with Store(db_path, create=True) as store:
        if store.rows("select id from study"):
            raise StoreError(f"{db_path}: already holds a study ({store.study()['name']})")
        store.write("study", {"name": protocol.name, "protocol_path": str(Path(protocol_path).resolve()), "protocol_text": protocol.text,
                              "protocol_sha256": protocol.sha256, "created_at": now()}, pk="id")
        return {"db": str(db_path), "study": protocol.name, "protocol_sha256": protocol.sha256, "schema_version": SCHEMA_VERSION}


def dumps(obj) -> str:
    return json.dumps(obj, separators=(",", ":"))
