"""A store an experimenter can trust (issue 15): foreign and read-only databases, provenance,
the everyday commands (status, lists, consent, withdrawal, cancelled slots, corrected answers,
contacts, --dry-run), CSVs as spreadsheets save them, and reports on an empty study."""

import csv
import json
import sqlite3
import stat
import subprocess
from pathlib import Path

import pytest

from tests.helpers import PROTOCOL, fast_protocol, query, studyctl, tree_state


def test_a_foreign_sqlite_file_is_byte_identical_after_every_command(tmp_path):
    db = tmp_path / "other.db"
    con = sqlite3.connect(db)
    con.execute("create table foo (x)")
    con.execute("insert into foo values (42)")
    con.commit()
    con.close()
    (tmp_path / "p.csv").write_text("code\nP01\n")
    (tmp_path / "a.csv").write_text("participant,model,item,answer\nP01,fem,natural,yes\n")
    before = tree_state(tmp_path)
    commands = [
        ["participants", "add", "P01"], ["participants", "import", tmp_path / "p.csv"], ["participants", "list"],
        ["participants", "consent", "P01"], ["participants", "withdraw", "P01"], ["participants", "contacts", "--out", tmp_path / "c.csv"],
        ["answers", "import", tmp_path / "a.csv"],
        ["answers", "correct", "--participant", "P01", "--model", "fem", "--item", "natural", "--answer", "no", "--reason", "x"],
        ["schedule", "--start", "2037-12-01", "--end", "2037-12-04"], ["schedule", "cancel", "P01"],
        ["session", "run", "--participant", "P01", "--synthetic"], ["session", "list"], ["status"],
        ["synth", "--participants", "1"], ["replay", "--session", "1", "--trial", "1"],
        ["report", "table1"], ["report", "table1", "--format", "json"], ["report", "stats"], ["report", "plots", "--out", tmp_path / "plots"],
        ["export", "--out", tmp_path / "ex"], ["study", "init", "--protocol", PROTOCOL],
    ]
    for args in commands:
        res = studyctl(*args, "--db", db)
        assert res.exit_code == 1, (args, res.output)
        assert "not a study database (it holds other tables: foo)" in res.output, (args, res.output)
    assert tree_state(tmp_path) == before
    assert query(db, "select x from foo") == [(42,)]


def test_study_init_only_on_a_new_or_empty_file(tmp_path):
    (tmp_path / "empty.db").write_bytes(b"")
    assert studyctl("study", "init", "--protocol", PROTOCOL, "--db", tmp_path / "empty.db").exit_code == 0
    res = studyctl("study", "init", "--protocol", PROTOCOL, "--db", tmp_path / "no" / "dir.db")
    assert res.exit_code == 1
    assert "is not an existing folder" in res.output
    assert not (tmp_path / "no").exists()


@pytest.fixture
def read_only_copy(tmp_path):
    """A study on a read-only bind mount (as on a read-only share); skipped where mounting is
    not allowed. Root ignores file modes, so chmod would not test this."""
    src, mnt = tmp_path / "src", tmp_path / "ro"
    src.mkdir()
    mnt.mkdir()
    db = src / "s.db"
    studyctl("study", "init", "--protocol", fast_protocol(tmp_path, conditions=("plate_spring",), trials=1), "--db", db)
    studyctl("participants", "add", "S01", "--synthetic", "--db", db)
    assert studyctl("session", "run", "--participant", "S01", "--synthetic", "--db", db).exit_code == 0
    if subprocess.run(["mount", "--bind", "-o", "ro", str(src), str(mnt)], capture_output=True).returncode != 0:
        pytest.skip("cannot make a read-only mount here (needs root or CAP_SYS_ADMIN)")
    try:
        if _writable(mnt):
            pytest.skip("the bind mount is not read-only here")
        yield mnt / "s.db"
    finally:
        if subprocess.run(["umount", str(mnt)], capture_output=True).returncode != 0:
            subprocess.run(["umount", "-l", str(mnt)], check=False)  # busy: detach now, gone when released


def _writable(d: Path) -> bool:
    try:
        (d / ".probe").write_text("x")
    except OSError:
        return False
    (d / ".probe").unlink()
    return True


def test_a_read_only_study_reports_and_exports_but_refuses_writes(read_only_copy, tmp_path):
    db = read_only_copy
    for args in (["report", "table1"], ["report", "stats", "--json"], ["status"], ["participants", "list"], ["session", "list"],
                 ["export", "--out", tmp_path / "ex"], ["replay", "--session", "1", "--trial", "1"]):
        res = studyctl(*args, "--db", db)
        assert res.exit_code == 0, (args, res.output)
    assert "S01" in studyctl("participants", "list", "--db", db).output
    assert len(list(csv.reader(open(tmp_path / "ex" / "answers.csv")))) == 10  # header + 9 answers
    res = studyctl("participants", "add", "P01", "--db", db)
    assert res.exit_code == 1
    assert "read-only (read-only file system); nothing was written" in res.output
    assert len(res.output.strip().splitlines()) == 1


def _study(tmp_path, **kw):
    db = tmp_path / "s.db"
    protocol = fast_protocol(tmp_path, conditions=("plate_spring",), trials=1)
    if kw.get("withdrawal"):
        protocol.write_text(protocol.read_text().replace('withdrawal = "keep"', f'withdrawal = "{kw["withdrawal"]}"'))
    assert studyctl("study", "init", "--protocol", protocol, "--db", db).exit_code == 0
    return db


def test_provenance_a_participant_is_a_person_or_synthetic_never_both(tmp_path):
    db = _study(tmp_path)
    studyctl("participants", "add", "S01", "--synthetic", "--db", db)
    studyctl("participants", "add", "P01", "--db", db)
    assert studyctl("session", "run", "--participant", "S01", "--synthetic", "--db", db).exit_code == 0
    assert "registered as a person" in studyctl("session", "run", "--participant", "P01", "--synthetic", "--db", db).output
    # answers carry their source; a synthetic participant's come only from the synthetic answerer
    assert query(db, "select distinct code, source from answers") == [("S01", "synthetic")]
    facts = json.loads(studyctl("report", "table1", "--format", "json", "--db", db).output)["facts"]
    assert facts["synthetic"]
    assert facts["synthetic_participants"] == 1
    assert facts["mixed_source_participants"] == []


def test_reports_count_synthetic_answers_from_rows_not_flags(tmp_path):
    """A database written before provenance checks (flags that drifted): the report finds the
    synthetic answers and names the participant whose answers are mixed."""
    db = _study(tmp_path)
    for code in ("P01", "P02", "P03"):
        studyctl("participants", "add", code, "--db", db)
    items = ["natural", "behaviour", "texture", "comfortable", "guidance", "realtime", "feedback", "deformation", "stable"]
    con = sqlite3.connect(db)  # every answer of each (complete: counted), P01's first synthetic and the rest a person's
    con.executemany("insert into answers (code, model, item, answer, session_id, source, answered_at) values (?, 'plate_spring', ?, 1, null, ?, '')",
                    [("P01", i, "synthetic" if k == 0 else "terminal") for k, i in enumerate(items)]
                    + [("P02", i, "synthetic") for i in items] + [("P03", i, "terminal") for i in items])
    con.commit()
    con.close()
    facts = json.loads(studyctl("report", "table1", "--format", "json", "--db", db).output)["facts"]
    assert facts["synthetic_participants"] == 2
    assert facts["synthetic"]
    assert facts["mixed_source_participants"] == ["P01"]
    text = studyctl("report", "table1", "--db", db).output
    assert "MIXED DATA: 1 person and 2 SYNTHETIC" in text
    assert "WARNING: P01 answered both as a person and synthetically" in text


def test_resume_with_other_options_than_the_start_is_refused(tmp_path):
    db = _study(tmp_path)
    studyctl("participants", "add", "S01", "--synthetic", "--db", db)
    # a session that died while started with a real device (as after a crash of the rig)
    con = sqlite3.connect(db)
    con.execute("insert into sessions (code, started_at, status, synthetic, device) values ('S01', '', 'running', 0, 'openhaptics')")
    con.commit()
    con.close()
    res = studyctl("session", "run", "--participant", "S01", "--synthetic", "--resume", "--db", db)
    assert res.exit_code == 1
    assert "was started with --device openhaptics, not simulated; resume it with --device openhaptics" in res.output
    assert query(db, "select count(*) from answers") == [(0,)]


def test_a_person_needs_consent_and_imported_answers_are_not_mixed_with_a_session(tmp_path):
    db = _study(tmp_path)
    studyctl("participants", "add", "P01", "--db", db)
    res = studyctl("session", "run", "--participant", "P01", "--time-scale", "0", "--view", "none", "--db", db)
    assert res.exit_code == 1
    assert "no consent recorded" in res.output
    assert studyctl("participants", "consent", "P01", "--date", "2026-01-05", "--db", db).exit_code == 0
    assert query(db, "select code, version, given_on from consent") == [("P01", "1", "2026-01-05")]
    (tmp_path / "a.csv").write_text("participant,model,item,answer\nP01,plate_spring,natural,Y\n")
    assert studyctl("answers", "import", tmp_path / "a.csv", "--db", db).exit_code == 0
    res = studyctl("session", "run", "--participant", "P01", "--time-scale", "0", "--view", "none", "--db", db)
    assert res.exit_code == 1
    assert "would mix sources" in res.output


def test_dry_run_writes_nothing_and_says_so(tmp_path):
    db = _study(tmp_path)
    studyctl("participants", "add", "P01", "--contact", "p1@example.org", "--db", db)
    (tmp_path / "p.csv").write_text("code\nP02\nP03\n")
    studyctl("schedule", "--start", "2037-12-01", "--end", "2037-12-04", "--db", db)
    assert studyctl("answers", "import", tmp_path / "none.csv", "--db", db).exit_code == 1  # (a missing file: nothing)
    studyctl("participants", "add", "P04", "--db", db)  # waiting for a slot
    before = tree_state(tmp_path)
    said = "dry run, nothing written: would have "
    for args, first in ((["participants", "add", "P09"], said + "added P09"),
                        (["participants", "import", tmp_path / "p.csv"], said + "imported 2 participants"),
                        (["participants", "consent", "P01"], said + "recorded consent of P01: form 1, signed "),
                        (["participants", "withdraw", "P01"], said + "withdrawn P01: 0 sessions and 0 answers kept; contact details deleted"),
                        (["schedule", "cancel", "P01"], said + "cancelled P01's slot at 2037-12-01T09:00:00; `studyctl schedule` gives a new one"),
                        (["schedule", "--start", "2037-12-07", "--end", "2037-12-08", "--ics", tmp_path / "s.ics"],
                         "DRY RUN, nothing stored: Schedule")):  # the schedule's table says it in its title
        res = studyctl(*args, "--dry-run", "--db", db)
        assert res.exit_code == 0, (args, res.output)
        assert res.output.startswith(first), (args, res.output)
    assert tree_state(tmp_path) == before


def test_withdrawal_keeps_or_deletes_data_as_the_protocol_says(tmp_path):
    for policy in ("keep", "delete"):
        d = tmp_path / policy
        d.mkdir()
        db = _study(d, withdrawal=policy)
        studyctl("participants", "add", "S01", "--synthetic", "--db", db)
        studyctl("participants", "add", "P02", "--name", "Bo", "--contact", "bo@example.org", "--db", db)
        assert studyctl("session", "run", "--participant", "S01", "--synthetic", "--db", db).exit_code == 0
        traces = list((d / "s.db.traces").rglob("*.npz"))
        assert len(traces) == 1
        res = studyctl("participants", "withdraw", "S01", "--reason", "asked to", "--db", db)
        assert res.exit_code == 0
        assert f"answers {'kept' if policy == 'keep' else 'deleted'}" in res.output
        answers = query(db, "select count(*) from answers where code = 'S01'")[0][0]
        assert answers == (9 if policy == "keep" else 0)
        assert traces[0].exists() == (policy == "keep")
        assert query(db, "select withdrawal from participants where code = 'S01'") == [("kept" if policy == "keep" else "deleted",)]
        assert query(db, "select kind from events where kind = 'withdrawn'") == [("withdrawn",)]
        assert "withdrew on" in studyctl("session", "run", "--participant", "S01", "--synthetic", "--db", db).output
        studyctl("participants", "withdraw", "P02", "--db", db)
        assert query(db, "select count(*) from identities") == [(0,)]  # contact details go with the withdrawal


def test_cancel_and_reschedule_keep_the_order(tmp_path):
    db = _study(tmp_path)
    for c in ("P01", "P02"):
        studyctl("participants", "add", c, "--db", db)
    studyctl("schedule", "--start", "2037-12-01", "--end", "2037-12-01", "--db", db)
    first = dict((c, (s, o)) for c, s, o in query(db, "select code, slot_start, conditions from schedule"))
    assert studyctl("schedule", "cancel", "P01", "--db", db).exit_code == 0
    assert query(db, "select slot_start from schedule where code = 'P01'") == [(None,)]
    res = studyctl("schedule", "--start", "2037-12-02", "--end", "2037-12-02", "--json", "--db", db)
    rows = {r["code"]: r for r in json.loads(res.output)}
    assert rows["P01"]["slot_start"].startswith("2037-12-02")
    assert rows["P01"]["conditions"] == first["P01"][1]
    assert rows["P02"]["slot_start"] == first["P02"][0]  # the others keep theirs
    assert query(db, "select kind from events") == [("slot_cancelled",)]


def test_answers_correct_keeps_an_audit_trail(tmp_path):
    db = _study(tmp_path)
    studyctl("participants", "add", "P01", "--db", db)
    studyctl("participants", "consent", "P01", "--db", db)
    (tmp_path / "a.csv").write_text("participant,model,item,answer\nP01,plate_spring,natural,yes\n")
    studyctl("answers", "import", tmp_path / "a.csv", "--db", db)
    res = studyctl("answers", "correct", "--participant", "P01", "--model", "plate_spring", "--item", "natural", "--answer", "no",
                   "--reason", "paper sheet misread", "--db", db)
    assert res.exit_code == 0
    assert "yes -> no" in res.output
    assert query(db, "select answer from answers") == [(0,)]
    assert query(db, "select code, item, old_answer, new_answer, reason from corrections") == [("P01", "natural", 1, 0, "paper sheet misread")]
    assert "corrections.csv" in {p.name for p in (tmp_path / "ex").glob("*")} if studyctl("export", "--out", tmp_path / "ex", "--db", db).exit_code == 0 else False


def test_status_and_lists(tmp_path):
    db = _study(tmp_path)
    studyctl("participants", "add", "S01", "--synthetic", "--db", db)
    studyctl("participants", "add", "P01", "--name", "Ann Secretname", "--db", db)
    studyctl("participants", "consent", "P01", "--db", db)
    studyctl("session", "run", "--participant", "S01", "--synthetic", "--db", db)
    studyctl("schedule", "--start", "2037-12-01", "--end", "2037-12-01", "--db", db)
    out = json.loads(studyctl("status", "--json", "--db", db).output)
    assert out["participants"] == {"persons": 1, "synthetic": 1, "withdrawn": 0, "withdrawn_synthetic": 0, "consented": 1}
    assert out["sessions"] == {"done": 1}
    assert out["complete"] == {"persons": 0, "synthetic": 1, "mixed": 0}
    assert out["target_participants"] == 35
    assert [r["code"] for r in out["next"]] == ["P01"]
    assert out["answers"] == 9
    text = studyctl("status", "--db", db).output
    assert "0 of 35 people complete (and 1 SYNTHETIC)" in text
    assert "next: P01 2037-12-01 09:00" in text
    listed = {r["code"]: r for r in json.loads(studyctl("participants", "list", "--json", "--db", db).output)}
    assert listed["S01"]["kind"] == "synthetic"
    assert listed["S01"]["session"] == "done"
    assert listed["S01"]["answers"] == 9
    assert listed["P01"]["consent"] == "1"
    assert listed["P01"]["slot"] == "2037-12-01T09:00:00"
    assert "Secretname" not in studyctl("participants", "list", "--db", db).output
    sessions = json.loads(studyctl("sessions", "list", "--json", "--db", db).output)
    assert [(s["code"], s["status"], s["kind"], s["answers"]) for s in sessions] == [("S01", "done", "synthetic", 9)]


def test_contacts_export_is_marked_and_private(tmp_path):
    db = _study(tmp_path)
    studyctl("participants", "add", "P01", "--name", "Ann Example", "--contact", "ann@example.org", "--db", db)
    studyctl("participants", "add", "P02", "--db", db)
    res = studyctl("participants", "contacts", "--out", tmp_path / "c.csv", "--db", db)
    assert res.exit_code == 0
    assert "IDENTIFYING" in res.output
    text = (tmp_path / "c.csv").read_text()
    assert text.startswith("# IDENTIFYING DATA")
    assert "P01,Ann Example,ann@example.org" in text
    assert "P02" not in text
    assert stat.S_IMODE((tmp_path / "c.csv").stat().st_mode) == 0o600
    studyctl("export", "--out", tmp_path / "ex", "--db", db)
    assert not any("ann@example.org" in p.read_text() for p in (tmp_path / "ex").glob("*.csv"))


def test_csvs_as_spreadsheets_save_them(tmp_path):
    db = _study(tmp_path)
    # UTF-8 with BOM, CRLF, ';' separated, a capitalised header: what a spreadsheet in many locales writes
    (tmp_path / "p.csv").write_bytes("\ufeffCode;Age;Name\r\nP01;24;Zoë Müller\r\nP02;25;\r\n\r\n".encode("utf-8"))
    res = studyctl("participants", "import", tmp_path / "p.csv", "--db", db)
    assert res.exit_code == 0, res.output
    assert query(db, "select code, age from participants order by code") == [("P01", 24), ("P02", 25)]
    assert query(db, "select name from identities") == [("Zoë Müller",)]
    for c in ("P01", "P02"):
        studyctl("participants", "consent", c, "--db", db)
    (tmp_path / "a.csv").write_text("Participant,Model,Item,Answer\r\nP01,plate_spring,natural,Y\r\nP01,plate_spring,texture,0\r\n"
                                    "P02,plate_spring,natural,yes\r\nP02,plate_spring,texture,N\r\nP02,plate_spring,stable, TRUE \r\n")
    assert studyctl("answers", "import", tmp_path / "a.csv", "--db", db).exit_code == 0
    assert query(db, "select code, item, answer from answers order by code, item") == [
        ("P01", "natural", 1), ("P01", "texture", 0), ("P02", "natural", 1), ("P02", "stable", 1), ("P02", "texture", 0)]


def test_reports_on_an_empty_study_say_so(tmp_path):
    db = _study(tmp_path)
    for fmt in ("md", "csv", "latex", "html"):
        res = studyctl("report", "table1", "--format", fmt, "--out", tmp_path / f"t.{fmt}", "--db", db)
        assert res.exit_code == 0
        assert res.output == "brain_pull_2015: no answers yet; nothing to report\n"
        assert not (tmp_path / f"t.{fmt}").exists()
    assert json.loads(studyctl("report", "table1", "--format", "json", "--db", db).output)["message"] == "no answers yet"
    assert studyctl("report", "stats", "--db", db).output == "brain_pull_2015: no answers yet; nothing to report\n"
    res = studyctl("report", "plots", "--out", tmp_path / "plots", "--db", db)
    assert res.exit_code == 0
    assert "no answers yet" in res.output
    assert not (tmp_path / "plots").exists()
    assert "nan" not in studyctl("status", "--db", db).output
    studyctl("export", "--out", tmp_path / "ex", "--db", db)
    header = (tmp_path / "ex" / "answers.csv").read_text()
    assert header == "code,model,item,trial,answer,session_id,source,answered_at\n"  # a header, even with no rows
    assert (tmp_path / "ex" / "traces.csv").read_text().startswith("session_id,model,trial,t,hand,")


def test_a_foreign_file_with_an_unmerged_wal_is_left_as_it_was(tmp_path):
    """Another program killed with its WAL not merged: even a read-write open would merge it."""
    import sys

    db = tmp_path / "w.db"
    code = (f"import sqlite3, os; c = sqlite3.connect({str(db)!r}, isolation_level=None); c.execute('pragma journal_mode=wal'); "
            "c.execute('pragma wal_autocheckpoint=0'); c.execute('create table foo (a)'); c.execute('insert into foo values (1)'); "
            "os._exit(0)")
    subprocess.run([sys.executable, "-c", code], check=True)
    assert (tmp_path / "w.db-wal").stat().st_size > 0
    # the database and its WAL stay byte-identical; the -shm file is SQLite's shared-memory
    # index of the WAL, rebuilt by any reader (it holds no data)
    before = {k: v for k, v in tree_state(tmp_path).items() if not k.endswith("-shm")}
    for args in (["status"], ["participants", "add", "P01"], ["report", "table1"], ["study", "init", "--protocol", PROTOCOL]):
        res = studyctl(*args, "--db", db)
        assert res.exit_code == 1, (args, res.output)
        assert "not a study database (it holds other tables: foo)" in res.output, (args, res.output)
    assert {k: v for k, v in tree_state(tmp_path).items() if not k.endswith("-shm")} == before


def test_withdrawal_waits_for_a_running_session(tmp_path):
    from studyctl.session.lock import session_lock

    db = _study(tmp_path)
    studyctl("participants", "add", "S01", "--synthetic", "--db", db)
    with session_lock(db, "S01"):  # as a running `session run` holds it
        res = studyctl("participants", "withdraw", "S01", "--db", db)
    assert res.exit_code == 1
    assert "their session is running now; stop it first" in res.output
    assert query(db, "select withdrawn_at from participants") == [(None,)]
    assert studyctl("participants", "withdraw", "S01", "--db", db).exit_code == 0


def test_a_session_stopped_before_its_first_trial_is_discarded(tmp_path):
    db = _study(tmp_path)
    studyctl("participants", "add", "S01", "--synthetic", "--db", db)
    con = sqlite3.connect(db)
    con.execute("insert into sessions (id, code, started_at, status, synthetic, device) values (7, 'S01', '', 'running', 1, 'simulated')")
    con.execute("insert into conditions (session_id, position, model, status, label) values (7, 0, 'plate_spring', 'pending', 'A')")
    con.commit()
    con.close()
    res = studyctl("session", "run", "--participant", "S01", "--synthetic", "--db", db)
    assert res.exit_code == 0
    assert "discarded session 7 of S01: it stopped before its first trial" in res.output
    assert query(db, "select status from sessions") == [("done",)]
    assert query(db, "select count(*) from conditions where session_id = 7") == [(0,)]
    assert query(db, "select kind from events where kind = 'session_discarded'") == [("session_discarded",)]


def test_synth_skips_codes_in_use_and_refuses_another_protocol(tmp_path):
    db = _study(tmp_path)
    studyctl("participants", "add", "S001", "--synthetic", "--db", db)
    res = studyctl("synth", "--participants", "1", "--db", db)
    assert res.exit_code == 0, res.output
    assert [c for (c,) in query(db, "select code from participants order by code")] == ["S001", "S002"]
    res = studyctl("synth", "--participants", "1", "--protocol", PROTOCOL, "--db", db)
    assert res.exit_code == 1
    assert "is not the protocol" in res.output


def test_an_older_schema_is_refused_until_study_migrate_upgrades_it(tmp_path):
    db = _study(tmp_path)
    studyctl("participants", "add", "P01", "--db", db)
    con = sqlite3.connect(db)  # back to schema 2: no withdrawal, consent, corrections or observer features
    con.execute("drop table observer_features")
    con.execute("alter table sessions drop column seed")
    con.execute("drop table consent")
    con.execute("drop table corrections")
    con.execute("alter table participants drop column withdrawn_at")
    con.execute("alter table participants drop column withdrawal")
    con.execute("alter table conditions drop column config")
    con.execute("alter table conditions drop column config_sha256")
    con.execute("drop table rig_profile")
    con.execute("drop table discrimination")
    con.execute("drop table synthetic_traits")
    con.execute("drop table participant_fields")
    con.execute("update meta set value = '2' where key = 'schema_version'")
    con.commit()
    con.close()
    res = studyctl("participants", "list", "--json", "--db", db)
    assert res.exit_code == 1
    assert "schema version 2, this studyctl needs 10; run `studyctl study migrate" in res.output
    assert query(db, "select value from meta where key = 'schema_version'") == [("2",)]
    assert studyctl("study", "migrate", "--db", db).exit_code == 0
    res = studyctl("participants", "list", "--json", "--db", db)
    assert json.loads(res.output)[0]["code"] == "P01"
    assert query(db, "select value from meta where key = 'schema_version'") == [("10",)]
    assert query(db, "select count(*) from observer_features") == [(0,)]
    assert {"config", "config_sha256"} <= {r[1] for r in query(db, "pragma table_info(conditions)")}


def test_a_synthetic_session_resumes_with_its_own_seed(tmp_path):
    db = _study(tmp_path)
    studyctl("participants", "add", "S01", "--synthetic", "--db", db)
    con = sqlite3.connect(db)  # a session that stopped after it started, with seed 3
    con.execute("insert into sessions (id, code, started_at, status, synthetic, device, seed, conditions) "
                "values (5, 'S01', '', 'running', 1, 'simulated', 3, ?)", (json.dumps(["plate_spring", "fem", "mass_spring"]),))
    con.execute("insert into trials (session_id, model, trial, started_at) values (5, 'zz', 0, '')")  # it had started
    con.commit()
    con.close()
    res = studyctl("session", "run", "--participant", "S01", "--synthetic", "--resume", "--seed", "4", "--db", db)
    assert res.exit_code == 1
    assert "started with --seed 3" in res.output
