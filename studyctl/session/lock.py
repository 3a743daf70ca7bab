"""One process drives a participant's session, and one `synth` a study: an exclusive lock
(flock) on a file in a folder beside the database (the real file, a link resolved), held for the
whole session or run. The kernel drops it when its process dies, however it dies, so a live
session or run is told apart from an interrupted one without guessing from timestamps. The
file names the owner (pid, host, start) for the message a second process gets. A released lock
takes its file (and the folder, when empty) with it: the study's folder keeps no trace of it.
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import os
import re
import socket
from pathlib import Path

from analysis.errors import StoreError
from analysis.study.trace_files import beside
from studyctl.store import now


class SessionRunning(StoreError):
    """A participant's session is running now in another process."""


class SynthRunning(StoreError):
    """Another `synth` is running now on the same study."""


def _file_name(code: str) -> str:
    return f"{re.sub(r'[^A-Za-z0-9_.-]', '_', code)[:40]}-{hashlib.sha256(code.encode()).hexdigest()[:8]}.lock"


def lock_folder(db) -> Path:
    return beside(db, ".locks")


def _take(path: Path) -> int | str:
    """The descriptor of `path`, locked, or the owner's line when another process holds it.
    The lock must be on the file that is at `path` now: one its holder unlinked as it released
    it (after this process opened it) is tried again, so two processes never both hold one."""
    for _ in range(100):
        try:
            path.parent.mkdir(exist_ok=True)
            fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
        except FileNotFoundError:  # the folder was removed by a release in between: again
            continue
        except OSError as exc:
            raise StoreError(f"{path.parent}: cannot create the lock: {exc.strerror}") from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            owner = os.pread(fd, 200, 0).decode(errors="replace").strip() or "another process"
            os.close(fd)
            return owner
        try:
            same = os.stat(path).st_ino == os.fstat(fd).st_ino
        except FileNotFoundError:
            same = False
        if same:
            return fd
        os.close(fd)
    raise StoreError(f"{path}: the lock could not be taken (it kept changing); try again")


@contextlib.contextmanager
def _held(path: Path, busy):
    """Hold the lock at `path` for the block; `busy(owner)` is the error raised where another
    process holds it. Released in `finally`, its file and an empty folder removed."""
    fd = _take(path)
    if isinstance(fd, str):
        raise busy(fd)
    try:
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"pid {os.getpid()} on {socket.gethostname()} since {now()}".encode(), 0)
        yield
    finally:
        with contextlib.suppress(OSError):
            path.unlink()  # while still held: a process that opened it before sees the change and tries again
        with contextlib.suppress(OSError):
            path.parent.rmdir()  # only when empty
        fcntl.flock(fd, fcntl.LOCK_UN)
        os.close(fd)


def session_lock(db, code: str):
    def busy(owner):
        return SessionRunning(f"participant {code}: the session is running now ({owner}); "
                              "wait for it to finish, or stop that process and continue with --resume")

    return _held(lock_folder(db) / _file_name(code), busy)


def synth_lock(db):
    """Held by a `synth` for its whole run: a second one on the same study is told the first is
    running (with its pid) rather than that it was interrupted."""
    def busy(owner):
        pid = re.match(r"pid (\d+)", owner)
        return SynthRunning(f"{db}: another synth ({'pid ' + pid.group(1) if pid else owner}) is running on this study; "
                            "wait for it or stop it")

    return _held(lock_folder(db) / "synth.lock", busy)
