"""Answers given on paper: imported from a CSV into the study, each checked against its question's kind."""

from __future__ import annotations

import re
from pathlib import Path

from analysis.errors import InputError
from analysis.study.csvfiles import read_csv
from analysis.study.questions import NOT_PER_TRIAL, SESSION, AnswerError, Kind, allowed, parse_answer
from sim.text import quoted
from studyctl.store import Store, lab_records, now, roster


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
        consented = lab_records.consented_codes(store, protocol.consent_version)
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
                         + (", ".join(protocol.conditions) if q.kind == Kind.CHOICE else allowed(q))) from None
    return (SESSION if q.when == "end" else model), trial, value
