"""The house's rules, as the design states them (docs/architecture.md): three packages in layers
that run one way, folders small enough to read by concept, imports at the top, no cycles, SQL
only in the store."""

import ast
import builtins
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
# bottom to top: a package imports only those before it
LAYERS = ("sim", "analysis", "studyctl")
SUBPACKAGES = ("sim/devices", "sim/geometry", "sim/models", "sim/models/fem", "sim/servo", "sim/view", "analysis/discrimination",
               "analysis/reports", "analysis/statistics", "analysis/study", "analysis/validity", "analysis/verification", "studyctl/cli", "studyctl/session", "studyctl/store", "studyctl/synthetic")


def _imports(path: Path) -> set[str]:
    """Top-level packages a module imports, anywhere in it (inside functions too)."""
    out = set()
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            out |= {a.name.split(".")[0] for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            out.add(node.module.split(".")[0])
    return out


def _modules_imported(path: Path) -> set[str]:
    """The full names of the modules a module imports, anywhere in it."""
    out = set()
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            out |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            out |= {node.module} | {f"{node.module}.{a.name}" for a in node.names}
    return out


def test_statistics_and_verification_return_data_and_never_format():
    """Every table, sentence, page and figure lives in analysis/reports: the statistics and the
    models' verification return data and import nothing from it."""
    offenders = {}
    for p in sorted((ROOT / "analysis").rglob("*.py")):
        if p.is_relative_to(ROOT / "analysis" / "reports"):
            continue
        hits = sorted(m for m in _modules_imported(p) if m == "analysis.reports" or m.startswith("analysis.reports."))
        if hits:
            offenders[str(p.relative_to(ROOT))] = hits
    assert offenders == {}


@pytest.mark.parametrize("level", range(len(LAYERS)))
def test_a_package_imports_only_the_layers_below_it(level):
    """sim runs, ships and is tested alone; analysis (the statistics of studies, the verification of
    models) reads sim only; studyctl (the study, the store, the synthetic participants, the CLI) is on top."""
    pkg, above = LAYERS[level], set(LAYERS[level + 1:])
    files = sorted((ROOT / pkg).rglob("*.py"))
    offenders = {str(p.relative_to(ROOT)): sorted(_imports(p) & above) for p in files}
    assert len(files) > 40
    assert {k: v for k, v in offenders.items() if v} == {}


def test_no_folder_holds_more_than_20_modules():
    """A folder past 20 modules holds several concepts: each gets its sub-package."""
    counts = {str(d.relative_to(ROOT)): sum(1 for p in d.glob("*.py") if p.name != "__init__.py")
              for pkg in LAYERS for d in [ROOT / pkg, *(ROOT / pkg).rglob("*")] if d.is_dir() and d.name != "__pycache__"}
    assert len(counts) >= len(LAYERS) + len(SUBPACKAGES)
    assert {k: v for k, v in counts.items() if v > 20} == {}


@pytest.mark.parametrize("sub", SUBPACKAGES)
def test_each_sub_package_says_what_lives_in_it(sub):
    """Its `__init__` names what the folder holds and what it may import (a few lines, no code)."""
    init = ROOT / sub / "__init__.py"
    doc = ast.get_docstring(ast.parse(init.read_text()))
    assert doc is not None, sub
    assert len(doc.splitlines()) >= 2, sub
    assert "Imports:" in doc, sub  # what it may import


def _in_function_imports() -> list[str]:
    found = []
    for pkg in LAYERS:
        for p in sorted((ROOT / pkg).rglob("*.py")):
            if p.is_relative_to(ROOT / "studyctl" / "cli"):
                continue
            tree = ast.parse(p.read_text(), filename=str(p))
            for fn in ast.walk(tree):
                if isinstance(fn, (ast.FunctionDef, ast.AsyncFunctionDef)):
                    found += [f"{p.relative_to(ROOT)}:{n.lineno}" for n in ast.walk(fn) if isinstance(n, (ast.Import, ast.ImportFrom))]
    return sorted(set(found))


def test_imports_sit_at_the_top_outside_the_cli():
    """An import inside a function hides a dependency; the few left load an optional or slow
    dependency only where it is used, each with its reason on its line."""
    found = _in_function_imports()
    assert len(found) <= 15, found


def test_no_issue_number_in_the_code():
    """Issue numbers go stale in code; the changelog and the docs keep them."""
    pattern = re.compile(r"\b[Ii]ssues? #?\d+")
    found = [f"{p.relative_to(ROOT)}:{k}" for pkg in LAYERS for p in sorted((ROOT / pkg).rglob("*.py"))
             for k, line in enumerate(p.read_text().splitlines(), 1) if pattern.search(line)]
    assert found == []


def _module_graph() -> tuple[list[str], dict[str, set[str]]]:
    """The project's modules and who imports whom, function-level imports included (`from a
    import b` counts a.b where that is a module)."""
    files = {}
    for pkg in ("sim", "studyctl", "analysis"):
        for p in sorted((ROOT / pkg).rglob("*.py")):
            parts = p.relative_to(ROOT).with_suffix("").parts
            files[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = p

    def resolve(name: str) -> str | None:
        while name and name not in files:
            name = name.rpartition(".")[0]
        return name or None

    edges: dict[str, set[str]] = {m: set() for m in files}
    for mod, path in files.items():
        for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
            if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                targets = {resolve(f"{node.module}.{a.name}") or resolve(node.module) for a in node.names}
            elif isinstance(node, ast.Import):
                targets = {resolve(a.name) for a in node.names}
            else:
                continue
            edges[mod] |= {t for t in targets if t and t != mod}
    return list(files), edges


def test_no_import_cycles_between_the_projects_modules():
    """Strongly connected components of the import graph (scipy), function-level imports
    included: an import inside a function hides a cycle from Python, not from the design. The
    CLI's commands may import each other (they are one program's entry points)."""
    import numpy as np
    from scipy.sparse import csr_matrix
    from scipy.sparse.csgraph import connected_components

    mods, edges = _module_graph()
    index = {m: i for i, m in enumerate(mods)}
    pairs = [(index[a], index[b]) for a, bs in edges.items() for b in bs]
    graph = csr_matrix((np.ones(len(pairs)), tuple(zip(*pairs))), shape=(len(mods), len(mods)))
    _, label = connected_components(graph, directed=True, connection="strong")
    groups: dict[int, list[str]] = {}
    for m, lab in zip(mods, label):
        groups.setdefault(int(lab), []).append(m)
    cycles = {tuple(sorted(g)) for g in groups.values() if len(g) > 1 and not all(m.startswith("studyctl.cli") for m in g)}
    assert len(mods) > 120
    assert edges["studyctl.protocol"] >= {"studyctl.fields", "studyctl.text"}
    assert cycles == set()


def test_no_private_name_is_imported_from_another_package():
    """A leading underscore is a module's own: another package uses its public API."""
    offenders = []
    for pkg in ("sim", "studyctl", "analysis"):
        for p in sorted((ROOT / pkg).rglob("*.py")):
            for node in ast.walk(ast.parse(p.read_text(), filename=str(p))):
                if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                    top = node.module.split(".")[0]
                    if top in ("sim", "studyctl", "analysis") and top != pkg:
                        offenders += [f"{p.relative_to(ROOT)}:{node.lineno} {node.module}.{a.name}" for a in node.names if a.name.startswith("_")]
    assert offenders == []


def test_no_module_is_over_600_lines():
    """A module past 600 lines holds more than one concept (issue 45): split it by concept."""
    sizes = {str(p.relative_to(ROOT)): p.read_text().count("\n") for pkg in ("sim", "studyctl", "analysis") for p in (ROOT / pkg).rglob("*.py")}
    assert len(sizes) > 120
    assert {k: v for k, v in sizes.items() if v > 600} == {}


SQL = re.compile(r"^\s*(select\s.+\sfrom\s|insert\s+(or\s+\w+\s+)?into\s|update\s+\w+\s+set\s|delete\s+from\s|create\s+(table|index)\s)",
                 re.I | re.S)


def test_only_the_store_layer_writes_sql():
    """The study library and the reports call studyctl/store/'s functions (issue 45): a string
    that starts an SQL statement anywhere else is a query that has lost its home."""
    found = []
    for pkg in ("sim", "studyctl", "analysis"):
        for p in sorted((ROOT / pkg).rglob("*.py")):
            if p.is_relative_to(ROOT / "studyctl" / "store"):
                continue
            for node in ast.walk(ast.parse(p.read_text(), filename=str(p))):
                if isinstance(node, ast.Constant) and isinstance(node.value, str) and SQL.match(node.value):
                    found.append(f"{p.relative_to(ROOT)}:{node.lineno}")
    in_store = sum(1 for p in (ROOT / "studyctl" / "store").rglob("*.py")
                   for node in ast.walk(ast.parse(p.read_text())) if isinstance(node, ast.Constant) and isinstance(node.value, str)
                   and SQL.match(node.value))
    assert found == []  # the check sees the store's own statements
    assert in_store > 100


def test_every_function_has_a_caller_outside_the_tests():
    """No dead code (issue 66): every function and method defined in the packages, the benches and
    the scripts is named somewhere else in them (a call, a reference, a string naming it for a
    registry, an entry point in pyproject.toml); what only tests use lives in tests/. Dunder
    methods and decorated functions (commands, properties, numba kernels) are reached by their
    framework."""
    roots = ("sim", "studyctl", "analysis", "bench", "brainsim_assets", "scripts")
    named: set[str] = set(re.findall(r"[A-Za-z_]\w*", (ROOT / "pyproject.toml").read_text()))
    defs = []
    for p in sorted(q for r in roots for q in (ROOT / r).rglob("*.py")):
        tree = ast.parse(p.read_text(), filename=str(p))
        docstrings = {id(n.body[0].value) for n in ast.walk(tree)  # a docstring naming a function does not call it
                      if isinstance(n, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)) and n.body
                      and isinstance(n.body[0], ast.Expr) and isinstance(n.body[0].value, ast.Constant)}
        for node in ast.walk(tree):
            if isinstance(node, ast.Constant) and id(node) in docstrings:
                continue
            if isinstance(node, ast.Name):
                named.add(node.id)
            elif isinstance(node, ast.Attribute):
                named.add(node.attr)
            elif isinstance(node, ast.Constant) and isinstance(node.value, str):
                named |= set(re.findall(r"[A-Za-z_]\w*", node.value))
            elif isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) and not node.decorator_list and not node.name.startswith("__"):
                defs.append((node.name, f"{p.relative_to(ROOT)}:{node.lineno}"))
    assert len(defs) > 1000
    assert sorted(where + " " + name for name, where in defs if name not in named) == []


def test_the_papers_figures_are_typed_once_in_data():
    """The seed paper's deformation times live in data/paper_deformation_time_ms.csv alone
    (`analysis.verification.paper` reads it); no module types them again."""
    from analysis.verification.paper import deformation_ms

    times = deformation_ms()
    assert list(times) == ["plate_spring", "fem", "mass_spring"]
    typed = re.compile("|".join(re.escape(f"{ms:.2f}") for ms in times.values()))
    files = [p for r in ("sim", "studyctl", "analysis", "bench", "scripts") for p in (ROOT / r).rglob("*.py")]
    assert [str(p.relative_to(ROOT)) for p in files if typed.search(p.read_text())] == []


def test_every_library_error_is_under_the_two_bases():
    """One vocabulary of errors (issue 66): every exception class the libraries define derives
    from sim.errors.SimError or analysis.errors.StudyError, so the CLI turns each into one line in
    one place (studyctl/cli/common.py); only the CLI's own click exceptions stand apart."""
    bases: dict[str, list[str]] = {}
    where: dict[str, str] = {}
    for p in sorted(q for r in ("sim", "analysis", "studyctl") for q in (ROOT / r).rglob("*.py")):
        for node in ast.walk(ast.parse(p.read_text(), filename=str(p))):
            if isinstance(node, ast.ClassDef):
                names = [b.attr if isinstance(b, ast.Attribute) else getattr(b, "id", "") for b in node.bases]
                bases[node.name], where[node.name] = names, str(p.relative_to(ROOT))

    def roots(name: str, seen=()) -> set[str]:
        if name in ("SimError", "StudyError") or name not in bases or name in seen:
            return {name}
        return set().union(*(roots(b, (*seen, name)) for b in bases[name])) if bases[name] else {name}

    # an exception's root outside the project: a built-in (KeyboardInterrupt and warnings too), or a
    # library's (sqlite3.Error, click's exceptions), by the name it is written with
    builtin = {n for n, v in vars(builtins).items() if isinstance(v, type) and issubclass(v, BaseException)}
    foreign = {r for n in bases for r in roots(n) if r not in bases and r.endswith(("Error", "Exception", "Warning", "Interrupt"))}
    errors = {n for n in bases if roots(n) & (builtin | foreign | {"SimError", "StudyError"})}
    assert len(errors) > 25
    stray = sorted(f"{where[n]} {n}" for n in errors if not roots(n) & {"SimError", "StudyError"} and "ClickException" not in roots(n))
    assert stray == []


def test_no_question_or_field_kind_is_compared_as_a_string():
    """Question kinds and participant-field kinds are enums (analysis.study.questions.Kind,
    analysis.study.fields.FieldKind): a kind is compared with a member, never with its name typed
    again. (A model's option kinds are the plugin API's own words, in sim/models/api.py.)"""
    from analysis.study.fields import FieldKind
    from analysis.study.questions import Kind

    names = {k.value for k in Kind} | {k.value for k in FieldKind}

    def is_kind(node) -> bool:
        return (isinstance(node, ast.Attribute) and node.attr == "kind") or (isinstance(node, ast.Name) and node.id == "kind")

    def typed(node) -> bool:
        if isinstance(node, ast.Constant):
            return node.value in names
        return isinstance(node, (ast.Tuple, ast.List, ast.Set)) and any(typed(e) for e in node.elts)

    found = []
    for pkg in ("analysis", "studyctl", "bench", "scripts"):
        for p in sorted((ROOT / pkg).rglob("*.py")):
            for node in ast.walk(ast.parse(p.read_text(), filename=str(p))):
                if isinstance(node, ast.Compare):
                    sides = [node.left, *node.comparators]
                    if any(is_kind(x) for x in sides) and any(typed(x) for x in sides):
                        found.append(f"{p.relative_to(ROOT)}:{node.lineno}")
    assert found == []

