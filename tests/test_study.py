"""Study management: protocols, store, participants, schedule, sessions, resume, exports."""

import json
import os
import signal
import sqlite3
import subprocess
import sys
import time

import pytest
from click.testing import CliRunner

from studyctl.cli import cli
from studyctl.protocol import check_protocol, load_protocol
from studyctl.schedule import williams
from tests.conftest import ROOT
from tests.helpers import PROTOCOL, count_rows, fast_protocol, pty_session, studyctl


def test_shipped_protocol_is_the_papers_study():
    p = load_protocol(PROTOCOL)
    assert p.conditions == ("fem", "mass_spring", "plate_spring")
    assert p.counterbalancing == "williams"
    assert p.items == ("natural", "behaviour", "texture", "comfortable", "guidance", "realtime", "feedback", "deformation", "stable")
    assert (p.target_participants, p.age_min, p.age_max, p.training_minutes) == (35, 22, 28, 5.0)


def test_williams_design_balances_first_order_carry_over():
    for n in (2, 3, 4, 5):
        rows = williams(n)
        assert len(rows) == (n if n % 2 == 0 else 2 * n)
        follows = {}
        for r in rows:
            assert sorted(r) == list(range(n))
            for a, b in zip(r, r[1:]):
                follows[(a, b)] = follows.get((a, b), 0) + 1
        assert len(set(follows.values())) == 1
        assert len(follows) == n * (n - 1)
    assert len({tuple(r) for r in williams(3)}) == 6  # all six orders of three models


BROKEN = {
    "syntax": ("[study\nname = 1", r"protocol.toml:1: invalid TOML:"),
    "unknown_model": ('conditions = ["fem", "mass_spring", "plate_spring"]', 'conditions = ["fem", "rubber"]',
                      r"protocol.toml:\d+: design.conditions: unknown condition 'rubber'; allowed: a \[conditions.NAME\] table or a model name \(fem, mass_spring, plate_spring\)"),
    "wrong_type": ("trials_per_condition = 3", 'trials_per_condition = "three"', r":\d+: design.trials_per_condition: 'three' is not an integer"),
    "out_of_range": ("age_max = 28", "age_max = 200", r":\d+: inclusion.age_max: 200 is out of range; allowed: 0..120"),
    "duplicate_id": ('id = "texture"', 'id = "natural"', r":\d+: questions\[2\].id: duplicate item id 'natural' \(also questions\[0\]\)"),
    "missing_section": ("[inclusion]", "[inclusions]", r":\d+: inclusions: unknown section"),
    "bad_design": ('counterbalancing = "williams"', 'counterbalancing = "random"', r"design.counterbalancing: 'random' is not one of williams"),
}


@pytest.mark.parametrize("case", sorted(BROKEN))
def test_broken_protocols_give_precise_errors_without_traceback(tmp_path, case):
    spec = BROKEN[case]
    path = tmp_path / "protocol.toml"
    if case == "syntax":
        path.write_text(spec[0])
        pattern = spec[1]
    else:
        old, new, pattern = spec
        text = PROTOCOL.read_text()
        assert old in text
        path.write_text(text.replace(old, new).replace('scene = "scenes/', f'scene = "{ROOT}/protocols/scenes/'))
    proc = subprocess.run([sys.executable, "-m", "studyctl.cli", "protocol", "validate", str(path)], capture_output=True, text=True)
    assert proc.returncode == 1
    assert "Traceback" not in proc.stderr
    import re

    assert re.search(pattern, proc.stderr), proc.stderr
    # the line number points at the offending line
    line = int(proc.stderr.split(":")[1])
    if case == "out_of_range":
        assert "age_max" in path.read_text().splitlines()[line - 1]


def test_every_problem_is_reported(tmp_path):
    text = PROTOCOL.read_text().replace("age_max = 28", "age_max = 200").replace('id = "texture"', 'id = "natural"')
    text = text.replace('scene = "scenes/', f'scene = "{ROOT}/protocols/scenes/')
    (tmp_path / "p.toml").write_text(text)
    _, problems = check_protocol(tmp_path / "p.toml")
    assert len(problems) == 2


def test_participants_schedule_and_ics(tmp_path):
    db = tmp_path / "s.db"
    assert studyctl("study", "init", "--protocol", PROTOCOL, "--db", db).exit_code == 0
    env = {"STUDYCTL_DB": str(db)}
    assert studyctl("participants", "add", "P01", "--age", "24", env=env).exit_code == 0
    res = studyctl("participants", "add", "P02", "--age", "30", env=env)
    assert res.exit_code == 1
    assert "outside the inclusion range 22..28" in res.output
    (tmp_path / "p.csv").write_text("code,age,name\nP02,23,Bob Real\nP03,25,\nP04,22,\n")
    assert studyctl("participants", "import", tmp_path / "p.csv", env=env).exit_code == 0
    (tmp_path / "bad.csv").write_text("code,age\nP05,23\nP06,99\n")
    res = studyctl("participants", "import", tmp_path / "bad.csv", env=env)
    assert res.exit_code == 1
    assert "line 3" in res.output
    assert [r[0] for r in sqlite3.connect(db).execute("select code from participants order by code")] == ["P01", "P02", "P03", "P04"]  # all or none
    (tmp_path / "avail.csv").write_text("code,date,start,end\nP01,2037-12-01,13:00,17:00\nP02,2037-12-01,09:00,12:00\n"
                                        "P03,2037-12-01,09:00,12:00\nP04,2037-12-02,09:00,10:00\n")
    res = studyctl("schedule", "--start", "2037-12-01", "--end", "2037-12-02", "--availability", tmp_path / "avail.csv",
                   "--ics", tmp_path / "s.ics", "--json", env=env)
    assert res.exit_code == 0, res.output
    rows = json.loads(res.output)
    slots = {r["code"]: (r["slot_start"], r["slot_end"]) for r in rows}
    # on the 45-minute grid from 09:00, within each participant's availability
    assert slots["P01"] == ("2037-12-01T13:30:00", "2037-12-01T14:15:00")
    assert slots["P04"] == ("2037-12-02T09:00:00", "2037-12-02T09:45:00")
    assert slots["P02"][1] <= "2037-12-01T12:00:00"
    assert slots["P03"][1] <= "2037-12-01T12:00:00"
    spans = sorted(slots.values())
    assert all(a[1] <= b[0] for a, b in zip(spans, spans[1:]))  # one rig: no overlap
    orders = [tuple(json.loads(r["conditions"])) for r in rows]
    assert len(set(orders)) == 4  # four participants, four different Williams rows
    ics = (tmp_path / "s.ics").read_text()
    assert ics.count("BEGIN:VEVENT") == 4
    assert "DTSTART:20371201T133000" in ics


def test_session_killed_with_sigkill_resumes_with_every_answer_exactly_once(tmp_path):
    db = tmp_path / "s.db"
    studyctl("study", "init", "--protocol", fast_protocol(tmp_path), "--db", db)
    studyctl("participants", "add", "P01", "--age", "24", "--synthetic", "--db", db)
    cmd = [sys.executable, "-m", "studyctl.cli", "session", "run", "--db", str(db), "--participant", "P01", "--synthetic"]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.time() + 120
    while count_rows(db) < 5 and time.time() < deadline and proc.poll() is None:
        time.sleep(0.05)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    before = count_rows(db)
    assert 5 <= before < 27
    res = studyctl("session", "run", "--db", db, "--participant", "P01", "--synthetic")
    assert res.exit_code == 1
    assert "--resume" in res.output
    res = studyctl("session", "run", "--db", db, "--participant", "P01", "--synthetic", "--resume")
    assert res.exit_code == 0, res.output
    con = sqlite3.connect(db)
    rows = con.execute("select code, model, item, count(*) from answers group by code, model, item").fetchall()
    assert len(rows) == 27  # 3 models x 9 items, each once
    assert all(r[3] == 1 for r in rows)
    assert con.execute("select count(*) from trials").fetchone()[0] == 6  # no trial run twice
    assert con.execute("pragma integrity_check").fetchone()[0] == "ok"
    session = con.execute("select status, protocol_sha256, scene_sha256, software_version, synthetic from sessions").fetchone()
    assert session[0] == "done"
    assert len(session[1]) == 64
    assert len(session[2]) == 64
    assert session[3]
    assert session[4] == 1


def test_a_session_and_an_import_write_at_once(tmp_path):
    db = tmp_path / "s.db"
    studyctl("study", "init", "--protocol", fast_protocol(tmp_path, conditions=("plate_spring",), trials=3), "--db", db)
    studyctl("participants", "add", "P01", "--synthetic", "--db", db)
    studyctl("participants", "add", "P02", "--db", db)
    studyctl("participants", "consent", "P02", "--db", db)
    session = subprocess.Popen([sys.executable, "-m", "studyctl.cli", "session", "run", "--db", str(db), "--participant", "P01", "--synthetic"],
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    lines = ["participant,model,item,answer"] + [f"P02,plate_spring,{q},yes" for q in load_protocol(PROTOCOL).items]
    (tmp_path / "a.csv").write_text("\n".join(lines) + "\n")
    imports = [subprocess.run([sys.executable, "-m", "studyctl.cli", "answers", "import", "--db", str(db), str(tmp_path / "a.csv")],
                              capture_output=True, text=True) for _ in range(2)]
    out, err = session.communicate(timeout=120)
    assert session.returncode == 0, err
    assert imports[0].returncode == 0
    assert imports[1].returncode == 1
    assert "already answered" in imports[1].stderr
    con = sqlite3.connect(db)
    assert con.execute("pragma integrity_check").fetchone()[0] == "ok"
    assert con.execute("select count(*) from answers").fetchone()[0] == 18


def test_answers_import_rejects_the_whole_file(tmp_path):
    db = tmp_path / "s.db"
    studyctl("study", "init", "--protocol", PROTOCOL, "--db", db)
    studyctl("participants", "add", "P01", "--db", db)
    studyctl("participants", "consent", "P01", "--db", db)
    (tmp_path / "a.csv").write_text("participant,model,item,answer\nP01,fem,natural,yes\nP01,fem,colour,no\n")
    res = studyctl("answers", "import", "--db", db, tmp_path / "a.csv")
    assert res.exit_code == 1
    assert "line 3: unknown item 'colour'" in res.output
    (tmp_path / "b.csv").write_text("participant,model,item,answer\nP01,fem,natural,yes\nP09,fem,texture,no\n")
    assert "unknown participant 'P09'" in studyctl("answers", "import", "--db", db, tmp_path / "b.csv").output
    assert sqlite3.connect(db).execute("select count(*) from answers").fetchone()[0] == 0


def test_exports_never_contain_identifying_fields(tmp_path):
    db = tmp_path / "s.db"
    studyctl("study", "init", "--protocol", PROTOCOL, "--db", db)
    studyctl("participants", "add", "P01", "--age", "24", "--name", "Ann Secretname", "--contact", "ann@example.org", "--db", db)
    studyctl("participants", "consent", "P01", "--db", db)
    (tmp_path / "a.csv").write_text("participant,model,item,answer\nP01,fem,natural,yes\n")
    studyctl("answers", "import", "--db", db, tmp_path / "a.csv")
    for fmt in ("csv", "parquet"):
        res = studyctl("export", "--db", db, "--format", fmt, "--out", tmp_path / fmt)
        assert res.exit_code == 0, res.output
        blob = b"".join(p.read_bytes() for p in (tmp_path / fmt).iterdir())
        assert b"Secretname" not in blob
        assert b"example.org" not in blob
        assert b"contact" not in blob
        assert not (tmp_path / fmt / f"identities.{fmt}").exists()
    assert "P01" in (tmp_path / "csv" / "answers.csv").read_text()


def test_terminal_questionnaire_through_a_real_pty(tmp_path):
    db = tmp_path / "s.db"
    studyctl("study", "init", "--protocol", fast_protocol(tmp_path, conditions=("plate_spring",), trials=1), "--db", db)
    studyctl("participants", "add", "P01", "--db", db)
    studyctl("participants", "consent", "P01", "--db", db)
    answers = iter(["y", "maybe", "n"] + ["y"] * 8)
    text = pty_session(["session", "run", "--db", db, "--participant", "P01", "--time-scale", "0"], lambda: next(answers))
    assert "Is interaction real and natural? [y/n]" in text
    assert "Please answer yes or no (y/n, 1/0)." in text
    got = dict(sqlite3.connect(db).execute("select item, answer from answers").fetchall())
    assert len(got) == 9
    assert got["natural"] == 1
    assert got["behaviour"] == 0
    assert got["stable"] == 1
    assert "complete" in text


def test_session_on_openhaptics_without_the_library_is_a_clean_error(tmp_path, monkeypatch):
    db = tmp_path / "s.db"
    studyctl("study", "init", "--protocol", fast_protocol(tmp_path, conditions=("plate_spring",), trials=1), "--db", db)
    studyctl("participants", "add", "P01", "--db", db)
    studyctl("participants", "consent", "P01", "--db", db)
    monkeypatch.setenv("BRAINSIM_LIBHD", str(tmp_path / "none" / "libHD.so"))
    res = studyctl("session", "run", "--db", db, "--participant", "P01", "--device", "openhaptics", "--view", "none")
    assert res.exit_code == 1
    assert "libHD.so) was not found" in res.output
    assert sqlite3.connect(db).execute("select count(*) from sessions").fetchone()[0] == 0  # nothing half-written
    res = studyctl("session", "run", "--db", db, "--participant", "P01", "--device", "openhaptics", "--time-scale", "0")
    assert res.exit_code == 1
    assert "real time only" in res.output


def test_ics_round_trips_through_icalendar_with_escapes_folding_and_the_time_zone():
    import icalendar

    from studyctl.schedule import to_ics

    name, title = "Pull, study; A\\B", "A long description, with; every\\special character " + "x" * 150
    assert len(title) >= 200
    slots = [{"code": "P01", "slot_start": "2037-12-01T13:30:00", "slot_end": "2037-12-01T14:15:00",
              "conditions": json.dumps(["fem", "mass_spring", "plate_spring"])}]
    text = to_ics(slots, name, "Asia/Shanghai", title)
    assert all(len(line.encode()) <= 75 for line in text.split("\r\n"))  # RFC 5545 folding
    assert "SUMMARY:Pull\\, study\\; A\\\\B: session P01" in text  # RFC 5545 escaping
    cal = icalendar.Calendar.from_ical(text)
    (ev,) = cal.walk("VEVENT")
    assert str(ev["summary"]) == f"{name}: session P01"
    assert str(ev["description"]) == f"{title}\norder fem > mass_spring > plate_spring"
    start = ev.decoded("dtstart")
    assert start.isoformat() == "2037-12-01T13:30:00+08:00"
    assert str(start.tzinfo) == "Asia/Shanghai"
    assert [str(tz["tzid"]) for tz in cal.walk("VTIMEZONE")] == ["Asia/Shanghai"]
    # no time zone in the protocol: floating local times, as before
    floating = icalendar.Calendar.from_ical(to_ics(slots, name))
    assert floating.walk("VEVENT")[0].decoded("dtstart").tzinfo is None


def test_protocol_time_zone_is_checked(tmp_path):
    from studyctl.protocol import check_protocol

    text = PROTOCOL.read_text().replace('version = 1\n', 'version = 1\ntimezone = "Mars/Olympus"\n', 1)
    path = tmp_path / "p.toml"
    path.write_text(text.replace('scene = "scenes/brain_pull.toml"', f'scene = "{ROOT}/protocols/scenes/brain_pull.toml"'))
    _, problems = check_protocol(path)
    assert any("study.timezone" in p and "IANA" in p for p in problems)


def _commands(group, prefix=()):
    import click

    for name, cmd in group.commands.items():
        if getattr(cmd, "hidden", False):
            continue
        if isinstance(cmd, click.Group):
            if cmd.invoke_without_command:
                yield (*prefix, name), cmd
            yield from _commands(cmd, (*prefix, name))
        else:
            yield (*prefix, name), cmd


def test_cli_conventions_hold_for_every_command():
    """-h everywhere; --json wherever something is reported; the study database's environment
    variable shown; models spelt either way; python -m studyctl."""
    import subprocess
    import sys

    missing = []
    for path, cmd in _commands(cli):
        res = CliRunner().invoke(cli, [*path, "-h"])
        assert res.exit_code == 0, path
        assert "Usage:" in res.output, path
        names = {o for p in cmd.params for o in getattr(p, "opts", [])}
        fmt = next((p for p in cmd.params if "--format" in getattr(p, "opts", [])), None)
        if "--json" not in names and not (fmt is not None and "json" in getattr(fmt.type, "choices", ())):
            missing.append(path)
        if "--db" in names:
            assert "STUDYCTL_DB" in res.output, path
    assert missing == []
    assert "The paper's plate-spring model" in CliRunner().invoke(cli, ["model", "plate_spring", "-h"]).output
    out = subprocess.run([sys.executable, "-m", "studyctl", "--version"], capture_output=True, text=True, cwd=ROOT)
    assert out.returncode == 0
    assert out.stdout.startswith("studyctl, version ")


def test_a_missing_extra_is_a_one_line_error_naming_it(tmp_path, monkeypatch):
    from sim.sweep import SweepError, connect

    db = tmp_path / "s.db"
    studyctl("study", "init", "--db", db)  # the shipped protocol
    monkeypatch.setitem(sys.modules, "pyarrow", None)  # as if not installed: its import raises ModuleNotFoundError
    monkeypatch.setitem(sys.modules, "pyarrow.parquet", None)
    res = studyctl("export", "--db", db, "--format", "parquet", "--out", tmp_path / "out")
    assert res.exit_code == 1
    assert "brainsim-study[parquet]" in res.output
    assert len(res.output.strip().splitlines()) == 1
    assert not (tmp_path / "out").exists()  # nothing written
    monkeypatch.setitem(sys.modules, "distributed", None)  # as if not installed
    with pytest.raises(SweepError, match=r"brainsim-study\[dask\]"):
        connect("tcp://127.0.0.1:1")
