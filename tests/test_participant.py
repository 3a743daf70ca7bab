"""A person in the chair: every movement recorded, replays, blind labels, the terminal
questionnaire in real time through a real pseudo-terminal, and kills mid-trial."""

import json
import os
import signal
import sqlite3
import subprocess
import sys
import time

import numpy as np
import pandas as pd

from analysis.study.trace_files import read_trace
from studyctl.store import Store
from tests.helpers import MODEL_WORDS, count_rows, participant_protocol, pty_run, pty_session, studyctl


def _synthetic_db(tmp_path, name="s.db", code="P01"):
    db = tmp_path / name
    studyctl("study", "init", "--protocol", participant_protocol(tmp_path, trials=3), "--db", db)
    studyctl("participants", "add", code, "--age", "24", "--synthetic", "--db", db)
    return db


def test_export_has_every_tick_of_every_trial_and_replay_reproduces_the_forces(tmp_path):
    db = _synthetic_db(tmp_path)
    res = studyctl("session", "run", "--db", db, "--participant", "P01", "--synthetic")
    assert res.exit_code == 0, res.output
    res = studyctl("export", "--db", db, "--out", tmp_path / "ex")
    assert res.exit_code == 0, res.output
    tr = pd.read_csv(tmp_path / "ex" / "traces.csv")
    assert list(tr.columns) == ["session_id", "model", "trial", "t", "hand", "x", "y", "z", "fx", "fy", "fz", "button"]
    counts = tr.groupby(["model", "trial", "hand"]).size()
    assert len(counts) == 9 * 2  # 9 trials, 3 s at 1 kHz, per hand
    assert (counts == 3000).all()
    cond = pd.read_csv(tmp_path / "ex" / "conditions.csv")
    assert sorted(cond["label"]) == ["A", "B", "C"]  # blind labels, shown in exports
    store = Store(db)
    rows = store.rows("select * from trials order by model, trial")
    store.close()
    assert all(r["grasped"] == 1 and r["started_by"] == "clock" and len(r["trace_sha256"]) == 64 for r in rows)
    # the trace file holds exactly what the trial summary says
    for r in rows:
        t = read_trace(db, r["trace_path"], r["trace_sha256"])
        assert abs(np.linalg.norm(t.forces, axis=2).max() - r["max_force_n"]) < 1e-12
    # a lockstep replay of the recorded motion gives the recorded forces, bit for bit, for every model
    for k in (1, 4, 7):
        res = studyctl("replay", "--db", db, "--session", 1, "--trial", k, "--json")
        assert res.exit_code == 0, res.output
        out = __import__("json").loads(res.output)
        assert out["ticks"] == out["recorded_ticks"] == 3000
        assert out["max_force_difference_n"] == 0.0
    # a changed trace file is refused, by name
    path = db.parent / rows[0]["trace_path"]
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0x01
    path.write_bytes(bytes(data))
    res = studyctl("export", "--db", db, "--out", tmp_path / "ex2")
    assert res.exit_code == 1
    assert "does not match the SHA-256" in res.output
    assert str(path) in res.output
    assert not (tmp_path / "ex2").exists()  # nothing half-written
    res = studyctl("replay", "--db", db, "--session", 1, "--trial", 10)
    assert res.exit_code == 1
    assert "allowed: 1..9" in res.output


def test_sigkill_mid_trial_loses_only_that_trial_and_resumed_answers_use_every_trace(tmp_path):
    db = _synthetic_db(tmp_path, "killed.db")
    cmd = [sys.executable, "-m", "studyctl.cli", "session", "run", "--db", str(db), "--participant", "P01", "--synthetic"]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.time() + 120
    while count_rows(db, "trials") < 2 and time.time() < deadline and proc.poll() is None:
        time.sleep(0.01)
    time.sleep(0.3)  # into the next trial
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    before = count_rows(db, "trials")
    assert 2 <= before < 9
    res = studyctl("session", "run", "--db", db, "--participant", "P01", "--synthetic", "--resume")
    assert res.exit_code == 0, res.output
    con = sqlite3.connect(db)
    rows = con.execute("select model, trial, trace_path, trace_sha256 from trials").fetchall()
    assert len(rows) == 9
    assert len({(m, t) for m, t, _, _ in rows}) == 9
    for _, _, path, sha in rows:
        read_trace(db, path, sha)  # every trace there, matching its hash
    assert not list((tmp_path / "killed.db.traces").rglob("*.tmp"))
    # the same participant and seed, never interrupted: the same answers (they are computed from
    # every stored trace of a condition, also those run before the kill)
    fresh = _synthetic_db(tmp_path, "fresh.db")
    assert studyctl("session", "run", "--db", fresh, "--participant", "P01", "--synthetic").exit_code == 0
    q = "select model, item, answer from answers order by model, item"
    assert con.execute(q).fetchall() == sqlite3.connect(fresh).execute(q).fetchall()
    # and the same perceived features, recomputed from the stored traces after the resume
    q = "select model, feature, value from observer_features order by model, feature"
    feats = con.execute(q).fetchall()
    assert len(feats) >= 3 * 8
    assert feats == sqlite3.connect(fresh).execute(q).fetchall()


def test_real_time_session_through_a_pty_discards_keys_typed_during_training_and_names_no_model(tmp_path):
    db = tmp_path / "s.db"
    studyctl("study", "init", "--protocol", participant_protocol(tmp_path, trials=1, trial_seconds=1.0, training=0.05), "--db", db)
    studyctl("participants", "add", "P01", "--db", db)
    studyctl("participants", "consent", "P01", "--db", db)
    typed = []

    def during_training(fd, out):
        if not typed and b"training:" in out:
            time.sleep(0.5)
            os.write(fd, b"n")  # a key typed during training, no Enter: must not answer anything
            typed.append(True)

    text = pty_session(["session", "run", "--db", db, "--participant", "P01", "--view", "none"], lambda: "y", timeout=120,
                       on_output=during_training)
    typed_early = bool(typed)
    assert typed_early, text
    assert "complete" in text, text
    assert "Please answer" not in text  # the early "n" never reached a question (no refusal was printed)
    assert not MODEL_WORDS.search(text), MODEL_WORDS.search(text)
    con = sqlite3.connect(db)
    answers = con.execute("select answer, source from answers").fetchall()
    assert len(answers) == 27
    assert all(a == (1, "terminal") for a in answers)
    trials = con.execute("select started_by, grasped, waited_s from trials").fetchall()
    assert len(trials) == 3
    assert all(t[0] == "grasp" and t[1] == 1 and t[2] > 0.2 for t in trials)
    training = con.execute("select detail from events where kind = 'training_done'").fetchone()[0]
    assert '"ended_early":false' in training


def test_a_second_process_cannot_drive_a_live_session_and_is_told_so(tmp_path):
    db = tmp_path / "s.db"
    studyctl("study", "init", "--protocol", participant_protocol(tmp_path, trials=2, trial_seconds=1.0), "--db", db)
    studyctl("participants", "add", "P05", "--synthetic", "--db", db)
    cmd = [sys.executable, "-m", "studyctl.cli", "session", "run", "--db", str(db), "--participant", "P05", "--synthetic", "--time-scale", "1"]
    first = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.time() + 60
        while count_rows(db, "trials") < 1 and time.time() < deadline and first.poll() is None:
            time.sleep(0.05)
        before = sqlite3.connect(db).execute("select count(*) from events").fetchone()[0]
        for extra in ([], ["--resume"]):  # neither a new start nor a resume may touch the live session
            res = studyctl("session", "run", "--db", db, "--participant", "P05", "--synthetic", *extra)
            assert res.exit_code == 1, res.output
            assert "the session is running now (pid" in res.output, res.output
            assert len(res.output.strip().splitlines()) == 1
        assert sqlite3.connect(db).execute("select count(*) from events").fetchone()[0] == before  # no false "resumed"
        out, err = first.communicate(timeout=120)
    finally:
        if first.poll() is None:
            first.kill()
    assert first.returncode == 0, err
    con = sqlite3.connect(db)
    assert con.execute("select count(*) from answers").fetchone()[0] == 27
    assert con.execute("select count(*) from trials").fetchone()[0] == 6
    assert con.execute("select status from sessions").fetchall() == [("done",)]


def _ctrl_c(argv, when: bytes, timeout=120.0, delay=1.0) -> tuple[str, int]:
    """Run `studyctl ARGV` on a real pseudo-terminal (`pty_run`), type Ctrl-C `delay` s after the
    output first shows `when` (the terminal sends SIGINT to every process of the command: the
    session's servo process, a pool's workers); (all the terminal showed, exit status)."""
    sent = []

    def interrupt(fd, out) -> None:
        if not sent and when in out:
            time.sleep(delay)
            os.write(fd, b"\x03")
            sent.append(True)

    text, status = pty_run(argv, interrupt, timeout)
    assert sent, text[-2000:]
    return text, status


def test_ctrl_c_in_the_chair_marks_the_session_interrupted_and_says_how_to_resume(tmp_path):
    db = tmp_path / "s.db"
    studyctl("study", "init", "--protocol", participant_protocol(tmp_path, conditions=("plate_spring",), trials=2, trial_seconds=3.0), "--db", db)
    studyctl("participants", "add", "P01", "--db", db)
    studyctl("participants", "consent", "P01", "--db", db)
    text, code = _ctrl_c(["session", "run", "--db", db, "--participant", "P01", "--view", "none"], b"trial 2 of 2")
    assert code == 130, text
    assert "Traceback" not in text, text
    assert "KeyboardInterrupt" not in text, text
    last = text.strip().splitlines()[-1]
    assert "session 1 of P01 interrupted (1 trial kept" in last
    assert f"studyctl session run --db {db} --participant P01 --resume" in last
    assert sqlite3.connect(db).execute("select status from sessions").fetchall() == [("interrupted",)]
    listed = json.loads(studyctl("session", "list", "--db", db, "--json").output)
    assert [s["status"] for s in listed] == ["interrupted"]
    res = studyctl("session", "run", "--db", db, "--participant", "P01", "--view", "window", "--device", "mouse", "--resume")
    assert res.exit_code != 0  # another device: said, not resumed
    assert "was started with --device simulated" in res.output
    text = pty_session(["session", "run", "--db", db, "--participant", "P01", "--view", "none", "--resume"], lambda: "y", timeout=120)
    assert "resuming session 1 of P01" in text, text
    assert "condition A (1 of 1): loading" in text, text
    assert "complete" in text, text
    con = sqlite3.connect(db)
    assert con.execute("select status from sessions").fetchall() == [("done",)]
    assert con.execute("select trial from trials order by trial").fetchall() == [(0,), (1,)]


def test_ctrl_c_during_a_parallel_synth_prints_one_line_and_the_next_run_completes_it(tmp_path):
    db = tmp_path / "s.db"
    proto = participant_protocol(tmp_path, conditions=("plate_spring",), trials=1, trial_seconds=1.0)
    text, code = _ctrl_c(["synth", "--db", db, "--protocol", proto, "--participants", "12", "--jobs", "2", "--seed", "3"],
                         b"%", delay=0.1)  # Ctrl-C once the first sessions are stored (the bar shows a percentage)
    assert code == 130, text
    assert "Traceback" not in text, text
    assert "KeyboardInterrupt" not in text, text
    assert "synth: interrupted after" in text, text
    assert "--complete` runs the" in text, text
    res = studyctl("synth", "--db", db, "--complete", "--participants", "1")
    assert res.exit_code == 0, res.output
    con = sqlite3.connect(db)
    assert con.execute("select count(*) from participants p where not exists (select 1 from sessions s where s.code = p.code)").fetchone()[0] == 0
    assert con.execute("select count(*) from sessions where status = 'done'").fetchone()[0] == 13
