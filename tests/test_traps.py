"""Commands never do what the user did not ask for without saying so (issue 42, item 3): each
trap reproduced through the CLI first, then refused or made explicit."""

import csv
import sqlite3
from pathlib import Path

import pytest

from tests.helpers import fast_protocol, studyctl


def _person_with_answers(tmp_path, db, proto):
    """A study holding a person's data: P01 registered, consented, answers imported from paper."""
    assert studyctl("study", "init", "--db", db, "--protocol", proto).exit_code == 0
    assert studyctl("participants", "add", "P01", "--db", db, "--age", "24").exit_code == 0
    assert studyctl("participants", "consent", "P01", "--db", db).exit_code == 0
    answers = tmp_path / "paper.csv"
    items = ("natural", "behaviour", "texture", "comfortable", "guidance", "realtime", "feedback", "deformation", "stable")
    rows = [f"P01,plate_spring,{item},yes" for item in items]
    answers.write_text("participant,model,item,answer\n" + "\n".join(rows) + "\n")
    return answers


def test_synth_never_creates_a_study_it_was_not_told_to(tmp_path):
    typo = tmp_path / "typo.db"
    res = studyctl("synth", "--db", typo, "--participants", "1")
    assert res.exit_code != 0
    assert "typo.db does not exist" in res.output
    assert "--protocol" in res.output
    assert not typo.exists()
    assert "Traceback" not in res.output
    proto = fast_protocol(tmp_path, conditions=("plate_spring",), trials=1)
    res = studyctl("synth", "--db", typo, "--participants", "1", "--protocol", proto)
    assert res.exit_code == 0, res.output
    assert f"created {typo} for the protocol {proto}" in res.output


def test_an_empty_scheduler_address_is_an_error(tmp_path):
    db = tmp_path / "s.db"
    res = studyctl("synth", "--db", db, "--participants", "1", "--protocol", fast_protocol(tmp_path), "--scheduler", "")
    assert res.exit_code != 0
    assert "--scheduler" in res.output
    assert "empty" in res.output
    assert not db.exists()


def test_synthetic_sessions_into_a_study_of_people_are_refused_unless_asked_for(tmp_path):
    db = tmp_path / "s.db"
    proto = fast_protocol(tmp_path, conditions=("plate_spring",), trials=1)
    answers = _person_with_answers(tmp_path, db, proto)
    res = studyctl("answers", "import", "--db", db, answers)
    assert res.exit_code == 0, res.output
    res = studyctl("synth", "--db", db, "--participants", "1")
    assert res.exit_code != 0
    assert "is a study of people (1 person registered)" in res.output
    assert "--alongside-people" in res.output
    assert sqlite3.connect(db).execute("select count(*) from participants where synthetic = 1").fetchone()[0] == 0
    res = studyctl("synth", "--db", db, "--participants", "1", "--alongside-people")
    assert res.exit_code == 0, res.output
    first = studyctl("report", "table1", "--db", db).output.strip().splitlines()[0]
    assert "MIXED DATA" in first, first
    assert "1 person" in first, first
    assert "1 SYNTHETIC" in first, first


def test_an_interrupted_synth_leaves_no_participant_without_a_session(tmp_path, monkeypatch):
    import studyctl.synthetic.synth_run as runner  # where the synthetic study takes its completed sessions from

    db = tmp_path / "s.db"
    proto = fast_protocol(tmp_path, conditions=("plate_spring",), trials=1)
    real = runner.completed

    def one_then_ctrl_c(fn, tasks, jobs, scheduler):
        for k, item in enumerate(real(fn, tasks, jobs, scheduler)):
            if k == 1:
                raise KeyboardInterrupt
            yield item

    monkeypatch.setattr(runner, "completed", one_then_ctrl_c)
    res = studyctl("synth", "--db", db, "--participants", "3", "--protocol", proto, "--seed", "4")
    assert res.exit_code != 0
    assert "Traceback" not in res.output
    assert "interrupted after 1 of 3 sessions" in res.output, res.output
    assert f"`studyctl synth --db {db} --complete`" in res.output, res.output
    monkeypatch.setattr(runner, "completed", real)
    con = sqlite3.connect(db)
    assert con.execute("select count(*) from participants").fetchone()[0] == 3
    res = studyctl("synth", "--db", db, "--complete", "--participants", "1", "--seed", "9")
    assert res.exit_code == 0, res.output
    assert "ran 3 SYNTHETIC sessions of 'brain_pull_2015': 1 new (seed 9), 2 left by an interrupted run, run from the start (S002, S003; seed 4);" in res.output, res.output
    orphans = con.execute("select count(*) from participants p where not exists (select 1 from sessions s where s.code = p.code)")
    assert orphans.fetchone()[0] == 0
    seeds = dict(con.execute("select code, seed from sessions").fetchall())
    assert seeds == {"S001": 4, "S002": 4, "S003": 4, "S004": 9}


TEXT_PROTOCOL = """
[[questions]]
id = "comment"
text = "Anything else?"
kind = "text"
when = "end"
"""


def _text_study(tmp_path):
    db = tmp_path / "s.db"
    proto = fast_protocol(tmp_path, conditions=("plate_spring",), trials=1)
    proto.write_text(proto.read_text() + TEXT_PROTOCOL)
    assert studyctl("study", "init", "--db", db, "--protocol", proto).exit_code == 0, proto.read_text()
    assert studyctl("participants", "add", "P01", "--db", db, "--age", "24").exit_code == 0
    assert studyctl("participants", "consent", "P01", "--db", db).exit_code == 0
    return db


@pytest.mark.parametrize("char", ["\x00", "\x1b", "\x7f"])
def test_text_answers_with_control_characters_are_refused(tmp_path, char):
    db = _text_study(tmp_path)
    bad = tmp_path / "a.csv"
    bad.write_text(f"participant,model,item,answer\nP01,,comment,fine{char}rest\n")
    res = studyctl("answers", "import", "--db", db, bad)
    assert res.exit_code != 0, res.output
    assert f"a.csv: line 2: answer: control character U+{ord(char):04X}" in res.output, res.output
    assert sqlite3.connect(db).execute("select count(*) from answers").fetchone()[0] == 0


def test_exports_neutralise_spreadsheet_formulas(tmp_path):
    db = _text_study(tmp_path)
    good = tmp_path / "a.csv"
    good.write_text('participant,model,item,answer\nP01,,comment,"=HYPERLINK(""http://x"",""y"")"\n')
    assert studyctl("answers", "import", "--db", db, good).exit_code == 0
    stored = sqlite3.connect(db).execute("select answer from answers").fetchone()[0]
    assert stored == '=HYPERLINK("http://x","y")'  # stored as given
    out = tmp_path / "export"
    assert studyctl("export", "--db", db, "--out", out).exit_code == 0
    with open(out / "answers.csv", newline="") as fh:
        cells = [r["answer"] for r in csv.DictReader(fh)]
    assert cells == ["'=HYPERLINK(\"http://x\",\"y\")"]


def test_a_long_refused_value_is_quoted_by_a_short_prefix(tmp_path):
    db = _text_study(tmp_path)
    bad = tmp_path / "a.csv"
    bad.write_text("participant,model,item,answer\nP01,plate_spring,natural," + "y" * 10_000 + "\n")
    res = studyctl("answers", "import", "--db", db, bad)
    assert res.exit_code != 0
    assert "(10000 characters)" in res.output
    assert len(res.output) < 400, res.output


def test_names_contacts_and_reasons_with_control_characters_are_refused(tmp_path):
    db = _text_study(tmp_path)
    res = studyctl("participants", "add", "P02", "--db", db, "--age", "24", "--name", "Ann\x00e")
    assert res.exit_code != 0
    assert "--name: control character U+0000 at character 4" in res.output
    res = studyctl("participants", "withdraw", "P01", "--db", db, "--reason", "moved\x1b[2J")
    assert res.exit_code != 0
    assert "--reason: control character U+001B" in res.output
    con = sqlite3.connect(db)
    assert con.execute("select count(*) from participants").fetchone()[0] == 1
    assert con.execute("select count(*) from participants where withdrawn_at is not null").fetchone()[0] == 0


@pytest.mark.parametrize("kind", ["yes_no", "rating", "discrimination", "validity"])
def test_protocol_new_writes_a_protocol_that_validates_and_runs_from_its_own_folder(tmp_path, kind):
    import json as _json
    import os

    out = tmp_path / "lab" / "study"
    res = studyctl("protocol", "new", "--kind", kind, "--out", out, "--name", "my_study", "--json")
    assert res.exit_code == 0, res.output
    made = _json.loads(res.output)
    assert made["name"] == "my_study"
    assert (out / "protocol.toml").exists()
    assert (out / "scene.toml").exists()
    assert "../" not in (out / "scene.toml").read_text()  # every path resolves from anywhere
    elsewhere = tmp_path / "other"
    elsewhere.mkdir()
    cwd = os.getcwd()
    try:
        os.chdir(elsewhere)
        res = studyctl("protocol", "validate", out / "protocol.toml")
    finally:
        os.chdir(cwd)
    assert res.exit_code == 0, res.output
    assert "my_study" in res.output, res.output
    res = studyctl("protocol", "new", "--kind", kind, "--out", out)
    assert res.exit_code != 0
    assert "protocol.toml: exists (and 1 more of the files this command writes); --force overwrites them" in res.output


def test_inclusion_and_latency_have_documented_defaults_and_a_missing_section_says_what_to_write(tmp_path):
    from studyctl.protocol import DEFAULT_AGES, DEFAULT_LATENCY, load_protocol

    proto = fast_protocol(tmp_path)
    text = proto.read_text()
    for section in ("[inclusion]", "[latency]"):
        start = text.index(section)
        end = text.index("\n[", start + 1)
        text = text[:start] + text[end + 1:]
    proto.write_text(text)
    p = load_protocol(proto)
    assert (p.age_min, p.age_max) == DEFAULT_AGES
    assert p.latency_measures == DEFAULT_LATENCY
    start = text.index("[study]")
    end = text.index("\n[", start + 1)
    proto.write_text(text[:start] + text[end + 1:])
    res = studyctl("protocol", "validate", proto)
    assert res.exit_code != 0
    assert "study: missing section; write [study] with name = " in res.output
    docs = (Path(__file__).resolve().parents[1] / "docs/study.md").read_text()
    assert "`[inclusion]` left out: adults, 18-120" in docs
    assert "`[latency]` left out:" in docs


def test_docs_list_every_section_and_key_the_validator_knows():
    from studyctl.protocol import SECTIONS

    docs = (Path(__file__).resolve().parents[1] / "docs/study.md").read_text()
    for section, keys in SECTIONS.items():
        assert f"`[{section}" in docs or f"`[[{section}]]`" in docs, section
        for key in keys or ():
            assert f"`{key}`" in docs, (section, key)
