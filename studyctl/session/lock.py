"""One process drives a participant's session: an exclusive lock (flock) on a file beside the
database, held for the whole session. The kernel drops it when its process dies, however it
dies, so a live session is told apart from an interrupted one without guessing from
timestamps. The file names the owner (pid, host, start) for the message a second process gets.
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
from studyctl.store import now


def _file_name(code: str) -> str:
    return f"{re.sub(r'[^A-Za-z0-9_.-]', '_', code)[:40]}-{hashlib.sha256(code.encode()).hexdigest()[:8]}.lock"


@contextlib.contextmanager
def session_lock(db, code: str):
    folder = Path(db).parent / f"{Path(db).name}.locks"
    try:
        folder.mkdir(exist_ok=True)
        fd = os.open(folder / _file_name(code), os.O_RDWR | os.O_CREAT, 0o644)
    except OSError as exc:
        raise StoreError(f"{folder}: cannot create the session lock: {exc.strerror}") from None
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            owner = os.pread(fd, 200, 0).decode(errors="replace").strip() or "another process"
            raise StoreError(f"participant {code}: the session is running now ({owner}); "
                             "wait for it to finish, or stop that process and continue with --resume") from None
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"pid {os.getpid()} on {socket.gethostname()} since {now()}".encode(), 0)
        try:
            yield
        finally:
            os.ftruncate(fd, 0)
            fcntl.flock(fd, fcntl.LOCK_UN)
    finally:
        os.close(fd)
