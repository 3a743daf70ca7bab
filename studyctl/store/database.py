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
import os
import re
import shlex
import sqlite3
from pathlib import Path

import sqlite_utils

from analysis.errors import StoreError
from studyctl.protocol import load_protocol, protocol_from_text

SCHEMA_VERSION = 10
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
    """Question kinds (analysis/study/questions.py): an answer keeps its type (integer, real or text:
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


def _migration_10(db: sqlite_utils.Database) -> None:
    """Each discrimination trial's servo events (JSON: kind to count, its two intervals summed), as
    an ordinary trial's: what a condition's faults are counted from (analysis/statistics/faults.py). Older
    trials recorded none (NULL: counted as a trial without events)."""
    db["discrimination"].add_column("events", str)


MIGRATIONS = {1: _migration_1, 2: _migration_2, 3: _migration_3, 4: _migration_4, 5: _migration_5, 6: _migration_6, 7: _migration_7,
              8: _migration_8, 9: _migration_9, 10: _migration_10}


STUDY_TABLES = ("meta", "study")  # what makes a file a study database (with meta.schema_version)


def _tables(conn: sqlite3.Connection) -> list[str]:
    return [r[0] for r in conn.execute("select name from sqlite_master where type = 'table' order by name")]


def cannot_write(path: Path) -> str | None:
    """Why this process cannot write the database file `path` (its permissions, the immutable
    flag, a read-only disk, a folder that takes no side file), or None where it can. Asked of the
    kernel (statvfs, access), never by opening the file: closing any descriptor of a file drops
    every POSIX lock this process holds on it, an open SQLite connection's included."""
    if os.statvfs(path).f_flag & os.ST_RDONLY:
        return "read-only file system"
    if not os.access(path, os.W_OK, effective_ids=os.access in os.supports_effective_ids):
        # the kernel refuses an immutable file's write to root too; its mode then allows it
        return "operation not permitted" if os.geteuid() == 0 and os.stat(path).st_mode & 0o200 else "permission denied"
    if not os.access(path.parent, os.W_OK | os.X_OK):
        return f"its folder {path.parent} takes no new file"
    return None


def _open_read(path: Path) -> sqlite3.Connection:
    """A connection that only reads (query_only) and leaves no side file behind. Where a -wal or
    -shm is there already (someone has it open, or was killed): read-only, reading the last
    writes through them and merging nothing. Else, where this process can write the file:
    read-write, so closing it removes the -wal and -shm it made as a writer's close does (a
    read-only connection would leave them); where it cannot (permissions, the immutable flag, a
    read-only disk): immutable, which makes no side file and misses nothing, as nobody writes it."""
    side = any(path.with_name(path.name + s).exists() for s in ("-wal", "-shm"))
    writable = cannot_write(path) is None
    modes = ("ro", "rw") if side else ("rw", "immutable")
    modes = tuple(m for m in modes if m != "rw" or writable)
    uri = path.as_uri()
    for mode in modes:
        conn = None
        try:
            conn = sqlite3.connect(uri + ("?immutable=1" if mode == "immutable" else f"?mode={mode}"), uri=True, isolation_level=None)
            conn.execute("PRAGMA query_only = ON")
            conn.execute("select count(*) from sqlite_master").fetchone()
            return conn
        except BaseException as exc:
            if conn is not None:
                conn.close()  # opened but unusable: closed now, not left to the garbage collector
            if mode != modes[-1] and isinstance(exc, sqlite3.OperationalError):
                continue
            if mode == "ro" and isinstance(exc, sqlite3.OperationalError) and _has_wal(path):
                raise StoreError(f"{path}: its last writes are still in {path.name}-wal, which cannot be read here (a read-only "
                                 "disk); copy the database with its -wal file to a writable folder") from None
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


def _shown(value) -> str:
    text = repr(value)
    return text if len(text) <= 40 else text[:37] + "..."


class Store:
    """An open study database.

    mode "write" (the default) opens a study database of this software's schema for writing
    (WAL); "read" opens it to read only: it changes nothing and leaves no side file, so reports
    work on a read-only copy; "create" may also start a new one in a new or empty file;
    "migrate" opens one of an older schema for `migrate_study`, the only code that upgrades one.
    Refused before anything is written: a file that is not a study database (inspected
    read-only first), a schema_version this software does not read, an older schema (but for
    "migrate"), and a file this process cannot write (but for "read"). `path` is the database as
    named (for messages); `file` the file itself, a link resolved once here: its traces and
    locks live beside it.
    """

    def __init__(self, path: str | Path, create: bool = False, mode: str = "write"):
        self.path = Path(path)
        self.file = Path(os.path.realpath(self.path))
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
        if kind != "missing" and not self.read_only and (why := cannot_write(self.file)) is not None:
            raise StoreError(f"{self.path}: read-only ({why}); nothing was written"
                             + ("; reports and exports still work on it" if kind == "study" else ""))
        try:
            if self.read_only:
                conn = _open_read(self.file)
            else:
                conn = sqlite3.connect(str(self.file), timeout=30.0, isolation_level=None)
            try:
                conn.execute("PRAGMA busy_timeout = 30000")  # wait for another writer rather than fail
                self.db = sqlite_utils.Database(conn)
                self.version = self._version() if kind == "study" else 0
                if kind == "study" and self.version < SCHEMA_VERSION and mode != "migrate":
                    raise StoreError(f"{self.path}: schema version {self.version}, this studyctl needs {SCHEMA_VERSION}; run "
                                     f"`studyctl study migrate --db {shlex.quote(str(self.path))}` (it backs up the file first, "
                                     "then upgrades it whole or not at all)")
                if not self.read_only:
                    conn.execute("PRAGMA foreign_keys = ON")
                if mode in ("write", "create"):
                    self.db.enable_wal()
                    self._upgrade()  # a new file: its whole schema at once; a study of this schema: nothing
            except BaseException:
                conn.close()  # now, so the WAL side files go with it
                raise
        except sqlite3.OperationalError as exc:
            if "readonly" in str(exc) or "unable to open" in str(exc):
                raise StoreError(f"{self.path}: cannot write here ({exc}); nothing was written") from None
            raise StoreError(f"{self.path}: not a study database ({exc})") from None
        except sqlite3.DatabaseError as exc:
            raise StoreError(f"{self.path}: not a study database ({exc})") from None

    def _version(self) -> int:
        """meta.schema_version, refused unless a version this software reads (1..SCHEMA_VERSION)."""
        row = self.db.execute("select value from meta where key = 'schema_version'").fetchone()
        value = row[0] if row else None
        number = int(value) if isinstance(value, (int, str)) and re.fullmatch(r"[0-9]{1,9}", str(value)) else None
        if number is not None and 1 <= number <= SCHEMA_VERSION:
            return number
        newer = number is not None and number > SCHEMA_VERSION
        raise StoreError(f"{self.path}: schema_version {_shown(value)} is not a version this studyctl reads (1..{SCHEMA_VERSION})"
                         + ("; a newer studyctl wrote it: update studyctl" if newer else ""))

    def _upgrade(self) -> None:
        """Every step from this file's schema to this software's in one transaction (DDL
        included): all of them, or (on an error or Ctrl-C) none."""
        if self.version == SCHEMA_VERSION:
            return
        with self.transaction() as conn:
            if "meta" not in self.db.table_names():
                self.db["meta"].create({"key": str, "value": str}, pk="key")
            for v in range(self.version + 1, SCHEMA_VERSION + 1):
                MIGRATIONS[v](self.db)
            conn.execute("insert or replace into meta (key, value) values ('schema_version', ?)", (str(SCHEMA_VERSION),))
        self.version = SCHEMA_VERSION

    def backup(self, to: Path) -> None:
        """A consistent copy of the whole database in a new file `to` (SQLite's online backup)."""
        copy = sqlite3.connect(to)
        try:
            self.db.conn.backup(copy)
        finally:
            copy.close()

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


def migrate_study(db_path: str | Path) -> dict:
    """Bring a study database of older software to this schema, the one command that does: a
    backup copy first (beside the file, `NAME.schema-K.bak`, never overwritten), then every step
    in one transaction. Whole or not at all: on any failure (Ctrl-C included) the database is as
    it was and the backup is removed. A database of this schema is left alone."""
    with Store(db_path, mode="migrate") as store:
        before = store.version
        out = {"db": str(db_path), "from": before, "to": SCHEMA_VERSION, "backup": None}
        if before == SCHEMA_VERSION:
            return out
        backup = store.file.with_name(f"{store.file.name}.schema-{before}.bak")
        if backup.exists() or backup.is_symlink():
            raise StoreError(f"{backup}: a backup is there already (never overwritten); move it away, then migrate again")
        try:
            store.backup(backup)
            store._upgrade()
            store.db.enable_wal()
        except BaseException as exc:
            backup.unlink(missing_ok=True)  # the database is as it was: nothing to keep a copy of
            if isinstance(exc, sqlite3.Error):
                raise StoreError(f"{db_path}: migrating schema {before} to {SCHEMA_VERSION} failed ({exc}); nothing was changed") from None
            raise
        return {**out, "backup": str(backup)}


def dumps(obj) -> str:
    return json.dumps(obj, separators=(",", ":"))
