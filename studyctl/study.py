"""Participants, scheduling, paper answers and exports of a study database."""

from __future__ import annotations

import datetime as dt
import json
import re
from pathlib import Path

import pandas as pd

from analysis.csvfiles import read_csv
from analysis.errors import InputError, StoreError
from analysis.questions import NOT_PER_TRIAL, SESSION, AnswerError, allowed, parse_answer
from analysis.reports.formatting import spreadsheet_frame
from sim.text import NAME_MOST, TITLE_MOST, quoted, text_problem
from studyctl.fields import field_rows, parse_fields
from studyctl.outputs import Staged, refuse_existing, write_file
from studyctl.schedule import allocate, next_order, read_availability, to_ics, williams
from studyctl.session.traces import traces_frame
from studyctl.store import EXPORT_TABLES, Store, now, roster
from studyctl.store.participant_fields import group_of
from studyctl.store.tables import table_rows

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


def assign_order(store: Store, protocol, code: str) -> list[str]:
    """The participant's condition order: the stored one, else the next Williams row. With
    groups (design.groups), the rows are counted within the participant's group, so that each
    group is balanced on its own."""
    stored = roster.stored_order(store, code)
    if stored:
        return json.loads(stored)
    group = group_of(store, protocol, code)
    # with groups, the same group: its members' rows only
    completed = roster.completed_orders(store, protocol.groups, group)
    assigned = roster.assigned_orders(store, protocol.groups, group)
    k = next_order(protocol.conditions, completed, assigned)
    order = [protocol.conditions[i] for i in williams(len(protocol.conditions))[k]]
    # plain SQL, so the caller's transaction (if any) holds it
    roster.save_order(store.db.conn, code, k, json.dumps(order))
    return order


def schedule_study(db: str | Path, start: str, end: str, hours: str = "09:00-17:00", minutes: int = 45,
                   availability: str | Path | None = None, ics: str | Path | None = None, dry_run: bool = False,
                   today: dt.date | None = None, force: bool = False) -> list[dict]:
    """Slots and counterbalanced orders for every waiting participant, all stored or none
    (`dry_run`: none, the proposal is returned); `ics`, a calendar of the slots, is refused
    before anything is stored where it exists (unless `force`), and written whole or not at all."""
    if ics and not dry_run:
        refuse_existing([ics], force, inputs={"--db": db, "--availability": availability}, option="--ics")
    try:
        d0, d1 = dt.date.fromisoformat(start), dt.date.fromisoformat(end)
    except ValueError:
        raise InputError("--start/--end: dates must be YYYY-MM-DD") from None
    today = today or dt.date.today()
    if d0 < today:
        raise InputError(f"--start: {d0} is in the past; allowed: today ({today}) or later")
    if (d1 - d0).days > 366:
        raise InputError(f"--end: {d1} is more than a year after --start; allowed: at most 366 days")
    avail = read_availability(availability) if availability else None
    with Store(db) as store:
        protocol = store.protocol()
        codes = roster.participant_codes(store)
        if avail is not None and set(avail) - codes:
            raise InputError(f"{availability}: unknown participant {sorted(set(avail) - codes)[0]!r}")
        # people who still need the rig: no slot, not withdrawn, no finished session, no answers from paper
        waiting = roster.waiting_codes(store)
        if not waiting:
            raise InputError("nobody is waiting for a slot (every person has one, has finished, or withdrew)")
        taken = [(dt.datetime.fromisoformat(r["slot_start"]), dt.datetime.fromisoformat(r["slot_end"]))
                 for r in roster.taken_slots(store)]
        if d0 == today:  # the part of today that has passed is taken too
            taken.append((dt.datetime.combine(today, dt.time(0)), dt.datetime.now().replace(second=0, microsecond=0)))
        slots = allocate(waiting, d0, d1, hours, minutes, avail, taken)
        if not slots:
            why = "their availability" if avail is not None else "free rig time"
            raise InputError(f"no slot for any of the {len(waiting)} waiting participants: {start}..{end}, weekdays {hours}, "
                             f"{minutes} min each, has no {why} left; widen --start/--end or --hours")
        with store.transaction(dry_run) as conn:
            for code in waiting:
                assign_order(store, protocol, code)  # counterbalanced order, kept with the slot
                if code in slots:
                    a, b = slots[code]
                    roster.set_slot(conn, code, a.isoformat(), b.isoformat())
            out = roster.schedule_rows(store)
            if ics and not dry_run:
                write_file(ics, to_ics([r for r in out if r["slot_start"]], protocol.name, protocol.timezone, protocol.title), force,
                           inputs={"--db": db, "--availability": availability}, option="--ics")
        return out


def import_answers(db: str | Path, csv_path: str | Path, dry_run: bool = False) -> dict:
    """Long format participant,model,item,answer[,trial], e.g. a study run on paper: each answer
    as its question's kind allows (yes/no, a rating, 0..100, a condition's name, text); `model`
    empty for a question asked once at the end, `trial` (0-based) only for one asked after every
    trial. Unknown participants, models or items, or a bad answer, reject the whole file."""
    csv_path = Path(csv_path)
    with Store(db) as store:
        protocol = store.protocol()
        codes = roster.participant_codes(store)
        synthetic = roster.synthetic_codes(store)
        in_sessions = roster.session_codes(store)
        withdrawn = roster.withdrawn_codes(store)
        consented = roster.consented_codes(store, protocol.consent_version)
        rows = read_csv(csv_path, ("participant", "model", "item", "answer", "trial"), ("participant", "model", "item", "answer"))
        records, seen = [], set()
        for line, r in rows:
            where = f"{csv_path}: line {line}"
            if r["participant"] not in codes:
                raise InputError(f"{where}: unknown participant {r['participant']!r}")
            if r["participant"] in synthetic:
                raise InputError(f"{where}: participant {r['participant']} is synthetic; imported answers are a person's")
            if r["participant"] in withdrawn:
                raise InputError(f"{where}: participant {r['participant']} withdrew; no answers are added for them")
            if r["participant"] not in consented:
                raise InputError(f"{where}: participant {r['participant']}: no consent recorded; `studyctl participants consent {r['participant']}` first")
            if r["participant"] in in_sessions:
                raise InputError(f"{where}: participant {r['participant']} has a simulator session; importing would mix sources")
            model, trial, value = answer_key(protocol, r["item"], r["model"], r.get("trial"), r["answer"], lambda field, where=where: where)
            key = (r["participant"], model, r["item"], trial)
            if key in seen:
                raise InputError(f"{where}: a second answer for {'/'.join(map(str, key))}")
            seen.add(key)
            records.append({"code": key[0], "model": model, "item": key[2], "trial": trial, "answer": value,
                            "session_id": None, "source": "import", "answered_at": now()})
        existing = roster.answer_keys(store)
        clash = seen & existing
        if clash:
            raise InputError(f"{csv_path}: {'/'.join(map(str, sorted(clash)[0]))} is already answered in the database")
        if not records:
            raise InputError(f"{csv_path}: no answers (only a header)")
        if not dry_run:
            store.write_many("answers", records, pk=("code", "model", "item", "trial"))
        return {"imported": len(records), "dry_run": dry_run}


def answer_key(protocol, item: str, model: str, trial, raw, where) -> tuple[str, int, object]:
    """(condition, trial, typed value) of an answer given by hand (an import or a correction),
    checked against the question: its kind's values, a condition unless it is asked at the
    end (then none), a trial (0-based) only if it is asked after every trial. `where(field)`
    names the place of a field in messages (a file's line, or a command-line option)."""
    if item not in protocol.items:
        raise InputError(f"{where('item')}: unknown item {item!r}; allowed: {', '.join(protocol.items)}")
    q = protocol.question(item)
    model = (model or "").strip()
    if q.when == "end" and model:
        raise InputError(f"{where('model')}: item {item} is asked once at the end, about no one condition; leave the model empty (got {model!r})")
    if q.when != "end" and model not in protocol.conditions:
        raise InputError(f"{where('model')}: unknown model {model!r}; allowed: {', '.join(protocol.conditions)}")
    trial = (str(trial).strip() if trial is not None else "")
    if q.when == "trial":
        last = protocol.trials_per_condition - 1
        if not (re.fullmatch(r"[0-9]+", trial) and int(trial) <= last):
            raise InputError(f"{where('trial')}: item {item} is asked after every trial; trial {trial!r} is not allowed; allowed: 0..{last}")
        trial = int(trial)
    elif trial not in ("", str(NOT_PER_TRIAL)):
        raise InputError(f"{where('trial')}: item {item} is not asked per trial; leave trial empty (got {trial!r})")
    else:
        trial = NOT_PER_TRIAL
    try:
        value = parse_answer(q, raw, by_name=protocol.conditions)
    except AnswerError:
        raise InputError(f"{where('answer')}: answer {quoted(str(raw).strip())} to {item} ({q.kind}) is not allowed; allowed: "
                         + (", ".join(protocol.conditions) if q.kind == "choice" else allowed(q))) from None
    return (SESSION if q.when == "end" else model), trial, value


def export(db: str | Path, out_dir: str | Path, fmt: str = "csv", force: bool = False) -> Staged:
    """Every pseudonymous table, one file each, and every trial's per-tick trace (traces.csv or
    .parquet). The identities table is never exported. Everything is read (and every trace
    checked against its SHA-256) and converted before anything is written, the files are written
    to a temporary folder beside `out_dir` and moved in together (all or none); a file of the same
    name in `out_dir` is refused unless `force`. Returns the `Staged` folder (`.written`,
    `.replaced`)."""
    if fmt not in ("csv", "parquet"):
        raise InputError(f"--format: {fmt!r} is not csv or parquet")
    out_dir = Path(out_dir)
    tables = (*EXPORT_TABLES, "traces")
    # with force, an earlier export in either format goes whole; other files in the folder stay
    target = Staged(out_dir, force, folder=True, expect=[f"{t}.{fmt}" for t in tables], inputs={"--db": db},
                    own=[f"{t}.{f}" for t in tables for f in ("csv", "parquet")])
    if fmt == "parquet":
        _pyarrow()  # an optional extra: checked before anything is read or written
    with Store(db, mode="read") as store:
        # the columns from the schema, so an empty table still exports its header
        frames = {table: pd.DataFrame(table_rows(store, table), columns=list(store.db[table].columns_dict))
                  for table in EXPORT_TABLES}
        frames["traces"] = traces_frame(store)
    if fmt == "csv":  # text cells a spreadsheet would run as formulas are shown instead (docs/study.md)
        converted = {table: spreadsheet_frame(df).to_csv(index=False) for table, df in frames.items()}
    else:
        converted = {table: parquet_table(df) for table, df in frames.items()}
    with target as tmp:
        for table, data in converted.items():
            path = tmp / f"{table}.{fmt}"
            if fmt == "csv":
                path.write_text(data, encoding="utf-8")
            else:
                _pyarrow().parquet.write_table(data, path)
    return target


def parquet_table(df):
    """`df` as an Arrow table. A column holding text in some rows and numbers in others (the
    answers of a study that asks a text question) is written as text, a number as its digits
    (1 as "1"); the question's kind says how to read it (docs/study.md)."""
    df = df.copy()
    for col in [c for c in df.columns if df[c].dtype.kind == "O"]:
        kinds = {type(v) for v in df[col] if v is not None and v == v}
        if len(kinds) > 1 and not kinds <= {int, float}:
            df[col] = [None if v is None or v != v else str(v) for v in df[col]]
    return _pyarrow().Table.from_pandas(df, preserve_index=False)


def _pyarrow():
    """pyarrow with its parquet module (the parquet extra), or a StoreError saying how to install
    it: absent, or installed and failing to import (a missing shared library, a build for another
    NumPy), which raises ImportError or OSError from inside it."""
    try:
        import pyarrow.parquet  # optional: the parquet extra, only for --format parquet
    except ModuleNotFoundError as exc:
        if exc.name != "pyarrow":
            raise StoreError(_failed_import("pyarrow", exc)) from None
        raise StoreError("export --format parquet needs the parquet extra: pip install 'brainsim-study[parquet]'") from None
    except (ImportError, OSError) as exc:
        raise StoreError(_failed_import("pyarrow", exc)) from None
    return pyarrow


def _failed_import(name: str, exc: BaseException) -> str:
    reason = " ".join(str(exc).split())[:200] or type(exc).__name__  # one line, however long the loader's message
    return f"export --format parquet needs {name}, which failed to import: {reason}; pip install 'brainsim-study[parquet]'"
