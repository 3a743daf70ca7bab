"""Issue 15's bad-input corpus: files, options, CSVs and databases, each refused with one error
line, a non-zero exit, no traceback, and the database (and its folder) byte-identical after."""

import hashlib
import re
import sqlite3
from pathlib import Path

import pytest
from click.testing import CliRunner

from studyctl.cli import cli
from tests.helpers import fast_protocol, studyctl

BAD_UTF8 = "code,age\nP0\xe9,23\n".encode("latin-1")


def _without_section(text: str, header: str) -> str:
    a = text.index(header)
    return text[:a] + text[text.index("\n[", a + 1) + 1:]


@pytest.fixture(scope="module")
def study(tmp_path_factory):
    """A study with a consenting person P01 (answers imported), a person P02 without consent and
    a synthetic S01; input files for the corpus next to it."""
    d = tmp_path_factory.mktemp("corpus")
    db = d / "s.db"
    protocol = fast_protocol(d, conditions=("plate_spring", "fem"), trials=1)
    studyctl("study", "init", "--protocol", protocol, "--db", db)
    studyctl("participants", "add", "P01", "--age", "24", "--name", "Ann", "--db", db)
    studyctl("participants", "consent", "P01", "--db", db)
    studyctl("participants", "add", "P02", "--db", db)
    studyctl("participants", "add", "S01", "--synthetic", "--db", db)
    (d / "a.csv").write_text("participant,model,item,answer\nP01,fem,natural,yes\n")
    assert studyctl("answers", "import", "--db", db, d / "a.csv").exit_code == 0
    f = {
        "p_utf8": BAD_UTF8,
        "p_col": "code,age,email\nP09,23,x\n", "p_nocode": "age\n23\n", "p_twice": "code\nP09\nP09\n",
        "p_age": "code,age\nP09,99\n", "p_header": "code,age\n", "p_badcode": "code\nAnn Smith\n", "p_registered": "code\nP02\n",
        "p_cells": "code,age\nP09,23,extra\n", "p_empty": "",
        "a_utf8": "participant,model,item,answer\nP0\xe9,fem,natural,yes\n".encode("latin-1"),
        "a_who": "participant,model,item,answer\nP77,fem,natural,yes\n",
        "a_model": "participant,model,item,answer\nP01,sph,natural,yes\n",
        "a_item": "participant,model,item,answer\nP01,fem,colour,yes\n",
        "a_value": "participant,model,item,answer\nP01,fem,texture,maybe\n",
        "a_twice": "participant,model,item,answer\nP01,fem,texture,yes\nP01,fem,texture,no\n",
        "a_synthetic": "participant,model,item,answer\nS01,fem,natural,yes\n",
        "a_cols": "participant,model,answer\nP01,fem,yes\n",
        "a_consent": "participant,model,item,answer\nP02,fem,natural,yes\n",
        "a_clash": "participant,model,item,answer\nP01,fem,natural,no\n",
        "av_who": "code,date,start,end\nP88,2037-12-01,09:00,12:00\n",
        "av_date": "code,date,start,end\nP02,1 Dec,09:00,12:00\n",
        "av_order": "code,date,start,end\nP02,2037-12-01,12:00,09:00\n",
        "t_zero": "item,model,yes,no,printed_rate\nnatural,fem,0,0,0%\n",
        "t_negative": "item,model,yes,no,printed_rate\nnatural,fem,-2,5,0%\n",
        "t_rate": "item,model,yes,no,printed_rate\nnatural,fem,3,1,150%\n",
        "t_nan": "item,model,yes,no,printed_rate\nnatural,fem,3,1,nan\n",
        "t_utf8": "item,model,yes,no,printed_rate\nnat\xfcral,fem,3,1,75%\n".encode("latin-1"),
        "proto_utf8": protocol.read_text().replace("Virtual brain", "Virtual br\xe4in").encode("latin-1"),
        "proto_key": protocol.read_text().replace("[inclusion]", "[inclusion]\nage_mni = 3"),
        "proto_section": protocol.read_text() + "\n[extras]\nx = 1\n",
        # a scene that is any text file; a scene without the FEM that the protocol's conditions name
        "notes.txt": "the lab's notes, not a scene\n",
        "proto_scene_text": protocol.read_text().replace(str(d / "scene.toml"), str(d / "notes.txt")),
        "scene_nofem.toml": _without_section((d / "scene.toml").read_text(), "[models.fem]"),
        "proto_scene_model": protocol.read_text().replace(str(d / "scene.toml"), str(d / "scene_nofem.toml")),
        "text_db": "this is not a database\n", "empty_db": "",
    }
    for name, content in f.items():
        path = d / name
        path.write_bytes(content) if isinstance(content, bytes) else path.write_text(content)
    (d / "exists.csv").write_text("x\n")
    foreign = d / "foreign.db"
    con = sqlite3.connect(foreign)
    con.execute("create table foo (x)")
    con.execute("insert into foo values (1)")
    con.commit()
    con.close()
    newer = d / "newer.db"
    newer.write_bytes(db.read_bytes())
    con = sqlite3.connect(newer)
    con.execute("update meta set value = '99' where key = 'schema_version'")
    con.commit()
    con.close()
    return d


def _snapshot(d: Path) -> dict:
    """Every file and folder under the study's folder, files with their SHA-256."""
    return {str(p.relative_to(d)): hashlib.sha256(p.read_bytes()).hexdigest() if p.is_file() else "folder"
            for p in sorted(d.rglob("*"))}


DB, FOREIGN = "{d}/s.db", "{d}/foreign.db"
CASES = [
    # participants: files
    (["participants", "import", "--db", DB, "{d}/p_utf8"], "line 2: not UTF-8"),
    (["participants", "import", "--db", DB, "{d}/p_col"], "unknown column 'email'"),
    (["participants", "import", "--db", DB, "{d}/p_nocode"], "no 'code' column"),
    (["participants", "import", "--db", DB, "{d}/p_twice"], "appears twice"),
    (["participants", "import", "--db", DB, "{d}/p_age"], "outside the inclusion range"),
    (["participants", "import", "--db", DB, "{d}/p_header"], "no participants"),
    (["participants", "import", "--db", DB, "{d}/p_badcode"], "must be 1-32 letters"),
    (["participants", "import", "--db", DB, "{d}/p_registered"], "already registered"),
    (["participants", "import", "--db", DB, "{d}/p_cells"], "3 cells, the header has 2"),
    (["participants", "import", "--db", DB, "{d}/p_empty"], "empty"),
    (["participants", "import", "--db", DB, "{d}/missing.csv"], "not found"),
    # answers: files
    (["answers", "import", "--db", DB, "{d}/a_utf8"], "not UTF-8"),
    (["answers", "import", "--db", DB, "{d}/a_who"], "unknown participant 'P77'"),
    (["answers", "import", "--db", DB, "{d}/a_model"], "unknown model 'sph'"),
    (["answers", "import", "--db", DB, "{d}/a_item"], "unknown item 'colour'"),
    (["answers", "import", "--db", DB, "{d}/a_value"], "allowed: yes or no"),
    (["answers", "import", "--db", DB, "{d}/a_twice"], "a second answer"),
    (["answers", "import", "--db", DB, "{d}/a_synthetic"], "is synthetic"),
    (["answers", "import", "--db", DB, "{d}/a_cols"], "no 'item' column"),
    (["answers", "import", "--db", DB, "{d}/a_clash"], "already answered"),
    (["answers", "import", "--db", DB, "{d}/a_consent"], "no consent recorded"),
    # protocols
    (["protocol", "validate", "{d}/proto_utf8"], "not UTF-8"),
    (["study", "init", "--db", "{d}/new1.db", "--protocol", "{d}/proto_key"], "inclusion.age_mni: unknown key"),
    (["study", "init", "--db", "{d}/new2.db", "--protocol", "{d}/proto_section"], "extras: unknown section"),
    (["protocol", "validate", "{d}/proto_scene_text"], "notes.txt:1: invalid TOML"),
    (["study", "init", "--db", "{d}/new3.db", "--protocol", "{d}/proto_scene_text"], "notes.txt:1: invalid TOML"),
    (["protocol", "validate", "{d}/proto_scene_model"], "design.conditions: 'fem' is not configured in the scene"),
    (["study", "init", "--db", "{d}/new4.db", "--protocol", "{d}/proto_scene_model"], "configured: mass_spring, plate_spring"),
    (["study", "init", "--db", "{d}/missing/new.db", "--protocol", "{d}/protocol.toml"], "is not an existing folder"),
    (["study", "init", "--db", DB, "--protocol", "{d}/protocol.toml"], "already holds a study"),
    # schedule
    (["schedule", "--db", DB, "--start", "2020-01-06", "--end", "2020-01-10"], "is in the past"),
    (["schedule", "--db", DB, "--start", "2037-12-04", "--end", "2037-12-01"], "before --start"),
    (["schedule", "--db", DB, "--start", "1.12.2037", "--end", "2037-12-04"], "dates must be YYYY-MM-DD"),
    (["schedule", "--db", DB, "--start", "2037-12-01", "--end", "2039-12-01"], "more than a year"),
    (["schedule", "--db", DB, "--start", "2037-12-01", "--end", "2037-12-04", "--session-minutes", "0"], "--session-minutes"),
    (["schedule", "--db", DB, "--start", "2037-12-01", "--end", "2037-12-04", "--ics", "{d}/missing/s.ics"], "is not an existing folder"),
    (["schedule", "--db", DB, "--start", "2037-12-01", "--end", "2037-12-04", "--ics", "{d}/s.txt"], "allowed suffixes: .ics"),
    (["schedule", "--db", DB, "--start", "2037-12-05", "--end", "2037-12-06"], "no slot for any of the"),  # a weekend
    (["schedule", "--db", DB, "--start", "2037-12-01", "--end", "2037-12-04", "--availability", "{d}/av_who"], "unknown participant 'P88'"),
    (["schedule", "--db", DB, "--start", "2037-12-01", "--end", "2037-12-04", "--availability", "{d}/av_date"], "date must be YYYY-MM-DD"),
    (["schedule", "--db", DB, "--start", "2037-12-01", "--end", "2037-12-04", "--availability", "{d}/av_order"], "end is not after start"),
    (["schedule", "cancel", "P02", "--db", DB], "has no slot to cancel"),
    # participants: options
    (["participants", "add", "Ann Smith", "--db", DB], "must be 1-32 letters"),
    (["participants", "add", "P09", "--age", "200", "--db", DB], "--age"),
    (["participants", "add", "P01", "--db", DB], "already registered"),
    (["participants", "add", "S09", "--synthetic", "--name", "Bob", "--db", DB], "has no name or contact"),
    (["participants", "add", "P09", "--field", "experience=student", "--db", DB], "unknown field 'experience'; allowed: none"),
    (["participants", "add", "P09", "--field", "experience", "--db", DB], "--field: 'experience' is not NAME=VALUE"),
    (["participants", "consent", "P99", "--db", DB], "not registered"),
    (["participants", "consent", "P02", "--date", "2099-01-01", "--db", DB], "in the future"),
    (["participants", "consent", "P02", "--date", "yesterday", "--db", DB], "is not a date"),
    (["participants", "consent", "P02", "--version", "9", "--db", DB], "is not the protocol's consent form"),
    (["participants", "consent", "S01", "--db", DB], "give no consent"),
    (["participants", "consent", "P01", "--db", DB], "already recorded"),
    (["participants", "consent", "P02", "--date", "1900-01-01", "--db", DB], "more than a year before the study"),
    (["participants", "withdraw", "P99", "--db", DB], "not registered"),
    (["participants", "contacts", "--db", DB, "--out", "{d}/exists.csv"], "exists.csv: exists; --force overwrites it"),
    (["answers", "correct", "--db", DB, "--participant", "P01", "--model", "fem", "--item", "natural", "--answer", "no", "--reason", " "], "--reason"),
    (["answers", "correct", "--db", DB, "--participant", "P01", "--model", "fem", "--item", "texture", "--answer", "no", "--reason", "r"], "no stored answer"),
    (["answers", "correct", "--db", DB, "--participant", "P01", "--model", "fem", "--item", "natural", "--answer", "maybe", "--reason", "r"], "allowed: yes or no"),
    (["answers", "correct", "--db", DB, "--participant", "P01", "--model", "fem", "--item", "natural", "--answer", "y", "--reason", "r"], "already yes"),
    # sessions: provenance and options
    (["session", "run", "--db", DB, "--participant", "P02", "--time-scale", "0", "--view", "none"], "no consent recorded"),
    (["session", "run", "--db", DB, "--participant", "P02", "--synthetic"], "registered as a person"),
    (["session", "run", "--db", DB, "--participant", "S01", "--time-scale", "0", "--view", "none"], "registered as synthetic"),
    (["session", "run", "--db", DB, "--participant", "P01", "--time-scale", "0", "--view", "none"], "would mix sources"),
    (["session", "run", "--db", DB, "--participant", "S01", "--synthetic", "--resume"], "no interrupted session"),
    (["session", "run", "--db", DB, "--participant", "P99", "--synthetic"], "not registered"),
    (["session", "run", "--db", DB, "--participant", "S01", "--synthetic", "--time-scale", "nan"], "not a finite number"),
    (["session", "run", "--db", DB, "--participant", "S01", "--synthetic", "--time-scale", "inf"], "--time-scale"),
    (["synth", "--db", DB, "--participants", "0"], "--participants"),
    (["synth", "--db", DB, "--participants", "100000000"], "--participants"),
    (["replay", "--db", DB, "--session", "99", "--trial", "1"], "no session 99"),
    # reports
    (["report", "table1", "--db", DB, "--out", "{d}/missing/t.md"], "is not an existing folder"),
    (["report", "published", "--table", "{d}/t_zero"], "at least one answer"),
    (["report", "published", "--table", "{d}/t_negative"], "counts must be >= 0"),
    (["report", "published", "--table", "{d}/t_rate"], "allowed: 0%..100%"),
    (["report", "published", "--table", "{d}/t_nan"], "printed_rate"),
    (["report", "published", "--table", "{d}/t_utf8"], "not UTF-8"),
    (["export", "--db", DB, "--out", "{d}/exists.csv/ex"], "is a file, not a folder"),
    # databases that are not (this software's) study databases
    (["participants", "add", "P01", "--db", FOREIGN], "not a study database (it holds other tables: foo)"),
    (["report", "table1", "--db", FOREIGN], "not a study database"),
    (["export", "--db", FOREIGN, "--out", "{d}/ex_foreign"], "not a study database"),
    (["status", "--db", FOREIGN], "not a study database"),
    (["study", "init", "--db", FOREIGN, "--protocol", "{d}/protocol.toml"], "not a study database"),
    (["session", "run", "--db", FOREIGN, "--participant", "P01", "--synthetic"], "not a study database"),
    (["participants", "list", "--db", "{d}/text_db"], "not a study database"),
    (["participants", "add", "P01", "--db", "{d}/empty_db"], "an empty file"),
    (["status", "--db", "{d}/nothing.db"], "no such study database"),
    (["report", "stats", "--db", "{d}/newer.db"], "schema_version '99' is not a version this studyctl reads"),
    (["participants", "add", "P09", "--db", "{d}/newer.db"], "schema_version '99' is not a version this studyctl reads"),
]


def test_the_corpus_is_big_enough():
    assert len(CASES) >= 50


@pytest.mark.parametrize("args, needle", CASES, ids=[f"{k:02d}-{' '.join(a[:2])}" for k, (a, _) in enumerate(CASES)])
def test_bad_input_is_one_line_and_writes_nothing(study, args, needle):
    before = _snapshot(study)
    res = CliRunner().invoke(cli, [a.format(d=study) for a in args])
    out = res.output
    # "Error: ..." or, from `protocol validate`, a problem as FILE:LINE: field: message
    errors = [ln for ln in out.splitlines() if ln.startswith("Error:") or re.match(r"^\S+:\d+: ", ln)]
    assert res.exit_code in (1, 2), out
    assert res.exception is None or isinstance(res.exception, SystemExit), repr(res.exception)  # no traceback
    assert "Traceback" not in out, out
    assert len(errors) == 1, out
    assert needle in errors[0], out
    if res.exit_code == 1:  # a library error: that one line and nothing else
        assert out.strip() == errors[0], out
    assert _snapshot(study) == before  # nothing written, nothing changed
