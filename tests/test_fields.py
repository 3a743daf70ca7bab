"""Participant fields and groups (issue 32, item 1): the protocol's [fields.NAME] and
design.groups, values at registration and import, stored and exported, orders balanced within
each group, synthetic participants in balanced groups."""

import json
import sqlite3
from collections import Counter
from pathlib import Path

import pytest

from studyctl.protocol import check_protocol, load_protocol
from studyctl.schedule import williams
from tests.helpers import FIELDS, fast_protocol, field_protocol, studyctl


def study(tmp_path: Path, **kw) -> Path:
    db = tmp_path / "study.db"
    res = studyctl("study", "init", "--protocol", field_protocol(tmp_path, **kw), "--db", db)
    assert res.exit_code == 0, res.output
    return db


def _q(db, sql, args=()):
    con = sqlite3.connect(db)
    try:
        return con.execute(sql, args).fetchall()
    finally:
        con.close()


def test_a_protocol_with_fields_and_groups_loads(tmp_path):
    p = load_protocol(field_protocol(tmp_path))
    assert p.groups == "experience"
    assert [f.name for f in p.fields] == ["experience", "years", "hours_per_week", "note"]
    exp = p.group_field
    assert exp.kind == "choice"
    assert exp.values == ("student", "resident", "neurosurgeon")
    assert exp.required
    years = p.field_named("years")
    assert (years.min, years.max, years.required) == (0, 40, False)
    assert not p.field_named("note").analysed


def test_the_group_field_is_required_even_when_the_protocol_does_not_say_so(tmp_path):
    p = load_protocol(field_protocol(tmp_path, fields=FIELDS.replace("required = true\n", "")))
    assert p.group_field.required


BAD = [
    ('[fields.x]\nkind = "colour"\n', None, "fields.x.kind", "'colour' is not a field kind; allowed: choice, integer, number, text"),
    ('[fields.x]\nkind = "choice"\nvalues = ["a", "b"]\nunits = "mm"\n', None, "fields.x.units", "unknown key; allowed: kind, values"),
    ('[fields.x]\nkind = "choice"\n', None, "fields.x.values", "missing"),
    ('[fields.x]\nkind = "choice"\nvalues = ["a"]\n', None, "fields.x.values", "at least two non-empty texts"),
    ('[fields.x]\nkind = "choice"\nvalues = ["a", "a"]\n', None, "fields.x.values", "a value appears twice"),
    ('[fields.x]\nkind = "integer"\nmin = 10\nmax = 2\n', None, "fields.x.max", "2 is below min 10"),
    ('[fields.x]\nkind = "integer"\nmin = 1.5\n', None, "fields.x.min", "1.5 is not an integer"),
    ('[fields.x]\nkind = "text"\nvalues = ["a", "b"]\n', None, "fields.x.values", "only a choice field has values"),
    ('[fields.x]\nkind = "choice"\nvalues = ["a", "b"]\n', "experience", "design.groups", "'experience' names no field; allowed: a [fields.NAME] choice (x)"),
    ('[fields.x]\nkind = "integer"\n[fields.y]\nkind = "choice"\nvalues = ["a", "b"]\n', "x", "design.groups",
     "'x' is a integer field; the groups are a choice field's values; allowed: y"),
    ('[fields.Bad]\nkind = "text"\n', None, "fields.Bad", "must be lower-case letters"),
    ('[fields.age]\nkind = "integer"\n', None, "fields.age", "is a participant's own column"),
    ("", "experience", "design.groups", "'experience' names no field; allowed: a [fields.NAME] table with kind = \"choice\""),
]


@pytest.mark.parametrize("fields,groups,where,message", BAD, ids=[b[2] + ":" + b[3][:20] for b in BAD])
def test_a_bad_field_is_refused_at_its_line_with_what_is_allowed(tmp_path, fields, groups, where, message):
    path = field_protocol(tmp_path, fields=fields, groups=groups)
    protocol, problems = check_protocol(path)
    assert protocol is None
    hits = [p for p in problems if f": {where}: " in p and message in p]
    assert hits, problems
    file, line, _ = hits[0].split(":", 2)
    assert file == str(path)
    key = where.split(".")[-1] if where.count(".") == 2 else where.rpartition(".")[2]
    text_line = path.read_text().splitlines()[int(line) - 1]
    assert key in text_line or where.split(".")[1] in text_line, (hits[0], text_line)
    res = studyctl("protocol", "validate", path)
    assert res.exit_code != 0
    assert message in res.output


def test_registration_stores_typed_values_and_export_includes_them(tmp_path):
    db = study(tmp_path)
    res = studyctl("participants", "add", "P01", "--field", "experience=resident", "--field", "years=3", "--field", "hours_per_week=2.5",
                   "--field", "note=left-handed", "--db", db, "--json")
    assert res.exit_code == 0, res.output
    assert json.loads(res.output)["fields"] == {"experience": "resident", "years": 3, "hours_per_week": 2.5, "note": "left-handed"}
    rows = dict(_q(db, "select field, value from participant_fields where code = 'P01'"))
    assert rows == {"experience": "resident", "years": 3, "hours_per_week": 2.5, "note": "left-handed"}
    assert studyctl("participants", "add", "P02", "--field", "experience=student", "--db", db).exit_code == 0
    out = tmp_path / "export"
    assert studyctl("export", "--db", db, "--out", out).exit_code == 0
    import pandas as pd

    df = pd.read_csv(out / "participant_fields.csv")
    assert list(df.columns) == ["code", "field", "value"]
    assert len(df) == 5
    assert set(df[df.code == "P02"].value) == {"student"}


@pytest.mark.parametrize("args,message", [
    (["--field", "experience=professor"], "participant P01: experience = 'professor' is not allowed; allowed: student, resident, neurosurgeon"),
    (["--field", "experience=student", "--field", "years=41"], "years = '41' is not allowed; allowed: an integer in 0..40"),
    (["--field", "experience=student", "--field", "years=two"], "years = 'two' is not allowed; allowed: an integer in 0..40"),
    (["--field", "experience=student", "--field", "hours_per_week=nan"], "hours_per_week = 'nan' is not allowed; allowed: a number"),
    ([], "participant P01: field experience is required; allowed: student, resident, neurosurgeon"),
    (["--field", "experience=student", "--field", "handedness=left"],
     "unknown field 'handedness'; allowed: experience, years, hours_per_week, note"),
    (["--field", "experience"], "--field: 'experience' is not NAME=VALUE"),
    (["--field", "experience=student", "--field", "experience=resident"], "--field: experience is given twice"),
])
def test_a_value_outside_its_field_is_refused_and_nothing_written(tmp_path, args, message):
    db = study(tmp_path)
    res = studyctl("participants", "add", "P01", *args, "--db", db)
    assert res.exit_code != 0, res.output
    assert message in res.output, res.output
    assert len(res.output.strip().splitlines()) == 1
    assert _q(db, "select count(*) from participants") == [(0,)]
    assert _q(db, "select count(*) from participant_fields") == [(0,)]


def test_a_study_without_fields_refuses_any(tmp_path):
    db = tmp_path / "study.db"
    assert studyctl("study", "init", "--protocol", fast_protocol(tmp_path), "--db", db).exit_code == 0
    res = studyctl("participants", "add", "P01", "--field", "experience=student", "--db", db)
    assert res.exit_code != 0
    assert "unknown field 'experience'; allowed: none" in res.output


def test_import_reads_field_columns_all_or_none(tmp_path):
    db = study(tmp_path)
    good = tmp_path / "people.csv"
    good.write_text("Code;Age;Experience;Years\nP01;23;student;0\nP02;25;neurosurgeon;12\nP03;24;resident;\n")
    res = studyctl("participants", "import", good, "--db", db)
    assert res.exit_code == 0, res.output
    assert _q(db, "select code, field, value from participant_fields order by code, field") == [
        ("P01", "experience", "student"), ("P01", "years", 0), ("P02", "experience", "neurosurgeon"), ("P02", "years", 12),
        ("P03", "experience", "resident")]
    cases = [
        ("code,experience\nQ01,student\nQ02,professor\n", "line 3: experience = 'professor' is not allowed; allowed: student, resident, neurosurgeon"),
        ("code,age\nQ01,23\n", "no 'experience' column"),
        ("code,experience,handedness\nQ01,student,left\n", "unknown column 'handedness'; allowed: code, age, name, contact, experience, years"),
        ("code,experience\nQ01,\n", "line 2: field experience is required"),
    ]
    for k, (text, message) in enumerate(cases):
        bad = tmp_path / f"bad{k}.csv"
        bad.write_text(text)
        res = studyctl("participants", "import", bad, "--db", db)
        assert res.exit_code != 0, (text, res.output)
        assert message in res.output, (text, res.output)
    assert _q(db, "select count(*) from participants") == [(3,)]
    assert _q(db, "select count(*) from participant_fields") == [(5,)]


def test_orders_are_balanced_within_each_group(tmp_path):
    db = study(tmp_path)
    people = tmp_path / "people.csv"
    # 2 groups of 6, interleaved: 3 conditions have 6 Williams orders, each group gets each once
    people.write_text("code,experience\n" + "".join(f"P{k:02d},{('student', 'neurosurgeon')[k % 2]}\n" for k in range(12)))
    assert studyctl("participants", "import", people, "--db", db).exit_code == 0
    res = studyctl("schedule", "--start", "2099-01-05", "--end", "2099-01-30", "--db", db, "--json")
    assert res.exit_code == 0, res.output
    group = dict(_q(db, "select code, value from participant_fields where field = 'experience'"))
    orders = {g: Counter() for g in ("student", "neurosurgeon")}
    for r in json.loads(res.output):
        orders[group[r["code"]]][r["order_index"]] += 1
    for g, counts in orders.items():
        assert sorted(counts) == list(range(len(williams(3)))), (g, counts)
        assert set(counts.values()) == {1}, (g, counts)


def test_synthetic_participants_get_balanced_groups_and_a_single_condition_study_runs(tmp_path):
    db = study(tmp_path, conditions=("plate_spring",), trials=1)
    res = studyctl("synth", "--db", db, "--participants", "3", "--seed", "2")
    assert res.exit_code == 0, res.output
    groups = _q(db, "select code, value from participant_fields where field = 'experience' order by code")
    assert groups == [("S001", "student"), ("S002", "resident"), ("S003", "neurosurgeon")]
    assert _q(db, "select count(*) from sessions where status = 'done'") == [(3,)]
    assert _q(db, "select count(distinct model) from trials") == [(1,)]
    res = studyctl("report", "table1", "--db", db)
    assert res.exit_code == 0, res.output
    assert "n/a (one condition)" in res.output
    assert "One condition: there is nothing to compare between conditions" in res.output
    for fmt in ("csv", "latex", "html", "json"):  # one condition is still a report, in every format
        out = tmp_path / f"table1.{fmt}"
        res = studyctl("report", "table1", "--db", db, "--format", fmt, "--out", out)
        assert res.exit_code == 0, (fmt, res.output)
        assert res.output == f"wrote {out}\n", fmt
        assert out.stat().st_size > 0, fmt


def test_synthetic_groups_continue_in_turn_and_are_the_same_for_the_same_seed(tmp_path):
    from studyctl.fields import synthetic_fields

    p = load_protocol(field_protocol(tmp_path))
    a = synthetic_fields(p, [f"S{k:03d}" for k in range(1, 8)], seed=1)
    assert Counter(v["experience"] for v in a.values()) == {"student": 3, "resident": 2, "neurosurgeon": 2}
    assert a == synthetic_fields(p, [f"S{k:03d}" for k in range(1, 8)], seed=1)
    assert synthetic_fields(p, ["S008"], seed=1, start=7)["S008"]["experience"] == "resident"
    assert set(a["S001"]) == {"experience"}  # only required fields are given a value


def test_the_list_shows_each_participants_group_and_a_deleting_withdrawal_deletes_their_fields(tmp_path):
    path = field_protocol(tmp_path)
    path.write_text(path.read_text().replace('withdrawal = "keep"', 'withdrawal = "delete"'))
    db = tmp_path / "study.db"
    assert studyctl("study", "init", "--protocol", path, "--db", db).exit_code == 0
    for code, group in (("P01", "student"), ("P02", "neurosurgeon")):
        assert studyctl("participants", "add", code, "--field", f"experience={group}", "--field", "years=1", "--db", db).exit_code == 0
    listed = {r["code"]: r["group"] for r in json.loads(studyctl("participants", "list", "--json", "--db", db).output)}
    assert listed == {"P01": "student", "P02": "neurosurgeon"}
    assert "neurosurgeon" in studyctl("participants", "list", "--db", db).output
    assert studyctl("participants", "withdraw", "P01", "--db", db).exit_code == 0
    assert _q(db, "select code, field from participant_fields order by field") == [("P02", "experience"), ("P02", "years")]
