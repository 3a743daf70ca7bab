"""The wheel as a user installs it: built from the repository, installed into a new venv, run
from a folder outside the checkout. It must carry the brain, the scene, the protocol, the model
files, the field and the observer's truth (brainsim_assets), and declare every third-party
module it imports (pyproject.toml's dependencies and, recursively, theirs)."""

import ast
import importlib.metadata
import json
import os
import shutil
import subprocess
import sys
import tomllib
import zipfile
from pathlib import Path

import pytest
from packaging.requirements import Requirement
from packaging.utils import canonicalize_name

from studyctl.cli.reports import report_table1
from tests.conftest import ROOT
from tests.helpers import build_wheel

PACKAGES = ("sim", "analysis", "studyctl", "brainsim_assets")
# modules imported only behind a guard (inside the function that needs them, checked first): each an extra's
OPTIONAL = {"pyarrow": "parquet", "distributed": "dask"}
# pytetwild imports PyVista only to register an accessor; sim/geometry/tetmesh.py stubs that where PyVista is absent
STUBBED = {"pyvista"}
TABLE1_FORMATS = next(p for p in report_table1.params if p.name == "fmt").type.choices


# -- the declared dependencies, as installed here -----------------------------------------------

def _wanted(lines, extras=()) -> list[Requirement]:
    """The requirements of `lines` (Requires-Dist) that apply here, those of an extra only when asked."""
    out = []
    for line in lines:
        req = Requirement(line)
        if req.marker is None or any(req.marker.evaluate({"extra": e}) for e in ("", *extras)):
            out.append(req)
    return out


def closure(requires) -> dict[str, importlib.metadata.Distribution]:
    """The distributions named in `requires` (Requires-Dist lines, extras excluded) and,
    recursively, theirs, as installed in this venv: {canonical name: distribution}."""
    found: dict = {}
    done: set = set()
    todo = _wanted(requires)
    while todo:
        req = todo.pop()
        name = canonicalize_name(req.name)
        if (name, frozenset(req.extras)) in done:
            continue
        done.add((name, frozenset(req.extras)))
        found[name] = importlib.metadata.distribution(req.name)
        todo += _wanted(found[name].requires or [], sorted(req.extras))
    return found


def declared() -> tuple[list[str], dict[str, list[str]]]:
    """pyproject.toml's dependencies and its extras' ({extra: requirements})."""
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    return project["dependencies"], project.get("optional-dependencies", {})


def wheel_requires(wheel: Path) -> list[str]:
    """The wheel's Requires-Dist lines (its METADATA)."""
    with zipfile.ZipFile(wheel) as z:
        meta = next(n for n in z.namelist() if n.endswith(".dist-info/METADATA"))
        text = z.read(meta).decode()
    return [line.split(":", 1)[1].strip() for line in text.splitlines() if line.startswith("Requires-Dist:")]


def top_level(dist) -> set[str]:
    """What a distribution puts at the top of site-packages: its packages, modules, .libs
    folders, extension modules and its .dist-info."""
    return {Path(f).parts[0] for f in dist.files or [] if Path(f).parts and Path(f).parts[0] not in ("..", "__pycache__")}


def closure_venv(venv: Path, requires: list[str], wheel: Path | None = None) -> None:
    """A new venv that sees exactly the distributions of `requires`' closure (this venv's files,
    linked into one folder a path file names): what a user's install of them holds, no more;
    then `wheel`, without its dependencies (no download, no build of scikit-sparse)."""
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True)
    deps = venv / "closure"
    deps.mkdir()
    for dist in closure(requires).values():
        for name in top_level(dist):
            if not (deps / name).exists():
                (deps / name).symlink_to(dist.locate_file(name))
    site = subprocess.run([str(venv / "bin/python"), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                          check=True, capture_output=True, text=True).stdout.strip()
    Path(site, "closure.pth").write_text(f"{deps}\n")
    if wheel is not None:  # this venv's pip, installing into the new one
        subprocess.run([sys.executable, "-m", "pip", "--python", str(venv / "bin/python"), "install", "-q", "--no-deps", str(wheel)],
                       check=True, capture_output=True)


def run_as_a_user(venv: Path, cwd: Path) -> dict:
    """The issue's commands, from `cwd`, with the venv's own `studyctl` and Python (PYTHONPATH unset)."""
    bin_ = venv / "bin"
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "STUDYCTL_DB")}

    def run(*args, codes=(0,)):
        res = subprocess.run([str(a) for a in args], cwd=cwd, env=env, capture_output=True, text=True, timeout=600)
        assert res.returncode in codes and "Traceback" not in res.stderr, f"{args}: exit {res.returncode}: {res.stdout[-2000:]}{res.stderr[-3000:]}"
        return res.stdout

    studyctl = bin_ / "studyctl"
    out = {"help": run(studyctl, "-h"), "version": run(bin_ / "python", "-m", "studyctl", "--version")}
    out["sim"] = json.loads(run(studyctl, "sim", "run", "--time-scale", "0", "--duration", "0.5", "--json"))
    # exit 1 when this machine misses a time budget (a loaded machine): the contract's checks are what is judged
    out["contract"] = json.loads(run(studyctl, "model", "check", "fem", "--contract", "--json", codes=(0, 1)))
    out["init"] = run(studyctl, "study", "init", "--db", cwd / "study.db")  # the shipped protocol, installed
    out["synth"] = json.loads(run(studyctl, "synth", "--db", cwd / "study.db", "--participants", "2", "--json"))
    out["table1"] = {}
    for fmt in TABLE1_FORMATS:
        run(studyctl, "report", "table1", "--db", cwd / "study.db", "--format", fmt, "--out", cwd / f"table1.{fmt}")
        out["table1"][fmt] = (cwd / f"table1.{fmt}").read_text()
    out["text"] = run(studyctl, "report", "text", "--db", cwd / "study.db")
    out["stats"] = json.loads(run(studyctl, "report", "stats", "--db", cwd / "study.db", "--json"))
    out["published"] = json.loads(run(studyctl, "report", "published", "--json"))
    out["where"] = run(bin_ / "python", "-c", "import brainsim_assets, studyctl; print(brainsim_assets.root()); print(studyctl.__file__)")
    return out


def _check(out: dict, venv: Path) -> None:
    assert "Usage: studyctl" in out["help"]
    assert "--help" in out["help"]
    assert out["version"].strip().startswith("studyctl, version ")
    assert out["sim"]["ticks"] == 500
    assert out["sim"]["scene"] == "brain_pull"
    assert [c["check"] for c in out["contract"]["contract"] if not c["ok"]] == []
    assert out["synth"]["participants"] == 2
    assert out["synth"]["synthetic"] is True
    assert sorted(out["table1"]) == sorted(TABLE1_FORMATS)
    assert all("SYNTHETIC DATA" in text for fmt, text in out["table1"].items() if fmt != "csv")
    assert out["table1"]["csv"].splitlines()[0].endswith(",synthetic")  # a column, each row True
    assert json.loads(out["table1"]["json"])
    assert "\\begin{" in out["table1"]["latex"]
    assert out["text"].startswith("## Participants")
    assert "SYNTHETIC DATA" in out["text"]
    assert out["stats"]["facts"]["participants"] == 2
    assert len(out["published"]["flags"]) == 1
    assert "bounds" in out["published"]
    # everything came from the venv, nothing from the checkout
    assert str(ROOT) not in out["where"]
    assert all(str(venv) in line for line in out["where"].split())


def test_the_wheel_runs_every_command_from_its_declared_dependencies_outside_the_repository(tmp_path):
    """Installed (no dependencies) into a new venv that sees only the distributions the wheel
    declares and theirs (this venv's files, linked), not the checkout: a module only a
    development tool brought in (jinja2, once) is missing there as for a user."""
    wheel = build_wheel(tmp_path)
    venv = tmp_path / "venv"
    closure_venv(venv, wheel_requires(wheel), wheel)
    outside = tmp_path / "elsewhere"
    outside.mkdir()
    _check(run_as_a_user(venv, outside), venv)


# -- every third-party module the package imports is declared ------------------------------------

def import_statements() -> dict[str, list[str]]:
    """Every import of a module outside the standard library and the project, in every module of
    the package (inside functions too), as a statement that repeats it: {statement: [file:line]}."""
    out: dict = {}
    for pkg in PACKAGES:
        for path in sorted((ROOT / pkg).rglob("*.py")):
            for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
                if isinstance(node, ast.Import):
                    stmts = [f"import {a.name}" for a in node.names]
                elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                    stmts = [f"from {node.module} import {a.name}" for a in node.names]
                else:
                    continue
                for stmt in stmts:
                    top = stmt.split()[1].split(".")[0]
                    if top not in sys.stdlib_module_names and top not in PACKAGES:
                        out.setdefault(stmt, []).append(f"{path.relative_to(ROOT)}:{node.lineno}")
    return out


PROBE = """
import json, sys
failed = {}
for stmt in json.loads(sys.argv[1]):
    try:
        exec(stmt, {})
    except ImportError as exc:  # pandas' optional dependencies raise it with the name in the message only
        failed[stmt] = [exc.name or "", str(exc).splitlines()[0] if str(exc) else type(exc).__name__]
print(json.dumps(failed))
"""


def undeclared(requires: list[str], extras: dict[str, list[str]], tmp: Path) -> list[str]:
    """What the package imports that the declared distributions do not provide, each named with
    the import that needs it: every top-level module it names must belong
    (`packages_distributions`) to one of `requires` or, recursively, theirs (a module in OPTIONAL:
    or its extra's); and every import statement must run in a venv that sees only those
    (`closure_venv`), which finds what a dependency's submodule imports beyond its own
    requirements (`from pandas.io.formats.style_render import ...` needs jinja2, which pandas
    offers only as an extra)."""
    owners = importlib.metadata.packages_distributions()
    base = set(closure(requires))
    statements = import_statements()
    problems = []
    for module in sorted({s.split()[1].split(".")[0] for s in statements}):
        allowed = base | set(closure(extras[OPTIONAL[module]])) if module in OPTIONAL else base
        dists = {canonicalize_name(d) for d in owners.get(module, [])}
        if not dists & allowed:
            where = statements[next(s for s in sorted(statements) if s.split()[1].split(".")[0] == module)][0]
            problems.append(f"{module} ({where}): from {', '.join(sorted(dists)) or 'no installed distribution'}, "
                            "not a declared dependency nor one of theirs")
    closure_venv(tmp, requires)
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    run = [s for s in sorted(statements) if s.split()[1].split(".")[0] not in OPTIONAL]  # an extra's: guarded, not installed here
    res = subprocess.run([str(tmp / "bin/python"), "-c", PROBE, json.dumps(run)], capture_output=True, text=True, env=env,
                         cwd=tmp, check=True, timeout=300)
    for stmt, (name, message) in sorted(json.loads(res.stdout).items()):
        if name.split(".")[0] not in STUBBED:
            problems.append(f"{stmt} ({statements[stmt][0]}) fails where only the declared dependencies are installed: {message}")
    return problems


def test_every_third_party_module_the_package_imports_is_declared(tmp_path):
    requires, extras = declared()
    assert undeclared(requires, extras, tmp_path / "venv") == []


def test_an_undeclared_module_is_named(tmp_path):
    """The check above on a pyproject.toml without jinja2 (as it was): the module and the
    import that needs it are named."""
    requires, extras = declared()
    without = [r for r in requires if canonicalize_name(Requirement(r).name) != "jinja2"]
    assert len(without) == len(requires) - 1
    problems = undeclared(without, extras, tmp_path / "venv")
    (problem,) = problems
    assert problem.startswith("from pandas.io.formats.style_render import _escape_latex (analysis/reports/latex.py:")
    assert "Jinja2" in problem


def _python312():
    for cand in (shutil.which("python3.12"), str(Path.home() / ".pyenv/versions/3.12.1/bin/python3.12")):
        if cand and Path(cand).exists() and subprocess.run([cand, "-c", "pass"], capture_output=True).returncode == 0:
            return cand
    return None


@pytest.mark.slow
def test_the_wheel_installs_with_its_dependencies_on_python_3_12_and_runs_outside(tmp_path):
    """The whole install a user does, on Python 3.12, dependencies from the package index
    (about 2 minutes; scikit-sparse builds against the system's SuiteSparse)."""
    py312 = _python312()
    if py312 is None:
        pytest.fail("Python 3.12 is not installed (pyenv install 3.12, or the distribution's python3.12)")
    wheel = build_wheel(tmp_path)
    venv = tmp_path / "venv312"
    subprocess.run([py312, "-m", "venv", str(venv)], check=True)
    subprocess.run([str(venv / "bin/python"), "-m", "pip", "install", "-q", "--upgrade", "pip>=25.1"], check=True, capture_output=True)
    res = subprocess.run([str(venv / "bin/python"), "-m", "pip", "install", "-q", str(wheel)], capture_output=True, text=True)
    assert res.returncode == 0, res.stderr[-3000:]
    outside = tmp_path / "elsewhere"
    outside.mkdir()
    out = run_as_a_user(venv, outside)
    _check(out, venv)
    assert "python3.12" in out["where"]
