"""Inputs bounded (docs/study.md, "Limits on input"): TOML nesting and size, input paths that
must be regular files, control characters and lengths of texts, integer ranges of seeds, a
second Ctrl-C while an interrupted session cleans up. Each refusal: one line, a non-zero exit,
no traceback, nothing changed."""

import hashlib
import os
import signal
import sqlite3

import pytest

from tests.helpers import fast_protocol, studyctl


def _hash(path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _one_error_line(res) -> str:
    """The refusal's one line (click's usage errors print a usage line before it)."""
    lines = res.output.strip().splitlines()
    assert "Traceback" not in res.output, res.output
    return lines[-1]


def _study(tmp_path):
    db = tmp_path / "s.db"
    res = studyctl("study", "init", "--protocol", fast_protocol(tmp_path, conditions=("plate_spring",), trials=1), "--db", db)
    assert res.exit_code == 0, res.output
    return db


# --- TOML: depth and size -------------------------------------------------------------------

def test_a_protocol_nested_5000_deep_is_one_line_not_a_recursion_error(tmp_path):
    proto = fast_protocol(tmp_path, conditions=("plate_spring",), trials=1)
    proto.write_text(proto.read_text() + "deep = " + "[" * 5000 + "]" * 5000 + "\n")
    before = _hash(proto)
    res = studyctl("protocol", "validate", proto)
    assert res.exit_code == 1
    assert res.output.strip().count("\n") == 0, res.output
    assert "nested more than 32 levels deep; allowed: at most 32" in res.output
    assert "RecursionError" not in res.output
    assert _hash(proto) == before


def test_study_init_from_a_too_deep_protocol_writes_no_database(tmp_path):
    proto = fast_protocol(tmp_path, conditions=("plate_spring",), trials=1)
    proto.write_text(proto.read_text() + "deep = " + "{a = " * 100 + "1" + "}" * 100 + "\n")
    res = studyctl("study", "init", "--protocol", proto, "--db", tmp_path / "s.db")
    assert res.exit_code == 1
    assert "nested more than 32 levels deep" in _one_error_line(res)
    assert not (tmp_path / "s.db").exists()


def test_tables_nested_by_dotted_keys_are_limited_too(tmp_path):
    proto = tmp_path / "dotted.toml"
    proto.write_text("[study]\n" + "a." * 40 + "b = 1\n")
    res = studyctl("protocol", "validate", proto)
    assert res.exit_code == 1
    assert res.output.strip() == f"{proto}: tables nested more than 32 levels deep; allowed: at most 32"


def test_brackets_inside_strings_and_comments_do_not_count_as_nesting(tmp_path):
    proto = fast_protocol(tmp_path, conditions=("plate_spring",), trials=1)
    text = proto.read_text().replace('[study]\n', '[study]\n# ' + "[" * 50 + "\n", 1)
    text = text.replace('title = "Virtual', 'title = "' + "[{" * 40 + ' Virtual', 1)
    proto.write_text(text)
    res = studyctl("protocol", "validate", proto)
    assert res.exit_code == 0, res.output



def test_an_unterminated_string_of_escapes_is_scanned_once_and_named_by_the_parser(tmp_path):
    """Half a megabyte of `"\\` on one line: a backtracking scan would take hours."""
    proto = tmp_path / "p.toml"
    proto.write_text('x = "' + '\\"' * 300_000 + "\n")
    res = studyctl("protocol", "validate", proto)
    assert res.exit_code == 1
    assert res.output.startswith(f"{proto}:1: invalid TOML: "), res.output[:300]
    assert res.output.strip().count("\n") == 0

def test_a_toml_file_over_one_mib_is_refused_before_parsing(tmp_path):
    proto = fast_protocol(tmp_path, conditions=("plate_spring",), trials=1)
    proto.write_text(proto.read_text() + "# " + "x" * (1024 * 1024) + "\n")
    res = studyctl("protocol", "validate", proto)
    assert res.exit_code == 1
    assert res.output.strip() == f"{proto}: 1.0 MiB; allowed: at most 1 MiB"


# --- paths that must be regular files --------------------------------------------------------

def _with_scene(tmp_path, scene: str):
    proto = fast_protocol(tmp_path, conditions=("plate_spring",), trials=1)
    text = proto.read_text()
    start = text.index("scene = ")
    proto.write_text(text[:start] + f'scene = "{scene}"' + text[text.index("\n", start):])
    return proto


def test_a_scene_that_is_dev_zero_is_refused_before_reading(tmp_path):
    proto = _with_scene(tmp_path, "/dev/zero")
    res = studyctl("protocol", "validate", proto)
    assert res.exit_code == 1
    assert res.output.strip().endswith("study.scene: /dev/zero is not a regular file"), res.output
    assert res.output.strip().count("\n") == 0, res.output


def test_a_named_pipe_as_scene_is_refused_without_blocking(tmp_path):
    os.mkfifo(tmp_path / "pipe.toml")
    proto = _with_scene(tmp_path, str(tmp_path / "pipe.toml"))
    res = studyctl("study", "init", "--protocol", proto, "--db", tmp_path / "s.db")
    assert res.exit_code == 1
    assert _one_error_line(res).endswith(f"study.scene: {tmp_path / 'pipe.toml'} is not a regular file")
    assert not (tmp_path / "s.db").exists()


def test_a_protocol_that_is_a_device_or_a_pipe_is_named_as_such(tmp_path):
    os.mkfifo(tmp_path / "p.toml")
    res = studyctl("protocol", "validate", tmp_path / "p.toml")
    assert res.exit_code == 1
    assert res.output.strip() == f"{tmp_path / 'p.toml'}: is a named pipe; allowed: a regular file"
    res = studyctl("protocol", "validate", "/dev/zero")
    assert res.output.strip() == "/dev/zero: is a character device; allowed: a regular file"



@pytest.mark.parametrize("key", ["path", "file"])
def test_a_scene_naming_a_pipe_as_its_mesh_or_material_is_refused(tmp_path, key):
    proto = fast_protocol(tmp_path, conditions=("plate_spring",), trials=1)
    os.mkfifo(tmp_path / "pipe")
    scene = tmp_path / "scene.toml"
    lines = scene.read_text().splitlines()
    k = next(i for i, line in enumerate(lines) if line.startswith(f"{key} = "))
    lines[k] = f'{key} = "{tmp_path / "pipe"}"'
    scene.write_text("\n".join(lines) + "\n")
    before = _hash(scene)
    res = studyctl("protocol", "validate", proto)
    assert res.exit_code == 1
    assert res.output.strip().endswith(f": {'mesh' if key == 'path' else 'material'}.{key}: {tmp_path / 'pipe'} is not a regular file"), res.output
    assert res.output.strip().count("\n") == 0
    assert _hash(scene) == before

@pytest.mark.parametrize("command", [
    ["calibrate", "material", "--data"],
    ["calibrate", "rheology", "--mu-inf", "700", "--mu-1", "2000", "--tau-1", "9.7", "--bulk-modulus", "6e4", "--data"],
    ["calibrate", "plate-spring", "--reference"],
])
def test_data_files_that_are_devices_or_pipes_are_refused(tmp_path, command):
    os.mkfifo(tmp_path / "d.csv")
    for path, kind in (("/dev/zero", "a character device"), (str(tmp_path / "d.csv"), "a named pipe")):
        res = studyctl(*command, path)
        assert res.exit_code == 1
        assert _one_error_line(res) == f"Error: {path}: is {kind}; allowed: a regular file"


def test_answers_and_participants_imports_refuse_a_pipe_and_change_nothing(tmp_path):
    db = _study(tmp_path)
    before = _hash(db)
    os.mkfifo(tmp_path / "a.csv")
    for args in (["answers", "import", "--db", db, tmp_path / "a.csv"], ["participants", "import", "--db", db, tmp_path / "a.csv"]):
        res = studyctl(*args)
        assert res.exit_code == 1
        assert _one_error_line(res) == f"Error: {tmp_path / 'a.csv'}: is a named pipe; allowed: a regular file"
    assert _hash(db) == before


# --- integer ranges ---------------------------------------------------------------------------

@pytest.mark.parametrize("option", ["--seed"])
def test_a_seed_of_2_to_the_70_is_a_usage_error_not_an_overflow(tmp_path, option):
    db = _study(tmp_path)
    before = _hash(db)
    res = studyctl("synth", "--db", db, "--participants", "1", option, str(2**70))
    assert res.exit_code == 2
    assert _one_error_line(res) == f"Error: Invalid value for '{option}': {2**70} is not in the range 0<=x<=4294967295."
    assert "OverflowError" not in res.output
    assert _hash(db) == before


@pytest.mark.parametrize("args", [
    ["session", "run", "--participant", "P01", "--synthetic", "--seed", str(2**63)],
    ["report", "validity", "--seed", "-1"],
])
def test_seeds_of_other_commands_are_ranged_too(tmp_path, args):
    db = _study(tmp_path)
    before = _hash(db)
    res = studyctl(*args[:2], "--db", db, *args[2:])
    assert res.exit_code == 2
    assert "is not in the range 0<=x<=4294967295" in _one_error_line(res)
    assert _hash(db) == before



def test_replay_of_a_session_id_beyond_sqlites_integers_is_a_usage_error(tmp_path):
    db = _study(tmp_path)
    res = studyctl("replay", "--db", db, "--session", str(2**70), "--trial", "1")
    assert res.exit_code == 2
    assert _one_error_line(res) == f"Error: Invalid value for '--session': {2**70} is not in the range 1<=x<={2**63 - 1}."


def test_a_protocol_integer_beyond_its_range_is_one_line(tmp_path):
    proto = fast_protocol(tmp_path, conditions=("plate_spring",), trials=1)
    proto.write_text(proto.read_text().replace("version = 1\n", "version = 99999999999999999999999\n", 1))
    res = studyctl("study", "init", "--protocol", proto, "--db", tmp_path / "s.db")
    assert res.exit_code == 1
    assert _one_error_line(res).endswith("study.version: 99999999999999999999999 is out of range; allowed: 1..10000")
    assert not (tmp_path / "s.db").exists()

# --- a second Ctrl-C during the cleanup -----------------------------------------------------

def test_a_second_ctrl_c_while_a_resumed_session_cleans_up_still_says_how_to_resume(tmp_path, monkeypatch):
    import studyctl.session.run as session  # where a session runs its trials and marks itself interrupted

    old = signal.signal(signal.SIGINT, signal.default_int_handler)  # pytest-xdist's workers ignore SIGINT
    try:
        db = tmp_path / "s.db"
        assert studyctl("study", "init", "--protocol", fast_protocol(tmp_path, conditions=("plate_spring",), trials=3), "--db", db).exit_code == 0
        assert studyctl("participants", "add", "S01", "--db", db, "--synthetic").exit_code == 0
        real_scene, real_mark = session.run_scene, session.session_rows.mark_interrupted
        calls = []

        def ctrl_c_at_the_second_run(*a, **kw):
            calls.append(1)
            if len(calls) == 2:
                raise KeyboardInterrupt
            return real_scene(*a, **kw)

        def ctrl_c_again_while_marking(store, session_id):
            os.kill(os.getpid(), signal.SIGINT)  # the second Ctrl-C, in the cleanup
            real_mark(store, session_id)

        monkeypatch.setattr(session, "run_scene", ctrl_c_at_the_second_run)
        run = ["session", "run", "--db", db, "--participant", "S01", "--synthetic"]
        assert studyctl(*run).exit_code == 130
        calls.clear()
        monkeypatch.setattr(session.session_rows, "mark_interrupted", ctrl_c_again_while_marking)
        res = studyctl(*run, "--resume")
        assert res.exit_code == 130
        last = _one_error_line(res)
        assert last.startswith("Error: session 1 of S01 interrupted"), res.output
        assert last.endswith(f"studyctl session run --db {db} --participant S01 --synthetic --resume")
        assert sqlite3.connect(db).execute("select status from sessions").fetchall() == [("interrupted",)]
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # the shield restored the handler
    finally:
        signal.signal(signal.SIGINT, old)


# --- texts: control characters and lengths -----------------------------------------------------

ESC, NUL, CSI = "\x1b[2J", "\x00", "\x9b2J"  # an ESC sequence (clear the screen), a NUL, a C1 control (CSI)


def _toml_text(s: str) -> str:
    """`s` as the inside of a TOML basic string, control characters escaped as \\uXXXX."""
    return "".join(f"\\u{ord(c):04x}" if ord(c) < 0x20 or 0x7F <= ord(c) <= 0x9F else c for c in s)


@pytest.mark.parametrize("old, new, field, problem", [
    ('name = "brain_pull_2015"', f'name = "brain{_toml_text(ESC)}pull"', "study.name", "control character U+001B at character 6"),
    ('title = "Virtual', f'title = "{_toml_text(NUL)}Virtual', "study.title", "control character U+0000 at character 1"),
    ('text = "Is interaction real', f'text = "Is {_toml_text(CSI)}interaction real', "questions[0].text", "control character U+009B at character 4"),
    # a right-to-left override, and an isolate: the text shown would not read as the file holds it
    ('text = "Is interaction real', 'text = "Is \\u202Einteraction real', "questions[0].text", "control character U+202E at character 4"),
    ('title = "Virtual', 'title = "\\u2067Virtual', "study.title", "control character U+2067 at character 1"),
    ('name = "brain_pull_2015"', 'name = "' + "b" * 101 + '"', "study.name", "101 characters; allowed: at most 100"),
    ('title = "Virtual brain pulling with three soft-tissue models"', 'title = "' + "t" * 201 + '"', "study.title",
     "201 characters; allowed: at most 200"),
    ('text = "Is interaction real and natural?"', 'text = "' + "q" * 2001 + '"', "questions[0].text", "2001 characters; allowed: at most 2000"),
])
def test_protocol_texts_with_control_characters_or_too_long_are_refused(tmp_path, old, new, field, problem):
    proto = fast_protocol(tmp_path, conditions=("plate_spring",), trials=1)
    assert old in proto.read_text()
    proto.write_text(proto.read_text().replace(old, new, 1))
    before = _hash(proto)
    res = studyctl("study", "init", "--protocol", proto, "--db", tmp_path / "s.db")
    assert res.exit_code == 1
    line = _one_error_line(res)
    assert f": {field}: {problem}" in line, res.output
    assert "\x1b" not in res.output
    assert "\x00" not in res.output
    assert "\x9b" not in res.output
    assert "\u202e" not in res.output
    assert "\u2067" not in res.output
    assert not (tmp_path / "s.db").exists()
    assert _hash(proto) == before


@pytest.mark.parametrize("anchor, problem", [
    (_toml_text(ESC) + "Not at all", "anchors: low: control character U+001B at character 1"),
    ("Not at all\\tquite", "anchors: low: control character U+0009 at character 11; a one-line text"),
    ("n" * 101, "anchors: low: 101 characters; allowed: at most 100"),
])
def test_scale_anchors_with_control_characters_or_too_long_are_refused(tmp_path, anchor, problem):
    from tests.helpers import variants_protocol

    proto = variants_protocol(tmp_path)
    proto.write_text(proto.read_text().replace('anchors = ["Not at all"', f'anchors = ["{anchor}"', 1))
    res = studyctl("protocol", "validate", proto)
    assert res.exit_code == 1
    assert problem in _one_error_line(res), res.output


def test_a_scene_text_with_an_escape_sequence_is_refused(tmp_path):
    proto = fast_protocol(tmp_path, conditions=("plate_spring",), trials=1)
    scene = tmp_path / "scene.toml"
    text = scene.read_text()
    assert '[scene]\nname = "' in text
    scene.write_text(text.replace('[scene]\nname = "', '[scene]\nname = "\\u001b]0;owned\\u0007', 1))
    res = studyctl("protocol", "validate", proto)
    assert res.exit_code == 1
    assert "scene.name: control character U+001B at character 1" in res.output, res.output


def _free_text_study(tmp_path):
    db = tmp_path / "s.db"
    proto = fast_protocol(tmp_path, conditions=("plate_spring",), trials=1)
    proto.write_text(proto.read_text() + '\n[[questions]]\nid = "comment"\ntext = "Anything else?"\nkind = "text"\nwhen = "end"\n')
    assert studyctl("study", "init", "--db", db, "--protocol", proto).exit_code == 0
    assert studyctl("participants", "add", "P01", "--db", db, "--age", "24").exit_code == 0
    assert studyctl("participants", "consent", "P01", "--db", db).exit_code == 0
    return db


def test_a_free_text_answer_over_2000_characters_is_refused_on_import(tmp_path):
    db = _free_text_study(tmp_path)
    answers = tmp_path / "a.csv"
    answers.write_text("participant,model,item,answer\nP01,,comment," + "w" * 2001 + "\n")
    before = _hash(db)
    res = studyctl("answers", "import", "--db", db, answers)
    assert res.exit_code == 1
    assert _one_error_line(res).endswith("(2001 characters) to comment (text) is not allowed; allowed: a text of at most 2000 characters")
    assert _hash(db) == before


@pytest.mark.parametrize("args, problem", [
    (["participants", "add", "P02", "--name", "A" * 101], "--name: 101 characters; allowed: at most 100"),
    (["participants", "add", "P02", "--name", "Ann\te"], "--name: control character U+0009 at character 4"),
    (["participants", "add", "P02", "--contact", "c" * 201], "--contact: 201 characters; allowed: at most 200"),
    (["participants", "withdraw", "P01", "--reason", "r" * 2001], "--reason: 2001 characters; allowed: at most 2000"),
    (["participants", "withdraw", "P01", "--reason", "moved\x9b2J"], "--reason: control character U+009B"),
    (["participants", "add", "P02", "--name", "Ann\u202eenna"], "--name: control character U+202E at character 4"),
    (["participants", "withdraw", "P01", "--reason", "moved\u200f"], "--reason: control character U+200F at character 6"),
])
def test_participant_texts_are_bounded(tmp_path, args, problem):
    db = _free_text_study(tmp_path)
    before = _hash(db)
    res = studyctl(*args[:2], "--db", db, *args[2:])
    assert res.exit_code == 1
    assert problem in _one_error_line(res), res.output
    assert _hash(db) == before


def test_the_terminal_questionnaire_asks_again_for_a_free_text_with_an_escape_sequence():
    from analysis.study.questions import Question
    from studyctl.session.asking import TerminalAnswers

    replies, shown = iter(["fine\x1b[2J", "x" * 2001, "fine"]), []
    ask = TerminalAnswers(prompt=lambda text: next(replies), echo=shown.append)
    answer = ask(Question("comment", "Anything else?", kind="text", when="end"), "", {"labels": {}})
    assert answer == "fine"
    assert shown[0] == "Please type it again: control character U+001B at character 5; text may hold no control characters " \
                       "(tabs and line breaks aside)."
    assert shown[1] == "Please type it again: 2001 characters; allowed: at most 2000."


def test_an_imported_name_over_100_characters_is_refused_like_an_added_one(tmp_path):
    db = _free_text_study(tmp_path)
    people = tmp_path / "p.csv"
    people.write_text("code,age,name\nP02,24," + "N" * 101 + "\n")
    before = _hash(db)
    res = studyctl("participants", "import", "--db", db, people)
    assert res.exit_code == 1
    assert _one_error_line(res) == f"Error: {people}: line 2: name: 101 characters; allowed: at most 100"
    assert _hash(db) == before


# --- one model, two spellings -----------------------------------------------------------------

def test_a_scene_configuring_one_model_under_both_spellings_is_refused_naming_both(tmp_path):
    fast_protocol(tmp_path, conditions=("plate_spring",), trials=1)
    scene = tmp_path / "scene.toml"
    text = scene.read_text()
    assert "[models.fem]" in text
    scene.write_text(text.replace("[models.fem]", '[models.plate-spring]\nvariant = "paper"\n\n[models.fem]', 1))
    before = _hash(scene)
    res = studyctl("sim", "run", "--scene", scene, "--time-scale", "0", "--duration", "0.1")
    assert res.exit_code == 1
    line = _one_error_line(res)
    assert len(res.output.strip().splitlines()) == 1, res.output
    assert f"{scene}:" in line, line
    assert "models.plate-spring: the same model as [models.plate_spring]" in line, line
    assert _hash(scene) == before


def test_a_protocol_listing_one_model_under_both_spellings_is_refused_naming_both(tmp_path):
    proto = fast_protocol(tmp_path, conditions=("plate_spring", "plate-spring"), trials=1)
    before = _hash(proto)
    res = studyctl("study", "init", "--protocol", proto, "--db", tmp_path / "s.db")
    assert res.exit_code == 1
    line = _one_error_line(res)
    assert len(res.output.strip().splitlines()) == 1, res.output
    assert "design.conditions: 'plate_spring' and 'plate-spring' are the same model" in line, res.output
    assert not (tmp_path / "s.db").exists()
    assert _hash(proto) == before


def test_joiners_and_the_soft_hyphen_which_scripts_need_are_allowed(tmp_path):
    proto = fast_protocol(tmp_path, conditions=("plate_spring",), trials=1)
    proto.write_text(proto.read_text().replace('text = "Is interaction real', 'text = "Is inter\\u00adaction \\u200d\\u200creal', 1))
    res = studyctl("protocol", "validate", proto)
    assert res.exit_code == 0, res.output
