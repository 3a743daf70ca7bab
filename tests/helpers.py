"""What the tests share: the paper's protocol, a fast protocol, the CLI in this process, and a
person at a real pseudo-terminal (pty_run, pty_session)."""

import json
import os
import signal
import sqlite3
import sys
import time
from pathlib import Path

from click.testing import CliRunner

from studyctl.cli import cli
from tests.conftest import ROOT

PROTOCOL = ROOT / "protocols" / "brain_pull_2015.toml"


def fast_protocol(tmp_path: Path, conditions=("plate_spring", "fem", "mass_spring"), trials=2, training=0.0) -> Path:
    """The shipped protocol on a coarse (8 mm) brain, short trials: quick synthetic sessions.
    The FEM on linear tetrahedra: the study machinery under test does not need P2's accuracy,
    and P2 costs 3-4 s more to assemble in every process that builds it (test_fem_model,
    test_accuracy and test_stability test the shipped P2)."""
    scene = (ROOT / "protocols/scenes/brain_pull.toml").read_text()
    scene = scene.replace('"../../data/', f'"{ROOT}/data/').replace('"../models/', f'"{ROOT}/protocols/models/').replace('"../materials/', f'"{ROOT}/protocols/materials/')
    scene = scene.replace("\norder = 2 ", "\norder = 1 ", 1).replace('kind = "offscreen"', 'kind = "none"')
    (tmp_path / "scene.toml").write_text(scene)
    text = PROTOCOL.read_text().replace('scene = "scenes/brain_pull.toml"', f'scene = "{tmp_path / "scene.toml"}"')
    text = text.replace('conditions = ["fem", "mass_spring", "plate_spring"]', f"conditions = {json.dumps(list(conditions))}")
    text = text.replace("trials_per_condition = 3", f"trials_per_condition = {trials}").replace("trial_seconds = 3.0", "trial_seconds = 1.0")
    text = text.replace("training_minutes = 5.0", f"training_minutes = {training}")
    path = tmp_path / "protocol.toml"
    path.write_text(text)
    return path


def studyctl(*args, env=None):
    return CliRunner().invoke(cli, [str(a) for a in args], env=env, catch_exceptions=False)


def count_rows(db, table: str = "answers") -> int:
    """Rows in `table` of a database another process may be writing (0 before it exists)."""
    try:
        return sqlite3.connect(db, timeout=10).execute(f"select count(*) from {table}").fetchone()[0]
    except sqlite3.OperationalError:
        return 0


def pty_run(argv, on_output=None, timeout=60.0) -> tuple[str, int]:
    """Run `studyctl ARGV` on a real pseudo-terminal; after each chunk of output,
    `on_output(fd, out)` (out: a bytearray of all the terminal showed so far) may type, or append
    a marker to `out`. Killed at `timeout`. Returns (all the terminal showed, exit status)."""
    import pty
    import select

    pid, fd = pty.fork()
    if pid == 0:  # the child: a real session on a terminal
        signal.signal(signal.SIGINT, signal.SIG_DFL)  # pytest-xdist's workers ignore SIGINT, and an ignored signal stays so across exec
        os.execv(sys.executable, [sys.executable, "-m", "studyctl.cli", *map(str, argv)])
    out = bytearray()
    deadline = time.time() + timeout
    while time.time() < deadline:
        if not select.select([fd], [], [], 0.5)[0]:
            continue
        try:
            chunk = os.read(fd, 4096)
        except OSError:
            break
        if not chunk:
            break
        out += chunk
        if on_output is not None:
            on_output(fd, out)
    else:
        os.kill(pid, 9)
    _, status = os.waitpid(pid, 0)
    return out.decode(errors="replace"), os.waitstatus_to_exitcode(status)


def pty_session(argv, answer=None, timeout=60.0, on_output=None, replies: dict[str, list[str]] | None = None) -> str:
    """Run `studyctl ARGV` on a real pseudo-terminal (`pty_run`) and answer its prompts: each
    time the output ends with a "[y/n]" prompt, type `answer()` and Enter; or, with `replies`,
    each time it ends with one of their prompt tails (e.g. "[1-7]"), type that tail's next reply
    (each must be used up; asking once more than given fails). `on_output(fd, text so far)` may
    type more. Returns all the terminal showed."""
    left = {tail: list(r) for tail, r in (replies or {"[y/n]": []}).items()}

    def respond(fd, out: bytearray) -> None:
        if on_output is not None:
            on_output(fd, out)
        tail = out.decode(errors="replace").rstrip()
        for prompt, todo in left.items():
            if tail.endswith(prompt):
                if replies is None:
                    reply = answer()
                else:
                    assert todo, f"asked once more than expected: {prompt}\n{tail[-500:]}"
                    reply = todo.pop(0)
                os.write(fd, (reply + "\n").encode())
                out += b"<sent>"
                break

    text, _ = pty_run(argv, respond, timeout)
    if replies is not None:
        assert not any(left.values()), (left, text[-2000:])
    return text
