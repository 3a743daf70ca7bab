"""Files written whole or not at all; input files read only when they are regular files of a
bounded size."""

from __future__ import annotations

import hashlib
import os
import stat
from pathlib import Path

import numpy as np

from sim.errors import InputFileError

MIB = 1024 * 1024
TOML_MAX_BYTES = 1 * MIB  # a protocol, scene, material or parameter file: a page of settings, not data
DATA_MAX_BYTES = 64 * MIB  # a CSV or JSON a command reads (tissue data, answers, participants, a rig profile)
MESH_MAX_BYTES = 512 * MIB  # a surface mesh (.npz): far above a brain surface, far below what exhausts memory


def _kind(mode: int) -> str:
    for test, name in ((stat.S_ISDIR, "a folder"), (stat.S_ISFIFO, "a named pipe"), (stat.S_ISCHR, "a character device"),
                       (stat.S_ISBLK, "a block device"), (stat.S_ISSOCK, "a socket")):
        if test(mode):
            return name
    return "not a regular file"


def check_input(path, max_bytes: int) -> Path:
    """`path` if it is a regular file (after links) of at most `max_bytes`; else InputFileError.
    Checked before anything is read: a device such as /dev/zero never ends, a named pipe blocks."""
    path = Path(path)
    try:
        st = os.stat(path)
    except FileNotFoundError:
        raise InputFileError(f"{path}: not found") from None
    except OSError as exc:
        raise InputFileError(f"{path}: cannot read: {exc.strerror or exc}") from None
    if not stat.S_ISREG(st.st_mode):
        raise InputFileError(f"{path}: is {_kind(st.st_mode)}; allowed: a regular file")
    if st.st_size > max_bytes:
        raise InputFileError(f"{path}: {st.st_size / MIB:.1f} MiB; allowed: at most {max_bytes / MIB:g} MiB")
    return path


def read_input(path, max_bytes: int) -> bytes:
    """The bytes of `path`, checked by `check_input` first (and read no further than the limit,
    should the file grow meanwhile)."""
    path = check_input(path, max_bytes)
    try:
        with open(path, "rb") as fh:
            raw = fh.read(max_bytes + 1)
    except OSError as exc:
        raise InputFileError(f"{path}: cannot read: {exc.strerror or exc}") from None
    if len(raw) > max_bytes:
        raise InputFileError(f"{path}: more than {max_bytes / MIB:g} MiB; allowed: at most {max_bytes / MIB:g} MiB")
    return raw


def save_npz(path, /, compressed: bool = False, **arrays) -> Path:
    """NumPy arrays to `path`, through a temporary file of this process beside it, renamed over
    it: a concurrent reader, or a run killed halfway, never sees half a file (caches, shipped
    tables)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    # a short name of the target's (a name near the file system's limit must not become one over
    # it) and of this process
    tmp = path.with_name(f".{hashlib.sha256(path.name.encode()).hexdigest()[:12]}.{os.getpid()}.tmp.npz")
    try:
        (np.savez_compressed if compressed else np.savez)(tmp, **arrays)
        os.replace(tmp, path)
    except BaseException:  # a full disk or Ctrl-C: no temporary left behind
        tmp.unlink(missing_ok=True)
        raise
    return path
