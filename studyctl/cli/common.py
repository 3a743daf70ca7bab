"""What the command groups share: library errors as one-line CLI errors (`_Group`), output
(`_console`, `_print_json`, `_listing`, `_done`), progress bars, option types that check before
any work is done, and the options several groups take (--db, --json, --dry-run, --devices,
--fullscreen)."""

from __future__ import annotations

import json
import math
import os
import shlex
import sqlite3
import sys
from pathlib import Path

import click

from analysis.errors import Interrupted, StudyError
from brainsim_assets import path as _asset
from sim.errors import SimError
from sim.jsonable import jsonable
from studyctl.outputs import Staged, replaced_line

DEFAULT_PROTOCOL = _asset("protocols/brain_pull_2015.toml")


class _Stopped(click.ClickException):
    exit_code = 130  # the shell's code for a command ended by Ctrl-C (128 + SIGINT)


class _Group(click.Group):
    """Turns library errors into clean CLI errors; a subcommand named with hyphens also answers
    to underscores (`model plate_spring`, as models are spelt in files and `--model`)."""

    def get_command(self, ctx, cmd_name):
        return super().get_command(ctx, cmd_name) or super().get_command(ctx, cmd_name.replace("_", "-"))

    def invoke(self, ctx: click.Context):
        try:
            return super().invoke(ctx)
        except Interrupted as exc:  # Ctrl-C where the library says what was kept
            raise _Stopped(str(exc)) from None
        except KeyboardInterrupt:  # Ctrl-C anywhere else: one line (writes are transactions: none is half-done)
            raise _Stopped(f"{ctx.command_path} {ctx.invoked_subcommand or ''}".rstrip()
                           + ": interrupted (Ctrl-C); nothing half-written") from None
        except (SimError, StudyError) as exc:
            raise click.ClickException(str(exc)) from None
        except sqlite3.OperationalError as exc:  # e.g. another process held the database for over 30 s
            if "readonly" in str(exc):  # made read-only while open (the library refuses one before it writes)
                raise click.ClickException(f"the study database is read-only ({exc}); nothing was written") from None
            raise click.ClickException(f"the study database: {exc} (another process may be writing to it; try again)") from None


def _command_line(ctx: click.Context) -> str:
    """The command as run, for an output's provenance: `studyctl`, the subcommands and every
    option given on the command line or by the environment, in the command's order (rebuilt
    from click's context: the same words whether run from a shell or in-process)."""
    from click.core import ParameterSource

    words = ["studyctl", *ctx.command_path.split()[1:]]
    for param in ctx.command.params:
        if ctx.get_parameter_source(param.name) not in (ParameterSource.COMMANDLINE, ParameterSource.ENVIRONMENT):
            continue
        value = ctx.params[param.name]
        option = max(param.opts, key=len) if isinstance(param, click.Option) else None
        for v in (value if param.multiple else [value]):
            if isinstance(param, click.Option) and param.is_flag:
                words += [option] if v else (param.secondary_opts[:1] or [])
            else:
                words += [option, str(v)] if option else [str(v)]
    return " ".join(shlex.quote(w) for w in words)


def _console():
    from rich.console import Console

    console = Console()
    if not console.is_terminal:  # pipes and tests: wide, stable layout
        console = Console(width=120)
    return console


def _print_json(obj) -> None:
    click.echo(json.dumps(jsonable(obj), indent=2))


class Finite(click.FloatRange):
    """A float range that also refuses NaN (click's ranges let it through: NaN compares false)."""

    def convert(self, value, param, ctx):
        v = super().convert(value, param, ctx)
        if not math.isfinite(v):
            self.fail(f"{value!r} is not a finite number", param, ctx)
        return v


class OutFile(click.Path):
    """A file to write: its folder must exist and the suffix be one of `suffixes`, checked
    before any work is done (so a typo never costs a long run or leaves half a result)."""

    def __init__(self, suffixes: tuple[str, ...] | None = None):
        super().__init__(dir_okay=False, path_type=Path)
        self.suffixes = suffixes

    def convert(self, value, param, ctx):
        path = super().convert(value, param, ctx)
        if not os.path.isdir(path.parent):  # False, not an error, for a name too long to look up
            self.fail(f"{path.parent} is not an existing folder", param, ctx)
        if self.suffixes and path.suffix.lower() not in self.suffixes:
            self.fail(f"{path.name}: allowed suffixes: {', '.join(self.suffixes)}", param, ctx)
        return path


class OutDir(click.Path):
    """A folder to write into (made if missing): nothing on its way may be a file."""

    def __init__(self):
        super().__init__(file_okay=False, path_type=Path)

    def convert(self, value, param, ctx):
        path = super().convert(value, param, ctx)
        for p in (path, *path.parents):
            if os.path.exists(p):  # False for a name too long to look up: the write then says why
                if not os.path.isdir(p):
                    self.fail(f"{p} is a file, not a folder", param, ctx)
                break
        return path


def _names(ctx, param, value):
    if value is None:
        return None
    names = [n.strip() for n in value.split(",")]
    if not all(names) or len(names) > 2:
        raise click.BadParameter(f"{value!r}: one or two device names, comma-separated")
    return names


FULLSCREEN = click.option("--fullscreen", is_flag=True,
                          help="The participant view fills the primary monitor (else a resizable 1280x720 window).")
DEVICES = click.option("--devices", "device_names", callback=_names, default=None,
                       help='OpenHaptics device names, comma-separated, e.g. "PHANToM 1,PHANToM 2" (default: the scene\'s).')
DB = click.option("--db", envvar="STUDYCTL_DB", show_envvar=True, required=True, type=click.Path(dir_okay=False, path_type=Path),
                  help="Study database; required unless the STUDYCTL_DB environment variable names one.")
# a seed: what NumPy and Python take, and within SQLite's 64-bit integers (a larger one overflowed the store)
SEED = click.IntRange(0, 2**32 - 1)
JSON = click.option("--json", "as_json", is_flag=True, help="Machine-readable output (JSON).")
SCHEDULER = click.option("--scheduler", default=None, metavar="ADDRESS",
                         help="Run on a Dask cluster (tcp://host:8786; the dask extra) instead of local processes.")
FORCE = click.option("--force", is_flag=True,
                     help="Overwrite output files that exist (without it the command refuses and changes nothing).")
DRY_RUN = click.option("--dry-run", is_flag=True, help="Check and show what would be done; write nothing.")


# what a run's --frames folder holds (sim/run.py write_outputs): the trace and force plot named before
# the run, and every picture; with --force an earlier run's go, other files stay
FRAMES_EXPECTED = ("trace.csv", "force.png")
FRAMES_OWN = (*FRAMES_EXPECTED, "frame_*.png")


def staged(path, force: bool, folder: bool = False, expect=(), inputs=None, option: str = "--out", own=None) -> Staged | None:
    """An output option's target (studyctl/outputs.py), or None where the option was not given;
    made at the command's start, so an existing target, or one of the command's `inputs`
    (option -> path), is refused before any work."""
    return None if path is None else Staged(path, force, folder=folder, expect=expect, inputs=inputs, option=option, own=own)


def say_replaced(out: Staged | None) -> None:
    """One line on stderr (a --json document on stdout stays clean) where --force overwrote,
    removed or kept files."""
    line = "" if out is None else replaced_line(out)
    if line:
        click.echo(line, err=True)


def write_output(out: Staged, text: str) -> None:
    """A text output, whole or not at all, saying where --force overwrote it."""
    out.write(text)
    say_replaced(out)


def _done(out: dict, text: str, as_json: bool = False) -> None:
    if as_json:
        _print_json(out)
        return
    click.echo(("dry run, nothing written: would have " if out.get("dry_run") else "") + text)


def _listing(rows: list[dict], as_json: bool, db, what: str, columns: list[str]) -> None:
    if as_json:
        _print_json(rows)
    elif not rows:
        click.echo(f"{db}: no {what} yet")
    else:
        _table(rows, f"{len(rows)} {what}", columns)


def _table(rows: list[dict], title: str, columns: list[str]) -> None:
    from rich.table import Table

    t = Table(title=title)
    for c in columns:
        t.add_column(c)
    for r in rows:
        t.add_row(*("-" if r[c] is None else str(r[c]) for c in columns))
    _console().print(t)


def read_snapshot(db):
    """The study in `db`, read once (analysis.study.study_snapshot.Study): every report is made from it."""
    from studyctl.store import Store
    from studyctl.store.snapshot import read_study  # the reports' stack loads only for the commands that make one

    with Store(db, mode="read") as store:
        return read_study(store)


PROGRESS_LINES = 10  # a pipe or a log gets a line at each tenth of the work, not one per step


def progress_lines(label):
    """`progress(done, total)` that says "LABEL: done of total" on stderr at the start and as
    each tenth of the work is done (`PROGRESS_LINES`): what a log or a pipe shows of a long run."""
    said = [-1]

    def progress(k, n):
        tenth = PROGRESS_LINES * k // n if n else PROGRESS_LINES
        if tenth > said[0]:
            said[0] = tenth
            click.echo(f"{label}: {k} of {n}", err=True)
    return progress


def _with_progress(label, fn, stage=None):
    """`fn(progress)` with a progress bar that `progress(done, total)` advances, on stderr (a
    --json document on stdout stays clean). Where stderr is no terminal, `stage(done, total)`
    (if given) is a line said there as each stage starts (done < total), else `progress_lines`':
    a log still shows where a long run is."""
    from rich.console import Console
    from rich.progress import Progress

    console = Console(stderr=True)
    if not console.is_terminal:  # a pipe or a log: no bar (stopping one there leaves a blank line before an error's one line)
        if stage is None:
            return fn(progress_lines(label))
        return fn(lambda k, n: click.echo(stage(k, n), err=True) if k < n else None)
    with Progress(transient=True, console=console) as progress:
        task = progress.add_task(label, total=None)
        return fn(lambda k, n: progress.update(task, completed=k, total=n))


def _model_name(value):
    """A condition as named on the command line: a model spelt plate_spring or plate-spring
    (as the registry keys it), or a condition's table (named with _ only, so a - is a _)."""
    if value is None:
        return None
    from sim.models.registry import canonical, is_model_name

    return canonical(value) if is_model_name(value) else value.replace("-", "_")


OPTIONAL_EXTRAS = ("pyarrow", "distributed")  # the parquet and dask extras' packages


class LoadErrorsAsImportErrors:
    """A meta path finder: an optional extra that is installed but cannot load (a shared library
    missing raises OSError from inside it) fails as the ImportError its importers catch. pandas
    imports pyarrow as it loads and catches only ImportError, so a broken pyarrow would end every
    command in a traceback; the command that needs the extra says the reason (`studyctl.export`)."""

    def find_spec(self, name, path=None, target=None):
        if name not in OPTIONAL_EXTRAS:
            return None
        finders = [f for f in sys.meta_path if f is not self and hasattr(f, "find_spec")]
        spec = next((s for f in finders if (s := f.find_spec(name, path, target)) is not None), None)
        if spec is not None and spec.loader is not None and hasattr(spec.loader, "exec_module"):
            run = spec.loader.exec_module

            def exec_module(module):
                try:
                    run(module)
                except OSError as exc:
                    raise ImportError(str(exc), name=name) from exc

            spec.loader.exec_module = exec_module  # this module's loader only: its other methods kept
        return spec
