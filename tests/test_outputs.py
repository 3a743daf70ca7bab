"""Outputs are never overwritten without --force, and a command that writes several files writes
all or none (studyctl/outputs.py): every output option of every command, through the CLI."""

import errno
import fnmatch
import hashlib
import re
from pathlib import Path

import pytest

from tests.conftest import ROOT
from tests.helpers import PROTOCOL, fast_protocol, studyctl

# (command with {db} and {out}, where the existing file is: "" for `out` itself, else a name in the folder `out`,
#  whether the --force run is quick enough to run here)
CASES = {
    "report table1": (["report", "table1", "--db", "{db}", "--out", "{out}"], "table1.md", "", True),
    "report table1 html": (["report", "table1", "--db", "{db}", "--format", "html", "--out", "{out}"], "r.html", "", True),
    "report jnd": (["report", "jnd", "--db", "{db}", "--out", "{out}"], "jnd.md", "", False),
    "report text": (["report", "text", "--db", "{db}", "--out", "{out}"], "text.md", "", True),
    "report validity": (["report", "validity", "--db", "{db}", "--out", "{out}"], "v.md", "", False),
    "report plots": (["report", "plots", "--db", "{db}", "--out", "{out}"], "plots", "rates.png", True),
    "export": (["export", "--db", "{db}", "--out", "{out}"], "export", "answers.csv", True),
    "export parquet": (["export", "--db", "{db}", "--format", "parquet", "--out", "{out}"], "export", "answers.parquet", True),
    "metrics": (["metrics", "--db", "{db}", "--out", "{out}"], "metrics.csv", "", True),
    "participants contacts": (["participants", "contacts", "--db", "{db}", "--out", "{out}"], "contacts.csv", "", True),
    "protocol new": (["protocol", "new", "--kind", "yes_no", "--out", "{out}"], "lab", "scene.toml", True),
    "schedule --ics": (["schedule", "--db", "{db}", "--start", "2099-01-05", "--end", "2099-01-09", "--ics", "{out}"], "s.ics", "", False),
    "plan --plot": (["plan", "--protocol", PROTOCOL, "--plot", "{out}"], "power.png", "", False),
    "calibrate plate-spring": (["calibrate", "plate-spring", "--out", "{out}"], "ps.toml", "", False),
    "calibrate material": (["calibrate", "material", "--out", "{out}"], "m.toml", "", True),
    "calibrate rheology": (["calibrate", "rheology", "--mu-inf", "700", "--mu-1", "2000", "--tau-1", "9.7", "--bulk-modulus", "6e4",
                            "--out", "{out}"], "r.toml", "", False),
    "calibrate field --out": (["calibrate", "field", "--out", "{out}"], "f.npz", "", False),
    "calibrate field --params-out": (["calibrate", "field", "--out", "{tmp}/new.npz", "--params-out", "{out}"], "p.toml", "", False),
    "calibrate rig": (["calibrate", "rig", "--protocol", PROTOCOL, "--out", "{out}"], "rig.json", "", False),
    "calibrate truth": (["calibrate", "truth", "--out", "{out}"], "t.npz", "", False),
    "model check": (["model", "check", "plate_spring", "--contract", "--out", "{out}"], "card.md", "", True),
    "bench accuracy": (["bench", "accuracy", "--quick", "--out", "{out}"], "acc", "accuracy.json", False),
    "bench stability": (["bench", "stability", "--quick", "--out", "{out}"], "stab", "stability.json", False),
    "bench reference": (["bench", "reference", "--quick", "--out", "{out}"], "ref", "reference.md", False),
    "sim run --frames": (["sim", "run", "--scene", "{tmp}/scene.toml", "--duration", "0.2", "--time-scale", "0", "--frames", "{out}"],
                         "frames", "trace.csv", True),
    "sim run --screenshot": (["sim", "run", "--view", "window", "--screenshot", "{out}"], "shot.png", "", False),
    "sim live --screenshot": (["sim", "live", "--screenshot", "{out}"], "shot.png", "", False),
    "replay --frames": (["replay", "--db", "{db}", "--session", "1", "--trial", "1", "--frames", "{out}"], "replay", "trace.csv", True),
}
OLD = b"an earlier result\n"


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _listing(folder: Path) -> list[str]:
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*"))


@pytest.mark.parametrize("case", list(CASES))
def test_an_existing_output_is_refused_without_force_and_replaced_with_it(case, small_study, tmp_path):
    argv, name, inside, quick = CASES[case]
    fast_protocol(tmp_path)  # the quick scene, tmp_path / "scene.toml"
    out = tmp_path / name
    existing = out / inside if inside else out
    existing.parent.mkdir(parents=True, exist_ok=True)
    existing.write_bytes(OLD)
    before = _listing(tmp_path)
    args = [str(a).format(db=small_study, out=out, tmp=tmp_path) for a in argv]

    res = studyctl(*args)
    assert res.exit_code == 1, res.output
    lines = res.output.strip().splitlines()
    assert lines == [f"Error: {existing}: exists; --force overwrites it"], res.output
    assert _sha(existing) == hashlib.sha256(OLD).hexdigest()
    assert _listing(tmp_path) == before  # nothing else written, no temporary left
    if not quick:
        return
    res = studyctl(*args, "--force")
    assert res.exit_code == 0, res.output
    assert existing.read_bytes() != OLD
    assert f"--force: overwrote {existing}" in res.output.splitlines()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no temporary left


def test_a_second_existing_file_is_counted(tmp_path):
    out = tmp_path / "lab"
    out.mkdir()
    for name in ("protocol.toml", "scene.toml"):
        (out / name).write_bytes(OLD)
    res = studyctl("protocol", "new", "--kind", "yes_no", "--out", out)
    assert res.exit_code == 1
    assert res.output.strip() == f"Error: {out / 'protocol.toml'}: exists (and 1 more of the files this command writes); --force overwrites them"


def test_force_leaves_the_folders_other_files(small_study, tmp_path):
    out = tmp_path / "export"
    out.mkdir()
    (out / "answers.csv").write_bytes(OLD)
    (out / "notes.txt").write_bytes(OLD)
    res = studyctl("export", "--db", small_study, "--out", out, "--force")
    assert res.exit_code == 0, res.output
    assert (out / "notes.txt").read_bytes() == OLD
    assert (out / "answers.csv").read_bytes() != OLD


@pytest.mark.parametrize("fmt", ["csv", "parquet"])
def test_export_writes_all_files_or_none(fmt, small_study, tmp_path, monkeypatch):
    """The disk fills up at the sixth file: the five written go too, and the retry works."""
    import pyarrow.parquet as pq

    written = []
    module, name = (Path, "write_text") if fmt == "csv" else (pq, "write_table")
    real = getattr(module, name)

    def full_at_the_sixth(*args, **kwargs):
        written.append(args)
        if len(written) == 6:
            raise OSError(errno.ENOSPC, "No space left on device")
        return real(*args, **kwargs)

    out = tmp_path / "export"
    out.mkdir()
    (out / "notes.txt").write_bytes(OLD)
    monkeypatch.setattr(module, name, full_at_the_sixth)
    res = studyctl("export", "--db", small_study, "--format", fmt, "--out", out)
    assert res.exit_code == 1
    assert res.output.strip() == f"Error: {out}: cannot write: No space left on device; nothing was written"
    assert len(written) == 6
    assert _listing(tmp_path) == ["export", "export/notes.txt"]  # no half export, no temporary folder
    monkeypatch.setattr(module, name, real)
    res = studyctl("export", "--db", small_study, "--format", fmt, "--out", out)
    assert res.exit_code == 0, res.output
    assert len(list(out.iterdir())) == 17


TEXT_QUESTION = '\n[[questions]]\nid = "comment"\ntext = "Anything else?"\nkind = "text"\nwhen = "end"\n'


def test_parquet_export_of_a_study_with_text_answers(tmp_path):
    import pandas as pd

    db = tmp_path / "s.db"
    proto = fast_protocol(tmp_path, conditions=("plate_spring",), trials=1)
    proto.write_text(proto.read_text() + TEXT_QUESTION)
    assert studyctl("study", "init", "--db", db, "--protocol", proto).exit_code == 0
    assert studyctl("participants", "add", "P01", "--db", db, "--age", "24").exit_code == 0
    assert studyctl("participants", "consent", "P01", "--db", db).exit_code == 0
    answers = tmp_path / "a.csv"
    answers.write_text("participant,model,item,answer\nP01,,comment,felt soft\nP01,plate_spring,natural,yes\n")
    assert studyctl("answers", "import", "--db", db, answers).exit_code == 0
    out = tmp_path / "parquet"
    res = studyctl("export", "--db", db, "--format", "parquet", "--out", out)
    assert res.exit_code == 0, res.output
    assert res.output.strip() == f"wrote 16 files to {out}"
    got = pd.read_parquet(out / "answers.parquet").set_index("item")["answer"].to_dict()
    assert got == {"comment": "felt soft", "natural": "1"}  # one column, as text where a study asks for text


def test_protocol_new_on_a_full_disk_leaves_nothing_and_the_retry_works(tmp_path, monkeypatch):
    real = Path.write_text

    def full_disk(self, *args, **kwargs):
        if self.name == "scene.toml":
            raise OSError(errno.ENOSPC, "No space left on device")
        return real(self, *args, **kwargs)

    out = tmp_path / "lab" / "study"
    monkeypatch.setattr(Path, "write_text", full_disk)
    res = studyctl("protocol", "new", "--kind", "yes_no", "--out", out)
    assert res.exit_code == 1
    assert res.output.strip() == f"Error: {out}: cannot write: No space left on device; nothing was written"
    assert not out.exists()
    assert _listing(tmp_path / "lab") == []  # no temporary folder either
    monkeypatch.setattr(Path, "write_text", real)
    res = studyctl("protocol", "new", "--kind", "yes_no", "--out", out)
    assert res.exit_code == 0, res.output
    assert _listing(out) == ["protocol.toml", "scene.toml"]


def test_make_demo_forces_every_output_and_says_so():
    text = (ROOT / "Makefile").read_text()
    recipe = text[text.index("\ndemo:"):text.index("\n\n", text.index("\ndemo:"))]
    commands = re.sub(r"\\\n\s*", " ", recipe).splitlines()
    writers = [c for c in commands if "studyctl" in c and re.search(r"--out |--frames ", c)]
    assert len(writers) == 5
    assert [c for c in writers if "--force" not in c] == []
    assert "make demo overwrites its own outputs in $(OUT)/demo/" in recipe


def test_a_read_only_folder_is_one_line_and_leaves_nothing(small_study, tmp_path, monkeypatch):
    import tempfile

    def read_only(*args, **kwargs):
        raise OSError(errno.EROFS, "Read-only file system")

    monkeypatch.setattr(tempfile, "mkstemp", read_only)
    res = studyctl("report", "table1", "--db", small_study, "--out", tmp_path / "table1.md")
    assert res.exit_code == 1
    assert res.output.strip() == f"Error: {tmp_path / 'table1.md'}: cannot write: Read-only file system; nothing was written"
    assert _listing(tmp_path) == []


def test_an_output_name_near_the_file_system_s_limit_is_written(small_study, tmp_path):
    """The temporary name beside it is short, whatever the target's name: 254 characters fit."""
    out = tmp_path / ("a" * 251 + ".md")
    res = studyctl("report", "table1", "--db", small_study, "--out", out)
    assert res.exit_code == 0, res.output
    assert res.output.strip().splitlines()[-1] == f"wrote {out}"
    assert out.read_text().startswith("**Table 1: ")
    assert _listing(tmp_path) == [out.name]  # no temporary left


PROC = Path("/proc/self").is_dir()  # a file system that takes no new file: Linux's /proc


@pytest.mark.parametrize(("argv", "target", "why"), [
    (["report", "table1", "--db", "{db}", "--out", "{tmp}/" + "a" * 260 + ".md"], "{tmp}/" + "a" * 260 + ".md", "File name too long"),
    (["export", "--db", "{db}", "--out", "{tmp}/" + "b" * 260], "{tmp}/" + "b" * 260, "File name too long"),
    (["export", "--db", "{db}", "--out", "{tmp}/" + "b" * 260 + "/sub"], "{tmp}/" + "b" * 260 + "/sub", "File name too long"),
    # refused before the solves (minutes), not after them
    (["calibrate", "field", "--out", "{tmp}/" + "f" * 260 + ".npz"], "{tmp}/" + "f" * 260 + ".npz", "File name too long"),
    (["calibrate", "truth", "--out", "{tmp}/" + "t" * 260 + ".npz"], "{tmp}/" + "t" * 260 + ".npz", "File name too long"),
    pytest.param(["report", "table1", "--db", "{db}", "--out", "/proc/t.md"], "/proc/t.md", "No such file or directory",
                 marks=pytest.mark.skipif(not PROC, reason="no /proc")),
    pytest.param(["export", "--db", "{db}", "--out", "/proc/sub"], "/proc/sub", "No such file or directory",
                 marks=pytest.mark.skipif(not PROC, reason="no /proc")),
], ids=["file name too long", "folder name too long", "parent name too long", "field name too long", "truth name too long",
        "proc file", "proc folder"])
def test_an_output_the_file_system_refuses_is_one_line_and_leaves_nothing(argv, target, why, small_study, tmp_path):
    before = _listing(tmp_path)
    db_sha = _sha(small_study)
    res = studyctl(*[a.format(db=small_study, tmp=tmp_path) for a in argv])
    assert res.exit_code == 1, res.output
    assert res.output.strip().splitlines() == [f"Error: {target.format(tmp=tmp_path)}: cannot write: {why}; nothing was written"]
    assert _listing(tmp_path) == before
    assert _sha(small_study) == db_sha


def _quick_field(monkeypatch):
    """The field's solves (minutes) replaced by a small file written where the command asks."""
    import numpy as np

    from analysis.verification import field_fit

    def build_field(scene_path, out, progress=None):
        np.savez(out, K_per_pa=np.zeros((1, 6), dtype=np.float32))
        return {"path": str(out), "sites": 1, "vertices": 1, "size_mm": 8.0, "seconds": 0.0}

    monkeypatch.setattr(field_fit, "build_field", build_field)


def test_calibrate_field_writes_neither_file_when_the_shape_fit_fails(tmp_path, monkeypatch):
    """The second step fails after the field is computed: the field is not moved into place
    either, and the files that were there (replaced only on success, with --force) stay."""
    from analysis.verification import field_fit
    from sim.errors import SimError

    def failing_fit(*args, **kwargs):
        raise SimError("the shape fit failed")

    _quick_field(monkeypatch)
    monkeypatch.setattr(field_fit, "fit_shape", failing_fit)
    field, params = tmp_path / "f.npz", tmp_path / "p.toml"
    field.write_bytes(OLD)
    params.write_bytes(OLD)
    before = _listing(tmp_path)
    res = studyctl("calibrate", "field", "--out", field, "--params-out", params, "--force")
    assert res.exit_code == 1
    assert res.output.strip().splitlines() == ["Error: the shape fit failed"]
    assert field.read_bytes() == OLD
    assert params.read_bytes() == OLD
    assert _listing(tmp_path) == before  # no temporary left


def test_calibrate_field_moves_both_files_into_place_when_both_steps_ran(tmp_path, monkeypatch):
    _quick_field(monkeypatch)
    field, params = tmp_path / "f.npz", tmp_path / "p.toml"
    res = studyctl("calibrate", "field", "--out", field, "--params-out", params, "--formulation", "small-strain")
    assert res.exit_code == 0, res.output
    assert res.output.strip().splitlines()[-2:] == [f"wrote {field}: 1 sites, 1 vertices (0 s)", f"wrote {params} (small-strain curve)"]
    assert _listing(tmp_path) == ["f.npz", "p.toml"]
    assert "layers = 1" in params.read_text()


def test_a_table_a_tool_writes_itself_takes_a_long_name_and_leaves_no_temporary(tmp_path, monkeypatch):
    """sim.files.save_npz (the field's, truth table's and caches' writer) under the same rule:
    a short temporary name, removed when the write fails."""
    import numpy as np

    from sim.files import save_npz

    out = tmp_path / ("t" * 250 + ".npz")
    save_npz(out, x=np.arange(3))
    assert _listing(tmp_path) == [out.name]
    assert np.load(out)["x"].tolist() == [0, 1, 2]

    def full_disk_halfway(file, **arrays):
        Path(file).write_bytes(b"PK")  # the start of a zip, then the disk is full
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(np, "savez", full_disk_halfway)
    with pytest.raises(OSError):
        save_npz(tmp_path / "other.npz", x=np.arange(3))
    assert _listing(tmp_path) == [out.name]


# ---- no output destroys an input, a special file, or another output of the same command ----

def _state(folder: Path) -> dict:
    """Every file under `folder` (hidden ones too), links as their text: what a refused command must leave as it was."""
    out = {}
    for p in sorted(folder.rglob("*")):
        rel = str(p.relative_to(folder))
        if p.is_symlink():
            out[rel] = "-> " + str(p.readlink())
        elif p.is_file():
            out[rel] = _sha(p)
        elif not p.is_dir():
            out[rel] = "special"
    return out


@pytest.fixture
def study_copy(small_study, tmp_path):
    """The small study, database and traces, in this test's own folder (a refusal that fails
    must not take the shared one with it)."""
    import shutil

    db = tmp_path / "s.db"
    shutil.copy2(small_study, db)
    shutil.copytree(small_study.parent / f"{small_study.name}.traces", tmp_path / "s.db.traces")
    fast_protocol(tmp_path)  # tmp_path / "scene.toml", tmp_path / "protocol.toml"
    return db


# (argv, the output as the command names it, how it is an input: "itself", "hard", "symlink", or a companion's
#  name "s.db.traces"; the message's tail after "is (part of) an input of this command (")
AS_INPUT = {
    "table1 --out the db": (["report", "table1", "--db", "{db}", "--out", "{db}"], "{db}", None, "--db {db})"),
    "table1 --out a hard link to the db": (["report", "table1", "--db", "{db}", "--format", "md", "--out", "{tmp}/t.md"],
                                           "{tmp}/t.md", "hard", "--db {db})"),
    "table1 --out a symlink to the db": (["report", "table1", "--db", "{db}", "--format", "md", "--out", "{tmp}/t.md"],
                                         "{tmp}/t.md", "symlink", "--db {db})"),
    "table1 --out the db's traces": (["report", "table1", "--db", "{db}", "--out", "{db}.traces/t.md"], "{db}.traces/t.md", None,
                                     "--db {db}: s.db.traces)"),
    "table1 --out the db's WAL": (["report", "table1", "--db", "{db}", "--format", "md", "--out", "{db}-wal"], "{db}-wal", None,
                                  "--db {db}: s.db-wal)"),
    "table1 --out --accuracy": (["report", "table1", "--db", "{db}", "--format", "json", "--accuracy", "{tmp}/a.json",
                                 "--out", "{tmp}/a.json"], "{tmp}/a.json", None, "--accuracy {tmp}/a.json)"),
    "text --out the db": (["report", "text", "--db", "{db}", "--format", "md", "--out", "{db}"], "{db}", None, "--db {db})"),
    "jnd --out the db": (["report", "jnd", "--db", "{db}", "--format", "md", "--out", "{db}"], "{db}", None, "--db {db})"),
    "validity --out the db": (["report", "validity", "--db", "{db}", "--format", "md", "--out", "{db}"], "{db}", None, "--db {db})"),
    "metrics --out a hard link to the db": (["metrics", "--db", "{db}", "--out", "{tmp}/m.csv"], "{tmp}/m.csv", "hard", "--db {db})"),
    "contacts --out a hard link to the db": (["participants", "contacts", "--db", "{db}", "--out", "{tmp}/c.csv"], "{tmp}/c.csv", "hard",
                                             "--db {db})"),
    "schedule --ics a hard link to the db": (["schedule", "--db", "{db}", "--start", "2099-01-05", "--end", "2099-01-09", "--ics",
                                              "{tmp}/s.ics"], "{tmp}/s.ics", "hard", "--db {db})"),
    "export --out the db's traces": (["export", "--db", "{db}", "--out", "{db}.traces"], "{db}.traces", None, "--db {db}: s.db.traces)"),
    "plots --out the db's locks": (["report", "plots", "--db", "{db}", "--out", "{db}.locks"], "{db}.locks", None, "--db {db}: s.db.locks)"),
    "replay --frames the db's traces": (["replay", "--db", "{db}", "--session", "1", "--trial", "1", "--frames", "{db}.traces"],
                                        "{db}.traces", None, "--db {db}: s.db.traces)"),
    "sim run --frames over its scene": (["sim", "run", "--scene", "{tmp}/fr/trace.csv", "--frames", "{tmp}/fr"], "{tmp}/fr/trace.csv",
                                        None, "--scene {tmp}/fr/trace.csv)"),
    "plan --plot a hard link to the protocol": (["plan", "--protocol", "{tmp}/protocol.toml", "--plot", "{tmp}/p.png"], "{tmp}/p.png",
                                                "hard", "--protocol {tmp}/protocol.toml)"),
    "calibrate plate-spring --out its scene": (["calibrate", "plate-spring", "--scene", "{tmp}/scene.toml", "--out", "{tmp}/scene.toml"],
                                               "{tmp}/scene.toml", None, "--scene {tmp}/scene.toml)"),
    "model check --out a hard link to its scene": (["model", "check", "plate_spring", "--contract", "--scene", "{tmp}/scene.toml",
                                                    "--out", "{tmp}/card.md"], "{tmp}/card.md", "hard", "--scene {tmp}/scene.toml)"),
}
SOURCE = {"--db": "{db}", "--accuracy": "{tmp}/a.json", "--protocol": "{tmp}/protocol.toml", "--scene": "{tmp}/scene.toml"}


@pytest.mark.parametrize("force", [False, True], ids=["", "--force"])
@pytest.mark.parametrize("case", list(AS_INPUT))
def test_an_output_that_is_an_input_is_refused_and_nothing_changes(case, force, study_copy, tmp_path):
    import os

    argv, out, link, tail = AS_INPUT[case]
    fill = {"db": study_copy, "tmp": tmp_path}
    (tmp_path / "a.json").write_text('{"rows": [], "meta": {}}')
    (tmp_path / "fr").mkdir()
    (tmp_path / "fr" / "trace.csv").write_bytes((tmp_path / "scene.toml").read_bytes())  # a scene under the name of a frame file
    (tmp_path / "s.db-wal").write_bytes(b"")
    (tmp_path / "s.db.locks").mkdir()
    out = out.format(**fill)
    source = next(SOURCE[o].format(**fill) for o in SOURCE if tail.startswith(o + " "))
    if link == "hard":
        os.link(source, out)
    elif link == "symlink":
        os.symlink(source, out)
    before = _state(tmp_path)
    res = studyctl(*[a.format(**fill) for a in argv], *(["--force"] if force else []))
    assert res.exit_code == 1, res.output
    what = "is part of an input" if ": s.db" in tail else "is an input"
    option = next(o for o in ("--frames", "--ics", "--plot", "--out") if o in argv)
    assert res.output.strip().splitlines() == [f"Error: {out}: {what} of this command ({tail.format(**fill)}; choose another {option}"]
    assert _state(tmp_path) == before


# (how the special file is made, what --out names): each refused with or without --force, and nothing changes
SPECIAL = {
    "fifo": lambda p: __import__("os").mkfifo(p),
    "symlink to a device": lambda p: p.symlink_to("/dev/null"),
    "symlink to /dev/stdout": lambda p: p.symlink_to("/dev/stdout"),  # as root, --force once replaced /dev/stdout itself
    "symlink to a socket": lambda p: _socket(p),
    "a copy of /dev/full": lambda p: _device(p),
}


def _device(p):
    import os
    import stat

    try:
        os.mknod(p, stat.S_IFCHR | 0o666, os.makedev(1, 7))  # /dev/full's numbers
    except PermissionError:
        pytest.skip("making a device takes CAP_MKNOD")


def _socket(p):
    import socket

    s = socket.socket(socket.AF_UNIX)
    s.bind(str(p.with_suffix(".sock")))
    p.symlink_to(p.with_suffix(".sock"))


@pytest.mark.parametrize("force", [False, True], ids=["", "--force"])
@pytest.mark.parametrize("kind", list(SPECIAL))
def test_an_output_that_is_a_special_file_is_refused_and_nothing_changes(kind, force, small_study, tmp_path):
    out = tmp_path / "t.md"
    SPECIAL[kind](out)
    before = _state(tmp_path)
    res = studyctl("report", "table1", "--db", small_study, "--out", out, *(["--force"] if force else []))
    assert res.exit_code == 1, res.output
    assert res.output.strip().splitlines() == [f"Error: {out}: not a regular file; outputs go to regular files or new names"]
    assert _state(tmp_path) == before


def test_a_folder_output_that_is_a_special_file_is_refused(tmp_path):
    import os

    from studyctl.outputs import OutputNotRegular, Staged

    out = tmp_path / "frames"
    os.mkfifo(out)
    with pytest.raises(OutputNotRegular, match=r"frames: not a folder; folder outputs go to folders or new names$"):
        Staged(out, force=True, folder=True)
    assert _state(tmp_path) == {"frames": "special"}


def test_force_replaces_a_symlink_to_a_regular_file_and_leaves_the_file_it_named(small_study, tmp_path):
    """The documented choice (docs/study.md, Output files): the name is replaced, as `mv` would."""
    real = tmp_path / "kept.md"
    real.write_bytes(OLD)
    out = tmp_path / "t.md"
    out.symlink_to(real)
    res = studyctl("report", "table1", "--db", small_study, "--out", out, "--force")
    assert res.exit_code == 0, res.output
    assert not out.is_symlink()
    assert out.read_text().startswith("**Table 1: ")
    assert real.read_bytes() == OLD


@pytest.mark.parametrize("force", [False, True], ids=["", "--force"])
@pytest.mark.parametrize(("argv", "message"), [
    (["sim", "run", "--scene", "{tmp}/scene.toml", "--view", "window", "--frames", "{tmp}/fr", "--screenshot", "{tmp}/fr/force.png"],
     "{tmp}/fr/force.png: --screenshot names a file --frames writes ({tmp}/fr); choose another --screenshot"),
    (["sim", "run", "--scene", "{tmp}/scene.toml", "--view", "window", "--frames", "{tmp}/fr", "--screenshot", "{tmp}/fr/frame_0001.png"],
     "{tmp}/fr/frame_0001.png: --screenshot names a file --frames writes ({tmp}/fr); choose another --screenshot"),
    (["calibrate", "field", "--out", "{tmp}/f.npz", "--params-out", "{tmp}/p.toml"],
     "{tmp}/p.toml: both --out and --params-out name it; choose one place for each"),
], ids=["screenshot on a frame file", "a screenshot named as a frame", "params on the field"])
def test_two_outputs_of_one_command_on_one_path_are_refused_before_any_work(argv, message, force, tmp_path):
    fast_protocol(tmp_path)
    (tmp_path / "fr").mkdir()
    (tmp_path / "fr" / "force.png").write_bytes(OLD)
    (tmp_path / "f.npz").write_bytes(OLD)
    (tmp_path / "p.toml").symlink_to(tmp_path / "f.npz")
    before = _state(tmp_path)
    res = studyctl(*[a.format(tmp=tmp_path) for a in argv], *(["--force"] if force else []))
    assert res.exit_code == 1, res.output
    assert res.output.strip().splitlines() == [f"Error: {message.format(tmp=tmp_path)}"]
    assert _state(tmp_path) == before


def test_a_file_of_another_name_inside_a_folder_output_is_no_conflict(tmp_path):
    """`sim run --frames fr --screenshot fr/shot.png`: the screenshot is kept in the folder like
    any file the frames do not write; only the folder's own names are refused."""
    from studyctl.cli.common import FRAMES_OWN
    from studyctl.outputs import OutputConflict, refuse_overlap

    refuse_overlap({"--frames": (tmp_path / "fr", FRAMES_OWN), "--screenshot": (tmp_path / "fr" / "shot.png", False)})
    with pytest.raises(OutputConflict, match="names a file --frames writes"):
        refuse_overlap({"--frames": (tmp_path / "fr", FRAMES_OWN), "--screenshot": (tmp_path / "fr" / "trace.csv", False)})
    with pytest.raises(OutputConflict, match="names a file --frames writes"):
        refuse_overlap({"--frames": (tmp_path / "fr", FRAMES_OWN), "--screenshot": (tmp_path / "fr" / "frame_0003.png", False)})


def test_a_study_database_s_companions_are_named_as_the_store_names_them(tmp_path):
    from analysis.study.trace_files import trace_dir
    from studyctl.outputs import database_companions
    from studyctl.session.lock import session_lock

    db = tmp_path / "s.db"
    with session_lock(db, "P01"):  # the lock's folder exists while it is held
        made = list(tmp_path.iterdir())
    assert len(made) == 1
    assert made[0] in database_companions(db)
    assert trace_dir(db) in database_companions(db)


def test_a_linked_database_s_companions_beside_the_real_file_are_inputs_too(tmp_path):
    """The store keeps traces and locks beside the real file: an output there is refused through the link."""
    real = tmp_path / "real"
    real.mkdir()
    (real / "s.db").write_bytes(b"")
    link = tmp_path / "s.db"
    link.symlink_to(real / "s.db")
    from studyctl.outputs import database_companions

    names = database_companions(link)
    assert real / "s.db.traces" in names
    assert tmp_path / "s.db-wal" in names


def test_force_replaces_a_frames_folder_whole_and_says_what_it_removed_and_kept(tmp_path):
    """An earlier run of 5 frames, then one of 2: no frame of the earlier run is left beside the new ones."""
    scene = fast_protocol(tmp_path).parent / "scene.toml"
    offscreen = tmp_path / "offscreen.toml"
    offscreen.write_text(re.sub(r'^kind = "none"', 'kind = "offscreen"', scene.read_text(), count=1, flags=re.M))
    fr = tmp_path / "fr"
    fr.mkdir()
    for name in ("trace.csv", "force.png", "notes.txt", *(f"frame_{k:04d}.png" for k in range(5))):
        (fr / name).write_bytes(OLD)
    res = studyctl("sim", "run", "--scene", offscreen, "--duration", "0.2", "--time-scale", "0", "--frames", fr, "--force", "--json")
    assert res.exit_code == 0, res.output
    assert _listing(fr) == ["force.png", "frame_0000.png", "frame_0001.png", "notes.txt", "trace.csv"]
    assert (fr / "notes.txt").read_bytes() == OLD
    assert (f"--force: overwrote 4 files in {fr}; removed 3 earlier files of this command from {fr} (frame_0002.png, "
            f"frame_0003.png, frame_0004.png); kept 1 file in {fr} it does not write (notes.txt)") in res.output.splitlines()
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []  # nothing left aside


def test_force_never_swaps_the_folder_itself(small_study, tmp_path):
    """A folder output may hold the study it reads (its WAL, locks and traces) or be a shell's
    working folder: --force replaces files in it, the folder stays the same folder."""
    import shutil

    out = tmp_path / "st"
    shutil.copytree(Path(small_study).parent, out)  # the study, its traces beside it
    db = out / Path(small_study).name
    (out / "answers.parquet").write_bytes(OLD)  # an earlier export of the other format: removed
    inode = out.stat().st_ino
    res = studyctl("export", "--db", db, "--out", out, "--force")
    assert res.exit_code == 0, res.output
    assert out.stat().st_ino == inode
    assert not (out / "answers.parquet").exists()
    assert studyctl("status", "--db", db).exit_code == 0


def test_a_folder_output_named_dot_stages_beside_it_not_inside(small_study, tmp_path, monkeypatch):
    out = tmp_path / "here"
    out.mkdir()
    (out / "notes.txt").write_bytes(OLD)
    monkeypatch.chdir(out)
    res = studyctl("export", "--db", small_study, "--out", ".", "--force")
    assert res.exit_code == 0, res.output
    assert ".studyctl-" not in res.output
    assert "kept 1 file in . it does not write (notes.txt)" in res.output
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".studyctl-")]
    assert not [p for p in out.iterdir() if p.name.startswith(".studyctl-")]


def test_report_plots_force_keeps_a_users_own_figures(small_study, tmp_path):
    """Only the figures `report plots` writes are its own: a manuscript or a logo in the folder stays."""
    out = tmp_path / "fig"
    out.mkdir()
    for name in ("manuscript.pdf", "logo.png", "choice_old.png"):
        (out / name).write_bytes(OLD)
    res = studyctl("report", "plots", "--db", small_study, "--out", out, "--force")
    assert res.exit_code == 0, res.output
    assert (out / "manuscript.pdf").read_bytes() == OLD
    assert (out / "logo.png").read_bytes() == OLD
    assert not (out / "choice_old.png").exists()


def test_every_figure_report_plots_writes_is_one_of_its_own(small_study, tmp_path):
    from studyctl.cli.reports import FIGURE_FILES

    res = studyctl("report", "plots", "--db", small_study, "--out", tmp_path / "fig")
    assert res.exit_code == 0, res.output
    written = sorted(p.name for p in (tmp_path / "fig").iterdir())
    assert written
    assert [n for n in written if not any(fnmatch.fnmatchcase(n, pat) for pat in FIGURE_FILES)] == []


@pytest.mark.parametrize(("argv", "message"), [
    (["report", "table1", "--out", "{tmp}/t.pdf"], "{tmp}/t.pdf: report table1 writes md, csv, latex (.tex), html, json; .pdf is not one"),
    (["report", "table1", "--format", "md", "--out", "{tmp}/t.html"],
     "{tmp}/t.html: --format md writes .md, not .html; name it t.md or give --format html"),
    (["report", "table1", "--out", "{tmp}/t.txt"],
     "{tmp}/t.txt: .txt names no format; report table1 writes md, csv, latex (.tex), html, json: end the name so or give --format"),
    (["report", "jnd", "--format", "html", "--out", "{tmp}/j.md"], "{tmp}/j.md: --format html writes .html, not .md; name it j.html or give --format md"),
    (["report", "jnd", "--out", "{tmp}/j.csv"], "{tmp}/j.csv: report jnd writes md, html, json, latex (.tex); .csv is not one"),
    (["report", "validity", "--json", "--out", "{tmp}/v.html"], "{tmp}/v.html: --format json writes .json, not .html; name it v.json or give --format html"),
    (["report", "text", "--out", "{tmp}/x.html"], "{tmp}/x.html: report text writes md, latex (.tex), json; .html is not one"),
    (["metrics", "--format", "csv", "--out", "{tmp}/m.json"], "{tmp}/m.json: --format csv writes .csv, not .json; name it m.csv or give --format json"),
], ids=["pdf", "md as html", "no format", "jnd html as md", "jnd csv", "validity json as html", "text html", "metrics csv as json"])
def test_a_report_s_format_and_its_suffix_agree(argv, message, small_study, tmp_path):
    res = studyctl(*[a.format(tmp=tmp_path) for a in argv], "--db", small_study)
    assert res.exit_code == 1, res.output
    assert res.output.strip().splitlines() == [f"Error: {message.format(tmp=tmp_path)}"]
    assert _listing(tmp_path) == []


@pytest.mark.parametrize(("name", "start"), [("t.html", "<!doctype html>"), ("t.tex", "% needs in the preamble: "), ("t.json", "{"),
                                             ("t.csv", "item,"), ("t.md", "**Table 1: ")])
def test_report_table1_takes_its_format_from_the_suffix(name, start, small_study, tmp_path):
    res = studyctl("report", "table1", "--db", small_study, "--out", tmp_path / name)
    assert res.exit_code == 0, res.output
    assert (tmp_path / name).read_text().startswith(start)


def test_force_removes_only_the_command_s_own_kind_of_file_at_the_folder_s_top(tmp_path):
    """`report plots` writes figures at the folder's top: a figure in a subfolder is someone else's."""
    from studyctl.outputs import Staged

    out = tmp_path / "plots"
    (out / "mine").mkdir(parents=True)
    for name in ("old.png", "rates.png", "mine/keep.png", "notes.txt"):
        (out / name).write_bytes(OLD)
    target = Staged(out, force=True, folder=True, own=("*.png", "*.svg", "*.pdf"))
    with target as tmp:
        (tmp / "rates.png").write_bytes(b"new")
    assert _listing(out) == ["mine", "mine/keep.png", "notes.txt", "rates.png"]
    assert [p.name for p in tmp_path.iterdir()] == ["plots"]  # nothing left aside


def test_export_with_force_replaces_an_earlier_export_whole(small_study, tmp_path):
    out = tmp_path / "export"
    out.mkdir()
    for name in ("answers.parquet", "answers.csv", "notes.txt"):
        (out / name).write_bytes(OLD)
    res = studyctl("export", "--db", small_study, "--out", out, "--force")
    assert res.exit_code == 0, res.output
    assert not (out / "answers.parquet").exists()
    assert (out / "notes.txt").read_bytes() == OLD
    assert (f"--force: overwrote {out / 'answers.csv'}; removed 1 earlier file of this command from {out} (answers.parquet); "
            f"kept 1 file in {out} it does not write (notes.txt)") in res.output.splitlines()
