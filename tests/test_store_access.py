"""How commands reach the study database: reading commands never write (no migration, no -wal,
-shm or lock file left), a schema_version this software does not read refused in one line, an
older schema upgraded only by `study migrate` (whole or not at all), read-only and immutable
files named so, locks taken after the arguments are checked and gone when released, a second
`synth` told that the first is running, and a database reached through a link keeping its traces
and locks beside the real file."""

import hashlib
import json
import os
import shutil
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import pytest

from studyctl.session.lock import session_lock
from studyctl.store import SCHEMA_VERSION
from studyctl.store import database as store_database
from tests.helpers import fast_protocol, query, studyctl, tree_state

ROOT = Path(__file__).resolve().parents[1]


def _set(db, sql, params=()):
    con = sqlite3.connect(db)
    con.execute(sql, params)
    con.commit()
    con.close()


@pytest.fixture
def study(tmp_path):
    """A study of one short condition with a person P01 and a synthetic S01, in a folder of its own."""
    d = tmp_path / "study"
    d.mkdir()
    db = d / "s.db"
    assert studyctl("study", "init", "--protocol", fast_protocol(tmp_path, conditions=("plate_spring",), trials=1), "--db", db).exit_code == 0
    assert studyctl("participants", "add", "P01", "--db", db).exit_code == 0
    assert studyctl("participants", "add", "S01", "--synthetic", "--db", db).exit_code == 0
    return db


@pytest.fixture(scope="module")
def ran_once(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("ran")
    db = tmp / "study" / "s.db"
    db.parent.mkdir()
    assert studyctl("study", "init", "--protocol", fast_protocol(tmp, conditions=("plate_spring",), trials=1), "--db", db).exit_code == 0
    assert studyctl("participants", "add", "P01", "--db", db).exit_code == 0
    assert studyctl("participants", "add", "S01", "--synthetic", "--db", db).exit_code == 0
    assert studyctl("session", "run", "--participant", "S01", "--synthetic", "--db", db).exit_code == 0
    return db


@pytest.fixture
def ran(ran_once, tmp_path):
    """A copy (traces included) of a study whose synthetic S01 ran a session, that a test may change."""
    shutil.copytree(ran_once.parent, tmp_path / "study")
    return tmp_path / "study" / "s.db"


def _to_schema_2(db):
    """The study as software of schema 2 left it: no withdrawal, consent, corrections, observer
    features, configurations, rig profiles, discrimination, traits or fields."""
    con = sqlite3.connect(db)
    for sql in ("drop table observer_features", "alter table sessions drop column seed", "drop table consent", "drop table corrections",
                "alter table participants drop column withdrawn_at", "alter table participants drop column withdrawal",
                "alter table conditions drop column config", "alter table conditions drop column config_sha256", "drop table rig_profile",
                "drop table discrimination", "drop table synthetic_traits", "drop table participant_fields",
                "update meta set value = '2' where key = 'schema_version'"):
        con.execute(sql)
    con.commit()
    con.close()


READING = (["status"], ["status", "--json"], ["participants", "list"], ["session", "list"], ["report", "table1"], ["report", "stats"],
           ["metrics"], ["replay", "--session", "1", "--trial", "1"])
WRITING = (["participants", "add", "P02"], ["participants", "withdraw", "P01"], ["participants", "consent", "P01"],
           ["session", "run", "--participant", "P01"], ["synth", "--participants", "1"])


# -- the schema version -------------------------------------------------------------------


@pytest.mark.parametrize("value", ["abc", "-1", "0", "1.5", "99"])
@pytest.mark.parametrize("args", [["status"], ["participants", "add", "P02"], ["study", "migrate"]])
def test_a_schema_version_this_software_does_not_read_is_refused_in_one_line(study, value, args):
    _set(study, "update meta set value = ? where key = 'schema_version'", (value,))
    before = tree_state(study.parent)
    res = studyctl(*args, "--db", study)
    assert res.exit_code == 1
    newer = "; a newer studyctl wrote it: update studyctl" if value == "99" else ""
    assert res.output == f"Error: {study}: schema_version '{value}' is not a version this studyctl reads (1..{SCHEMA_VERSION}){newer}\n"
    assert tree_state(study.parent) == before


def _outdated(db) -> str:
    return (f"Error: {db}: schema version 2, this studyctl needs {SCHEMA_VERSION}; run `studyctl study migrate --db {db}` "
            "(it backs up the file first, then upgrades it whole or not at all)\n")


@pytest.mark.parametrize("args", READING + WRITING + (["export", "--out", "EX"],))
def test_an_older_schema_is_neither_read_nor_written_but_named_for_migrate(study, tmp_path, args):
    _to_schema_2(study)
    before = tree_state(study.parent)
    res = studyctl(*[tmp_path / "ex" if a == "EX" else a for a in args], "--db", study)
    assert res.exit_code == 1
    assert res.output == _outdated(study)
    assert tree_state(study.parent) == before
    assert not (tmp_path / "ex").exists()


def test_study_migrate_upgrades_every_step_and_keeps_a_backup(study):
    _to_schema_2(study)
    old = hashlib.sha256(study.read_bytes()).hexdigest()
    res = studyctl("study", "migrate", "--db", study)
    assert res.exit_code == 0, res.output
    backup = study.parent / "s.db.schema-2.bak"
    assert res.output == f"migrated {study} from schema 2 to {SCHEMA_VERSION}; the schema-2 file was copied to {backup} first\n"
    assert query(study, "select value from meta where key = 'schema_version'") == [(str(SCHEMA_VERSION),)]
    assert query(backup, "select value from meta where key = 'schema_version'") == [("2",)]
    assert {"config", "config_sha256"} <= {r[1] for r in query(study, "pragma table_info(conditions)")}
    assert json.loads(studyctl("participants", "list", "--json", "--db", study).output)[0]["code"] == "P01"
    assert old != hashlib.sha256(study.read_bytes()).hexdigest()


def test_study_migrate_on_a_current_database_changes_nothing(study):
    before = tree_state(study.parent)
    res = studyctl("study", "migrate", "--db", study)
    assert res.output == f"{study}: already schema {SCHEMA_VERSION}; nothing to do\n"
    assert tree_state(study.parent) == before


def test_study_migrate_never_overwrites_a_backup(study):
    _to_schema_2(study)
    (study.parent / "s.db.schema-2.bak").write_text("mine")
    before = tree_state(study.parent)
    res = studyctl("study", "migrate", "--db", study)
    assert res.exit_code == 1
    assert "a backup is there already (never overwritten)" in res.output
    assert tree_state(study.parent) == before


@pytest.mark.parametrize("stop, code", [(sqlite3.OperationalError("disk I/O error"), 1), (KeyboardInterrupt(), 130)])
def test_a_migration_stopped_midway_leaves_the_file_as_it_was(study, monkeypatch, stop, code):
    """Step 6 rebuilds the answers table, then fails (or Ctrl-C): steps 3-5 done before it, and
    its own half, are all rolled back; the backup goes too."""
    _to_schema_2(study)
    before = tree_state(study.parent)
    step = store_database.MIGRATIONS[6]

    def failing(db):
        step(db)
        raise stop

    monkeypatch.setitem(store_database.MIGRATIONS, 6, failing)
    res = studyctl("study", "migrate", "--db", study)
    assert res.exit_code == code
    assert tree_state(study.parent) == before


def test_a_failed_migration_says_nothing_was_changed(study, monkeypatch):
    _to_schema_2(study)

    def failing(db):
        raise sqlite3.OperationalError("disk I/O error")

    monkeypatch.setitem(store_database.MIGRATIONS, 7, failing)
    res = studyctl("study", "migrate", "--db", study)
    assert res.output == f"Error: {study}: migrating schema 2 to {SCHEMA_VERSION} failed (disk I/O error); nothing was changed\n"


# -- reading commands leave no side file; read-only files named so ---------------------------


@pytest.mark.parametrize("args", READING)
def test_a_reading_command_leaves_the_folder_as_it_was(ran, args):
    before = tree_state(ran.parent)
    res = studyctl(*args, "--db", ran)
    assert res.exit_code == 0, res.output
    assert tree_state(ran.parent) == before


@pytest.fixture
def immutable(ran):
    """The study's file with the immutable flag (chattr +i: not even root writes it), in a folder that is writable."""
    if subprocess.run(["chattr", "+i", str(ran)], capture_output=True).returncode != 0:
        pytest.skip("chattr +i does not work here (needs root and a file system that keeps the flag)")
    try:
        yield ran
    finally:
        subprocess.run(["chattr", "-i", str(ran)], check=True)


@pytest.mark.parametrize("args", READING)
def test_a_reading_command_on_an_immutable_file_leaves_no_side_file(immutable, args):
    before = tree_state(immutable.parent)
    res = studyctl(*args, "--db", immutable)
    assert res.exit_code == 0, res.output
    assert tree_state(immutable.parent) == before


@pytest.mark.parametrize("args", WRITING + (["study", "migrate"],))
def test_a_writing_command_on_an_immutable_file_says_read_only(immutable, args):
    before = tree_state(immutable.parent)
    res = studyctl(*args, "--db", immutable)
    assert res.exit_code == 1
    assert res.output == f"Error: {immutable}: read-only (operation not permitted); nothing was written; reports and exports still work on it\n"
    assert tree_state(immutable.parent) == before


# root without the capabilities that pass over file modes: chmod applies to it as to any user
PLAIN = ["setpriv", "--bounding-set=-dac_override,-dac_read_search,-fowner"]


def _plain(*args) -> subprocess.CompletedProcess:
    return subprocess.run([*PLAIN, sys.executable, "-m", "studyctl", *map(str, args)], capture_output=True, text=True,
                          env={**os.environ, "PYTHONPATH": str(ROOT)})


@pytest.fixture
def modes(study):
    """`chmod` of the study's file or folder that applies to the commands run by `_plain`; skipped
    where setpriv cannot drop those capabilities."""
    probe = study.parent / "probe"
    probe.write_text("x")
    probe.chmod(0o444)
    try:
        held = subprocess.run([*PLAIN, sys.executable, "-c", f"open({str(probe)!r}, 'a')"], capture_output=True).returncode == 0
    except OSError:
        held = True
    probe.unlink()
    if held:
        pytest.skip("file modes do not apply here (no setpriv, or it cannot drop CAP_DAC_OVERRIDE)")
    yield study
    study.chmod(0o644)
    study.parent.chmod(0o755)


def _chmod(db, what: str) -> None:
    if what == "file":
        db.chmod(0o444)
    else:
        db.parent.chmod(0o555)


@pytest.mark.parametrize("what", ["file", "folder"])
@pytest.mark.parametrize("args", [["status"], ["participants", "list"]])
def test_a_reading_command_on_a_read_only_file_or_folder_leaves_no_side_file(modes, what, args):
    _chmod(modes, what)
    before = tree_state(modes.parent)
    res = _plain(*args, "--db", modes)
    assert res.returncode == 0, res.stderr
    assert tree_state(modes.parent) == before


@pytest.mark.parametrize("what, why", [("file", "permission denied"), ("folder", "its folder {folder} takes no new file")])
def test_a_writing_command_on_a_read_only_file_or_folder_says_read_only(modes, what, why):
    _chmod(modes, what)
    before = tree_state(modes.parent)
    res = _plain("participants", "add", "P02", "--db", modes)
    assert res.returncode == 1
    assert res.stderr == (f"Error: {modes}: read-only ({why.format(folder=modes.parent)}); nothing was written; "
                          "reports and exports still work on it\n")
    assert tree_state(modes.parent) == before


@pytest.fixture
def read_only_mount(ran, tmp_path):
    """The study's folder on a read-only bind mount; skipped where mounting is not allowed."""
    mnt = tmp_path / "ro"
    mnt.mkdir()
    if subprocess.run(["mount", "--bind", "-o", "ro", str(ran.parent), str(mnt)], capture_output=True).returncode != 0:
        pytest.skip("cannot make a read-only mount here (needs root or CAP_SYS_ADMIN)")
    try:
        yield mnt / "s.db"
    finally:
        if subprocess.run(["umount", str(mnt)], capture_output=True).returncode != 0:
            subprocess.run(["umount", "-l", str(mnt)], check=False)


@pytest.mark.parametrize("args", WRITING)
def test_a_writing_command_on_a_read_only_disk_says_read_only(read_only_mount, args):
    res = studyctl(*args, "--db", read_only_mount)
    assert res.exit_code == 1
    assert res.output == (f"Error: {read_only_mount}: read-only (read-only file system); nothing was written; "
                          "reports and exports still work on it\n")


def test_a_database_made_read_only_while_open_is_named_read_only_not_busy(study, monkeypatch):
    """A write that SQLite refuses as read-only (the file changed under an open store) is said so."""
    real = sqlite3.connect

    def read_only_connect(target, *a, **kw):
        if str(target) == str(study):  # the writing open: read-only underneath
            return real(Path(study).as_uri() + "?mode=ro", *a, uri=True, **{k: v for k, v in kw.items() if k != "uri"})
        return real(target, *a, **kw)

    monkeypatch.setattr(store_database, "cannot_write", lambda path: None)
    monkeypatch.setattr(store_database.sqlite3, "connect", read_only_connect)
    res = studyctl("participants", "add", "P02", "--db", study)
    assert res.exit_code == 1
    assert "is read-only (attempt to write a readonly database); nothing was written" in res.output
    assert "another process may be writing" not in res.output


# -- locks -------------------------------------------------------------------------------------


def test_withdraw_refused_for_a_control_character_leaves_no_lock(study):
    before = tree_state(study.parent)
    res = studyctl("participants", "withdraw", "P01", "--reason", "left\x07early", "--db", study)
    assert res.exit_code == 1
    assert res.output.startswith("Error: --reason: control character U+0007")
    assert tree_state(study.parent) == before


def test_a_lock_released_takes_its_file_and_folder(study):
    assert studyctl("participants", "withdraw", "P01", "--db", study).exit_code == 0
    assert not (study.parent / "s.db.locks").exists()


HOLD = """
import sys, time
from studyctl.session.lock import synth_lock
with synth_lock(sys.argv[1]):
    print("held", flush=True)
    if sys.argv[2] == "die":
        import os; os._exit(9)  # killed: the kernel drops the lock, its file stays
    time.sleep(120)
"""


def _holder(db, how: str) -> subprocess.Popen:
    """Another process holding `db`'s synth lock as a running synth does (or dying with it held)."""
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.Popen([sys.executable, "-c", HOLD, str(db), how], stdout=subprocess.PIPE, text=True, env=env)
    assert proc.stdout.readline().strip() == "held"
    return proc


@pytest.fixture
def pending(tmp_path):
    """A synthetic study whose synth registered S002 and had not yet run its session."""
    db = tmp_path / "study" / "s.db"
    db.parent.mkdir()
    assert studyctl("synth", "--participants", "1", "--db", db,
                    "--protocol", fast_protocol(tmp_path, conditions=("plate_spring",), trials=1)).exit_code == 0
    con = sqlite3.connect(db)
    con.execute("insert into participants (code, age, synthetic, created_at) values ('S002', 30, 1, '')")
    con.execute("insert into synthetic_traits select 'S002', trait, value, seed from synthetic_traits where code = 'S001'")
    con.commit()
    con.close()
    return db


@pytest.mark.parametrize("args", [["--participants", "1"], ["--complete"]])
def test_a_second_synth_is_told_the_first_is_running(pending, args):
    holder = _holder(pending, "hold")
    try:
        before = tree_state(pending.parent)
        res = studyctl("synth", *args, "--db", pending)
        assert res.exit_code == 1
        assert res.output == f"Error: {pending}: another synth (pid {holder.pid}) is running on this study; wait for it or stop it\n"
        assert tree_state(pending.parent) == before
    finally:
        holder.kill()
        holder.wait()


def test_a_synth_killed_is_told_apart_from_a_running_one(pending):
    holder = _holder(pending, "die")
    holder.wait()
    assert (pending.parent / "s.db.locks" / "synth.lock").exists()  # left by the killed process, no longer held
    res = studyctl("synth", "--participants", "1", "--db", pending)
    assert "an interrupted synth registered without a session; give --complete" in res.output
    res = studyctl("synth", "--complete", "--db", pending)
    assert res.exit_code == 0, res.output
    assert query(pending, "select code from sessions order by code") == [("S001",), ("S002",)]


def test_complete_while_a_real_synth_runs_reruns_no_session(tmp_path):
    """Two real synth processes on one study: the second, told to --complete, runs nothing."""
    db = tmp_path / "s.db"
    protocol = fast_protocol(tmp_path, conditions=("plate_spring",), trials=1)
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    first = subprocess.Popen([sys.executable, "-m", "studyctl", "synth", "--participants", "3", "--db", str(db), "--protocol", str(protocol)],
                             env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 120
        while not (db.parent / "s.db.locks" / "synth.lock").exists():
            assert first.poll() is None and time.monotonic() < deadline, first.communicate()
            time.sleep(0.05)
        res = studyctl("synth", "--complete", "--db", db)
        assert res.exit_code == 1
        assert f"another synth (pid {first.pid}) is running on this study" in res.output
    finally:
        out, err = first.communicate(timeout=300)
    assert first.returncode == 0, err
    assert query(db, "select code, count(*) from sessions group by code") == [("S001", 1), ("S002", 1), ("S003", 1)]


# -- a database reached through a link --------------------------------------------------------


def test_a_linked_database_keeps_its_traces_and_locks_beside_the_real_file(tmp_path):
    real = tmp_path / "real"
    real.mkdir()
    assert studyctl("study", "init", "--protocol", fast_protocol(tmp_path, conditions=("plate_spring",), trials=1),
                    "--db", real / "r.db").exit_code == 0
    first, second = tmp_path / "here", tmp_path / "there"
    first.mkdir()
    second.mkdir()
    (first / "s.db").symlink_to(real / "r.db")
    assert studyctl("participants", "add", "S01", "--synthetic", "--db", first / "s.db").exit_code == 0
    assert studyctl("session", "run", "--participant", "S01", "--synthetic", "--db", first / "s.db").exit_code == 0
    assert sorted(p.name for p in first.iterdir()) == ["s.db"]
    assert sorted(p.name for p in real.iterdir()) == ["r.db", "r.db.traces"]
    (first / "s.db").rename(second / "s.db")  # the link moved: its study still finds its traces
    res = studyctl("replay", "--session", "1", "--trial", "1", "--json", "--db", second / "s.db")
    assert res.exit_code == 0, res.output
    assert json.loads(res.output)["max_force_difference_n"] == 0.0


def test_a_linked_database_is_locked_beside_the_real_file(tmp_path):
    real = tmp_path / "real"
    real.mkdir()
    assert studyctl("study", "init", "--protocol", fast_protocol(tmp_path, conditions=("plate_spring",), trials=1),
                    "--db", real / "r.db").exit_code == 0
    (tmp_path / "s.db").symlink_to(real / "r.db")
    studyctl("participants", "add", "S01", "--synthetic", "--db", real / "r.db")
    with session_lock(tmp_path / "s.db", "S01"):  # a session run through the link
        res = studyctl("participants", "withdraw", "S01", "--db", real / "r.db")
        assert (real / "r.db.locks").is_dir()
    assert "their session is running now" in res.output


# -- status counts ---------------------------------------------------------------------------


def test_status_counts_withdrawn_synthetic_participants_as_it_counts_the_complete_who_withdrew(tmp_path):
    db = tmp_path / "s.db"
    assert studyctl("synth", "--participants", "3", "--db", db,
                    "--protocol", fast_protocol(tmp_path, conditions=("plate_spring",), trials=1)).exit_code == 0
    for code in ("S001", "S002", "S003"):
        assert studyctl("participants", "withdraw", code, "--db", db).exit_code == 0
    out = json.loads(studyctl("status", "--json", "--db", db).output)
    assert out["participants"]["withdrawn"] == 3
    assert out["complete_withdrawn"] == 3
    assert out["participants"]["withdrawn_synthetic"] == 3
    lines = studyctl("status", "--db", db).output.splitlines()
    assert lines[0] == "brain_pull_2015: 0 of 35 people complete (and 3 SYNTHETIC) (3 of these withdrew, data kept: counted, as in the reports)"
    assert lines[1] == "participants: 0 people (0 consented, 0 withdrawn), 3 synthetic (3 withdrawn)"


def test_asking_whether_a_database_can_be_written_keeps_this_process_s_locks_on_it(tmp_path):
    """Closing any descriptor of a file drops every POSIX lock the process holds on it (SQLite's
    own connections included): the check must not open the file."""
    import fcntl
    import subprocess
    import sys

    from studyctl.store.database import cannot_write

    db = tmp_path / "s.db"
    db.write_bytes(b"x" * 100)
    with open(db, "r+b") as held:
        fcntl.lockf(held, fcntl.LOCK_EX | fcntl.LOCK_NB, 1, 0)
        assert cannot_write(db) is None
        probe = ("import fcntl, sys\nf = open(sys.argv[1], 'r+b')\n"
                 "try:\n    fcntl.lockf(f, fcntl.LOCK_EX | fcntl.LOCK_NB, 1, 0)\n    print('free')\n"
                 "except OSError:\n    print('held')\n")
        out = subprocess.run([sys.executable, "-c", probe, str(db)], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "held"


@pytest.fixture
def older_linked_study(tmp_path):
    """A study that software resolving no link wrote through `here/s.db`, a link to `real/r.db`:
    its traces beside the link (`here/s.db.traces`), its rows' paths relative to `here`."""
    real, here = tmp_path / "real", tmp_path / "here"
    real.mkdir()
    here.mkdir()
    proto = fast_protocol(tmp_path, conditions=("plate_spring",), trials=1)
    proto.write_text(proto.read_text().replace('withdrawal = "keep"', 'withdrawal = "delete"'))
    assert 'withdrawal = "delete"' in proto.read_text()
    assert studyctl("synth", "--protocol", proto, "--participants", 1, "--seed", 1, "--db", here / "s.db").exit_code == 0
    (here / "s.db").rename(real / "r.db")
    (here / "s.db").symlink_to(real / "r.db")
    return here / "s.db"


def test_an_older_linked_study_s_traces_beside_the_link_are_replayed(older_linked_study):
    res = studyctl("replay", "--session", "1", "--trial", "1", "--json", "--db", older_linked_study)
    assert res.exit_code == 0, res.output


def test_an_older_linked_study_s_traces_beside_the_link_give_metrics(older_linked_study):
    res = studyctl("metrics", "--db", older_linked_study, "--format", "json")
    assert res.exit_code == 0, res.output


def test_an_older_linked_study_s_replay_reproduces_its_trace(older_linked_study):
    res = studyctl("replay", "--session", "1", "--trial", "1", "--json", "--db", older_linked_study)
    assert json.loads(res.output)["max_force_difference_n"] == 0.0


def test_withdrawing_with_deletion_deletes_an_older_linked_study_s_traces_beside_the_link(older_linked_study):
    assert studyctl("participants", "withdraw", "S001", "--db", older_linked_study).exit_code == 0
    assert not list((older_linked_study.parent / "s.db.traces").rglob("*.npz"))
