"""Files a command writes: never over an existing one unless asked (`--force`), and all or none.

Every output is written under a temporary name beside its target (a hidden file or folder in the
same folder, so the move is a rename on one file system) and moved into place only when the
whole of it is written; a failed or interrupted write removes what it wrote, so nothing is left
that blocks the retry. Whether a target exists is checked before the work where the names are
known, and again, for every file written, before anything is moved. With `force`, a file output
replaces the file of its name; a folder output that exists is replaced whole in place: the new
files moved in, then the earlier files of the command's own kinds that this run did not write
removed; files it does not write are kept and named. The folder itself stays (it may hold a study
in use, with its locks and traces).

Never, with or without `force`: an output that is one of the command's inputs or inside one (a
study database's companions: its WAL, traces and locks), an existing target that is not a regular
file (a folder output's: not a folder) such as a device, fifo or /dev/stdout, or two outputs of one
command on one path.
"""

from __future__ import annotations

import errno
import fnmatch
import os
import shutil
import stat
import tempfile
from collections.abc import Mapping
from pathlib import Path

from analysis.errors import InputError, StudyError


class OutputExists(StudyError):
    """An output file exists and the command was not told to overwrite it."""


class OutputFailed(StudyError):
    """The file system refused an output (full, read-only, not allowed); nothing was left of it."""


class OutputConflict(StudyError):
    """An output is an input of its command (or inside one), or two outputs share a path."""


class OutputNotRegular(StudyError):
    """An output's existing target is a device, fifo, socket or other special file."""


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


# the files and folders beside a study database that belong to it, named as SQLite (its WAL and
# journal), the trace files (analysis/study/trace_files.py) and the session locks (session/lock.py) name them
DATABASE_COMPANIONS = ("-wal", "-shm", "-journal", ".traces", ".locks")
DATABASE_OPTIONS = ("--db",)  # the input options that name a study database


def database_companions(db) -> list[Path]:
    """Beside the name given and, for a link, beside the real file too: SQLite keeps -wal and
    -shm beside the name it opened, the store keeps traces and locks beside the real file."""
    names = dict.fromkeys([Path(db), Path(os.path.realpath(db))])
    return [d.with_name(d.name + s) for d in names for s in DATABASE_COMPANIONS]


def _real(path) -> str:
    return os.path.realpath(os.path.abspath(path))


def _within(path: str, folder: str) -> bool:
    return path == folder or path.startswith(folder.rstrip(os.sep) + os.sep)


def _same(a, b) -> bool:
    """One file, through symbolic links (the resolved names) or hard links (the inode)."""
    if _real(a) == _real(b):
        return True
    try:
        return os.path.samefile(a, b)
    except (OSError, ValueError):
        return False


def refuse_inputs(outputs: Mapping, inputs: Mapping) -> None:
    """Each output (option -> path; None: not given) against each input (option -> a path or a
    list of them): an output that is an input, through any link, or lies in a study database's
    companions (`--db`), is an `OutputConflict`, `force` or not. An input inside a folder output
    is no conflict: the folder's other files are kept."""
    given = [(o, p) for o, v in inputs.items() for p in (v if isinstance(v, (list, tuple)) else [v]) if p is not None]
    for out_opt, out in outputs.items():
        for in_opt, inp in given:
            if out is None:
                continue
            if _same(out, inp):
                raise OutputConflict(f"{out}: is an input of this command ({in_opt} {inp}); choose another {out_opt}")
            for part in database_companions(inp) if in_opt in DATABASE_OPTIONS else ():
                if _same(out, part) or _within(_real(out), _real(part)):
                    raise OutputConflict(f"{out}: is part of an input of this command ({in_opt} {inp}: {part.name}); "
                                         f"choose another {out_opt}")


def _through_proc(path) -> bool:
    """A name that leads into /proc (/dev/stdout, /dev/fd/1): a process's open file, not a file."""
    p = os.path.abspath(path)
    for _ in range(40):  # the kernel's own limit on links followed
        p = os.path.join(os.path.realpath(os.path.dirname(p)), os.path.basename(p))
        if _within(p, "/proc"):
            return True
        if not os.path.islink(p):
            return False
        p = os.path.join(os.path.dirname(p), os.readlink(p))
    return True


def refuse_special(path, folder: bool = False) -> None:
    """An existing `path` that is not a regular file (`folder`: not a folder), through symbolic
    links, is an `OutputNotRegular`, `force` or not: a device, fifo or socket, /dev/stdout. A link
    to a regular file is replaced by the output (the file it named is left as it was)."""
    if not os.path.lexists(path):
        return
    try:
        mode = os.stat(path).st_mode
    except OSError:  # a link to nothing: replaced like any link
        return
    if _through_proc(path) or not (stat.S_ISDIR if folder else stat.S_ISREG)(mode):
        what = "not a folder; folder outputs go to folders or new names" if folder else "not a regular file; outputs go to regular files or new names"
        raise OutputNotRegular(f"{path}: {what}")


def refuse_overlap(outputs: Mapping) -> None:
    """`outputs`: option -> (path or None, what it is: False for a file; for a folder, the glob
    patterns of the names it writes at its top, `Staged`'s `own`). Two on one path, or a file
    the folder writes itself, is an `OutputConflict`: refused before any work. Another file
    inside the folder is no conflict: it is kept there like any file the folder does not write."""
    given = [(o, p, f) for o, (p, f) in outputs.items() if p is not None]
    for i, first in enumerate(given):
        for second in given[i + 1:]:
            if _same(first[1], second[1]):
                raise OutputConflict(f"{second[1]}: both {first[0]} and {second[0]} name it; choose one place for each")
            for (oa, pa, own), (ob, pb, _) in ((first, second), (second, first)):
                if own is False or not _within(_real(pb), _real(pa)):
                    continue
                inside = Path(os.path.relpath(_real(pb), _real(pa)))
                if any(_matches(inside, p) for p in own):
                    raise OutputConflict(f"{pb}: {ob} names a file {oa} writes ({pa}); choose another {ob}")


# the format a file's suffix names; a report takes its format from it when --format is not given
SUFFIX_FORMATS = {".md": "md", ".markdown": "md", ".csv": "csv", ".tex": "latex", ".latex": "latex", ".html": "html",
                  ".htm": "html", ".json": "json", ".pdf": "pdf", ".png": "png", ".svg": "svg", ".docx": "docx",
                  ".xlsx": "xlsx", ".parquet": "parquet"}
_FORMAT_SUFFIX = {"latex": ".tex"}


def _suffix(fmt: str) -> str:
    return _FORMAT_SUFFIX.get(fmt, "." + fmt)


def output_format(out, fmt: str | None, formats, default: str, command: str) -> str:
    """The format `command` writes to `out`: `fmt` (--format; None: not given), else the one `out`'s
    suffix names, else `default` (no --out). A suffix naming another format than `fmt`, or one
    the command does not write, or none, is an `InputError` naming both."""
    if out is None:
        return fmt or default
    suffix = Path(out).suffix.lower()
    named = SUFFIX_FORMATS.get(suffix)
    offered = ", ".join(f if _suffix(f) == "." + f else f"{f} ({_suffix(f)})" for f in formats)
    if fmt is None:
        if named in formats:
            return named
        if named is None:
            raise InputError(f"{out}: {suffix or 'no suffix'} names no format; {command} writes {offered}: "
                             "end the name so or give --format")
        raise InputError(f"{out}: {command} writes {offered}; {suffix} is not one")
    if named is not None and named != fmt:
        raise InputError(f"{out}: --format {fmt} writes {_suffix(fmt)}, not {suffix}; "
                         f"name it {Path(out).stem}{_suffix(fmt)}" + (f" or give --format {named}" if named in formats else ""))
    return fmt


def refuse_existing(paths, force: bool, inputs: Mapping | None = None, option: str = "--out") -> list[Path]:
    """The `paths` that exist; without `force`, any one existing is an `OutputExists` naming it.
    A path with a name longer than its file system takes is an `OutputFailed`; one that is not a
    regular file, or is one of the command's `inputs` (option -> path), is refused whatever `force`."""
    paths = list(paths)
    _refuse_long_names(paths)
    for p in paths:
        refuse_special(p)
        refuse_inputs({option: p}, inputs or {})
    found = [Path(p) for p in paths if os.path.lexists(p)]
    if found and not force:
        more = f" (and {len(found) - 1} more of the files this command writes)" if len(found) > 1 else ""
        raise OutputExists(f"{found[0]}: exists{more}; --force overwrites {'them' if more else 'it'}")
    return found


class Staged:
    """`with Staged(target, force) as tmp:` write the output to `tmp`, a temporary file (or, with
    `folder=True`, a temporary folder) beside `target`; on a clean exit it is moved to `target`,
    else removed. `expect`: the names a folder will hold, refused before the work when they
    exist. `inputs`: the command's inputs (option -> path), which no output may be; `option`: the
    output's own, for the messages. A folder that exists takes the new files beside its own
    without `force`; with it, it is replaced whole: its earlier files whose names match `own`
    (glob patterns; `expect` when not given) go (`removed`), the others are kept (`kept`). After
    the block, `replaced` lists the files overwritten and `written` every file moved into place."""

    def __init__(self, target, force: bool = False, folder: bool = False, expect=(), mode: int | None = None,
                 inputs: Mapping | None = None, option: str = "--out", own=None):
        self.target, self.force, self.folder, self.mode = Path(target), force, folder, mode
        self.inputs, self.option = dict(inputs or {}), option
        self.own = tuple(expect if own is None else own)
        self.replaced: list[Path] = []
        self.written: list[Path] = []
        self.removed: list[Path] = []
        self.kept: list[Path] = []
        _refuse_long_names([self.target])
        if folder:  # the folder itself; its files, as a file output, below
            refuse_special(self.target, folder=True)
            refuse_inputs({self.option: self.target}, self.inputs)
        self._refuse_files([self.target / n for n in expect] if folder else [self.target])

    def _refuse_files(self, files) -> list[Path]:
        """`refuse_existing` with this output's inputs: what no `force` allows (an input
        overwritten, a special file replaced), then what exists without it."""
        return refuse_existing(files, self.force, inputs=self.inputs, option=self.option)

    def __enter__(self) -> Path:
        self.tmp = None
        try:
            return self._make()
        except OSError as exc:  # any: a name too long, a folder that cannot be made, /proc
            self._remove()
            raise _failed(self.target, exc) from None

    def _make(self) -> Path:
        # the folder that holds the target, whatever its name: "." or "fr/.." hold nothing beside them
        parent = Path(os.path.abspath(self.target)).parent
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
            self.replaced = self._refuse_files([self.target])
            os.replace(self.tmp, self.target)
            self.written = [self.target]
            return
        files = sorted(p.relative_to(self.tmp) for p in self.tmp.rglob("*") if not p.is_dir())
        self.replaced = self._refuse_files([self.target / f for f in files])
        self.written = [self.target / f for f in files]
        if not os.path.lexists(self.target):  # a new folder: one rename moves all of it
            os.rename(self.tmp, self.target)
        elif not self.force:  # none of its names there: the new files join the folder's own
            self._join(files)
        else:
            self._replace_whole(files)

    def _join(self, files) -> None:
        for f in files:
            (self.target / f).parent.mkdir(parents=True, exist_ok=True)
            os.replace(self.tmp / f, self.target / f)

    def _replace_whole(self, files) -> None:
        """Where earlier files of the command's go: the new files moved in, then the command's own
        earlier files that this run did not write removed; everything else in the folder is left
        where it is (the folder itself is never swapped: it may hold a study in use, its locks and
        traces, or be a shell's working folder)."""
        new = set(files)
        gone = [f for f in _entries(self.target) if f not in new]
        self.removed = [self.target / f for f in gone if any(_matches(f, p) for p in self.own)]
        self.kept = [self.target / f for f in gone if self.target / f not in self.removed]
        self._join(files)
        for f in self.removed:
            f.unlink()


def _matches(path: Path, pattern: str) -> bool:
    """`path` (relative) is `pattern`'s, part by part: "*.png" is no file in a subfolder."""
    parts = Path(pattern).parts
    return len(path.parts) == len(parts) and all(fnmatch.fnmatchcase(a, b) for a, b in zip(path.parts, parts))


def _entries(folder: Path) -> list[Path]:
    """The files and links under `folder` (relative, links to folders not followed), but for this
    tool's own temporaries (another command's output being staged there)."""
    files = []
    for root, dirs, names in os.walk(folder):
        rel = Path(root).relative_to(folder)
        dirs[:] = [d for d in dirs if not d.startswith(_PREFIX)]
        links = [d for d in dirs if os.path.islink(os.path.join(root, d))]
        files += [rel / n for n in (*names, *links) if not n.startswith(_PREFIX)]
    return sorted(files)


def write_file(path, data: str | bytes, force: bool = False, mode: int | None = None, inputs: Mapping | None = None,
               option: str = "--out") -> list[Path]:
    """`data` to `path`, whole or not at all; returns the replaced file ([] when it was new)."""
    staged = Staged(path, force, mode=mode, inputs=inputs, option=option)
    staged.write(data)
    return staged.replaced


def _names(paths, folder: Path, most: int = 3) -> str:
    rel = [str(Path(p).relative_to(folder)) for p in paths]
    return ", ".join(rel[:most]) + (f" and {len(rel) - most} more" if len(rel) > most else "")


def replaced_line(out: Staged) -> str:
    """What `force` did to an output, in one line ("" where it changed nothing that was there)."""
    parts = []
    if out.replaced:
        parts.append(f"overwrote {out.replaced[0] if len(out.replaced) == 1 else f'{len(out.replaced)} files in {out.target}'}")
    if out.removed:
        parts.append(f"removed {len(out.removed)} earlier file{'s' if len(out.removed) > 1 else ''} of this command "
                     f"from {out.target} ({_names(out.removed, out.target)})")
    if out.kept:
        parts.append(f"kept {len(out.kept)} file{'s' if len(out.kept) > 1 else ''} in {out.target} it does not write "
                     f"({_names(out.kept, out.target)})")
    return "--force: " + "; ".join(parts) if parts else ""
