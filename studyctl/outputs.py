"""Files a command writes: never over an existing one unless asked (`--force`), and all or none.

Every output is written under a temporary name beside its target (a hidden file or folder in the
same folder, so the move is a rename on one file system) and moved into place only when the
whole of it is written; a failed or interrupted write removes what it wrote, so nothing is left
that blocks the retry. Whether a target exists is checked before the work where the names are
known, and again, for every file written, before anything is moved. With `force`, the files the
command writes replace those of the same names; other files in a folder are left as they are.
"""

from __future__ import annotations

import errno
import os
import shutil
import tempfile
from pathlib import Path

from analysis.errors import StudyError


class OutputExists(StudyError):
    """An output file exists and the command was not told to overwrite it."""


class OutputFailed(StudyError):
    """The file system refused an output (full, read-only, not allowed); nothing was left of it."""


# what a file system says when it cannot take an output: one line, not a traceback
_REFUSALS = {errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EACCES, errno.EPERM, errno.EIO, errno.EFBIG}


# temporary names: hidden, short, and recognisably this tool's
_PREFIX = ".studyctl-"
_SUFFIX_MAX = 16


def _failed(target: Path, exc: OSError) -> OutputFailed:
    return OutputFailed(f"{target}: cannot write: {exc.strerror or exc}; nothing was written")


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _name_max(path: Path) -> int:
    """The longest name (bytes) the file system holding `path`'s nearest existing folder takes."""
    for folder in path.parents:
        if os.path.isdir(folder):
            try:
                return os.pathconf(folder, "PC_NAME_MAX")
            except (OSError, ValueError):
                break
    return 255


def _refuse_long_names(paths) -> None:
    # before the work: a name the file system cannot hold would otherwise fail only at the end
    for path in map(Path, paths):
        limit = _name_max(path)
        if any(len(os.fsencode(part)) > limit for part in path.parts):
            raise _failed(path, OSError(errno.ENAMETOOLONG, os.strerror(errno.ENAMETOOLONG)))


def refuse_existing(paths, force: bool) -> list[Path]:
    """The `paths` that exist; without `force`, any one existing is an `OutputExists` naming it.
    A path with a name longer than its file system takes is an `OutputFailed`."""
    paths = list(paths)
    _refuse_long_names(paths)
    found = [Path(p) for p in paths if os.path.lexists(p)]
    if found and not force:
        more = f" (and {len(found) - 1} more of the files this command writes)" if len(found) > 1 else ""
        raise OutputExists(f"{found[0]}: exists{more}; --force overwrites {'them' if more else 'it'}")
    return found


class Staged:
    """`with Staged(target, force) as tmp:` write the output to `tmp`, a temporary file (or, with
    `folder=True`, a temporary folder) beside `target`; on a clean exit it is moved to `target`
    (a folder: each file into `target`, made if missing), else removed. `expect`: the names a
    folder will hold, refused before the work when they exist. After the block, `replaced`
    lists the files that were overwritten and `written` every file moved into place."""

    def __init__(self, target, force: bool = False, folder: bool = False, expect=(), mode: int | None = None):
        self.target, self.force, self.folder, self.mode = Path(target), force, folder, mode
        self.replaced: list[Path] = []
        self.written: list[Path] = []
        _refuse_long_names([self.target])
        refuse_existing([self.target / n for n in expect] if folder else [self.target], force)

    def __enter__(self) -> Path:
        self.tmp = None
        try:
            return self._make()
        except OSError as exc:  # any: a name too long, a folder that cannot be made, /proc
            self._remove()
            raise _failed(self.target, exc) from None

    def _make(self) -> Path:
        parent = self.target.parent
        parent.mkdir(parents=True, exist_ok=True)
        # a short fixed prefix, not the target's name: a name near the file system's limit must not
        # become one over it once the temporary's parts are added
        if self.folder:
            self.tmp = Path(tempfile.mkdtemp(prefix=_PREFIX, suffix=".tmp", dir=parent))
            os.chmod(self.tmp, 0o777 & ~_umask())
        else:  # the target's suffix kept: writers that choose a format by it (savefig, savez) see the same
            suffix = self.target.suffix if len(self.target.suffix) <= _SUFFIX_MAX else ""
            fd, name = tempfile.mkstemp(prefix=_PREFIX, suffix=".tmp" + suffix, dir=parent)
            os.close(fd)
            self.tmp = Path(name)
            os.chmod(self.tmp, self.mode if self.mode is not None else 0o666 & ~_umask())
        return self.tmp

    def __exit__(self, exc_type, exc, tb) -> None:
        moving = exc_type is None
        try:
            if moving:
                self._move()
        except OSError as failed:  # the move itself: any refusal there is the target's
            exc = failed
        finally:
            self._remove()
        # the work's own errors pass as they are, but for a file system that cannot take the output
        if isinstance(exc, OSError) and (moving or exc.errno in _REFUSALS):
            raise _failed(self.target, exc) from None

    def _remove(self) -> None:
        if self.tmp is None:
            return
        if self.tmp.is_dir():
            shutil.rmtree(self.tmp, ignore_errors=True)
        elif os.path.lexists(self.tmp):
            self.tmp.unlink()

    def write(self, data: str | bytes) -> None:
        """A single file's whole content (text as UTF-8, its line ends as given), then moved."""
        with self as tmp:
            if isinstance(data, bytes):
                tmp.write_bytes(data)
            else:
                with open(tmp, "w", encoding="utf-8", newline="") as fh:
                    fh.write(data)

    def final(self, path) -> Path:
        """Where a file written under the temporary name ends up."""
        return self.target / Path(path).relative_to(self.tmp) if self.folder else self.target

    def _move(self) -> None:
        if not self.folder:
            self.replaced = refuse_existing([self.target], self.force)
            os.replace(self.tmp, self.target)
            self.written = [self.target]
            return
        files = sorted(p.relative_to(self.tmp) for p in self.tmp.rglob("*") if not p.is_dir())
        self.replaced = refuse_existing([self.target / f for f in files], self.force)
        self.written = [self.target / f for f in files]
        if not os.path.lexists(self.target):  # a new folder: one rename moves all of it
            os.rename(self.tmp, self.target)
            return
        for f in files:
            (self.target / f).parent.mkdir(parents=True, exist_ok=True)
            os.replace(self.tmp / f, self.target / f)


def write_file(path, data: str | bytes, force: bool = False, mode: int | None = None) -> list[Path]:
    """`data` to `path`, whole or not at all; returns the replaced file ([] when it was new)."""
    staged = Staged(path, force, mode=mode)
    staged.write(data)
    return staged.replaced
