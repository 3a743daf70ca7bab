"""Bad input on the command line: one line naming the option and the allowed range, exit status
1 or 2, no traceback, nothing written (a first part of issue 15's corpus)."""

import sqlite3

import pytest
from click.testing import CliRunner

from studyctl.cli import cli
from tests.helpers import fast_protocol, studyctl


@pytest.mark.parametrize("args, needle", [
    (["sim", "run", "--duration", "nan", "--time-scale", "0"], "'nan' is not a finite number"),
    (["sim", "run", "--duration", "inf", "--time-scale", "0"], "--duration"),
    (["sim", "run", "--duration", "1e12", "--time-scale", "0"], "--duration"),
    (["sim", "run", "--time-scale", "nan"], "'nan' is not a finite number"),
    (["sim", "live", "--duration", "nan"], "'nan' is not a finite number"),
    (["model", "mass-spring", "--integrator", "explicit", "--dt", "nan"], "'nan' is not a finite number"),
    (["model", "mass-spring", "--integrator", "explicit", "--dt", "inf"], "--dt"),
    (["model", "mass-spring", "--integrator", "explicit", "--dt", "1e9"], "--dt"),
    (["plan", "--seed", "-1"], "--seed"),
])
def test_bad_numbers_are_one_clean_line(args, needle):
    res = CliRunner().invoke(cli, args)
    assert res.exit_code == 2, res.output
    assert needle in res.output, res.output
    assert "Traceback" not in res.output, res.output


def test_session_options_refused_before_anything_is_written(tmp_path):
    db = tmp_path / "s.db"
    studyctl("study", "init", "--protocol", fast_protocol(tmp_path, trials=1), "--db", db)
    studyctl("participants", "add", "P01", "--db", db)
    before = db.read_bytes()
    # a value click refuses is a usage error (exit 2, the usage line first); a combination
    # studyctl refuses is its one line (exit 1)
    for args, code, error in (
            (["--synthetic", "--time-scale", "nan"], 2, "Error: Invalid value for '--time-scale': 'nan' is not a finite number"),
            (["--device", "mouse", "--view", "none"], 1, "Error: --device mouse: the mouse drives the hands in the participant view; add --view window"),
            (["--answers", "window", "--view", "none"], 1, "Error: --answers window: answering with keys in the window needs --view window"),
            (["--device", "openhaptics", "--time-scale", "0"], 1,
             "Error: --device openhaptics: a person's device runs in real time only; leave out --time-scale 0")):
        res = CliRunner().invoke(cli, ["session", "run", "--db", str(db), "--participant", "P01", *args])
        assert res.exit_code == code, res.output
        assert res.output.strip().splitlines()[-1] == error, res.output
        if code == 1:
            assert res.output == error + "\n"
    assert db.read_bytes() == before  # nothing written
    assert not (tmp_path / "s.db.locks").exists()
    assert sqlite3.connect(db).execute("select count(*) from sessions").fetchone()[0] == 0


def test_outputs_into_missing_folders_or_with_wrong_suffixes_are_refused_before_any_work(tmp_path):
    db = tmp_path / "s.db"
    studyctl("study", "init", "--protocol", fast_protocol(tmp_path, trials=1), "--db", db)
    studyctl("participants", "add", "P01", "--db", db)
    before = db.read_bytes()
    (tmp_path / "afile").write_text("x")
    cases = [
        (["schedule", "--db", db, "--start", "2037-12-01", "--end", "2037-12-05", "--ics", tmp_path / "missing" / "s.ics"], "is not an existing folder"),
        (["report", "table1", "--db", db, "--out", tmp_path / "missing" / "t.md"], "is not an existing folder"),
        (["export", "--db", db, "--out", tmp_path / "afile" / "ex"], "is a file, not a folder"),
        (["calibrate", "plate-spring", "--out", tmp_path / "missing" / "p.toml"], "is not an existing folder"),
        (["plan", "--plot", tmp_path / "x.txt"], "allowed suffixes: .png, .svg, .pdf"),
        (["sim", "run", "--view", "window", "--screenshot", tmp_path / "shot.jpg"], "allowed suffixes: .png"),
    ]
    for args, needle in cases:
        res = CliRunner().invoke(cli, [str(a) for a in args])
        assert res.exit_code == 2, (args, res.output)
        assert needle in res.output, (args, res.output)
        assert "Traceback" not in res.output, (args, res.output)
    assert db.read_bytes() == before  # the schedule stored no slot
