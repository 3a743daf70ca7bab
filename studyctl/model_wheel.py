"""A lab's model package as a wheel, with nothing but the standard library (`studyctl model wheel`).

A tissue model is pure Python: its wheel is a zip of its packages and three small metadata files.
`pip install ./mymodel` builds one with setuptools, which pip fetches from the package index into
an isolated build; offline, a venv's own setuptools is too old to build one (Python 3.11's venv
has 65.5, without the `wheel` package it needs; Python 3.12's has none). This writes the wheel
from the package's pyproject.toml alone, so `pip install --no-deps` puts the model into any venv,
offline. It reads what a model package needs ([project] name, version, description,
requires-python, dependencies and entry points; the packages under `src/`, or where
[tool.setuptools.packages.find] says) and refuses anything else it cannot honour in one line."""

from __future__ import annotations

import base64
import hashlib
import re
import zipfile
from pathlib import Path

from analysis.errors import InputError
from sim.tomlfile import TomlFileError, read_toml
from studyctl.outputs import Staged

NAME = re.compile(r"^[A-Za-z0-9]([A-Za-z0-9._-]*[A-Za-z0-9])?$")
VERSION = re.compile(r"^[0-9]+(\.[0-9]+)*([a-z0-9.+-]*)$")
ENTRY_NAME = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9._-]*$")
TARGET = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*(\.[A-Za-z_][A-Za-z0-9_]*)*(:[A-Za-z_][A-Za-z0-9_]*(\.[A-Za-z_][A-Za-z0-9_]*)*)?$")
READ = ("name", "version", "description", "requires-python", "dependencies", "entry-points", "license", "readme", "authors")


def _project(folder: Path) -> tuple[dict, Path]:
    """([project] of folder/pyproject.toml, the folder its packages are in)."""
    path = folder / "pyproject.toml"
    if not path.is_file():
        raise InputError(f"{path}: no such file; a model package has a pyproject.toml (docs/models.md)")
    try:  # the project's one TOML reader: a regular file, size and depth bounded, errors with a line
        data, _ = read_toml(path)
    except TomlFileError as exc:
        raise InputError(str(exc)) from None
    project = data.get("project")
    if not isinstance(project, dict):
        raise InputError(f"{path}: project: missing; allowed: a [project] table with name and version")
    for key in ("name", "version"):
        if not isinstance(project.get(key), str):
            raise InputError(f"{path}: project.{key}: missing; allowed: a string")
    if not NAME.match(project["name"]):
        raise InputError(f"{path}: project.name: {project['name']!r} is not a distribution name; allowed: letters, digits, . _ -")
    if not VERSION.match(project["version"]):
        raise InputError(f"{path}: project.version: {project['version']!r} is not a version; allowed: e.g. 0.1.0")
    unknown = sorted(set(project) - set(READ))
    if unknown:
        raise InputError(f"{path}: project.{unknown[0]}: not read by this builder; allowed: {', '.join(READ)} "
                         "(or build with `pip wheel` where setuptools can be fetched)")
    _check_types(path, project)
    find = data.get("tool", {}).get("setuptools", {}).get("packages", {}).get("find", {})
    where = find.get("where", ["src"] if (folder / "src").is_dir() else ["."])
    if not (isinstance(where, list) and len(where) == 1 and isinstance(where[0], str)):
        raise InputError(f"{path}: tool.setuptools.packages.find.where: {where!r}; allowed: one folder, e.g. [\"src\"]")
    return project, folder / where[0]


def _one_line(value, empty: bool = False) -> bool:
    # a line break or other control character would end a METADATA or entry_points.txt line early
    return (isinstance(value, str) and (empty or value.strip() != "")
            and not any(c < " " or c == "\x7f" for c in value))


def _check_types(path: Path, project: dict) -> None:
    """What the wheel's metadata files are written from: each of the type it must have, or one line."""
    for key in ("description", "requires-python"):
        if key in project and not _one_line(project[key], empty=key == "description"):
            raise InputError(f"{path}: project.{key}: {project[key]!r}; allowed: one line of text")
    deps = project.get("dependencies", [])
    if not isinstance(deps, list):
        raise InputError(f"{path}: project.dependencies: {deps!r} is not a list; allowed: a list of strings, e.g. [\"numpy>=1.24\"]")
    for i, dep in enumerate(deps):
        if not _one_line(dep):
            raise InputError(f"{path}: project.dependencies[{i}]: {dep!r}; allowed: a requirement, one line of text, e.g. \"numpy>=1.24\"")
    groups = project.get("entry-points", {})
    if not isinstance(groups, dict):
        raise InputError(f"{path}: project.entry-points: {groups!r} is not a table; allowed: tables of name = \"package:Class\"")
    for group, table in groups.items():
        if not ENTRY_NAME.match(group):
            raise InputError(f"{path}: project.entry-points: group {group!r}; allowed: letters, digits, . _ -, e.g. \"brainsim.models\"")
        if not isinstance(table, dict):
            raise InputError(f"{path}: project.entry-points.\"{group}\": {table!r} is not a table; "
                             "allowed: a table of name = \"package:Class\", e.g. mymodel = \"mypackage:MyModel\"")
        for name, target in table.items():
            if not ENTRY_NAME.match(name):
                raise InputError(f"{path}: project.entry-points.\"{group}\": name {name!r}; allowed: letters, digits, . _ -")
            if not (isinstance(target, str) and TARGET.match(target)):
                raise InputError(f"{path}: project.entry-points.\"{group}\".{name}: {target!r}; "
                                 "allowed: a string \"package.module:Class\", e.g. \"mypackage:MyModel\"")


def _packages(root: Path) -> list[Path]:
    """The top-level packages under `root` (folders with an __init__.py)."""
    return sorted(p for p in root.iterdir() if p.is_dir() and (p / "__init__.py").is_file()) if root.is_dir() else []


def _metadata(project: dict) -> str:
    lines = ["Metadata-Version: 2.1", f"Name: {project['name']}", f"Version: {project['version']}"]
    if isinstance(project.get("description"), str):
        lines.append(f"Summary: {project['description']}")
    if isinstance(project.get("requires-python"), str):
        lines.append(f"Requires-Python: {project['requires-python']}")
    lines += [f"Requires-Dist: {d}" for d in project.get("dependencies", [])]
    return "\n".join(lines) + "\n"


def _entry_points(project: dict) -> str:
    out = []
    for group, table in (project.get("entry-points") or {}).items():
        out.append(f"[{group}]")
        out += [f"{name} = {target}" for name, target in table.items()]
        out.append("")
    return "\n".join(out)


def _record_line(name: str, data: bytes) -> str:
    digest = base64.urlsafe_b64encode(hashlib.sha256(data).digest()).rstrip(b"=").decode()
    return f"{name},sha256={digest},{len(data)}"


def build_wheel(folder: str | Path, out_dir: str | Path, force: bool = False) -> Staged:
    """The wheel of the model package in `folder`, written into `out_dir` (whole or not at all;
    an existing wheel of that name replaced only with `force`): its written output (`.target`,
    `.replaced`). Raises InputError, or OutputExists / OutputFailed."""
    folder, out_dir = Path(folder), Path(out_dir)
    project, root = _project(folder)
    packages = _packages(root)
    if not packages:
        raise InputError(f"{root}: no package (a folder with an __init__.py); allowed: the layout of docs/models.md, src/PACKAGE/__init__.py")
    if "brainsim.models" not in (project.get("entry-points") or {}):
        raise InputError(f"{folder / 'pyproject.toml'}: project.entry-points.\"brainsim.models\": missing; "
                         "allowed: a table naming the model's class, e.g. mymodel = \"mypackage:MyModel\"")
    dist = re.sub(r"[-_.]+", "_", project["name"]).lower()
    info = f"{dist}-{project['version']}.dist-info"
    files: list[tuple[str, bytes]] = []
    for pkg in packages:
        for f in sorted(pkg.rglob("*")):
            if f.is_file() and "__pycache__" not in f.parts and f.suffix not in (".pyc", ".pyo"):
                files.append((f.relative_to(root).as_posix(), f.read_bytes()))
    files += [(f"{info}/METADATA", _metadata(project).encode()),
              (f"{info}/WHEEL", b"Wheel-Version: 1.0\nGenerator: studyctl model wheel\nRoot-Is-Purelib: true\nTag: py3-none-any\n"),
              (f"{info}/entry_points.txt", _entry_points(project).encode())]
    record = "\n".join([*(_record_line(n, d) for n, d in files), f"{info}/RECORD,,"]) + "\n"
    files.append((f"{info}/RECORD", record.encode()))
    wheel = out_dir / f"{dist}-{project['version']}-py3-none-any.whl"
    out = Staged(wheel, force)
    with out as part, zipfile.ZipFile(part, "w", zipfile.ZIP_DEFLATED) as z:
        for name, data in files:
            z.writestr(name, data)
    return out
