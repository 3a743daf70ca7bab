"""The experimenter's everyday records: consent, withdrawal, the participant and session lists,
the study's status, corrected answers, cancelled slots, and the contact list.

Every function that writes takes `dry_run`: it checks and returns what it would do, writing
nothing. Writes are one transaction each, and each is logged in `events`.
"""

from __future__ import annotations

import csv
import datetime as dt
import getpass
import io
from pathlib import Path

from analysis.errors import InputError, StoreError
from analysis.reports.formatting import spreadsheet_safe
from analysis.study.questions import shown
from analysis.study.trace_files import trace_dir, trace_file
from sim.text import TEXT_MOST, text_problem
from studyctl.outputs import refuse_inputs, write_file
from studyctl.paper_answers import answer_key
from studyctl.session.lock import SessionRunning, session_lock
from studyctl.store import Store, lab_records, now, roster, snapshot
from studyctl.store import sessions as session_rows
from studyctl.store.participant_fields import read_fields


def _person(store: Store, code: str) -> dict:
    p = roster.person(store, code)
    if p is None:
        raise InputError(f"participant {code}: not registered")
    return p


def record_consent(db, code: str, given_on: str | None = None, version: str | None = None, dry_run: bool = False) -> dict:
    """Record that a person signed the protocol's consent form (version and date)."""
    with Store(db) as store:
        protocol = store.protocol()
        p = _person(store, code)
        if p["synthetic"]:
            raise InputError(f"participant {code}: synthetic participants give no consent")
        if p["withdrawn_at"]:
            raise InputError(f"participant {code}: withdrew on {p['withdrawn_at'][:10]}")
        version = version or protocol.consent_version
        if version != protocol.consent_version:
            raise InputError(f"--version: {version!r} is not the protocol's consent form ({protocol.consent_version!r})")
        try:
            day = dt.date.fromisoformat(given_on) if given_on else dt.date.today()
        except ValueError:
            raise InputError(f"--date: {given_on!r} is not a date (YYYY-MM-DD)") from None
        if day > dt.date.today():
            raise InputError(f"--date: {day} is in the future; allowed: today or earlier")
        created = dt.date.fromisoformat(store.study()["created_at"][:10])
        if day < created - dt.timedelta(days=366):
            raise InputError(f"--date: {day} is more than a year before the study was created ({created})")
        earlier = lab_records.consent_rows(store, code)
        if earlier:
            raise InputError(f"participant {code}: consent form {earlier[0]['version']} already recorded, signed {earlier[0]['given_on']}")
        row = {"code": code, "version": version, "given_on": day.isoformat(), "recorded_at": now(), "recorded_by": getpass.getuser()}

        with store.transaction(dry_run) as conn:
            lab_records.record_consent(conn, row, f"{code}: consent form {version} signed {day}")
        return {**row, "dry_run": dry_run}


def has_consent(store: Store, code: str, version: str) -> bool:
    return lab_records.has_consent(store, code, version)


def withdraw(db, code: str, reason: str = "", dry_run: bool = False) -> dict:
    """A participant withdraws: no further sessions or slots; their pseudonymous data is kept or
    deleted as the protocol's `ethics.withdrawal` says; their contact details are deleted.
    Refused while their session runs (it holds the session lock)."""
    if (problem := text_problem(reason, TEXT_MOST)) is not None:
        raise InputError(f"--reason: {problem}")
    # a missing, foreign, read-only or older database, an unknown code: refused before the lock is taken
    with Store(db) as store:
        _person(store, code)
    if dry_run:  # writes nothing, so needs no lock
        return _withdraw(db, code, reason, dry_run)
    try:
        with session_lock(db, code):
            return _withdraw(db, code, reason, dry_run)
    except SessionRunning:
        raise StoreError(f"participant {code}: their session is running now; stop it first, then withdraw") from None


def _withdraw(db, code: str, reason: str, dry_run: bool) -> dict:
    with Store(db) as store:
        protocol = store.protocol()
        p = _person(store, code)
        if p["withdrawn_at"]:
            raise InputError(f"participant {code}: already withdrew on {p['withdrawn_at'][:10]}")
        sessions = lab_records.session_ids(store, code)
        traces = lab_records.trace_paths(store, code)
        counts = lab_records.data_counts(store, code)
        delete = protocol.withdrawal == "delete"

        with store.transaction(dry_run) as conn:
            lab_records.withdraw_rows(conn, code, sessions, delete,
                                  f"{code}: data {'deleted' if delete else 'kept'} ({protocol.withdrawal} in the protocol)"
                                  + (f"; reason: {reason}" if reason else ""))
        if delete and not dry_run:  # the files after the rows: a crash between leaves files no row names
            for rel in traces:
                path = trace_file(store.path, rel)  # beside the link where older software wrote it
                path.unlink(missing_ok=True)
                if path.parent.is_dir() and not any(path.parent.iterdir()):
                    path.parent.rmdir()
            for sid in sessions:
                folder = trace_dir(store.file) / f"session-{sid:04d}"
                if folder.is_dir() and not any(folder.iterdir()):
                    folder.rmdir()
        return {"code": code, "data": ("deleted" if delete else "kept"), "sessions": counts["sessions"], "answers": counts["answers"],
                "traces": len(traces) if delete else 0, "dry_run": dry_run}


def cancel_slot(db, code: str, dry_run: bool = False) -> dict:
    """Free a participant's slot (keeping their condition order); `schedule` gives a new one."""
    with Store(db) as store:
        _person(store, code)
        slot = lab_records.slot_start(store, code)
        if slot is None:
            raise InputError(f"participant {code}: has no slot to cancel")

        with store.transaction(dry_run) as conn:
            lab_records.cancel_slot(conn, code, f"{code}: {slot}")
        return {"code": code, "cancelled": slot, "dry_run": dry_run}


def correct_answer(db, code: str, model: str, item: str, answer: str, reason: str, dry_run: bool = False, trial=None) -> dict:
    """Change one stored answer (a value its question's kind allows; `model` empty for one
    asked at the end, `trial` for one asked after every trial), keeping the old value, the
    reason and who did it in `corrections`."""
    if not reason.strip():
        raise InputError("--reason: say why the answer is corrected (it is kept in the audit trail)")
    if (problem := text_problem(reason, TEXT_MOST)) is not None:
        raise InputError(f"--reason: {problem}")
    with Store(db) as store:
        protocol = store.protocol()
        model, trial, new = answer_key(protocol, item, model, trial, answer, lambda field: f"--{field}")
        q = protocol.question(item)
        p = _person(store, code)
        if p["withdrawn_at"]:
            raise InputError(f"participant {code}: withdrew on {p['withdrawn_at'][:10]}; their answers are no longer corrected")
        if p["synthetic"]:
            raise InputError(f"participant {code}: synthetic answers come from the simulator and are not corrected by hand")
        key = (code, model, item, trial)
        stored = lab_records.stored_answer(store, key)
        if stored is None:
            raise InputError(f"participant {code}: no stored answer for model {model!r}, item {item!r}"
                             + (f", trial {trial}" if q.when == "trial" else ""))
        old = stored["answer"]
        if old == new:
            raise InputError(f"--answer: {'/'.join(x for x in (code, model, item) if x)} is already {shown(q, new)}")

        with store.transaction(dry_run) as conn:
            lab_records.correct_answer(conn, key, old, new, reason.strip(), getpass.getuser())
        return {"code": code, "model": model, "item": item, "trial": trial, "old": old, "new": new,
                "old_shown": shown(q, old), "new_shown": shown(q, new), "dry_run": dry_run}


def list_participants(db) -> list[dict]:
    """One row per participant (no identifying details): kind, age, their group (with
    design.groups), consent, slot, session state."""
    with Store(db, mode="read") as store:
        protocol = store.protocol()
        rows = lab_records.participant_list(store)
        if protocol.groups:
            fields = read_fields(store, protocol)
            rows = [{**r, "group": fields.get(r["code"], {}).get(protocol.groups)} for r in rows]
        return rows


def list_sessions(db) -> list[dict]:
    with Store(db, mode="read") as store:
        return lab_records.session_list(store)


def status(db, today: dt.datetime | None = None) -> dict:
    """Where the study stands: participants, sessions by state, progress to the target N, the
    next scheduled sessions. `complete` counts as Table 1's N and the banners do: `persons`,
    `synthetic` (mixed-source participants included) and `mixed` (how many of those synthetic
    have a person's answers too); `complete_withdrawn`: how many of the complete withdrew with
    their data kept (counted, as in the reports)."""
    with Store(db, mode="read") as store:
        protocol = store.protocol()
        people = lab_records.people_counts(store)
        sessions = lab_records.sessions_by_status(store)
        # complete: the reports' own rule and count (analysis.study.completeness): everyone whose answers the
        # study holds, withdrawn with their data kept included; a mixed-source participant counts as synthetic
        done = snapshot.completeness(store, protocol)
        withdrawn = roster.withdrawn_codes(store)
        moment = (today or dt.datetime.now()).isoformat(timespec="minutes")
        # a slot whose session is done is history, not what comes next
        upcoming = [r for r in lab_records.upcoming_slots(store, moment) if not session_rows.has_done_session(store, r["code"])]
        return {"study": protocol.name, "target_participants": protocol.target_participants, "participants": people,
                "sessions": sessions, "complete": {"persons": done.count("person"),
                                                   "synthetic": done.count("synthetic") + done.count("mixed"),
                                                   "mixed": done.count("mixed")},
                "complete_withdrawn": sum(1 for c in done.complete if c in withdrawn),
                "incomplete": list(done.incomplete),
                "answers": lab_records.answer_count(store), "next": upcoming}


CONTACTS_NOTE = ("# IDENTIFYING DATA: names and contact details of study participants, for the experimenter only.\n"
                 "# Keep it under the study's data-protection rules; never share it with the pseudonymous data.\n")


def export_contacts(db, out: str | Path, force: bool = False) -> dict:
    """The identifying table (code, name, contact) to a CSV whose first lines say what it is.
    Withdrawn participants' details were deleted when they withdrew. An existing file is refused
    unless `force` (studyctl/outputs.py); readable by the owner only (0600) from the start."""
    refuse_inputs({"--out": out}, {"--db": db})  # before the identifying table is read
    with Store(db, mode="read") as store:
        rows = lab_records.contacts(store)
    buf = io.StringIO()
    buf.write(CONTACTS_NOTE)
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["code", "name", "contact"])
    w.writerows([spreadsheet_safe(v) for v in (r["code"], r["name"] or "", r["contact"] or "")] for r in rows)
    path = Path(out)
    replaced = write_file(path, buf.getvalue(), force, mode=0o600, inputs={"--db": db})
    return {"file": str(path), "participants": len(rows), "replaced": [str(p) for p in replaced]}
